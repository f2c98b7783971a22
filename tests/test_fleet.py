"""Fleets on dask: same models as ``fonbw identify``, worker death, resume, summary.

The multi-process tests start a real scheduler and workers on 127.0.0.1 as
separate processes and always kill them (by PID) on the way out.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from fonbw.io import read_record, write_csv
from fonbw.fleet import (fit_options, identify_paths, model_bytes, read_fit, records_digest, task_seed)
from fonbw.fleet.summary import outliers, robust_z, summary_rows

FS, T = 2000.0, 2.0  # tiny records: 2 s at 2 kHz
EVALS = "60"
DASK = os.path.join(os.path.dirname(sys.executable), "dask")


def _make_fleet(root, n, start=0):
    """`n` actuators from benches with other seeds and a spread of the polynomial."""
    from fonbw.bench import Bench, BenchParams, eq19_input
    from fonbw.io import write_csv

    _, u = eq19_input(FS, T)
    for i in range(start, start + n):
        a1, a2, a3 = BenchParams().poly
        b = Bench(seed=100 + i, fs=FS, params=BenchParams(poly=(a1 * (1 + 0.04 * i), a2, a3)))
        d = root / f"act{i:02d}"
        d.mkdir(parents=True, exist_ok=True)
        r = b.record(u)
        write_csv(d / "eq19.csv", {"t": np.arange(r.n) * r.dt, "u": r.u, "y": r.y})
    return root


def _fleet(*argv):
    """``fonbw fleet`` through its own parser and run() (in this process)."""
    from fonbw.cli import fleet

    p = argparse.ArgumentParser()
    fleet.add_arguments(p)
    fleet.run(p.parse_args([str(a) for a in argv]))


def _serial_identify(paths, out):
    """``fonbw identify`` on one actuator's records, serially, with the fleet's options."""
    from fonbw.cli.main import main

    rc = main(["identify", *map(str, paths), "-o", str(out), "--max-evals", EVALS, "--seed", "0", "-q",
               "--no-holdout"])
    assert rc == 0
    return out.read_bytes()


def _assert_same_as_identify(fleet_json, paths, tmp_path):
    """Fleet model bytes equal ``fonbw identify``'s (its whole file once it writes the provenance,
    the model part until then) and the shared path's whole document."""
    got = fleet_json.read_bytes()
    ref = _serial_identify(paths, tmp_path / f"serial-{fleet_json.stem}.json")
    doc = json.loads(got)
    if "fit" in json.loads(ref):
        assert got == ref
    else:
        assert model_bytes({k: v for k, v in doc.items() if k != "fit"}) == ref
    assert got == model_bytes(identify_paths(paths, fit_options({"max_evals": int(EVALS)})).document)


# ---------------------------------------------------------------------------
# single-process checks


def test_task_seed_is_stable_and_distinct():
    assert task_seed(0, "act01") == task_seed(0, "act01")
    seeds = {task_seed(s, f"act{i}") for s in (0, 1) for i in range(50)}
    assert len(seeds) == 100 and all(0 <= s < 2**32 for s in seeds)
    # not Python's salted hash: the same in a fresh interpreter
    code = "from fonbw.fleet import task_seed; print(task_seed(7, 'x'))"
    assert int(subprocess.check_output([sys.executable, "-c", code])) == task_seed(7, "x")


