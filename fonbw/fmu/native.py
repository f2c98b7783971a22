"""Build the fonbw native FMI 2.0 co-simulation FMUs (C99, libc and libm only).

The FMUs, compiled from the C sources in ``fonbw/fmu/csrc/`` (package data):

* ``FonbwHysteresisNative``   u [V] -> y [µm], the FONBW model
* ``FonbwCompensatorNative``  y_ref [µm] -> u [V], its causal per-step inverse
* ``FonbwLinearPlantNative``  a linear state-space plant (python-control)
* ``FonbwPIDNative``          the closed loop's controller r, y, u_ff -> u
  (:class:`fonbw.loop.LoopController`: :class:`fonbw.pid.PIDStepper` with a
  feedforward added before the limits)
* ``FonbwSignalNative``       -> y, a table of samples played one per step
  (:func:`build_signal`; the libcosim master feeds the loop's exogenous
  inputs with it, so its run needs no Python per step)

and, for measuring what a master spends around the model, pass-through
variants (``FonbwPass...Native``, :data:`PASS_NAMES`): the same variables,
parameters, checks and state handling as their kind, but the step is
output = first input.

They transcribe the library's numerics operation by operation (history sums
in the same eight-lane order, the same safeguarded Newton solve and
predictor, the same compensator root finder; the fast engine's tail modes,
the GL weights and the plant's zero-order-hold discretization are computed at
initialization from the parameters), need no Python at run time, and carry
``sources/`` (declared in the model description) so any tool can compile them
for another platform. Binaries: ``linux64`` with the system ``gcc``,
``win64`` cross-compiled with ``x86_64-w64-mingw32-gcc`` when it is installed.
The FMI 2.0 headers are taken from the installed fmpy package at build time.

Every FMU is checked with fmpy's validator; a problem fails the build.
"""
from __future__ import annotations

import hashlib
import json
import math
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement, indent, tostring

import fonbw
from fonbw.compensate.rest import REST_MAX_STEPS, REST_PARAMETERS, rest_values

__all__ = ["NATIVE_DIR", "NATIVE_NAMES", "PASS_NAMES", "PLATFORMS", "SIGNAL_NAME", "host_platform", "build_native",
           "build_native_one", "build_signal", "fmi_headers", "compilers", "run"]

#: The C sources (package data).
NATIVE_DIR = Path(__file__).resolve().parent / "csrc"
C_SOURCES = ("fonbw_fmi2.c", "fonbw_model.c", "fonbw_numerics.c", "fonbw_compensator.c", "fonbw_plant.c",
             "fonbw_pid.c", "fonbw_table.c")
HEADERS = ("fonbw_instance.h", "fonbw_numerics.h")
SIGNAL_NAME = "FonbwSignalNative"
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
#: Model identifier of each kind (distinct from the pythonfmu FMUs').
NATIVE_NAMES = {"hysteresis": "FonbwHysteresisNative", "compensator": "FonbwCompensatorNative",
                "plant": "FonbwLinearPlantNative", "pid": "FonbwPIDNative"}
#: Model identifier of the pass-through variant of each kind.
PASS_NAMES = {k: v.replace("Fonbw", "FonbwPass", 1) for k, v in NATIVE_NAMES.items()}
#: Kinds that ``fonbw build-fmu --native`` builds by default.
DEFAULT_NATIVE_KINDS = ("hysteresis", "compensator", "plant")
KIND_CODES = {"hysteresis": 1, "compensator": 2, "plant": 3, "pid": 4, "signal": 5}
INTEGRATOR_CODES = {"forward": 0, "backward": 1, "tustin": 2}
ANTI_WINDUP_CODES = {"back-calculation": 0, "clamping": 1, "none": 2}
#: Platform folder -> (compiler, shared-library suffix, extra flags).
PLATFORMS = {"linux64": ("gcc", ".so", ["-fPIC", "-fvisibility=hidden", "-Wl,-Bsymbolic"]),
             "win64": ("x86_64-w64-mingw32-gcc", ".dll", ["-static-libgcc"])}
CFLAGS = ["-std=c99", "-O3", "-ffp-contract=off", "-shared"]
ENGINE_CODES = {"fast": 0, "exact": 1, "short": 2}
MAX_KU = 16
MAX_STATES = 32


