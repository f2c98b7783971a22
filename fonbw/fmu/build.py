"""Build the fonbw FMI 2.0 co-simulation FMUs (pythonfmu) and validate them.

The FMUs, built from the slave scripts installed as ``fonbw.fmu.slaves``
(the repository's ``fmu_src/``):

* ``FonbwHysteresis``   u [V] -> y [µm], the FONBW model
* ``FonbwCompensator``  y_ref [µm] -> u [V], the inverse of the same model
* ``FonbwLinearPlant``  a linear state-space plant (python-control)
* ``FonbwPID``          the closed loop's controller (:func:`build_pid_fmu`)

Every FMU is checked with fmpy's validator; a problem fails the build.

Run-time dependency: each FMU carries a copy of the ``fonbw`` package (with
its default parameter sets) in its resources folder next to the slave script,
so it runs in any Python with numpy, scipy, numba and python-control, without
``pip install fonbw``; its numerics are those of the version it was built
from. Python FMUs share one interpreter per process, so when ``fonbw`` is
already imported in the host process that copy is used.

Model parameters are not baked into a script: the parameter set rides in the
FMU's resources as JSON and is read per instance, so FMUs of one kind built
from different parameter sets load side by side in one process.

Nothing here reads files outside the installed packages, so a wheel install
builds FMUs from any directory.
"""
from __future__ import annotations

import argparse
import getpass
import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import fonbw
from fonbw.data import DEFAULT_MODEL, DEFAULT_PLANT
from fonbw.fmu.slaves import SLAVES_DIR
from fonbw.fmu.slaves.fonbw_fmu_common import MODEL_RESOURCE, PID_RESOURCE, PLANT_RESOURCE

__all__ = ["BuildError", "build", "build_one", "build_pid_fmu", "loop_fmus", "run_builder", "pid_resource", "model_resource",
           "statespace_resource", "plant_resource", "loop_plant_resource", "add_arguments", "main"]

COMMON = SLAVES_DIR / "fonbw_fmu_common.py"
SCRIPTS = {
    "hysteresis": SLAVES_DIR / "fonbw_hysteresis_fmu.py",
    "compensator": SLAVES_DIR / "fonbw_compensator_fmu.py",
    "plant": SLAVES_DIR / "fonbw_plant_fmu.py",
    "pid": SLAVES_DIR / "fonbw_pid_fmu.py",
}
#: FMU file of each kind.
FMU_NAMES = {"hysteresis": "FonbwHysteresis.fmu", "compensator": "FonbwCompensator.fmu",
             "plant": "FonbwLinearPlant.fmu", "pid": "FonbwPID.fmu"}
#: Kinds that `fonbw build-fmu` builds by default.
DEFAULT_KINDS = ("hysteresis", "compensator", "plant")
# pythonfmu model options: state get/set/serialize are implemented by the slaves.
FMU_OPTIONS = dict(canGetAndSetFMUstate=True, canSerializeFMUstate=True,
                   canHandleVariableCommunicationStepSize=True)
#: Default internal step of the hysteresis, compensator and plant FMUs [s].
DEFAULT_DT = 1e-4


class BuildError(ValueError):
    """An FMU could not be built (bad parameter set, failed validation)."""



def cache_dir() -> Path:
    """The per-user cache of built FMUs and compiled helpers (under the temporary
    folder, one per user so that users on one machine do not share builds)."""
    return Path(tempfile.gettempdir()) / f"fonbw-cosim-{getpass.getuser()}"


def _package_dirs():
    """The installed ``fonbw`` package folder and its default-model folder
    (the same folder in a wheel install, two folders in an editable one)."""
    return Path(fonbw.__file__).resolve().parent, DEFAULT_MODEL.parent


def _stage_package(stage: Path) -> Path:
    """Copy ``fonbw`` with its ``data`` sub-package into `stage`, so the FMU's
    copy is complete whether the library is installed from a wheel or editable."""
    pkg, data = _package_dirs()
    dest = stage / "fonbw"
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(pkg, dest, ignore=ignore)
    if data != pkg / "data":
        shutil.copytree(data, dest / "data", ignore=ignore, dirs_exist_ok=True)
    return dest


