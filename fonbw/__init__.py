"""fonbw — fractional-order normalized Bouc-Wen hysteresis of piezoelectric actuators.

Equation numbers refer to Kang et al., "A Fractional-Order Normalized Bouc-Wen
Model for Piezoelectric Hysteresis Nonlinearity".

Public contract (see the README)::

    m = fonbw.FONBW(ku=[k1, k2, k3], kh=..., rho=..., sigma=..., n=..., lam1=..., lam2=..., memory="fast")
    y = m.simulate(u, dt)
    s = m.stepper(dt); y_k = s.step(u_k)
    fonbw.CBW(alpha=..., k=..., D=..., A=..., beta=..., gamma=..., n=...).to_nbw()
    fonbw.load_model(path); m.save(path)
"""
__version__ = "0.1.0"


# Sub-packages whose every module may end up inside compiled code (kernels
# call and inline each other across these); elsewhere only modules that
# compile something themselves count.
_KERNEL_PACKAGES = ("fractional", "hysteresis", "compensate")


def _kernel_sources_digest(here, numba_version):
    """16 hex digits of a hash of the package sources at `here` that can reach
    compiled code (see :func:`_numba_cache_dir`) and of numba's version."""
    import hashlib
    import os

    h = hashlib.sha256(numba_version.encode())
    for root, dirs, files in os.walk(here):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")  # fixed order
        whole = os.path.relpath(root, here).split(os.sep)[0] in _KERNEL_PACKAGES
        for name in sorted(files):
            if name.endswith(".py"):
                path = os.path.join(root, name)
                with open(path, "rb") as fh:
                    src = fh.read()
                if whole or b"njit" in src or b"prange" in src:
                    h.update(os.path.relpath(path, here).encode() + b"\0" + src)
    return h.hexdigest()[:16]


def _numba_cache_dir():
    """Key numba's on-disk cache on the sources of the compiled code.

    numba invalidates a cached function only when *its own* file changes, but
    the kernels call (and inline) kernels of other modules: after an edit of
    the fractional kernels a cached hysteresis or compensate kernel would
    silently run the old code. A cache directory named by a hash of every
    source file that can reach compiled code (the kernel sub-packages whole,
    and any other module with a compiled function) makes any such edit (or a
    numba upgrade) start a fresh cache, while an edit of the command line,
    the loop or the reports keeps the compiled kernels (a cold cache costs
    minutes). An explicit NUMBA_CACHE_DIR is respected.
    """
    import os

    import numba

    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    digest = _kernel_sources_digest(os.path.dirname(os.path.abspath(__file__)), numba.__version__)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    path = os.path.join(base, "fonbw", "numba-" + digest)
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return  # unwritable home: numba's default (beside the sources) is used
    numba.config.CACHE_DIR = path


_numba_cache_dir()

from .compensate import compensate, compensator  # noqa: E402,F401
from .hysteresis import CBW, FONBW, NBW, Zhu2016, load_model, model_from_dict  # noqa: E402,F401
from .identify import identify  # noqa: E402,F401
from .io import Record, read_record, write_csv  # noqa: E402,F401
