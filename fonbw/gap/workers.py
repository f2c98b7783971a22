"""The candidate refits of a greedy step, on worker processes.

Each candidate's joint refit and checks depend only on the diagnosis as it
stands before the step, so the candidates of a step can run side by side.
Threads would not do: a refit is mostly Python between short numpy calls.
More BLAS or numba threads do not do either: on two cores, a diagnosis of
30 s of 5 kHz records took 171 s with two threads of each and 173 s with
one, and 113 s on two workers (``benchmarks/blind_gap.py --timing``,
BENCHMARKS.md).

Why not :mod:`multiprocessing`: a fork of this process dies at once once
numba's OpenMP threading layer has run here (the FONBW population kernel
does), and its spawn and fork-server workers import the user's main script
again, which runs a script without a ``__main__`` guard twice. A
:class:`Pool` starts fresh interpreters (running :func:`_serve`)
on this process's ``sys.path``, each with one BLAS and one numba thread,
and talks to them over two pipes; the task, a closure over the diagnosis,
travels with cloudpickle (a dependency of Dask). The workers live as long
as the pool, so their start and numba's loading of compiled kernels are
paid once per diagnosis; a diagnosis starts them first thing, and they import
its modules while the nominal is fitted (``fonbw demo --quick``'s diagnosis:
54 s in one process, 47 s with workers started at the first task, 44 s
started first thing).

A daemonic process (a Dask worker), or one on a system that is not POSIX,
runs the candidates itself, one after the other, as does ``workers=1``. A
refit's numbers depend on the number of BLAS threads (level-2 products on
long vectors split their sums by thread, see :mod:`fonbw.gap.blas`), so a
diagnosis with ``workers=1`` under one BLAS thread gives the same result,
bit for bit, as one on workers.
"""
from __future__ import annotations

import multiprocessing
import os
import pickle
import selectors
import struct
import subprocess
import sys

__all__ = ["default_workers", "Pool"]

#: Most processes a step uses by default: a step has at most seven candidates.
MAX_DEFAULT = 4

#: Thread counts of a worker: the other workers have the other cores.
_ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
               "NUMBA_NUM_THREADS": "1"}


def can_start() -> bool:
    """True where this process may start worker processes: not a daemon, and
    on a POSIX system (the pipes are handed over by descriptor)."""
    return os.name == "posix" and not multiprocessing.current_process().daemon