def sources_key() -> str:
    """A digest of everything an FMU is built from (library, slaves, data)."""
    h = hashlib.sha1()
    pkg, data = _package_dirs()
    for d in dict.fromkeys((pkg, data, SLAVES_DIR)):
        for p in sorted(d.rglob("*")):
            if p.suffix in (".py", ".json") and "__pycache__" not in p.parts:
                h.update(str(p.relative_to(d)).encode())
                h.update(p.read_bytes())
    return h.hexdigest()[:12]


# ---------------------------------------------------------------------------
# resources: what each FMU reads at instantiation

def model_resource(params, dt: float = DEFAULT_DT) -> dict:
    """Resource of the hysteresis and compensator FMUs: the model as the library
    writes it (`params` a model, or a JSON file round-tripped through
    :func:`fonbw.load_model`, so it is known to load), the default internal
    step [s] and the compensator's voltage range [V] (the model's training
    range, :func:`fonbw.compensate.default_limits`)."""
    from fonbw.compensate import default_limits

    if hasattr(params, "to_dict"):
        model = params
    else:
        try:
            model = fonbw.load_model(str(params))
        except Exception as e:
            raise BuildError(f"{params}: cannot load parameter set: {e}") from e
    if not isinstance(model, fonbw.FONBW):  # NBW is a FONBW with lam1 = lam2 = 1
        raise BuildError(f"{params}: the FMUs wrap the FONBW model, got kind {model.kind!r}")
    return {"model": model.as_fonbw().to_dict(), "dt": float(dt),
            "limits": [float(x) for x in default_limits(model)]}


#: (name, unit, description) of the plant FMU's input and output when not given.
PLANT_INPUT = ("x", "um", "Plant input")
PLANT_OUTPUT = ("y", "um", "Plant output")


def statespace_resource(sys_, input=PLANT_INPUT, output=PLANT_OUTPUT, dt=None) -> dict:
    """Resource of the plant FMU from a python-control state-space (or transfer
    function) system; `input` and `output` are (name, unit, description)."""
    import control
    import numpy as np

    ss = control.ss(sys_)
    if ss.ninputs != 1 or ss.noutputs != 1:
        raise BuildError(f"{ss.ninputs} input(s) and {ss.noutputs} output(s); the plant FMU is "
                         "single-input single-output")
    if ss.dt is True:
        raise BuildError("discrete plant without a sampling time")
    mats = {k: np.asarray(getattr(ss, k), dtype=float) for k in "ABCD"}
    sys_dt = None if ss.dt in (0, None) else float(ss.dt)
    return {
        "kind": "linear_plant",
        "input": dict(zip(("name", "unit", "description"), input)),
        "output": dict(zip(("name", "unit", "description"), output)),
        "A": mats["A"].tolist(), "B": mats["B"].tolist(),
        "C": mats["C"].tolist(), "D": mats["D"].tolist(),
        "shape": {k: list(v.shape) for k, v in mats.items()},
        "sys_dt": sys_dt,
        "dt": float(dt if dt is not None else (sys_dt or DEFAULT_DT)),
    }