class NativeBuildError(ValueError):
    """A native FMU could not be built."""


def fmi_headers() -> Path:
    """Folder of the FMI 2.0 headers shipped by the installed fmpy package."""
    import fmpy

    d = Path(fmpy.__file__).resolve().parent / "c-code"
    if not all((d / h).is_file() for h in FMI_HEADERS):
        raise NativeBuildError(f"FMI 2.0 headers not found in {d} (fmpy installation)")
    return d


def compilers() -> dict:
    """Platforms whose compiler is on PATH: ``{platform: compiler path}``."""
    return {p: shutil.which(cc) for p, (cc, _, _) in PLATFORMS.items() if shutil.which(cc)}


def _c(x: float) -> str:
    """A C double literal that reads back bit for bit."""
    x = float(x)
    if not math.isfinite(x):
        raise NativeBuildError(f"non-finite value {x!r} in a build-time parameter")
    return repr(x)


def _carray(xs) -> str:
    return "{" + ", ".join(_c(x) for x in xs) + "}"


def _model_config(res: dict) -> dict:
    """Start values of the hysteresis and compensator from a model resource
    (:func:`fonbw.fmu.build.model_resource`)."""
    p = res["model"]["params"]
    ku = [float(k) for k in (p["ku"] if isinstance(p["ku"], list) else [p["ku"]])]
    if not 1 <= len(ku) <= MAX_KU:
        raise NativeBuildError(f"the native FMUs take 1 to {MAX_KU} coefficients ku, got {len(ku)}")
    memory = p.get("memory", "fast")
    if memory not in ENGINE_CODES:
        raise NativeBuildError(f"memory engine {memory!r} is not available in the native FMUs "
                               f"(choose one of {', '.join(ENGINE_CODES)})")
    lo, hi = res["limits"]
    return {"NKU": str(len(ku)), "DEFAULT_KU": _carray(ku), "DEFAULT_KH": _c(p["kh"]),
            "DEFAULT_RHO": _c(p["rho"]), "DEFAULT_SIGMA": _c(p["sigma"]), "DEFAULT_N": _c(p["n"]),
            "DEFAULT_LAM1": _c(p["lam1"]), "DEFAULT_LAM2": _c(p["lam2"]), "DEFAULT_DT": _c(res["dt"]),
            "DEFAULT_UMIN": _c(lo), "DEFAULT_UMAX": _c(hi), "DEFAULT_K": str(int(p.get("K", fonbw.fractional.FAST_K))),
            "DEFAULT_M": str(int(p.get("M", fonbw.fractional.FAST_M))),
            "DEFAULT_L": str(int(p.get("L", fonbw.fractional.SHORT_L))),
            "DEFAULT_ENGINE": str(ENGINE_CODES[memory]), "REST_CYCLE": _carray(rest_values(res["model"])),
            "REST_MAX_STEPS": _c(REST_MAX_STEPS)}




def _plant_config(res: dict) -> dict:
    """Matrices and step of the plant from a plant resource
    (:func:`fonbw.fmu.build.plant_resource`)."""
    n = res["shape"]["A"][0]
    if not 1 <= n <= MAX_STATES:
        raise NativeBuildError(f"the native plant takes 1 to {MAX_STATES} states, got {n}")
    flat = {k: [float(x) for row in res[k] for x in row] for k in "ABCD"}
    return {"NSTATES": str(n), "PLANT_A": _carray(flat["A"]), "PLANT_B": _carray(flat["B"]),
            "PLANT_C": _carray(flat["C"]), "PLANT_D": _c(flat["D"][0]), "PLANT_DT": _c(res["sys_dt"] or 0.0),
            "DEFAULT_DT": _c(res["dt"])}


def _signal_config(res: dict) -> dict:
    """Start value of the signal's sample step [s]."""
    return {"DEFAULT_DT": _c(res["dt"])}