def test_digest_follows_contents_and_options(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text("t,u,y\n0,0,0\n")
    b.write_text("t,u,y\n0,0,0\n")
    o = fit_options({})
    assert records_digest([a], o) == records_digest([b], o)  # contents decide, not names
    assert records_digest([a], o) != records_digest([a], {**o, "seed": 1})
    b.write_text("t,u,y\n0,0,1\n")
    assert records_digest([a], o) != records_digest([b], o)


def test_fit_options_defaults_and_checks():
    from fonbw.cli.records import CLIError

    o = fit_options(argparse.Namespace(model="nbw", seed=3, max_evals=None))
    assert o["model"] == "nbw" and o["seed"] == 3 and o["max_evals"] == 5000
    with pytest.raises(CLIError, match="max-evals"):
        fit_options({"max_evals": 5})
    with pytest.raises(CLIError, match="seed"):
        fit_options({"seed": -1})


def test_robust_z_flags_the_odd_one():
    rows = [{"actuator": f"a{i}", "status": "ok", "rms": 0.3 + 0.01 * i,
             "params": {"kh": 1.0 + 0.01 * i, "rho": 10.0 ** (-3 + 0.1 * i)}} for i in range(9)]
    rows.append({"actuator": "odd", "status": "ok", "rms": 3.0, "params": {"kh": 1.04, "rho": 1e-2}})
    rows.append({"actuator": "bad", "status": "failed: x", "rms": float("nan"), "params": {}})
    flags = outliers(rows)
    assert set(flags) == {"odd"} and set(flags["odd"]) == {"training_rms_um"}
    assert np.allclose(robust_z([1.0, 1.0, 1.0]), 0)


def _pools():
    import numba

    return (numba.config.NUMBA_NUM_THREADS, os.environ.get("OPENBLAS_NUM_THREADS"),
            os.environ.get("OMP_NUM_THREADS"))


def test_embedded_cluster_workers_run_one_thread_of_each_pool(monkeypatch):
    # two numba threads in each of two workers on two cores would contend
    # (the suite's own setting, which the workers would inherit, is removed)
    from fonbw.fleet.engine import connect

    monkeypatch.delenv("NUMBA_NUM_THREADS", raising=False)
    with connect(n_workers=1) as client:
        assert list(client.run(_pools).values()) == [(1, "1", "1")]


def test_summary_rows_of_failures_and_models():
    doc = {"kind": "fonbw", "params": {"ku": [1.0, 2.0], "kh": 3.0},
           "fit": {"records": ["a.csv"], "training_rms_um": 0.5, "warnings": []}}
    rows = summary_rows({"b": "no CSV records", "a": doc})
    assert [r["actuator"] for r in rows] == ["a", "b"]
    assert rows[0]["params"] == {"ku1": 1.0, "ku2": 2.0, "kh": 3.0}
    assert rows[1]["status"] == "failed: no CSV records"


# ---------------------------------------------------------------------------
# a scheduler and workers as separate processes


class _Cluster:
    """``dask scheduler`` and ``dask worker`` processes on 127.0.0.1, killed by PID on close."""

    def __init__(self, tmp, n_workers):
        self.file = str(tmp / "scheduler.json")
        self.procs = []
        self.log = open(tmp / "dask.log", "wb")
        self._start([DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                     "--scheduler-file", self.file])
        t0 = time.monotonic()
        while not os.path.exists(self.file):
            assert time.monotonic() - t0 < 60, "the scheduler did not start"
            time.sleep(0.2)
        self.workers = [self._start([DASK, "worker", "--scheduler-file", self.file, "--nworkers", "1",
                                     "--nthreads", "1", "--no-nanny", "--host", "127.0.0.1",
                                     "--no-dashboard"]) for _ in range(n_workers)]
        from distributed import Client

        self.client = Client(scheduler_file=self.file, timeout="30s")
        self.client.wait_for_workers(n_workers, timeout=90)

    def _start(self, cmd):
        p = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.STDOUT, cwd=os.getcwd())
        self.procs.append(p)
        return p

    def close(self):
        try:
            self.client.close()
        finally:
            for p in self.procs:
                if p.poll() is None:
                    os.kill(p.pid, signal.SIGKILL)
                    p.wait(timeout=30)
            self.log.close()


@pytest.fixture
def cluster2(tmp_path):
    c = _Cluster(tmp_path, 2)
    try:
        yield c
    finally:
        c.close()


def _files(d):
    return {p.name: p.stat().st_mtime_ns for p in d.iterdir()}