def plant_resource(path, dt: float | None = None) -> dict:
    """Plant resource from a plant JSON file (kind linear_plant: matrices A, B,
    C, D; sys_dt null for continuous time; input/output name, unit, description)."""
    import control

    try:
        # utf-8-sig: a byte-order mark from an editor is read past, as in a model file
        d = json.loads(Path(path).read_text(encoding="utf-8-sig"))
        if not isinstance(d, dict):
            raise BuildError(f"{path}: expected a JSON object (kind linear_plant), got {type(d).__name__}")
        if d.get("kind") != "linear_plant":
            raise BuildError(f"{path}: expected kind 'linear_plant', got {d.get('kind')!r}")
        mats = [d[k] for k in "ABCD"]
    except KeyError as e:
        raise BuildError(f"{path}: missing field {e}") from e
    except json.JSONDecodeError as e:
        raise BuildError(f"{path}: not JSON ({e})") from e
    except (OSError, UnicodeDecodeError) as e:
        raise BuildError(f"{path}: cannot read: {getattr(e, 'strerror', None) or e}") from e
    ports = [_plant_port(path, d, "input", PLANT_INPUT), _plant_port(path, d, "output", PLANT_OUTPUT)]
    step = dt if dt is not None else _plant_dt(path, d)
    desc = d.get("description", "")
    if not isinstance(desc, str):
        raise BuildError(f"{path}: field 'description': expected text, got {json.dumps(desc)}")
    try:
        sys_ = control.ss(*mats, d["sys_dt"]) if d.get("sys_dt") else control.ss(*mats)
        res = statespace_resource(sys_, *ports, step)
    except (ValueError, TypeError) as e:
        # python-control's messages (and the resource's own checks) name the matrix, not the file
        raise BuildError(f"{path}: fields A, B, C, D, sys_dt: not a state-space system ({e})") from e
    res["description"] = desc
    return res


def _plant_port(path, d, key, default):
    """(name, unit, description) of a plant file's `key` ("input" or "output"); `default` when absent."""
    s = d.get(key)
    if s is None:
        return default
    ok = isinstance(s, dict) and isinstance(s.get("name"), str) and s["name"]
    if ok and all(s.get(k) is None or isinstance(s[k], str) for k in ("unit", "description")):
        return s["name"], s.get("unit"), s.get("description", "")
    raise BuildError(f"{path}: field {key!r}: expected an object with a \"name\" and optionally a \"unit\" "
                     f"and a \"description\", all text, got {json.dumps(s)}")


def _plant_dt(path, d):
    """The plant file's FMU step "dt" [s], or None when absent."""
    v = d.get("dt")
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise BuildError(f"{path}: field 'dt': expected a positive number of seconds, got {json.dumps(v)}")
    return float(v)


# ---------------------------------------------------------------------------
# building

def build_one(kind: str, resource_name: str, resource: dict, out_dir) -> Path:
    """Build one FMU of `kind` (the slave script, the shared slave module, the
    library and the resource JSON) into `out_dir`, then validate it with fmpy.

    pythonfmu imports the slave script to read its model description, so the
    calling process should not load the FMU itself afterwards (two copies of
    the slave module would meet in ``sys.modules``)."""
    from fmpy.validation import validate_fmu
    from pythonfmu.builder import FmuBuilder

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="fonbw_fmu_") as stage:
        stage = Path(stage)
        res_file = stage / resource_name
        res_file.write_text(json.dumps(resource, indent=1), encoding="utf-8")
        pkg = _stage_package(stage)
        sys.path.insert(0, str(SLAVES_DIR))  # the script imports fonbw_fmu_common
        try:
            fmu = FmuBuilder.build_FMU(SCRIPTS[kind], dest=out_dir, project_files=[COMMON, pkg, res_file],
                                       **FMU_OPTIONS)
        finally:
            sys.path.remove(str(SLAVES_DIR))
    problems = validate_fmu(str(fmu))
    if problems:
        raise BuildError(f"{fmu} fails validation:\n  " + "\n  ".join(problems))
    return Path(fmu)


def build(out_dir, *, params=None, plant=None, dt: float = DEFAULT_DT, kinds=DEFAULT_KINDS) -> list[Path]:
    """Build the hysteresis, compensator and plant FMUs into `out_dir`.

    Parameters
    ----------
    out_dir : path-like
        Output folder (created if missing).
    params : path-like, optional
        FONBW parameter set (JSON written by ``save()``); default the library's
        :data:`fonbw.data.DEFAULT_MODEL`.
    plant : path-like, optional
        Linear plant (JSON, kind linear_plant); default :data:`fonbw.data.DEFAULT_PLANT`.
    dt : float
        Default internal step of the hysteresis and compensator FMUs [s].
    kinds : sequence of str
        Which of "hysteresis", "compensator", "plant" to build.

    Returns
    -------
    list of Path
        The FMUs written, each validated by fmpy.
    """
    built = []
    for kind in kinds:
        res, name = kind_resource(kind, params, plant, None if kind == "plant" else dt)
        built.append(build_one(kind, name, res, out_dir))
    return built


