"""Independent tasks on ``dask.distributed``: an embedded cluster or an existing one.

:func:`map_tasks` submits ``fn(item)`` for every item and yields
``(item, result)`` as tasks complete, in whatever order they complete. The
caller's results must therefore not depend on that order nor on which worker
ran a task: give every task what it needs (a seed included, e.g.
:func:`task_seed`) in its item.

A task whose worker dies is re-run elsewhere by the scheduler (up to
``distributed.scheduler.allowed-failures`` times, then it fails with
``KilledWorker``); a task that raises is re-run up to `retries` times. Either
way its result reaches the caller once.
"""
from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import uuid

__all__ = ["connect", "map_tasks", "task_seed", "worker_versions"]


def task_seed(base: int, name: str) -> int:
    """A seed for task `name`, derived from the `base` seed.

    Stable across processes and machines (a SHA-256 of the name, not Python's
    salted ``hash``), so a task gets the same seed whichever worker runs it
    and in whatever order.

    Returns
    -------
    int
        In [0, 2**32).
    """
    words = [int.from_bytes(hashlib.sha256(str(name).encode()).digest()[i:i + 4], "little") for i in (0, 4)]
    import numpy as np

    return int(np.random.SeedSequence([int(base), *words]).generate_state(1)[0])


def worker_versions(client) -> dict:
    """fonbw version of every worker: ``{worker address: version}``."""
    def _version():
        import fonbw

        return fonbw.__version__

    return client.run(_version)


@contextlib.contextmanager
def connect(scheduler=None, n_workers: int | None = None):
    """A ``distributed.Client`` for the duration of the ``with`` block.

    Parameters
    ----------
    scheduler : str or distributed.Client, optional
        None: start an embedded ``LocalCluster`` (processes, one thread each,
        bound to 127.0.0.1) and shut it down afterwards. A string: the address
        of a running scheduler (``tcp://host:8786``) or the path of its
        ``--scheduler-file``. A Client: used as it is and left open.
    n_workers : int, optional
        Worker processes of the embedded cluster (default: one per core).
    """
    from distributed import Client, LocalCluster

    if isinstance(scheduler, Client):
        yield scheduler
        return
    if scheduler:
        kw = ({"scheduler_file": scheduler} if os.path.isfile(scheduler) else {"address": scheduler})
        with Client(timeout="20s", **kw) as client:
            yield client
        return
    n = int(n_workers) if n_workers else (os.cpu_count() or 1)
    if n < 1:
        raise ValueError(f"n_workers must be ≥ 1, got {n_workers!r}")
    # one single-threaded process per core: the tasks are CPU-bound Python and
    # numba, so threads in one process would contend for the GIL. dask keeps
    # the BLAS and OpenMP pools of its workers at one thread; numba's pool
    # (the population kernel's) is set here, or every worker would run one
    # thread per core as well
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR,
                      env={"NUMBA_NUM_THREADS": "1"}) as cluster, Client(cluster) as client:
        yield client


def map_tasks(fn, items, scheduler=None, n_workers: int | None = None, *, retries: int = 2,
              errors: str = "raise", name: str = "task"):
    """Run ``fn(item)`` for every item on a dask cluster; yield results as they complete.

    Parameters
    ----------
    fn : callable
        A picklable function of one item (module-level functions travel by
        reference: the workers need the same package versions).
    items : iterable
        Task inputs (picklable); each becomes one task.
    scheduler : str or distributed.Client, optional
        See :func:`connect` (default: an embedded cluster, shut down when the
        generator finishes or is closed).
    n_workers : int, optional
        Worker processes of the embedded cluster (default: one per core).
    retries : int
        Re-runs of a task that raised (a dead worker's task is re-run anyway).
    errors : {"raise", "return"}
        On a task that failed for good: raise its exception (remaining tasks
        are cancelled) or yield ``(item, exception)`` and go on.
    name : str
        Prefix of the task keys (shown on the dashboard).

    Yields
    ------
    (item, result)
        Once per item, in order of completion.
    """
    from distributed import as_completed

    if errors not in ("raise", "return"):
        raise ValueError(f"errors must be 'raise' or 'return', got {errors!r}")
    items = list(items)
    if not items:
        return
    token = uuid.uuid4().hex[:12]
    with connect(scheduler, n_workers) as client:
        futures = [client.submit(fn, it, key=f"{name}-{token}-{i}", pure=False, retries=retries)
                   for i, it in enumerate(items)]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in as_completed(futures):
                item = items[index[fut.key]]
                try:
                    res = fut.result()
                except Exception as exc:  # the task's own error, or KilledWorker
                    if errors == "raise":
                        raise
                    res = exc
                fut.release()  # the result is the caller's now; free the worker's memory
                yield item, res
        finally:
            client.cancel([f for f in futures if not f.done()])
