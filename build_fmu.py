"""Build the fonbw FMI 2.0 co-simulation FMUs (pythonfmu) and validate them.

    python build_fmu.py [--params MODEL.json] [--plant PLANT.json] [--dt DT] [-o DIR]

Builds, from the scripts in fmu_src/:

* FonbwHysteresis.fmu   u [V] -> y [um], FONBW model, parameters from MODEL.json
* FonbwCompensator.fmu  y_ref [um] -> u [V], inverse of the same model
* FonbwLinearPlant.fmu  linear state-space plant from PLANT.json

(defaults: models/fonbw_default.json, models/plant_default.json, output into
models/).  Every FMU is checked with fmpy's validator (schema, variable names,
model structure, units, start values); any problem fails the build (exit 2).

Run-time dependency decision: each FMU carries the `fonbw` package sources in
its resources folder, next to the slave script (pythonfmu puts that folder
first on sys.path), so it runs in any Python with numpy, scipy, numba and
python-control, without `pip install fonbw`.  The FMU's numerics are therefore
exactly those of the fonbw version it was built from.  At run time the slave
imports a digest-checked copy of these sources from a per-user cache folder, so
that numba's on-disk cache survives fresh extractions (fmu_src/README.md).
Caveat inherent to Python FMUs: all of them share one interpreter per process,
so if `fonbw` is already imported in the host process (or by an FMU loaded
earlier), that copy is used.

Model parameters are not baked into the script: the parameter set rides in the
FMU resources as JSON and is read per instance, so two FMUs of the same kind
built from different parameter sets can be loaded into one process.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent
FMU_SRC = ROOT / "fmu_src"
COMMON = FMU_SRC / "fonbw_fmu_common.py"
SCRIPTS = {
    "hysteresis": FMU_SRC / "fonbw_hysteresis_fmu.py",
    "compensator": FMU_SRC / "fonbw_compensator_fmu.py",
    "plant": FMU_SRC / "fonbw_plant_fmu.py",
}
# pythonfmu model options: state get/set/serialize are implemented by the slaves.
FMU_OPTIONS = dict(canGetAndSetFMUstate=True, canSerializeFMUstate=True,
                   canHandleVariableCommunicationStepSize=True)


class BuildError(Exception):
    pass


def _import_fonbw(fonbw_src: Path):
    """Import the fonbw package that will be bundled (not some other copy)."""
    sys.path.insert(0, str(fonbw_src.parent))
    try:
        import fonbw
    finally:
        sys.path.pop(0)
    if Path(fonbw.__file__).resolve().parent != fonbw_src.resolve():
        raise BuildError(f"imported fonbw from {fonbw.__file__}, expected {fonbw_src}")
    return fonbw


def model_resource(params: Path, dt: float, fonbw_src: Path) -> dict:
    """Resource JSON of the hysteresis/compensator FMUs: the model as fonbw
    writes it (round-tripped through fonbw.load_model so that it is known to
    load) and the default internal step."""
    fonbw = _import_fonbw(fonbw_src)
    try:
        model = fonbw.load_model(str(params))
    except Exception as e:
        raise BuildError(f"{params}: cannot load parameter set: {e}") from e
    if not isinstance(model, fonbw.FONBW):  # NBW is a FONBW with lam1 = lam2 = 1
        raise BuildError(f"{params}: the FMUs wrap the FONBW model, got kind {model.kind!r}")
    p = dict(model.params)
    p.setdefault("lam1", 1.0)
    p.setdefault("lam2", 1.0)
    from fonbw.compensate import DEFAULT_LIMITS  # the compensator's voltage range
    return {"model": fonbw.FONBW(**p).to_dict(), "dt": float(dt),
            "limits": [float(x) for x in DEFAULT_LIMITS]}


def statespace_resource(sys_, input=("x", "um", "Plant input"),
                        output=("y", "um", "Plant output"), dt=None) -> dict:
    """Resource JSON of the plant FMU from a python-control state-space (or
    transfer-function) system; input/output are (name, unit, description)."""
    import control
    import numpy as np
    ss = control.ss(sys_)
    if ss.ninputs != 1 or ss.noutputs != 1:
        raise BuildError("the plant FMU is single-input single-output")
    mats = {k: np.asarray(getattr(ss, k), dtype=float) for k in "ABCD"}
    sys_dt = None if ss.dt in (0, None) else float(ss.dt)
    if sys_dt is not None and ss.dt is True:
        raise BuildError("discrete plant without a sampling time")
    return {
        "kind": "linear_plant",
        "input": dict(zip(("name", "unit", "description"), input)),
        "output": dict(zip(("name", "unit", "description"), output)),
        "A": mats["A"].tolist(), "B": mats["B"].tolist(),
        "C": mats["C"].tolist(), "D": mats["D"].tolist(),
        "shape": {k: list(v.shape) for k, v in mats.items()},
        "sys_dt": sys_dt,
        "dt": float(dt if dt is not None else (sys_dt or 1e-4)),
    }


def plant_resource(path: Path, dt: float | None) -> dict:
    """Plant resource from a plant JSON file (kind linear_plant: matrices A, B,
    C, D, sys_dt null for continuous time, input/output name+unit)."""
    import control
    d = json.loads(Path(path).read_text(encoding="utf-8"))
    if d.get("kind") != "linear_plant":
        raise BuildError(f"{path}: expected kind 'linear_plant', got {d.get('kind')!r}")
    mats = [d[k] for k in "ABCD"]
    sys_ = control.ss(*mats, d["sys_dt"]) if d.get("sys_dt") else control.ss(*mats)
    io = lambda s: (s["name"], s.get("unit"), s.get("description", ""))
    res = statespace_resource(sys_, io(d["input"]), io(d["output"]),
                              dt if dt is not None else d.get("dt"))
    res["description"] = d.get("description", "")
    return res


def build_one(kind: str, resource_name: str, resource: dict, out_dir: Path,
              fonbw_src: Path) -> Path:
    """Build one FMU: the slave script + shared module + fonbw sources + the
    resource JSON; then validate it with fmpy."""
    from pythonfmu.builder import FmuBuilder
    from fmpy.validation import validate_fmu

    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="fonbw_fmu_") as stage:
        res_file = Path(stage) / resource_name
        res_file.write_text(json.dumps(resource, indent=1), encoding="utf-8")
        fmu = FmuBuilder.build_FMU(SCRIPTS[kind], dest=out_dir,
                                   project_files=[COMMON, fonbw_src, res_file],
                                   **FMU_OPTIONS)
    problems = validate_fmu(str(fmu))
    if problems:
        raise BuildError(f"{fmu} fails validation:\n  " + "\n  ".join(problems))
    return Path(fmu)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", type=Path, default=ROOT / "models" / "fonbw_default.json",
                    help="FONBW parameter set (JSON written by fonbw's save())")
    ap.add_argument("--plant", type=Path, default=ROOT / "models" / "plant_default.json",
                    help="linear plant (JSON, kind linear_plant)")
    ap.add_argument("--dt", type=float, default=1e-4,
                    help="default internal step of the hysteresis/compensator FMUs [s]")
    ap.add_argument("-o", "--out", type=Path, default=ROOT / "models", help="output directory")
    ap.add_argument("--only", choices=sorted(SCRIPTS), action="append",
                    help="build only this FMU (repeatable)")
    ap.add_argument("--fonbw-src", type=Path, default=ROOT / "fonbw",
                    help="fonbw package directory to bundle (default: this repository's)")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(FMU_SRC))
    from fonbw_fmu_common import MODEL_RESOURCE, PLANT_RESOURCE
    try:
        built = []
        for kind in a.only or ("hysteresis", "compensator", "plant"):
            if kind == "plant":
                res, name = plant_resource(a.plant, None), PLANT_RESOURCE
            else:
                res, name = model_resource(a.params, a.dt, a.fonbw_src), MODEL_RESOURCE
            built.append(build_one(kind, name, res, a.out, a.fonbw_src))
            print(f"built {built[-1]} (fmpy validate: no problem)")
    except (BuildError, OSError, KeyError, ValueError) as e:
        print(f"build_fmu: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