def kind_resource(kind, params=None, plant=None, dt=None):
    """The resource of a hysteresis, compensator or plant FMU and its file name.

    `params` and `plant` default to the library's default model and plant;
    `dt` [s] is the FMU's default internal step (None: :data:`DEFAULT_DT` for
    the model FMUs, the plant file's own step for the plant). Shared by the
    pythonfmu and the native builders.
    """
    if kind == "plant":
        return plant_resource(plant or DEFAULT_PLANT, dt), PLANT_RESOURCE
    if kind in ("hysteresis", "compensator"):
        return model_resource(params or DEFAULT_MODEL, DEFAULT_DT if dt is None else dt), MODEL_RESOURCE
    raise BuildError(f"unknown FMU kind {kind!r}; choose from {', '.join(DEFAULT_KINDS)}")


def pid_resource(controller=None, dt: float = DEFAULT_DT) -> dict:
    """Start values of the PID FMUs (pythonfmu and native): :func:`fonbw.loop.controller_spec`
    of `controller` (its keyword arguments; default kp = 1e-3 V/µm, ki = 100 V/(µm s)
    at step `dt` [s]), without its design notes."""
    from fonbw.loop.controller import CONTROLLER_KEYS, controller_spec

    c = dict(controller or {"kp": 1e-3, "ki": 100.0, "dt": dt})
    spec = controller_spec(**{k: c[k] for k in CONTROLLER_KEYS if k in c})
    return {k: spec[k] for k in CONTROLLER_KEYS}


def build_pid_fmu(out_dir, controller: dict) -> Path:
    """Build ``FonbwPID.fmu`` into `out_dir` with `controller` (a dict of the
    controller's FMU parameters, :data:`fonbw.loop.controller.LoopController`'s
    keys) as start values, and validate it."""
    return build_one("pid", PID_RESOURCE, dict(controller), out_dir)


# ---------------------------------------------------------------------------
# the closed loop's FMUs, built once per library version and plant