def _pid_config(res: dict) -> dict:
    """Start values of the PID from a controller spec
    (:func:`fonbw.loop.controller_spec`)."""
    for key, codes in (("integrator", INTEGRATOR_CODES), ("anti_windup", ANTI_WINDUP_CODES)):
        if res[key] not in codes:
            raise NativeBuildError(f"{key} = {res[key]!r} is not one of {', '.join(codes)}")
    cfg = {f"DEFAULT_{k.upper()}": _c(res[k]) for k in ("kp", "ki", "kd", "Tf", "Tt", "dt")}
    cfg.update(DEFAULT_UMIN=_c(res["u_min"]), DEFAULT_UMAX=_c(res["u_max"]),
               DEFAULT_INTEGRATOR=str(INTEGRATOR_CODES[res["integrator"]]),
               DEFAULT_ANTI_WINDUP=str(ANTI_WINDUP_CODES[res["anti_windup"]]))
    return cfg


def _sources(kind: str) -> tuple:
    """(C sources, headers) of an FMU of `kind`: the same for every kind (``MODEL_KIND`` in
    ``config.h`` selects the model)."""
    return C_SOURCES, HEADERS


def _name(kind: str, pass_through: bool = False) -> str:
    if kind == "signal":
        if pass_through:
            raise NativeBuildError("the signal FMU has no pass-through variant")
        return SIGNAL_NAME
    return (PASS_NAMES if pass_through else NATIVE_NAMES)[kind]


def config_header(kind: str, res: dict, guid: str, pass_through: bool = False) -> str:
    """Text of ``config.h`` for one FMU: its kind, GUID and start values
    (and ``PASS_THROUGH`` for the pass-through variant)."""
    name = _name(kind, pass_through)
    cfg = {"plant": _plant_config, "pid": _pid_config, "signal": _signal_config}.get(kind, _model_config)(res)
    lines = [f"/* {name}: written by fonbw.fmu.native (fonbw {fonbw.__version__}) */",
             "#ifndef FONBW_CONFIG_H", "#define FONBW_CONFIG_H",
             f"#define MODEL_KIND {KIND_CODES[kind]}", f'#define INSTANTIATION_TOKEN "{guid}"']
    if pass_through:
        lines.append("#define PASS_THROUGH 1")
    lines += [f"#define {k} {v}" for k, v in cfg.items()]
    if kind in ("plant", "pid", "signal"):  # unused FONBW names, so that one source serves all kinds
        lines += ["#define NKU 1"]
    lines.append("#endif")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------
# model description

_VR = {"in": 0, "out": 1, "kh": 2, "rho": 3, "sigma": 4, "n": 5, "lam1": 6, "lam2": 7, "dt": 8,
       "u_min": 9, "u_max": 10, "y": 11, "u_ff": 12, "kp": 13, "ki": 14, "kd": 15, "Tf": 16, "Tt": 17,
       "ku": 20, "K": 40, "M": 41, "L": 42, "status": 43, "rest_lo": 44, "rest_hi": 45, "rest_T": 46,
       "memory": 50, "integrator": 51,
       "anti_windup": 52, "file": 60}
_DT_DOC = "Internal fixed step; every communication step must be a whole multiple of it"


