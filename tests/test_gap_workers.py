"""The diagnosis's worker processes (fonbw.gap.workers): the same results as
the candidates run in process, bit for bit, errors that arrive as they were
raised, a worker that dies reported instead of waited for, and no workers
where a process may not start them."""
import json
import multiprocessing
import os
import signal

import numpy as np
import pytest

import gap_truth as tr
from fonbw.gap import diagnose
from fonbw.gap import workers
from fonbw.gap.workers import Pool, WorkerError, default_workers

#: The fixed case: a FONBW core behind a 250-Hz amplifier.
AMPLIFIER = {"amplifier": {"f_c": 250.0, "slew": None}}


def test_map_returns_in_item_order_and_reports_each_result():
    offset = np.arange(3.0)          # a closure over an array travels with the task
    seen = []
    with Pool(2) as pool:
        out = pool.map(lambda k: (k, float(np.sum(offset * k)), os.getpid()), [3, 1, 2, 5],
                       on_result=lambda j, r: seen.append(j))
        # a second task on the same workers
        again = pool.map(lambda k: -k, [4, 6])
    assert [o[:2] for o in out] == [(3, 9.0), (1, 3.0), (2, 6.0), (5, 15.0)]
    assert os.getpid() not in {o[2] for o in out} and len({o[2] for o in out}) == 2
    assert sorted(seen) == [0, 1, 2, 3]
    assert again == [-4, -6]


def test_one_worker_runs_in_this_process():
    with Pool(1) as pool:
        assert pool.map(lambda k: os.getpid(), [1, 2]) == [os.getpid()] * 2


def test_an_error_in_a_worker_is_raised_here_as_itself():
    def _fails(k):   # nested: it travels by value, the worker need not import this module
        if k == 2:
            raise ValueError(f"record {k} has no samples")
        return k

    with Pool(2) as pool:
        with pytest.raises(ValueError, match="record 2 has no samples") as info:
            pool.map(_fails, [1, 2, 3])
        # the worker's traceback rides along as the cause
        assert "_fails" in str(info.value.__cause__)
        # the pool starts afresh after an error
        assert pool.map(_fails, [1, 3]) == [1, 3]


def test_a_worker_that_dies_is_reported_not_waited_for():
    with Pool(2) as pool:
        with pytest.raises(WorkerError, match="exit code -9"):
            pool.map(lambda k: os.kill(os.getpid(), signal.SIGKILL) if k == 1 else k, [0, 1, 2])


def test_a_worker_that_died_before_its_task_is_reported():
    # killed while idle: the pipe to it is broken when the task is sent
    with Pool(2) as pool:
        pool.start()
        victim = pool._workers[1].proc
        victim.kill()
        victim.wait()
        with pytest.raises(WorkerError, match=r"ended \(exit code -9\) before it took its task"):
            pool.map(lambda k: k, [0, 1, 2])
        # the pool starts afresh
        assert pool.map(lambda k: 2 * k, [1, 2]) == [2, 4]


def test_no_workers_in_a_daemonic_process(monkeypatch):
    monkeypatch.delenv("FONBW_WORKERS", raising=False)
    assert default_workers() == min(len(os.sched_getaffinity(0)), 4)
    monkeypatch.setenv("FONBW_WORKERS", "3")
    assert default_workers() == 3
    monkeypatch.setenv("FONBW_WORKERS", "two")
    with pytest.raises(ValueError, match="FONBW_WORKERS"):
        default_workers()
    # a Dask worker is a daemonic process: it may not have children
    monkeypatch.setattr(multiprocessing.current_process(), "_config",
                        {**multiprocessing.current_process()._config, "daemon": True})
    assert multiprocessing.current_process().daemon
    assert default_workers() == 1
    with Pool(2) as pool:
        assert pool.map(lambda k: os.getpid(), [1, 2]) == [os.getpid()] * 2


def test_a_diagnosis_on_workers_equals_the_one_in_process(monkeypatch):
    # one BLAS thread here (tests/conftest.py) and in the workers: the same
    # sums in the same order, so the same numbers to the last bit; with 15
    # refit evaluations the amplifier ends short of its fit (it leaves 0.134
    # of the nominal's misfit at the step edges and is refused), with 30 it
    # leaves 0.065
    _, train, val = tr.fixed_case(12, AMPLIFIER, scale=0.15)
    kw = dict(seed=4, budget=150, global_evals=40, refit_evals=30, effects=("creep", "amplifier", "delay"))
    started = []
    real = workers._Worker.__init__
    monkeypatch.setattr(workers._Worker, "__init__", lambda self, *a: (started.append(1), real(self, *a))[1])
    out = {}
    for w in (1, 2):
        d = diagnose(train, val, workers=w, **kw).to_dict()
        d.pop("timing")
        out[w] = d
    assert len(started) == 2      # the second diagnosis ran on two workers
    assert out[1]["verdict"]["effects"][:1] == ["amplifier"]
    assert len(out[1]["candidates"]) == 3
    assert json.dumps(out[2], sort_keys=True) == json.dumps(out[1], sort_keys=True)


def _children(pid):
    """PIDs of the processes whose parent is `pid` (from /proc)."""
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as fh:
                    stat = fh.read()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(d))
    return out


def test_ctrl_c_during_a_step_stops_the_workers_and_exits_130(tmp_path):
    from fonbw.io import write_csv
    from test_cli import _popen, _wait_for

    _, train, val = tr.fixed_case(12, AMPLIFIER, scale=0.15)
    args = ["diagnose", "--json", tmp_path / "out.json", "--workers", "2", "--progress", "--budget", "100"]
    for kind, recs in (("train", train), ("validate", val)):
        for i, rec in enumerate(recs):
            write_csv(tmp_path / f"{kind}{i}.csv", {"t": rec.t, "u": rec.u, "y": rec.y})
            args += [f"--{kind}", tmp_path / f"{kind}{i}.csv"]
    (tmp_path / "out.json").write_text('{"previous": "result"}\n')
    # while the workers still import (they start with the diagnosis), and mid-step
    for when in (r"nominal fitted", r"step 1: \+\w+"):
        p = _popen(args, env={**os.environ, "FONBW_WORKERS": "1"}, new_session=True)
        seen = _wait_for(p, when)
        kids = _children(p.pid)
        assert len(kids) == 2
        os.killpg(p.pid, signal.SIGINT)     # what Ctrl-C at a terminal does: the whole job
        out, err = p.communicate(timeout=300)
        code, err = p.returncode, seen.decode() + err.decode()
        assert code == 130 and "Traceback" not in err, err
        assert "fonbw diagnose: interrupted" in err
        assert (tmp_path / "out.json").read_text() == '{"previous": "result"}\n'
        for k in kids:   # stopped and reaped, not left running
            assert not os.path.exists(f"/proc/{k}")
