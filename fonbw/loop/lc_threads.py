"""libcosim's fixed-step algorithm without its worker thread.

libcosim's fixed-step algorithm hands every slave's doStep to a thread pool
of ``std::thread::hardware_concurrency() - 1`` workers and waits for them
each step; with no worker the steps run on the calling thread. Its C++ API
takes a worker count, its C API (the one libcosimpy wraps) does not. For a
loop of four small FMUs at 10 kHz the hand-off is nearly all of the cost:
measured on a 2-CPU machine, 10 000 steps in one call took 25-46 µs per step
with one native slave (8 µs with every thread pinned to one CPU) and 0.9 µs
with no worker; with four slaves 25 µs (20 µs pinned) and 1.8 µs
(``benchmarks/bench_native_loop.py`` measures it again).

:func:`single_thread` makes the executions created inside it have no worker
thread: a small shared library, compiled on first use, defines
``std::thread::hardware_concurrency`` and is loaded into the global symbol
scope, so libcosimc (which calls it through its PLT, bound lazily) gets 1
there and the count of ``get_nprocs()`` (what libstdc++ returns on glibc)
anywhere else. It takes effect only if it is loaded before libcosimc first
calls the function, i.e. before the process's first libcosim execution, and
only on Linux with a C compiler; :func:`single_thread` therefore reports
whether the execution really has no worker (the thread count of the process
is compared before and after) instead of assuming it.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path

__all__ = ["single_thread", "thread_count"]

# libstdc++'s thread::hardware_concurrency() is get_nprocs() clamped at 0 on glibc
_SRC = r"""
#include <sys/sysinfo.h>
static volatile int fonbw_one_cpu = 0;
void fonbw_lc_single_thread(int on) { fonbw_one_cpu = on; }
unsigned int _ZNSt6thread20hardware_concurrencyEv(void) {
    int n;
    if (fonbw_one_cpu) return 1u;
    n = get_nprocs();
    return n < 0 ? 0u : (unsigned int)n;
}
"""

_lock = threading.Lock()
_lib = None
_failed: str | None = None


def thread_count() -> int:
    """Threads of this process (Linux; 0 where /proc is missing)."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return 0


def _load():
    """The shim, compiled into the per-user cache on first use, loaded
    RTLD_GLOBAL; None (with the reason in _failed) where that is impossible."""
    global _lib, _failed
    if _lib is not None or _failed is not None:
        return _lib
    if not sys.platform.startswith("linux") or not shutil.which("gcc"):
        _failed = "needs Linux and gcc"
        return None
    key = hashlib.sha1(_SRC.encode()).hexdigest()[:12]
    from ..fmu.build import cache_dir

    d = cache_dir() / "lc_threads"
    so = d / f"fonbw_lc_threads_{key}.so"
    try:
        if not so.is_file():
            d.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=d) as tmp:
                c, out = Path(tmp) / "shim.c", Path(tmp) / so.name
                c.write_text(_SRC)
                subprocess.run(["gcc", "-O2", "-shared", "-fPIC", "-o", str(out), str(c)],
                               check=True, capture_output=True)
                os.replace(out, so)  # atomic: concurrent runs share the cache
        _lib = ctypes.CDLL(str(so), mode=os.RTLD_GLOBAL | os.RTLD_NOW)
    except (OSError, subprocess.CalledProcessError) as e:
        _failed = f"cannot build or load the shim: {e}"
        return None
    return _lib


def prepare() -> None:
    """Load the shim now, before anything in the process creates a libcosim
    execution (call it before importing libcosimpy where possible)."""
    with _lock:
        _load()


@contextmanager
def single_thread(enabled: bool = True):
    """Executions created inside the block get no worker thread (see the
    module). Yields a dict that, after the block, holds ``"workers"``: the
    threads the execution added (0 when it took effect) and ``"note"``."""
    info = {"workers": None, "note": ""}
    with _lock:
        lib = _load() if enabled else None
        before = thread_count()
        if lib is not None:
            lib.fonbw_lc_single_thread(1)
        try:
            yield info
        finally:
            if lib is not None:
                lib.fonbw_lc_single_thread(0)
            info["workers"] = max(0, thread_count() - before)
            if not enabled:
                info["note"] = "libcosim's worker threads as it creates them"
            elif lib is None:
                info["note"] = f"libcosim's worker threads kept: {_failed}"
            elif info["workers"]:
                info["note"] = ("libcosim's worker threads kept: libcosimc had resolved "
                                "hardware_concurrency before the shim was loaded")
            else:
                info["note"] = "libcosim stepping on the calling thread (no worker)"