def _fonbw_variables(res: dict, kind: str) -> list:
    """(name, type, vr, causality, variability, unit, start, description) of
    the hysteresis or compensator FMU, in index order."""
    p = res["model"]["params"]
    ku = p["ku"] if isinstance(p["ku"], list) else [p["ku"]]
    if kind == "hysteresis":
        io = [("u", "Real", _VR["in"], "input", "continuous", "V", 0.0,
               "Actuator input voltage, held constant over each communication step"),
              ("y", "Real", _VR["out"], "output", "continuous", "um", None,
               "Actuator displacement y = g(u) + kh*h at the end of the step")]
    else:
        io = [("y_ref", "Real", _VR["in"], "input", "continuous", "um", 0.0,
               "Desired actuator displacement, held constant over each communication step"),
              ("u", "Real", _VR["out"], "output", "continuous", "V", None,
               "Compensating actuator voltage at the end of the step"),
              ("status", "Integer", _VR["status"], "output", "discrete", None, None,
               "Compensator status of the last internal step: 0 ok, 1 saturated at u_min, "
               "2 saturated at u_max, 3 solver not converged")]
    par = [(f"ku{i}", "Real", _VR["ku"] + i - 1, "parameter", "fixed", "um/V" if i == 1 else f"um/V{i}",
            k, f"Coefficient of u^{i} in the polynomial g(u) = sum_i ku_i u^i (eq. 10)")
           for i, k in enumerate(ku, start=1)]
    par += [("kh", "Real", _VR["kh"], "parameter", "fixed", "um", p["kh"],
             "Gain of the normalized hysteretic state: y = g(u) + kh*h (eq. 9)"),
            ("rho", "Real", _VR["rho"], "parameter", "fixed", "1/V", p["rho"],
             "Shape parameter rho of eq. (11); with fractional orders its time unit is "
             "s^(lam2-lam1), not shown"),
            ("sigma", "Real", _VR["sigma"], "parameter", "fixed", "1", p["sigma"], "Shape parameter sigma of eq. (11)"),
            ("n", "Real", _VR["n"], "parameter", "fixed", "1", p["n"], "Exponent n >= 1 of eq. (11)"),
            ("lam1", "Real", _VR["lam1"], "parameter", "fixed", "1", p["lam1"],
             "Fractional order lambda1 in (0, 1] of the input derivative (eq. 11)"),
            ("lam2", "Real", _VR["lam2"], "parameter", "fixed", "1", p["lam2"],
             "Fractional order lambda2 in (0, 1] of the hysteretic-state derivative (eq. 11)"),
            ("dt", "Real", _VR["dt"], "parameter", "fixed", "s", res["dt"], _DT_DOC),
            ("memory", "String", _VR["memory"], "parameter", "fixed", None, p.get("memory", "fast"),
             "Grunwald-Letnikov memory engine: fast (K exact lags + M geometric tail modes, "
             "computed at initialization from lam and dt), exact (full history, O(k) per step), "
             "short (window of L lags, inaccurate)"),
            ("K", "Integer", _VR["K"], "parameter", "fixed", None, int(p.get("K", fonbw.fractional.FAST_K)),
             "Fast engine: number of exact lags"),
            ("M", "Integer", _VR["M"], "parameter", "fixed", None, int(p.get("M", fonbw.fractional.FAST_M)),
             "Fast engine: number of geometric tail modes"),
            ("L", "Integer", _VR["L"], "parameter", "fixed", None, int(p.get("L", fonbw.fractional.SHORT_L)),
             "Short engine: window length (lags)")]
    par += [(name, "Real", _VR[name], "parameter", "fixed", unit, v, doc)
            for (name, unit, doc), v in zip(REST_PARAMETERS, rest_values(res["model"]))]
    if kind == "compensator":
        lo, hi = res["limits"]
        par += [("u_min", "Real", _VR["u_min"], "parameter", "fixed", "V", lo,
                 "Lower voltage limit; unreachable targets saturate here"),
                ("u_max", "Real", _VR["u_max"], "parameter", "fixed", "V", hi,
                 "Upper voltage limit; unreachable targets saturate here")]
    return io + par


def _pid_variables(res: dict) -> list:
    """The variables of the PID FMU (names as the pythonfmu FonbwPID's)."""
    io = [("r", "Real", _VR["in"], "input", "continuous", "um", 0.0,
           "Reference displacement, held over each communication step"),
          ("u", "Real", _VR["out"], "output", "continuous", "V", None,
           "Actuator voltage command sat(u_ff + PID(r - y)) at the end of the step"),
          ("y", "Real", _VR["y"], "input", "continuous", "um", 0.0,
           "Measured displacement, held over each communication step"),
          ("u_ff", "Real", _VR["u_ff"], "input", "continuous", "V", 0.0,
           "Feedforward voltage added to the PID output before the limits (0: feedback only)")]
    par = [(k, "Real", _VR[k], "parameter", "fixed", unit, res[k], doc) for k, unit, doc in (
        ("kp", "V/um", "Proportional gain"), ("ki", "V/(um.s)", "Integral gain"),
        ("kd", "V.s/um", "Derivative gain"), ("Tf", "s", "Derivative filter time constant"),
        ("Tt", "s", "Tracking time constant of the back-calculation anti-windup (>= dt)"),
        ("u_min", "V", "Lower output limit (use -1e300 for none)"),
        ("u_max", "V", "Upper output limit (use 1e300 for none)"),
        ("dt", "s", "Controller sample time; " + _DT_DOC[0].lower() + _DT_DOC[1:]))]
    par += [("integrator", "String", _VR["integrator"], "parameter", "fixed", None, res["integrator"],
             "Discretization of the integral: forward, backward or tustin"),
            ("anti_windup", "String", _VR["anti_windup"], "parameter", "fixed", None, res["anti_windup"],
             "Anti-windup: back-calculation, clamping or none")]
    return io + par