def default_workers() -> int:
    """Processes for the candidate refits: the environment variable
    ``FONBW_WORKERS`` when set, else the cores this process may use, at most
    :data:`MAX_DEFAULT`; 1 where it cannot start workers."""
    if not can_start():
        return 1
    env = os.environ.get("FONBW_WORKERS", "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            raise ValueError(f"FONBW_WORKERS must be a whole number of processes, got {env!r}") from None
        if n < 1:
            raise ValueError(f"FONBW_WORKERS must be at least 1, got {env!r}")
        return n
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # no affinity call on this platform
        n = os.cpu_count() or 1
    return max(1, min(n, MAX_DEFAULT))


# -- framing: an 8-byte length, then a pickle --------------------------------

def _send(fh, obj):
    data = pickle.dumps(obj)
    fh.write(struct.pack("<Q", len(data)))
    fh.write(data)
    fh.flush()


def _recv(fh):
    head = fh.read(8)
    if len(head) < 8:
        raise EOFError("worker pipe closed")
    (n,) = struct.unpack("<Q", head)
    data = fh.read(n)
    if len(data) < n:
        raise EOFError("worker pipe closed")
    return pickle.loads(data)


class WorkerError(RuntimeError):
    """A worker ended during a task, or a task raised an exception that does
    not pickle; the message says which, with the worker's traceback."""


class _Worker:
    def __init__(self, preload=()):
        r_task, w_task = os.pipe()
        r_res, w_res = os.pipe()
        env = {**os.environ, **_ONE_THREAD,
               "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
        # a session of its own: a Ctrl-C at the terminal reaches only the
        # pool's owner, which stops the workers (a worker still importing
        # would print a traceback of its own)
        self.proc = subprocess.Popen([sys.executable, "-c", _MAIN, str(r_task), str(w_res), *preload],
                                     pass_fds=(r_task, w_res), env=env, stdin=subprocess.DEVNULL,
                                     start_new_session=True)
        os.close(r_task)
        os.close(w_res)
        self.tasks = os.fdopen(w_task, "wb")
        self.results = os.fdopen(r_res, "rb")
        self.fn_id = None

    def send(self, msg, what):
        """Send `msg`; a worker that has ended (its pipe broken) is a
        :class:`WorkerError` that says so, whatever it was about to take."""
        try:
            _send(self.tasks, msg)
        except (BrokenPipeError, ConnectionResetError):
            try:
                code = self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                code = None
            raise WorkerError(f"a worker process ended (exit code {code}) before it took {what}") from None

    def close(self):
        for fh in (self.tasks, self.results):
            try:
                fh.close()
            except OSError:
                pass
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


class Pool:
    """Up to `workers` worker processes, started on the first :meth:`map`
    that has more than one item; a context manager (its exit stops them).

    Parameters
    ----------
    workers : int
        Processes; 1 (or a process that cannot start workers) runs every
        item here, in order.
    preload : sequence of str
        Modules each worker imports as it starts, before its first task
        (what the tasks will need: imported while the owner works on).
    """

    def __init__(self, workers: int, preload=()):
        self.n = max(1, int(workers)) if can_start() else 1
        self.preload = tuple(preload)
        self._workers = []
        self._fn_id = 0

    def start(self):
        """Start the workers now, so that they import while this process works
        on (a :meth:`map` starts them otherwise); returns the pool."""
        while self.n > 1 and len(self._workers) < self.n:
            self._workers.append(_Worker(self.preload))
        return self

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        """Stop the workers (a worker still busy is killed)."""
        for w in self._workers:
            w.close()
        self._workers = []

    def map(self, fn, items, on_result=None) -> list:
        """``[fn(x) for x in items]``, on the workers when there is more than one item.

        Parameters
        ----------
        fn : callable
            Called with one item; may be a closure (it travels with
            cloudpickle, once per worker). Its result must pickle.
        items : sequence
        on_result : callable, optional
            ``on_result(index, result)`` here as each item completes (progress).

        Returns
        -------
        list
            The results in the order of `items`, whatever the order they completed in.
        A task that raises in a worker raises here: the same exception when it
        pickles, else :class:`WorkerError`, with the worker's traceback.
        """
        items = list(items)
        n = min(self.n, len(items))
        if n <= 1:
            out = []
            for j, x in enumerate(items):
                out.append(fn(x))
                if on_result is not None:
                    on_result(j, out[-1])
            return out
        import cloudpickle

        while len(self._workers) < n:
            self._workers.append(_Worker(self.preload))
        self._fn_id += 1
        blob = cloudpickle.dumps(fn)
        out, todo, busy = [None] * len(items), list(enumerate(items))[::-1], {}
        sel = selectors.DefaultSelector()
        try:
            for w in self._workers[:n]:
                if w.fn_id != self._fn_id:
                    w.send(("fn", blob), "its task")
                    w.fn_id = self._fn_id
                self._give(w, todo, busy)
                sel.register(w.results, selectors.EVENT_READ, w)
            while busy:
                for key, _ in sel.select():
                    w = key.data
                    try:
                        j, ok, value = _recv(w.results)
                    except EOFError:
                        try:
                            code = w.proc.wait(timeout=10)
                        except subprocess.TimeoutExpired:
                            code = None
                        raise WorkerError(f"a worker process ended (exit code {code}) "
                                          f"while it ran item {busy[w]}") from None
                    del busy[w]
                    if not ok:
                        exc, tb = value
                        if isinstance(exc, BaseException):
                            raise exc from WorkerError(tb)
                        raise WorkerError(tb)
                    out[j] = value
                    if on_result is not None:
                        on_result(j, value)
                    self._give(w, todo, busy)
        except BaseException:
            # a worker may be mid-task (an error elsewhere, Ctrl-C): its
            # answer would arrive out of turn, so the pool starts afresh
            self.close()
            raise
        finally:
            sel.close()
        return out

    @staticmethod
    def _give(w, todo, busy):
        if todo:
            j, x = todo.pop()
            w.send(("item", (j, x)), f"item {j}")
            busy[w] = j


def _serve(fd_in, fd_out, preload=()):
    """A worker's loop: a task ("fn"), then items, until the pipe closes."""
    import importlib
    import traceback

    import cloudpickle

    for name in preload:
        importlib.import_module(name)
    tasks, results = os.fdopen(fd_in, "rb"), os.fdopen(fd_out, "wb")
    fn = None
    while True:
        try:
            kind, payload = _recv(tasks)
        except EOFError:
            return
        if kind == "fn":
            fn = cloudpickle.loads(payload)
            continue
        j, x = payload
        try:
            msg = (j, True, fn(x))
            _send(results, msg)
        except Exception as exc:  # the owner re-raises it
            tb = traceback.format_exc()
            try:
                _send(results, (j, False, (exc, tb)))
            except Exception:  # the exception itself does not pickle
                _send(results, (j, False, (None, tb)))


# a worker's program (not ``-m``: this module is already imported with its package)
_MAIN = ("import sys; from fonbw.gap.workers import _serve; "
         "_serve(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3:])")
