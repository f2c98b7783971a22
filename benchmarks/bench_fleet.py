"""Fleet identification on dask: speed-up with workers and the cost of scheduling.

Not a test. A fleet of small actuators (records of eq. (19), 2 s at 2 kHz,
from virtual benches with other noise seeds and a spread of the polynomial)
is identified with 1 and then 2 worker processes of an embedded LocalCluster,
side by side in one run. Each cluster is warmed first (one identification per
worker: imports and the compiled kernels' cache), so the figures are the
steady per-task cost a long fleet sees; the cold start is printed apart.
The scheduling overhead is the round trip of a no-op task, one at a time,
and the throughput of many no-op tasks through :func:`fonbw.fleet.map_tasks`.
The machine's load average is printed beside every figure: on a shared
machine the speed-up is only as good as the cores that are free.

On a cluster of many machines: install the same fonbw version on every
worker (``pip install fonbw==<version>``, which brings dask[distributed];
the tasks are fonbw functions sent by reference, so a different version on
a worker is a different computation), start ``dask scheduler`` on one
machine and ``dask worker tcp://SCHEDULER:8786 --nworkers N --nthreads 1``
on each (N = its cores), then run ``fonbw fleet DIR -o OUT --scheduler
tcp://SCHEDULER:8786`` (or the scheduler's ``--scheduler-file``). The
workers read the records themselves, so DIR must be the same path on every
machine (a shared filesystem: NFS, a cluster's parallel filesystem); the
client writes every model, so OUT need only be visible to the client.
Without a shared filesystem, read the records on the client and send the
arrays with :func:`fonbw.fleet.map_tasks` (items are pickled to the
workers). The cost of a fleet is its per-actuator CPU time (printed here)
times the actuators over the worker cores, plus a few ms of scheduling per
task.

Usage::

    .venv/bin/python benchmarks/bench_fleet.py [--actuators 20] [--evals 300]
        [--workers 1 2]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from fonbw.fleet import connect, fit_options, map_tasks, run_fleet  # noqa: E402
from fonbw.fleet.fit import identify_paths  # noqa: E402


def load() -> str:
    return "load %.2f %.2f %.2f" % os.getloadavg()


def make_fleet(root: Path, n: int, fs: float = 2000.0, T: float = 2.0) -> None:
    """`n` actuator folders with one record each (eq. 19, `T` s at `fs` Hz)."""
    from fonbw.bench import Bench, BenchParams, eq19_input
    from fonbw.io import write_csv

    _, u = eq19_input(fs, T)
    a1, a2, a3 = BenchParams().poly
    for i in range(n):
        b = Bench(seed=1000 + i, fs=fs, params=BenchParams(poly=(a1 * (1 + 0.01 * (i % 7)), a2, a3)))
        r = b.record(u)
        d = root / f"stage{i:03d}"
        d.mkdir(parents=True)
        write_csv(d / "eq19.csv", {"t": np.arange(r.n) * r.dt, "u": r.u, "y": r.y})


def _warm(path, options):
    """One identification on a worker: imports, compiled kernels, caches (the cold start)."""
    t0 = time.perf_counter()
    identify_paths([path], options, workers=1)
    return time.perf_counter() - t0


def _noop(x):
    return x


def overhead(client, n_serial: int = 50, n_batch: int = 400) -> tuple[float, float]:
    """Round trip of one no-op task [s] and cost per no-op task in a batch [s]."""
    client.submit(_noop, -1, pure=False).result()
    t0 = time.perf_counter()
    for i in range(n_serial):
        client.submit(_noop, i, pure=False).result()
    rt = (time.perf_counter() - t0) / n_serial
    t0 = time.perf_counter()
    assert sum(1 for _ in map_tasks(_noop, range(n_batch), client, name="noop")) == n_batch
    return rt, (time.perf_counter() - t0) / n_batch


def run(root: Path, n_workers: int, options: dict, quiet=lambda m: None) -> dict:
    """Identify the fleet at `root` on an embedded cluster of `n_workers`; timings [s]."""
    first = str(next(root.iterdir()) / "eq19.csv")
    t0 = time.perf_counter()
    with connect(None, n_workers) as client:
        startup = time.perf_counter() - t0
        cold = max(client.run(_warm, first, options).values())
        rt, per = overhead(client)
        with tempfile.TemporaryDirectory() as out:
            before = load()
            t0 = time.perf_counter()
            rep = run_fleet(root, out, options, scheduler=client, say=quiet)
            wall = time.perf_counter() - t0
    task_wall, task_cpu = np.sum(list(rep["tasks"].values()), axis=0)
    return dict(n=n_workers, startup=startup, cold=cold, wall=wall, roundtrip=rt, per_noop=per,
                task_wall=task_wall, task_cpu=task_cpu,
                load_before=before, load_after=load())


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--actuators", type=int, default=20)
    ap.add_argument("--evals", type=int, default=300, help="evaluation budget per actuator")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    a = ap.parse_args(argv)
    options = fit_options({"max_evals": a.evals})
    print(f"{a.actuators} actuators, 1 record each (eq. 19, 2 s at 2 kHz), max_evals {a.evals}; "
          f"{os.cpu_count()} cores; {load()}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "fleet"
        make_fleet(root, a.actuators)
        for n in a.workers:
            r = run(root, n, options)
            rows.append(r)
            print(f"{n} worker(s): fleet {r['wall']:.2f} s = {r['wall'] / a.actuators:.3f} s per actuator; "
                  f"cluster start {r['startup']:.1f} s, cold first task {r['cold']:.1f} s; no-op round trip "
                  f"{1e3 * r['roundtrip']:.2f} ms, batched {1e3 * r['per_noop']:.2f} ms/task; tasks got "
                  f"{r['task_cpu'] / r['task_wall']:.0%} of a core each (CPU {r['task_cpu'] / a.actuators:.3f} s "
                  f"per actuator); "
                  f"{r['load_before']} -> {r['load_after']}", flush=True)
    base = rows[0]
    for r in rows[1:]:
        print(f"speed-up {base['n']} -> {r['n']} workers: {base['wall'] / r['wall']:.2f}x wall; on free cores "
              f"(wall scaled by the share of a core the tasks got) "
              f"{base['wall'] * base['task_cpu'] / base['task_wall'] / (r['wall'] * r['task_cpu'] / r['task_wall']):.2f}x")
    task = base["task_cpu"] / a.actuators  # CPU cost of one actuator [s]
    print(f"\nestimate for 1000 actuators of this size: {1000 * task / 60:.1f} min on one worker, "
          f"{1000 * task / 64 / 60:.1f} min on 64 (scheduling {1000 * base['per_noop']:.1f} s in all)")
    ratio = (200_000 / 4000) * (5000 / a.evals)  # cost ~ samples x evaluations
    print(f"records of the paper's size (eq. 19, 20 s at 10 kHz) at the default 5000 evaluations cost about "
          f"{ratio:.0f}x more per task: {ratio * task:.0f} s, so 1000 actuators take "
          f"{1000 * ratio * task / 3600:.1f} core-hours ({1000 * ratio * task / 64 / 3600:.2f} h on 64 cores)")


if __name__ == "__main__":
    main()
