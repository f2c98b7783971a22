"""Sweeps over closed-loop settings as independent tasks on dask.distributed.

A sweep is a list of cases, each a set of :func:`fonbw.loop.run_cosim`
arguments (a controller bandwidth, a loop structure, a plant, a model, …).
Every case is one task of :func:`fonbw.fleet.map_tasks`: an embedded
``LocalCluster`` (one single-threaded worker process per core) by default, or
a running cluster given by its scheduler's address. A closed-loop run draws
no random numbers and each task carries all it needs, so the rows do not
depend on the number of workers nor on the order in which the tasks finish;
they come back in the order of the cases.

Example::

    from fonbw.loop.sweep import grid, sweep
    rows = sweep(grid(bandwidth_hz=[50, 100, 200], mode=["fb", "ff+fb"]),
                 scenario="sine5", T=1.0, plant="dynamics")

The FMU masters build their FMUs once per worker into the per-user cache;
the reference master needs none and is the one to sweep with on a cluster
whose workers share no file system.

Units: u [V], y, r, errors [µm], t [s].
"""
from __future__ import annotations

import inspect
import itertools
import sys
import time

from .run import run_cosim

__all__ = ["grid", "sweep"]

_ARGS = frozenset(inspect.signature(run_cosim).parameters)
ROW_KEYS = ("rms_error", "max_error", "rms_input", "steps", "error", "wall_s")


def grid(**axes) -> list:
    """Every combination of the given :func:`run_cosim` arguments.

    Parameters
    ----------
    **axes : sequence
        ``name=[value, …]`` per swept argument.

    Returns
    -------
    list of dict
        One case per combination, the last axis varying fastest.
    """
    for name, values in axes.items():
        if isinstance(values, (str, bytes)) or not hasattr(values, "__iter__"):
            raise ValueError(f"grid: {name}= needs a sequence of values, got {values!r}")
    names = list(axes)
    return [dict(zip(names, combo)) for combo in itertools.product(*(list(axes[n]) for n in names))]


def _case_row(item):
    """One task: ``(index, arguments)`` -> (index, the run's summary row)."""
    i, kwargs = item
    res = run_cosim(**kwargs)
    return i, {k: getattr(res, k) for k in ROW_KEYS}


def sweep(cases, *, scheduler=None, n_workers: int | None = None, progress: bool = False,
          **common) -> list:
    """Run the closed loop once per case on a dask cluster.

    Parameters
    ----------
    cases : sequence of dict
        :func:`run_cosim` arguments of each run (e.g. from :func:`grid`);
        they override `common`.
    scheduler : str or distributed.Client, optional
        A running scheduler's address (``tcp://host:8786``) or scheduler
        file; default an embedded LocalCluster (:func:`fonbw.fleet.connect`).
    n_workers : int, optional
        Worker processes of the embedded cluster (default one per core).
    progress : bool
        One line on stderr per finished case.
    **common
        :func:`run_cosim` arguments shared by every case.

    Returns
    -------
    list of dict
        In the order of `cases`: the case's own arguments plus ``rms_error``,
        ``max_error`` [µm], ``rms_input`` [V], ``steps``, ``error`` (None or
        why the run stopped) and ``wall_s`` (the stepping loop's wall time
        on its worker [s]).
    """
    from ..fleet import map_tasks

    cases = [dict(c) for c in cases]
    for j, kw in enumerate([common] + cases):
        bad = sorted(set(kw) - _ARGS)
        if bad:
            where = "sweep" if j == 0 else f"sweep: case {j - 1}"
            raise ValueError(f"{where}: unknown run_cosim argument(s) {bad}; valid: {sorted(_ARGS)}")
    items = [(i, {**common, **c}) for i, c in enumerate(cases)]
    rows = [None] * len(cases)
    t0 = time.perf_counter()
    for n_done, (_, (i, row)) in enumerate(map_tasks(_case_row, items, scheduler, n_workers, name="cosim-sweep"), 1):
        rows[i] = {**cases[i], **row}
        if progress:
            print(f"[sweep] {n_done}/{len(cases)} case {i} {cases[i]}: rms error {row['rms_error']:.4g} µm"
                  f" ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    return rows