@pytest.mark.slow
def test_fleet_on_a_scheduler_matches_serial_identify(tmp_path, cluster2):
    root = _make_fleet(tmp_path / "fleet", 3)
    # one actuator with two records: pooled like fonbw identify a.csv b.csv
    (root / "act01" / "eq19.csv").rename(root / "act01" / "a.csv")
    _make_fleet(tmp_path / "extra", 1, start=7)
    (tmp_path / "extra" / "act07" / "eq19.csv").rename(root / "act01" / "b.csv")
    out = tmp_path / "out"
    _fleet(root, "-o", out, "--scheduler", cluster2.file, "--max-evals", EVALS)
    names = sorted(p.name for p in out.iterdir())
    assert names == ["act00.json", "act01.json", "act02.json", "fleet.csv", "fleet.html"]
    for a in ("act00", "act01", "act02"):
        _assert_same_as_identify(out / f"{a}.json", sorted((root / a).glob("*.csv")), tmp_path)
    lines = (out / "fleet.csv").read_text().splitlines()
    assert lines[0].startswith("actuator,kind,ku1") and len(lines) == 4
    assert lines[2].split(",")[-3:-1] == ["2", "ok"]  # act01: two records
    html = (out / "fleet.html").read_text()
    assert "data:image/png;base64," in html and "Outliers" in html


@pytest.mark.slow
def test_a_worker_killed_mid_run_still_gives_every_model_once(tmp_path, cluster2, monkeypatch):
    import fonbw.fleet.run as fr

    root = _make_fleet(tmp_path / "fleet", 5)
    out = tmp_path / "out"
    writes = []
    real = fr.write_model
    monkeypatch.setattr(fr, "write_model", lambda p, d: (writes.append(os.path.basename(p)), real(p, d)))
    pids = cluster2.client.run(os.getpid)
    victim = cluster2.workers[1].pid
    addr = next(a for a, p in pids.items() if p == victim)
    killed = {}

    def kill_when_busy():
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120:
            busy = cluster2.client.processing(workers=[addr]).get(addr, [])
            if any(str(k).startswith("fleet-identify") for k in busy):
                os.kill(victim, signal.SIGKILL)
                killed["task"] = busy
                return
            time.sleep(0.05)

    th = threading.Thread(target=kill_when_busy, daemon=True)
    th.start()
    _fleet(root, "-o", out, "--scheduler", cluster2.file, "--max-evals", "300")
    th.join(timeout=5)
    assert killed, "the worker was never seen running an identification"
    assert cluster2.workers[1].wait(timeout=10) == -signal.SIGKILL
    models = sorted(p.name for p in out.glob("*.json"))
    assert models == [f"act{i:02d}.json" for i in range(5)]
    assert sorted(writes) == models  # each written once, by the client
    assert not [p for p in out.iterdir() if p.name.startswith(".tmp-")]
    for m in models:
        assert read_fit(out / m)["fit"]["records"] == ["eq19.csv"]


@pytest.mark.slow
def test_rerun_skips_up_to_date_models_and_redoes_a_changed_one(tmp_path, capfd):
    root = _make_fleet(tmp_path / "fleet", 3)
    out = tmp_path / "out"
    _fleet(root, "-o", out, "--max-evals", EVALS, "--n-workers", "2")  # the embedded cluster
    before = _files(out)
    assert len(before) == 5
    capfd.readouterr()
    _fleet(root, "-o", out, "--max-evals", EVALS)  # nothing to do: no cluster, no file touched
    assert _files(out) == before
    assert capfd.readouterr().err.count("up to date, skipped") == 3
    rec = root / "act01" / "eq19.csv"
    r = read_record(rec)
    write_csv(rec, {"t": r.t, "u": r.u, "y": r.y + 1e-3})  # another measurement of act01
    _fleet(root, "-o", out, "--max-evals", EVALS, "--n-workers", "1")
    after = _files(out)
    changed = {k for k in after if after[k] != before[k]}
    assert "act01.json" in changed and not changed & {"act00.json", "act02.json"}
    err = capfd.readouterr().err
    assert "[1/1] act01" in err and err.count("up to date, skipped") == 2
