"""Identify a fleet of actuators: one task per actuator, models written as they arrive.

The client finds the actuators, decides which models are stale, submits one
identification per stale actuator (:func:`fit_actuator`, run on a worker)
and writes each model itself as its result arrives, atomically and once:
workers never write, so a task re-run after its worker died cannot leave a
second or half-written copy.
"""
from __future__ import annotations

import os
import sys
import time

from .fit import identify_paths, read_fit, records_digest, write_model

__all__ = ["find_actuators", "fit_actuator", "run_fleet", "FleetError"]


class FleetError(RuntimeError):
    """Some actuators could not be identified (the others were written)."""


def find_actuators(root) -> dict:
    """``{actuator: [record paths]}``: every visible sub-folder of `root` and its CSV files, sorted.

    A sub-folder without CSV files maps to an empty list.
    """
    root = os.fspath(root)
    if not os.path.isdir(root):
        raise FileNotFoundError(f"{root}: not a folder of actuator sub-folders")
    out = {}
    for name in sorted(os.listdir(root)):
        d = os.path.join(root, name)
        if name.startswith(".") or not os.path.isdir(d):
            continue
        out[name] = sorted(os.path.join(d, f) for f in os.listdir(d)
                           if f.lower().endswith(".csv") and not f.startswith(".")
                           and os.path.isfile(os.path.join(d, f)))
    return out


def fit_actuator(task):
    """Identify one actuator on a worker (the task function).

    Parameters
    ----------
    task : tuple
        ``(actuator, record paths, fit options)``; the paths must be readable
        on the worker (a shared filesystem on a cluster of machines).

    Returns
    -------
    dict
        ``{"document": model document, "seconds": wall time [s], "cpu_seconds":
        CPU time of the worker process [s], "host": name}``
        or ``{"error": one-line reason, ...}`` for bad records (a fault in the
        data is reported, not retried).
    """
    import socket

    from ..io import DataError

    name, paths, options = task
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        # one numba thread: the cluster's parallelism is across actuators,
        # one single-threaded worker per core; the result does not depend on it
        fit = identify_paths(paths, options, workers=1)
        out = {"document": fit.document}
    except (DataError, ValueError, RuntimeError) as exc:
        out = {"error": " ".join(str(exc).split()) or type(exc).__name__}
    out.update(seconds=time.perf_counter() - t0, cpu_seconds=time.process_time() - c0,
               host=socket.gethostname())
    return out


def _plan(actuators, out_dir, options):
    """Split the actuators into up-to-date ones (``{name: document}``) and tasks to run."""
    done, todo, empty = {}, [], {}
    for name, paths in actuators.items():
        if not paths:
            empty[name] = "no CSV records in the folder"
            continue
        doc = read_fit(os.path.join(out_dir, f"{name}.json"))
        if doc is not None and doc["fit"].get("digest") == records_digest(paths, options):
            done[name] = doc
        else:
            todo.append((name, paths, options))
    return done, todo, empty


def _say(msg):
    print(msg, file=sys.stderr, flush=True)


def run_fleet(root, out_dir, options, *, scheduler=None, n_workers=None, say=_say) -> dict:
    """Identify every actuator of `root` whose model in `out_dir` is missing or stale.

    Parameters
    ----------
    root : path-like
        One sub-folder of records per actuator.
    out_dir : path-like
        Gets ``<actuator>.json``, ``fleet.csv`` and ``fleet.html`` (created if needed).
    options : dict
        :func:`fonbw.fleet.fit.fit_options` output, the same for every actuator.
    scheduler : str or distributed.Client, optional
        See :func:`fonbw.fleet.engine.connect`; no cluster is started when
        every model is up to date.
    n_workers : int, optional
        Worker processes of the embedded cluster (default: one per core).
    say : callable
        Where progress lines go (stderr).

    Returns
    -------
    dict
        ``identified``, ``skipped``, ``failed`` (lists of actuator names),
        ``written`` (every path written) and ``tasks`` (``{actuator: (wall
        [s], CPU [s])}`` of each task on its worker).

    Raises
    ------
    FleetError
        After the summary is written, when an actuator failed.
    """
    from .engine import map_tasks
    from .summary import write_summary

    actuators = find_actuators(root)
    if not actuators:
        raise FileNotFoundError(f"{os.fspath(root)}: no actuator sub-folders")
    os.makedirs(out_dir, exist_ok=True)
    done, todo, results = _plan(actuators, out_dir, options)
    results.update(done)
    for name in done:
        say(f"{name}: up to date, skipped")
    report = {"identified": [], "skipped": sorted(done), "failed": sorted(results.keys() - done.keys()),
              "written": [], "tasks": {}}
    if todo:
        say(f"identifying {len(todo)} of {len(actuators)} actuators ({len(done)} up to date)")
    t0, k = time.perf_counter(), 0
    try:
        for (name, _, _), res in map_tasks(fit_actuator, todo, scheduler, n_workers, errors="return",
                                           name="fleet-identify"):
            k += 1
            results[name] = _take(name, res, out_dir, report)
            say(f"[{k}/{len(todo)}] {name}: " + _progress(name, res, results[name], t0))
    except KeyboardInterrupt:
        raise KeyboardInterrupt(f"{len(report['identified'])} model(s) written to {out_dir}; run again to "
                                "resume with the others") from None
    report["written"] += write_summary(out_dir, results, options)
    if report["failed"]:
        raise FleetError(f"{len(report['failed'])} of {len(actuators)} actuators failed "
                         f"({', '.join(report['failed'])}); see {os.path.join(out_dir, 'fleet.csv')}")
    return report


def _take(name, res, out_dir, report):
    """Write the model of a finished task; its document, or the failure text."""
    if isinstance(res, BaseException):  # the worker died too often, or the task kept raising
        report["failed"].append(name)
        return f"{type(res).__name__}: {' '.join(str(res).split())}"
    if "error" in res:
        report["failed"].append(name)
        return res["error"]
    report["tasks"][name] = (res["seconds"], res["cpu_seconds"])
    path = os.path.join(out_dir, f"{name}.json")
    write_model(path, res["document"])
    report["identified"].append(name)
    report["written"].append(path)
    return res["document"]


def _progress(name, res, result, t0):
    if isinstance(result, str):
        return f"failed: {result}"
    return (f"training RMS {result['fit']['training_rms_um']:.4g} µm in {res['seconds']:.1f} s on "
            f"{res['host']} ({time.perf_counter() - t0:.1f} s elapsed) -> {name}.json")
