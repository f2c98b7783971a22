"""The loop's FMUs: built (or reused) by :mod:`fonbw.fmu.build` (pythonfmu)
or :mod:`fonbw.fmu.native` (C), and the parameter values a run sets on each
of them.

Units: dt [s]; model parameters as in :mod:`fonbw.hysteresis`; controller as
in :func:`fonbw.loop.controller_spec`.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..compensate import default_limits
from ..compensate.rest import REST_PARAMETERS, rest_values
from .controller import CONTROLLER_KEYS, plant_system

__all__ = ["build_fmus", "build_native_fmus", "fmu_settings"]

#: Roles of the loop -> kinds of :mod:`fonbw.fmu.native`.
NATIVE_KINDS = {"hyst": "hysteresis", "comp": "compensator", "ctrl": "pid", "plant": "plant"}


def build_fmus(out_dir=None, plant=None, hysteresis=True, native=False, models=None) -> dict:
    """Build (or reuse) the FMUs of the loop in `out_dir` (default: a
    per-user cache); returns {role: path}.

    Roles: ``hyst``, ``comp``, ``ctrl`` and ``plant`` (the FonbwLinearPlant of
    :func:`plant_system` of `plant`, if any); see :func:`fonbw.fmu.build.loop_fmus`.
    The controller and model parameters built into the FMUs are defaults
    that every run sets anew (:func:`fmu_settings`); the plant's matrices are
    built in.

    With `native` the FMUs are the C ones (:func:`build_native_fmus`;
    `models`, the (compensator, actuator) FONBW models, fix their number of
    polynomial coefficients).
    """
    if native:
        return build_native_fmus(out_dir, plant, hysteresis, models)
    from ..fmu.build import loop_fmus, pid_resource

    return loop_fmus(pid_resource(), out_dir, plant_system(plant) if plant is not None else None, hysteresis)


def _model_resource(model):
    """Resource of a native hysteresis or compensator FMU for `model` (a
    FONBW, or None): the default model's, unless `model` has another number
    of coefficients ku (fixed at build time), then its own."""
    from ..data import DEFAULT_MODEL
    from ..fmu.build import DEFAULT_DT, model_resource

    res = model_resource(DEFAULT_MODEL, DEFAULT_DT)
    if model is not None and len(model.params["ku"]) != len(res["model"]["params"]["ku"]):
        res = model_resource(model, DEFAULT_DT)
    return res


def native_resources(plant=None, hysteresis=True, models=None) -> dict:
    """{role: (native kind, resource)} of the loop's native FMUs."""
    from ..fmu.build import loop_plant_resource
    from ..fmu.build import pid_resource

    comp, truth = models if models is not None else (None, None)
    out = {"hyst": ("hysteresis", _model_resource(truth)), "comp": ("compensator", _model_resource(comp)),
           "ctrl": ("pid", pid_resource())}
    sys_ = plant_system(plant) if plant is not None else None
    if sys_ is not None:
        out["plant"] = ("plant", loop_plant_resource(sys_, hysteresis))
    return out


def build_native_fmus(out_dir=None, plant=None, hysteresis=True, models=None, pass_through=False) -> dict:
    """Build (or reuse) the native C FMUs of the loop for this platform;
    returns {role: path}.

    Roles as :func:`build_fmus`: ``hyst`` (FonbwHysteresisNative), ``comp``
    (FonbwCompensatorNative), ``ctrl`` (FonbwPIDNative) and ``plant``
    (FonbwLinearPlantNative of :func:`plant_system` of `plant`, if any).
    Each FMU lands in a folder named by its GUID (a digest of its sources and
    start values) under `out_dir`/native (default: a per-user cache), so a
    build is reused until either changes. `pass_through` builds the
    pass-through variants instead (:data:`fonbw.fmu.native.PASS_NAMES`: the
    same interface, output = first input).
    """
    from ..fmu import native

    if out_dir is None:
        from ..fmu.build import cache_dir

        out_dir = cache_dir()
    base = Path(out_dir) / "native"
    names = native.PASS_NAMES if pass_through else native.NATIVE_NAMES
    paths = {}
    for role, (kind, res) in native_resources(plant, hysteresis, models).items():
        key = native._guid(kind, res, pass_through).strip("{}")[:13]
        path = base / key / f"{names[kind]}.fmu"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
                built = native.build_native_one(kind, res, tmp, [native.host_platform()], pass_through)
                os.replace(built, path)
        paths[role] = path
    return paths


def _fmu_parameters(role, cfg) -> dict:
    """FMU parameter values of a block (name -> float or str)."""
    if role in ("hyst", "comp"):
        m = cfg["truth"] if role == "hyst" else cfg["model"]
        p = m.params
        out = {f"ku{i}": float(k) for i, k in enumerate(p["ku"], start=1)}
        out.update({k: float(p[k]) for k in ("kh", "rho", "sigma", "n", "lam1", "lam2")})
        out["memory"] = str(p["memory"])
        out["dt"] = cfg["dt"]
        # the model's start and (compensator) voltage range, as the library's blocks use them
        out.update(zip((n for n, _, _ in REST_PARAMETERS), rest_values(m)))
        if role == "comp":
            out["u_min"], out["u_max"] = (float(v) for v in default_limits(m))
        return out
    if role == "ctrl":
        return {k: cfg["controller"][k] for k in CONTROLLER_KEYS}
    return {"dt": cfg["dt"]}


def fmu_settings(role, cfg) -> dict:
    """Parameters of the FMU of `role` for a run with configuration `cfg`:
    the models' and controller's own values, then the run's overrides."""
    return {**_fmu_parameters(role, cfg), **cfg.get("overrides", {}).get(role, {})}