def _signal_variables(res: dict) -> list:
    return [("y", "Real", _VR["out"], "output", "continuous", None, None,
             "Sample k of the table after k internal steps (the last sample past the end)"),
            ("dt", "Real", _VR["dt"], "parameter", "fixed", "s", res["dt"],
             "Sample step; " + _DT_DOC[0].lower() + _DT_DOC[1:]),
            ("file", "String", _VR["file"], "parameter", "fixed", None, "",
             "Text file of the samples, one number per line (17 significant digits read back "
             "exactly); read at initialization")]


def _plant_variables(res: dict) -> list:
    i, o = res["input"], res["output"]
    return [(i["name"], "Real", _VR["in"], "input", "continuous", i.get("unit"), 0.0,
             i.get("description") or "Plant input"),
            (o["name"], "Real", _VR["out"], "output", "continuous", o.get("unit"), None,
             (o.get("description") or "Plant output") + " (C x + D u at the communication point)"),
            ("dt", "Real", _VR["dt"], "parameter", "fixed", "s", res["dt"],
             _DT_DOC + "; a continuous plant is discretized with it (zero-order hold) at initialization")]


_DESCRIPTIONS = {"hysteresis": "FONBW hysteresis of a piezo actuator (native C)",
                 "compensator": "Causal per-step inverse (compensator) of the FONBW hysteresis (native C)",
                 "pid": "Discrete PID controller with derivative filter, output limits and anti-windup "
                        "(fonbw.pid.PIDStepper), plus a feedforward input added before the limits: "
                        "u = sat(u_ff + PID(r - y)); fixed sample time dt (native C)"}


def _description(kind: str, res: dict, pass_through: bool) -> str:
    if kind == "signal":
        return "A table of samples played one per internal step: y = table[k] after k steps (native C)"
    if pass_through:
        return (f"Pass-through with the interface of {NATIVE_NAMES[kind]}: output = first input "
                f"(a baseline for the cost of a master; native C)")
    if kind == "plant":
        return res.get("description") or "Linear state-space plant, exact zero-order hold"
    return _DESCRIPTIONS[kind]


def model_description(kind: str, res: dict, guid: str, pass_through: bool = False) -> str:
    """modelDescription.xml of one native FMU (or of its pass-through variant)."""
    from fonbw.fmu.slaves.fonbw_fmu_common import base_unit

    mid = _name(kind, pass_through)
    plant = kind == "plant"
    variables = {"plant": _plant_variables, "pid": _pid_variables, "signal": _signal_variables}.get(
        kind, lambda r: _fonbw_variables(r, kind))(res)
    states = "false" if kind == "signal" else "true"
    root = Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": mid, "guid": guid, "generationTool": f"fonbw {fonbw.__version__}",
        "description": _description(kind, res, pass_through),
        "author": "fonbw", "license": "MIT", "variableNamingConvention": "structured",
        "numberOfEventIndicators": "0"})
    cs = SubElement(root, "CoSimulation", {
        "modelIdentifier": mid, "needsExecutionTool": "false", "canHandleVariableCommunicationStepSize": "true",
        "canBeInstantiatedOnlyOncePerProcess": "false", "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": states, "canSerializeFMUstate": states})
    files = SubElement(cs, "SourceFiles")
    for f in _sources(kind)[0]:
        SubElement(files, "File", {"name": f})
    units = sorted({v[5] for v in variables if v[5]})
    if units:
        defs = SubElement(root, "UnitDefinitions")
        for name in units:
            u = SubElement(defs, "Unit", {"name": name})
            attrs = base_unit(name)
            if attrs is not None:
                SubElement(u, "BaseUnit", attrs)
    cats = SubElement(root, "LogCategories")
    for c in ("logStatusWarning", "logStatusDiscard", "logStatusError"):
        SubElement(cats, "Category", {"name": c})
    SubElement(root, "DefaultExperiment", {"startTime": "0.0", "stopTime": "2.0", "stepSize": repr(float(res["dt"]))})
    mv = SubElement(root, "ModelVariables")
    for name, typ, vr, caus, var, unit, start, doc in variables:
        sv = SubElement(mv, "ScalarVariable", {"name": name, "valueReference": str(vr), "description": doc,
                                               "causality": caus, "variability": var})
        if caus == "output":
            sv.set("initial", "calculated")
        elif caus == "parameter":
            sv.set("initial", "exact")
        t = SubElement(sv, typ)
        if start is not None:
            t.set("start", repr(float(start)) if typ == "Real" else str(start))
        if unit:
            t.set("unit", unit)
    ms = SubElement(root, "ModelStructure")
    outs = [i for i, v in enumerate(variables, 1) if v[3] == "output"]
    feed = plant and not pass_through and float(res["D"][0][0]) != 0.0
    deps = "1" if feed else ""
    for tag in ("Outputs", "InitialUnknowns"):
        node = SubElement(ms, tag)
        for i in outs:
            SubElement(node, "Unknown", {"index": str(i), "dependencies": deps})
    indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="unicode") + "\n"


