"""One BLAS thread for a block of code, on the OpenBLAS libraries this process has loaded.

Tiny dense problems (the 4 x 4 matrix exponential of a resonance's
discretization) gain nothing from a second BLAS thread, and on a busy
machine the hand-off to it costs far more than the work: measured on two
cores at a load average of 12, 24 ms per 4 x 4 ``scipy.linalg.expm`` with
two OpenBLAS threads against 0.15 ms with one. :func:`single_thread` sets
every loaded OpenBLAS (numpy's and scipy's each bundle one) to one thread
and restores the previous counts on exit. Only code whose numbers do not
depend on the thread count belongs inside it (a matrix exponential of this
size never splits its work); BLAS level-2 products on long vectors do
depend on it and are left alone.

Where the libraries cannot be found (no ``/proc``, another BLAS) it does
nothing.
"""
from __future__ import annotations

import contextlib
import ctypes

__all__ = ["single_thread"]

# (get, set) symbol pairs of OpenBLAS builds: plain, scipy's, scipy's 64-bit integer one
_SYMBOLS = (("openblas_get_num_threads", "openblas_set_num_threads"),
            ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
            ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"))

_LIBS = None


def _libs():
    """(get, set) functions of every loaded OpenBLAS, found once."""
    global _LIBS
    if _LIBS is not None:
        return _LIBS
    found = []
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({ln.split()[-1] for ln in fh if "openblas" in ln.lower() and ".so" in ln})
    except OSError:
        paths = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for g, s in _SYMBOLS:
            if hasattr(lib, g) and hasattr(lib, s):
                get, put = getattr(lib, g), getattr(lib, s)
                get.restype, get.argtypes = ctypes.c_int, []
                put.restype, put.argtypes = None, [ctypes.c_int]
                found.append((get, put))
                break
    _LIBS = found
    return found


@contextlib.contextmanager
def single_thread():
    """Run the block with one thread in every loaded OpenBLAS; restores the counts after."""
    libs = _libs()
    before = [get() for get, _ in libs]
    for (get, put), n in zip(libs, before):
        if n != 1:
            put(1)
    try:
        yield
    finally:
        for (get, put), n in zip(libs, before):
            if n != 1:
                put(n)