def run_builder(args):
    """Run the builder (this module's command line, `args`) in a fresh process.

    Fresh because the builder imports the slave scripts, which must not meet
    the FMUs the calling process loads later. ``-P`` keeps the working folder
    off the child's import path: run from a clone of the repository, its
    ``fonbw/`` source folder would otherwise shadow the installed package.
    """
    r = subprocess.run([sys.executable, "-P", "-m", "fonbw.fmu.build", *map(str, args)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise BuildError(f"FMU build failed ({' '.join(map(str, args))}):\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}")


def _cached(path: Path, args) -> Path:
    """Build one FMU into `path` unless it is there; the build lands in a
    temporary folder beside it and is moved in whole."""
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
            run_builder([*args, "-o", tmp])
            os.replace(Path(tmp) / path.name, path)
    return path


def loop_plant_resource(plant_sys, hysteresis: bool = True) -> dict:
    """Resource of the closed loop's plant FMU: input ``h`` (a displacement [µm]
    after the hysteresis, or the voltage [V] when there is none), output ``x`` [µm]."""
    unit = "um" if hysteresis else "V"
    return statespace_resource(
        plant_sys, input=("h", unit, "Plant input (quasi-static displacement, or voltage without "
                                     "hysteresis block)"),
        output=("x", "um", "Displacement after the linear dynamics"), dt=DEFAULT_DT)


def loop_fmus(controller: dict, out_dir=None, plant_sys=None, hysteresis: bool = True) -> dict:
    """Build (or reuse) the FMUs of the closed loop; returns ``{role: path}``.

    Roles: ``hyst`` (FonbwHysteresis), ``comp`` (FonbwCompensator), ``ctrl``
    (FonbwPID, built with the start values `controller`), and ``plant``
    (FonbwLinearPlant of the python-control system
    `plant_sys`, if given; its input is a displacement [µm], or a voltage [V]
    when `hysteresis` is False). Model and controller parameters are FMU
    parameters set by the masters, so one build serves every parameter set; the
    plant's matrices ride in its resources, one build per plant. The default
    folder is a per-user cache keyed by :func:`sources_key`.
    """
    if out_dir is None:
        out_dir = cache_dir() / sources_key()
    out_dir = Path(out_dir)
    paths = {"hyst": _cached(out_dir / FMU_NAMES["hysteresis"], ["--only", "hysteresis"]),
             "comp": _cached(out_dir / FMU_NAMES["compensator"], ["--only", "compensator"])}
    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "controller.json"
        spec.write_text(json.dumps(controller), encoding="utf-8")
        paths["ctrl"] = _cached(out_dir / FMU_NAMES["pid"], ["--only", "pid", "--controller", spec])
        if plant_sys is not None:
            res = loop_plant_resource(plant_sys, hysteresis)
            key = hashlib.sha1(json.dumps(res, sort_keys=True).encode()).hexdigest()[:12]
            pj = Path(tmp) / "plant.json"
            pj.write_text(json.dumps(res), encoding="utf-8")
            paths["plant"] = _cached(out_dir / f"plant-{key}" / FMU_NAMES["plant"],
                                     ["--only", "plant", "--plant", pj])
    return paths


# ---------------------------------------------------------------------------
# command line (`fonbw build-fmu`, `python build_fmu.py`, `python -m fonbw.fmu.build`)

def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The builder's options, shared by every front door."""
    ap.add_argument("--params", type=Path, default=None, metavar="MODEL.json",
                    help="FONBW parameter set (JSON written by save(); default: the library's default model)")
    ap.add_argument("--plant", type=Path, default=None, metavar="PLANT.json",
                    help="linear plant (JSON, kind linear_plant; default: the library's default plant)")
    ap.add_argument("--dt", type=float, default=DEFAULT_DT,
                    help="default internal step of the hysteresis and compensator FMUs [s] (default %(default)g)")
    ap.add_argument("-o", "--output", type=Path, default=Path("models"), metavar="DIR",
                    help="output folder (default %(default)s)")
    ap.add_argument("--only", choices=sorted(SCRIPTS), action="append",
                    help="build only this FMU (repeatable; default: hysteresis, compensator, plant)")
    ap.add_argument("--controller", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--native", action="store_true",
                    help="build the native C FMUs (FonbwHysteresisNative, FonbwCompensatorNative, "
                         "FonbwLinearPlantNative: no Python at run time; linux64 with gcc, win64 with "
                         "x86_64-w64-mingw32-gcc when installed; sources/ included)")


def run(ns) -> int:
    """Build what the parsed options `ns` ask for; print each FMU written."""
    if getattr(ns, "native", False):
        from fonbw.fmu import native
        return native.run(ns)
    kinds = ns.only or DEFAULT_KINDS
    built = build(ns.output, params=ns.params, plant=ns.plant, dt=ns.dt,
                  kinds=[k for k in kinds if k != "pid"])
    if "pid" in kinds:
        if ns.controller is None:
            raise BuildError("the PID FMU is built by the closed loop, which gives its controller")
        built.append(build_pid_fmu(ns.output, json.loads(ns.controller.read_text(encoding="utf-8"))))
    for p in built:
        print(f"wrote {p} (fmpy validate: no problem)")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="build_fmu", description=__doc__.split("\n\n")[0])
    add_arguments(ap)
    ns = ap.parse_args(argv)
    try:
        return run(ns)
    except (BuildError, OSError, KeyError, ValueError) as e:
        print(f"build_fmu: error: {' '.join(str(e).split())}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