# ---------------------------------------------------------------------------
# building

def _stage_sources(src: Path, kind: str, res: dict, guid: str, pass_through: bool) -> None:
    src.mkdir(parents=True)
    for f in sum(_sources(kind), ()):
        shutil.copy(NATIVE_DIR / f, src / f)
    hdr = fmi_headers()
    for f in FMI_HEADERS:
        shutil.copy(hdr / f, src / f)
    (src / "config.h").write_text(config_header(kind, res, guid, pass_through), encoding="utf-8")


def compile_binary(src: Path, out: Path, platform: str, compiler: str | None = None,
                   sources=C_SOURCES) -> Path:
    """Compile the C `sources` in `src` into the shared library `out` for `platform`."""
    cc, _, extra = PLATFORMS[platform]
    cmd = [compiler or cc, *CFLAGS, *extra, "-I", str(src), "-o", str(out),
           *[str(src / f) for f in sources], "-lm"]
    out.parent.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise NativeBuildError(f"{platform} compile failed ({' '.join(cmd)}):\n{r.stderr[-3000:]}")
    return out


def _guid(kind: str, res: dict, pass_through: bool = False) -> str:
    h = hashlib.sha1(json.dumps([kind, res, pass_through], sort_keys=True).encode())
    for f in sum(_sources(kind), ()):
        h.update((NATIVE_DIR / f).read_bytes())
    return "{" + str(uuid.UUID(bytes=h.digest()[:16])) + "}"


def host_platform() -> str:
    """The platform folder of this process (``linux64`` or ``win64``)."""
    import sys

    return "win64" if sys.platform == "win32" else "linux64"


def build_native_one(kind: str, res: dict, out_dir, platforms=None, pass_through: bool = False) -> Path:
    """Build one native FMU of `kind` from its resource (the dict the
    pythonfmu builder writes: :func:`fonbw.fmu.build.model_resource` or
    :func:`~fonbw.fmu.build.plant_resource`) into `out_dir`, then validate it.

    Parameters
    ----------
    kind : {"hysteresis", "compensator", "plant", "pid", "signal"}
    res : dict
        Model or plant resource, for ``pid`` a controller spec
        (:func:`fonbw.loop.controller_spec`), for ``signal`` ``{"dt": step [s]}``.
    out_dir : path-like
        Output folder (created if missing).
    platforms : sequence of str, optional
        Binaries to compile (default: every platform whose compiler is on PATH).
    pass_through : bool
        Build the pass-through variant (:data:`PASS_NAMES`) instead.

    Returns
    -------
    Path
        The FMU written.
    """
    from fmpy.validation import validate_fmu

    avail = compilers()
    platforms = list(platforms) if platforms is not None else sorted(avail)
    missing = [p for p in platforms if p not in avail]
    if missing or not platforms:
        raise NativeBuildError(f"no compiler for {', '.join(missing) or 'any platform'} "
                               f"(need {', '.join(PLATFORMS[p][0] for p in missing or PLATFORMS)})")
    mid = _name(kind, pass_through)
    guid = _guid(kind, res, pass_through)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fmu = out_dir / f"{mid}.fmu"
    with tempfile.TemporaryDirectory(prefix="fonbw_native_") as stage:
        stage = Path(stage)
        _stage_sources(stage / "sources", kind, res, guid, pass_through)
        (stage / "modelDescription.xml").write_text(model_description(kind, res, guid, pass_through),
                                                    encoding="utf-8")
        for p in platforms:
            compile_binary(stage / "sources", stage / "binaries" / p / (mid + PLATFORMS[p][1]), p,
                           sources=_sources(kind)[0])
        tmp = out_dir / f".{mid}.fmu.tmp"
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
            for f in sorted(stage.rglob("*")):
                if f.is_file():
                    z.write(f, f.relative_to(stage).as_posix())
        tmp.replace(fmu)
    problems = validate_fmu(str(fmu))
    if problems:
        raise NativeBuildError(f"{fmu} fails validation:\n  " + "\n  ".join(problems))
    return fmu


