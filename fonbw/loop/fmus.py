"""The loop's FMUs: built (or reused) by :mod:`fonbw.fmu.build`, and the
parameter values a run sets on each of them.

Units: dt [s]; model parameters as in :mod:`fonbw.hysteresis`; controller as
in :func:`fonbw.loop.controller_spec`.
"""
from __future__ import annotations

from .controller import CONTROLLER_KEYS, controller_spec, plant_system

__all__ = ["build_fmus", "fmu_settings"]


def build_fmus(out_dir=None, plant=None, hysteresis=True) -> dict:
    """Build (or reuse) the FMUs of the loop in `out_dir` (default: a
    per-user cache); returns {role: path}.

    Roles: ``hyst``, ``comp``, ``ctrl`` and ``plant`` (the FonbwLinearPlant of
    :func:`plant_system` of `plant`, if any); see :func:`fonbw.fmu.build.loop_fmus`.
    The controller and model parameters built into the FMUs are defaults
    that every run sets anew (:func:`fmu_settings`); the plant's matrices are
    built in.
    """
    from ..fmu.build import loop_fmus

    spec = controller_spec(1e-3, 100.0)
    return loop_fmus({k: spec[k] for k in CONTROLLER_KEYS}, out_dir,
                     plant_system(plant) if plant is not None else None, hysteresis)


def _fmu_parameters(role, cfg) -> dict:
    """FMU parameter values of a block (name -> float or str)."""
    if role in ("hyst", "comp"):
        m = cfg["truth"] if role == "hyst" else cfg["model"]
        p = m.params
        out = {f"ku{i}": float(k) for i, k in enumerate(p["ku"], start=1)}
        out.update({k: float(p[k]) for k in ("kh", "rho", "sigma", "n", "lam1", "lam2")})
        out["memory"] = str(p["memory"])
        out["dt"] = cfg["dt"]
        return out
    if role == "ctrl":
        return {k: cfg["controller"][k] for k in CONTROLLER_KEYS}
    return {"dt": cfg["dt"]}


def fmu_settings(role, cfg) -> dict:
    """Parameters of the FMU of `role` for a run with configuration `cfg`:
    the models' and controller's own values, then the run's overrides."""
    return {**_fmu_parameters(role, cfg), **cfg.get("overrides", {}).get(role, {})}
