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


def _numba_cache_dir():
    """Key numba's on-disk cache on the sources of the whole package.

    numba invalidates a cached function only when *its own* file changes, but
    the kernels call (and inline) kernels of other modules: after an edit of
    the fractional kernels a cached hysteresis or compensate kernel would
    silently run the old code. A cache directory named by a hash of every
    source file of the package, subpackages included (kernels live in
    fonbw.hysteresis and fonbw.fractional too), makes any edit (or upgrade)
    start a fresh cache. An explicit NUMBA_CACHE_DIR is respected.
    """
    import hashlib
    import os

    import numba

    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    here = os.path.dirname(os.path.abspath(__file__))
    h = hashlib.sha256(numba.__version__.encode())
    for root, dirs, files in os.walk(here):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")  # fixed order
        for name in sorted(files):
            if name.endswith(".py"):
                path = os.path.join(root, name)
                with open(path, "rb") as fh:
                    h.update(os.path.relpath(path, here).encode() + b"\0" + fh.read())
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    path = os.path.join(base, "fonbw", "numba-" + h.hexdigest()[:16])
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