def build_signal(out_dir, dt: float, platforms=None) -> Path:
    """Build the signal FMU (``FonbwSignalNative``: y plays the samples of
    the text file named by its String parameter ``file``, one per step of
    `dt` [s]) into `out_dir`; see :func:`build_native_one`."""
    return build_native_one("signal", {"dt": float(dt)}, out_dir, platforms)


def cached_signal(cache_dir) -> Path | None:
    """The signal FMU for this platform under `cache_dir` (a folder named by
    its GUID), built on first use; None when this platform has no compiler.
    Its dt is a parameter, so one build serves every step."""
    import os

    if host_platform() not in compilers():
        return None
    res = {"dt": 1e-4}
    path = Path(cache_dir) / _guid("signal", res).strip("{}")[:13] / f"{SIGNAL_NAME}.fmu"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
            os.replace(build_native_one("signal", res, tmp, [host_platform()]), path)
    return path


def build_native(out_dir, *, params=None, plant=None, dt: float | None = None,
                 kinds=DEFAULT_NATIVE_KINDS, platforms=None, controller=None) -> list[Path]:
    """Build the native hysteresis, compensator and plant (and PID) FMUs into `out_dir`.

    Parameters
    ----------
    out_dir : path-like
        Output folder.
    params : path-like, optional
        FONBW parameter set (JSON); default the library's default model.
    plant : path-like, optional
        Linear plant (JSON, kind linear_plant); default the library's default plant.
    dt : float, optional
        Default internal step [s] (default 1e-4; the plant: its file's step).
    kinds : sequence of str
        Which FMUs to build (of :data:`NATIVE_NAMES`).
    platforms : sequence of str, optional
        ``linux64``, ``win64`` (default: those with a compiler on PATH).
    controller : dict, optional
        Start values of the PID (:func:`fonbw.loop.controller_spec` keyword
        arguments; default kp = 1e-3 V/um, ki = 100 V/(um s)).

    Returns
    -------
    list of Path
        The FMUs written, each validated by fmpy.
    """
    from fonbw.fmu.build import DEFAULT_DT, kind_resource, pid_resource

    built = []
    for kind in kinds:
        if kind == "pid":
            res = pid_resource(controller, DEFAULT_DT if dt is None else dt)
        elif kind in NATIVE_NAMES:
            res = kind_resource(kind, params, plant, dt)[0]
        else:
            raise NativeBuildError(f"no native FMU of kind {kind!r}; choose from {', '.join(NATIVE_NAMES)}")
        built.append(build_native_one(kind, res, out_dir, platforms))
    return built


def run(ns) -> int:
    """``build-fmu --native``: build the native FMUs the parsed options ask for."""
    kinds = [k for k in (ns.only or DEFAULT_NATIVE_KINDS) if k in NATIVE_NAMES]
    controller = None
    if getattr(ns, "controller", None) is not None:
        controller = json.loads(Path(ns.controller).read_text(encoding="utf-8"))
    avail = compilers()
    for p in PLATFORMS:
        if p not in avail:
            print(f"note: {PLATFORMS[p][0]} not found: no {p} binary (the FMUs carry sources/)")
    dt = ns.dt if ns.dt != 1e-4 else None
    for p in build_native(ns.output, params=ns.params, plant=ns.plant, dt=dt, kinds=kinds,
                          controller=controller):
        print(f"wrote {p} ({', '.join(sorted(avail))}; fmpy validate: no problem)")
    return 0
