"""fonbw — fractional-order normalized Bouc-Wen hysteresis of piezoelectric actuators.

Equation numbers refer to Kang et al., "A Fractional-Order Normalized Bouc-Wen
Model for Piezoelectric Hysteresis Nonlinearity" (the paper in shared/paper).

Public contract (see the README)::

    m = fonbw.FONBW(ku=[k1, k2, k3], kh=..., rho=..., sigma=..., n=..., lam1=..., lam2=..., memory="fast")
    y = m.simulate(u, dt)
    s = m.stepper(dt); y_k = s.step(u_k)
    fonbw.CBW(alpha=..., k=..., D=..., A=..., beta=..., gamma=..., n=...).to_nbw()
    fonbw.load_model(path); m.save(path)
"""
__version__ = "0.1.0"

from .hysteresis import CBW, FONBW, NBW, Zhu2016, load_model, model_from_dict  # noqa: F401
from .io import Record, read_record, write_csv  # noqa: F401


def __getattr__(name):
    # Heavier layers are imported on first use so `import fonbw` stays quick.
    lazy = {
        "identify": ("identify", "identify"),
        "compensator": ("compensate", "compensator"),
        "compensate": ("compensate", "compensate"),
    }
    if name in lazy:
        import importlib

        mod, attr = lazy[name]
        return getattr(importlib.import_module(f".{mod}", __name__), attr)
    raise AttributeError(f"module 'fonbw' has no attribute {name!r}")
