"""Shared plumbing of the fonbw FMUs (pythonfmu slaves). No numerics here.

Everything numerical comes from the `fonbw` package, which the FMU carries in
its resources folder, so an FMU runs in a fresh Python process that has
numpy/numba/scipy/control but no installed `fonbw` (use_bundled_fonbw below
imports it from a digest-checked copy so that numba's cache can be reused).

Why the slave methods never raise: pythonfmu's C layer turns any Python
exception into fmi2Fatal *and* releases the Python slave object on the spot
(`cleanPyObject`), so the next call on that instance (even fmi2FreeInstance)
touches freed memory -- checked with pythonfmu 0.7.0 + fmpy: a slave raising
in exit_initialization_mode segfaults the host at the following call.  A bad
parameter must not be able to take the host down, so every entry point here
catches, logs with an FMI status and reports through the channels pythonfmu
does offer: a log line with status fmi2Error at initialization, and
fmi2Discard from fmi2DoStep (do_step returning False).

This module is imported by every fonbw FMU under the same name; FMUs built by
one build_fmu.py run carry identical copies, so sharing it is harmless.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Optional
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Fmi2Slave, Fmi2Causality, Fmi2Variability, Real, String
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Initial, Fmi2Status

# Name of the parameter-set file inside an FMU's resources folder.
MODEL_RESOURCE = "fonbw_model.json"
PLANT_RESOURCE = "fonbw_plant.json"
PID_RESOURCE = "fonbw_pid.json"

# A communication step h is accepted when h/dt is within this many internal
# steps of a whole number >= 1.  Not zero: masters compute h as a difference of
# absolute times (fmpy: t_{k+1} - t_k), which is off by a few ulps of t.
STEP_MULTIPLE_TOL = 1e-6

MEMORY_ENGINES = ("fast", "exact", "short", "oustaloup")

# Steppers of freed instances, kept until the interpreter exits.  Workaround:
# when a fonbw stepper was destroyed inside fmi2FreeInstance, 3-6 host processes
# in 10 aborted at exit with "corrupted double-linked list" (in the exit handler
# of scipy's bundled libgfortran); kept alive, 0 in 10.  Root cause not found
# (a plain process deleting a stepper does not abort).  Cost: the memory of the
# retired steppers (KB for the fast engine, the run's history for 'exact').
_RETIRED: List[Any] = []

# SI base-unit exponents of the unit symbols used by these FMUs.  Unit names are
# written like "um/V2" (micrometre per volt squared): a product of symbols with
# optional integer powers, an optional single "/" for the denominator.
_SYMBOLS: Dict[str, tuple] = {
    "V": ({"kg": 1, "m": 2, "s": -3, "A": -1}, 1.0),
    "um": ({"m": 1}, 1e-6),
    "m": ({"m": 1}, 1.0),
    "s": ({"s": 1}, 1.0),
    "A": ({"A": 1}, 1.0),
    "N": ({"kg": 1, "m": 1, "s": -2}, 1.0),
    "rad": ({"rad": 1}, 1.0),
}


def base_unit(name: str) -> Optional[Dict[str, str]]:
    """BaseUnit attributes (SI exponents, factor) for a unit name, or None if
    the name uses a symbol not known here (the Unit is then written without a
    BaseUnit, which FMI 2.0 allows)."""
    if name == "1":
        return {}
    num, _, den = name.partition("/")
    exps: Dict[str, int] = {}
    factor = 1.0
    for part, sign in ((num, 1), (den, -1)):
        for tok in filter(None, part.split(".")):
            if tok == "1":
                continue
            m = re.fullmatch(r"([A-Za-z]+)(-?\d*)", tok)
            if not m or m.group(1) not in _SYMBOLS:
                return None
            p = sign * int(m.group(2) or 1)
            e, f = _SYMBOLS[m.group(1)]
            for k, v in e.items():
                exps[k] = exps.get(k, 0) + p * v
            factor *= f ** p
    attrs = {k: str(v) for k, v in exps.items() if v != 0}
    if factor != 1.0:
        attrs["factor"] = repr(factor)
    return attrs


def _tree_digest(folder: Path) -> str:
    """SHA-256 over the relative paths and bytes of the source files of a package."""
    h = hashlib.sha256()
    for p in sorted(q for q in folder.rglob("*") if q.is_file() and "__pycache__" not in q.parts):
        h.update(p.relative_to(folder).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def use_bundled_fonbw(resources: str) -> Optional[str]:
    """Make `import fonbw` load the fonbw sources bundled in this FMU, preferably
    from a content-addressed copy in a per-user cache folder; return the folder
    put first on sys.path (None if the process already imported fonbw: all
    FMUs of a process share one interpreter and sys.modules).

    Why a copy: numba's on-disk cache (cache=True) lives next to the sources and
    is keyed by their path and mtime.  Masters that extract the FMU to a fresh
    temporary folder on every run (fmpy's simulate_fmu, libcosim) would
    otherwise recompile every kernel in every process.  The copy sits at
    <cache>/<sha256 of the bundled sources> and is checked against that digest
    before use, so the code run is byte for byte the bundled code.  <cache> is
    $FONBW_FMU_CACHE, else $XDG_CACHE_HOME/fonbw-fmu, else ~/.cache/fonbw-fmu.
    Any problem (read-only home, digest mismatch) falls back to the bundled
    folder in place, which only costs the compile time.
    """
    if "fonbw" in sys.modules:
        return None
    path = str(resources)
    try:
        src = Path(resources) / "fonbw"
        digest = _tree_digest(src)
        root = Path(os.environ.get("FONBW_FMU_CACHE")
                    or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "fonbw-fmu")
        target = root / digest[:32]
        if not (target / "fonbw").is_dir():
            root.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=".tmp-", dir=root))
            shutil.copytree(src, tmp / "fonbw", ignore=shutil.ignore_patterns("__pycache__"))
            try:
                os.rename(tmp, target)  # atomic; fails if another process won the race
            except OSError:
                shutil.rmtree(tmp, ignore_errors=True)
        if _tree_digest(target / "fonbw") == digest:
            path = str(target)
    except OSError:
        pass
    if path in sys.path:
        sys.path.remove(path)
    sys.path.insert(0, path)
    return path


class UReal(Real):
    """pythonfmu Real with a unit, and a start value written so that it reads
    back bit for bit (repr, 17 significant digits when needed; pythonfmu's own
    '%.16g' can lose the last bit of an identified parameter)."""

    def __init__(self, name: str, unit: Optional[str] = None, **kwargs):
        super().__init__(name, **kwargs)
        self.unit = unit

    def to_xml(self) -> Element:
        node = super().to_xml()
        real = node.find("Real")
        if self.start is not None:
            real.set("start", repr(float(self.start)))
        if self.unit:
            real.set("unit", self.unit)
        return node


def read_json(path: Path) -> Dict[str, Any]:
    with open(path, "r", encoding="utf-8") as f:
        return json.load(f)


def fonbw_parameters(d: Dict[str, Any]) -> Dict[str, Any]:
    """The FONBW parameters of a fonbw model dictionary (as written by
    fonbw's save()/to_dict()).  Plain JSON reading, no fonbw import, so that
    building the model description does not pay the numba start-up."""
    p = d.get("params", d)
    out = {k: p[k] for k in ("kh", "rho", "sigma", "n", "lam1", "lam2")}
    out["ku"] = [float(k) for k in p["ku"]]
    out["memory"] = str(d.get("memory", p.get("memory", "fast")))
    return out


class FonbwSlaveBase(Fmi2Slave):
    """Single-input single-output fixed-step slave around a fonbw stepper.

    Sampling convention: doStep(t, h) holds the input value set before the
    call over (t, t+h] (zero-order hold), advances the stepper m = h/dt
    internal steps with it, and the output is the value at t+h with that input
    still held.  For the hysteresis and the compensator that is the last
    stepper output, so with h = dt the output at t_{k+1} is the library's
    y[k] = F(u[0..k]); before the first step it is 0 (at rest, no sample
    processed).  These outputs do not react to an input set at a communication
    point until the next doStep, so ModelStructure says dependencies="" (no
    direct feedthrough, hence no algebraic loop for the master).  Subclasses
    with a true feedthrough override _output() and set _feedthrough.
    """

    _feedthrough = False

    author = "fonbw"
    license = "MIT"
    copyright = "fonbw authors"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._stepper = None
        self._built_from = None      # parameter snapshot the stepper was built from
        self._fault: Optional[str] = "not initialized (fmi2ExitInitializationMode not called yet)"
        self._in_name = self._out_name = None
        self._x_in = 0.0
        self._x_out = 0.0
        self._vr_in = self._vr_out = -1  # value references of the input/output (_io)
        self._param_names: List[str] = []
        self._restoring = False      # True while fmi2SetFMUstate writes parameters
        self.dt = 1e-4

    def __del__(self):
        # runs inside pythonfmu's fmi2FreeInstance / fmi2Reset: see _RETIRED
        self._drop_stepper()

    def _drop_stepper(self):
        """Forget the current stepper without destroying it (see _RETIRED)."""
        if getattr(self, "_stepper", None) is not None:
            _RETIRED.append(self._stepper)
        self._stepper = None

    # ---- registration helpers ------------------------------------------------
    def _fixed_setter(self, name: str, cast):
        """Setter of a 'fixed' parameter: once the stepper is built, a new value
        would silently disagree with it, so it is refused with an error log
        (pythonfmu offers no error status from fmi2SetXXX)."""
        def set_(v):
            v = cast(v)
            old = getattr(self, name)
            if self._stepper is not None and not self._restoring and v != old:
                self.log(f"{self.instance_name}: {name} is a fixed parameter; the new value "
                         f"{v!r} is ignored after initialization (kept {old!r})", Fmi2Status.error)
                return
            setattr(self, name, v)
        return set_

    def _parameter(self, name: str, start: float, unit: Optional[str], description: str):
        setattr(self, name, float(start))
        self._param_names.append(name)
        self.register_variable(UReal(
            name, unit=unit, description=description,
            causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
            initial=Fmi2Initial.exact, setter=self._fixed_setter(name, float)))

    def _string_parameter(self, name: str, start: str, description: str):
        setattr(self, name, str(start))
        self._param_names.append(name)
        self.register_variable(String(
            name, description=description, causality=Fmi2Causality.parameter,
            variability=Fmi2Variability.fixed, initial=Fmi2Initial.exact,
            setter=self._fixed_setter(name, str)))

    def _io(self, inp: tuple, out: tuple):
        """Register the input (name, unit, description) and output."""
        self._in_name, self._out_name = inp[0], out[0]
        self._vr_in, self._vr_out = len(self.vars), len(self.vars) + 1  # registered next

        def set_in(v):
            self._x_in = float(v)

        self.register_variable(UReal(
            inp[0], unit=inp[1], description=inp[2], causality=Fmi2Causality.input,
            variability=Fmi2Variability.continuous, getter=lambda: self._x_in, setter=set_in))
        self.register_variable(UReal(
            out[0], unit=out[1], description=out[2], causality=Fmi2Causality.output,
            variability=Fmi2Variability.continuous, initial=Fmi2Initial.calculated,
            getter=lambda: self._output(), setter=None))

    def _output(self) -> float:
        return self._x_out

    # Fast paths for the per-step calls fmi2SetReal(input) / fmi2GetReal(output):
    # pythonfmu's generic loops cost ~1 us each per call, a tenth of an FMU step.
    def set_real(self, vrs, values):
        if len(vrs) == 1 and vrs[0] == self._vr_in:
            self._x_in = float(values[0])
        else:
            super().set_real(vrs, values)

    def get_real(self, vrs):
        if len(vrs) == 1 and vrs[0] == self._vr_out:
            return [float(self._output())]
        return super().get_real(vrs)

    def _default_experiment(self, stop_time: float = 2.0):
        self.default_experiment = DefaultExperiment(start_time=0.0, stop_time=stop_time,
                                                    step_size=self.dt)

    # ---- to be provided by subclasses ----------------------------------------
    def _check_parameters(self) -> List[str]:
        """Problems with the current parameter values (empty list: fine)."""
        return []

    def _build(self):
        """Return a fresh stepper object for the current parameter values."""
        raise NotImplementedError

    # ---- FMI entry points ----------------------------------------------------
    def _params_snapshot(self):
        return tuple(getattr(self, n) for n in self._param_names)

    def _check_dt(self) -> List[str]:
        dt = self.dt
        if not (isinstance(dt, float) and math.isfinite(dt) and dt > 0.0):
            return [f"dt = {dt!r} s must be a finite number > 0"]
        return []

    def _try_build(self) -> bool:
        what = "invalid parameters"
        try:
            problems = self._check_dt() + self._check_parameters()
            if not problems:
                use_bundled_fonbw(self.resources)  # before the first `import fonbw`
                stepper = self._build()
                # Warm-up step then reset: numba compiles on the first call;
                # do it now rather than inside the first (timed) doStep.
                stepper.step(0.0)
                stepper.reset()
        except ValueError as e:  # the library refuses the parameter set
            problems = [str(e)]
        except Exception as e:  # anything else: say so, do not blame the parameters
            what, problems = "cannot build the model", [f"{type(e).__name__}: {e}"]
        if problems:
            self._drop_stepper()
            self._fault = f"{what}: " + "; ".join(problems)
            self.log(f"{self.instance_name}: {self._fault}", Fmi2Status.error)
            return False
        self._drop_stepper()
        self._stepper = stepper
        self._built_from = self._params_snapshot()
        self._fault = None
        return True

    def exit_initialization_mode(self):
        self._x_out = 0.0
        self._try_build()

    def do_step(self, current_time: float, step_size: float) -> bool:
        stepper = self._stepper
        if stepper is None:
            self.log(f"{self.instance_name}: doStep at t={current_time!r} refused: {self._fault}",
                     Fmi2Status.discard)
            return False
        m = step_size / self.dt
        # (written so that NaN and inf fail the first comparison)
        k = int(m + 0.5) if 0.5 <= m < 1e15 else 0
        if k < 1 or abs(m - k) > STEP_MULTIPLE_TOL:
            self.log(f"{self.instance_name}: doStep at t={current_time!r} refused: communication "
                     f"step {step_size!r} s is not a whole multiple of the internal step "
                     f"dt = {self.dt!r} s (ratio {m!r}); no resampling is done",
                     Fmi2Status.discard)
            return False
        try:
            u = self._x_in
            if k == 1:  # the common case, without loop overhead
                self._x_out = float(stepper.step(u))
            else:
                step = stepper.step
                y = 0.0
                for _ in range(k):
                    y = step(u)
                self._x_out = float(y)
        except Exception as e:
            # the stepper may be half-way through the step: refuse further steps
            self._drop_stepper()
            self._fault = f"doStep at t={current_time!r} failed: {type(e).__name__}: {e}"
            self.log(f"{self.instance_name}: {self._fault}", Fmi2Status.error)
            return False
        return True

    # ---- FMU state: variables + the stepper's full memory ----------------------
    def _get_fmu_state(self) -> Dict[str, Any]:
        state = {v.name: v.getter() for v in self.vars.values()}
        state["__fault__"] = self._fault
        state["__stepper__"] = (None if self._stepper is None
                                else [float(x) for x in self._stepper.get_state()])
        return state

    def _set_fmu_state(self, state: Dict[str, Any]):
        try:
            import numpy as np
            self._restoring = True
            try:
                for v in self.vars.values():
                    if v.name in state and v.setter is not None:
                        v.setter(state[v.name])
            finally:
                self._restoring = False
            self._x_out = float(state.get(self._out_name, 0.0))
            arr = state.get("__stepper__")
            if arr is None:
                self._drop_stepper()
                self._fault = state.get("__fault__") or "restored state has no stepper"
                return
            if self._stepper is None or self._built_from != self._params_snapshot():
                if not self._try_build():
                    return
            self._stepper.set_state(np.asarray(arr, dtype=np.float64))
            self._fault = None
        except Exception as e:
            self._drop_stepper()
            self._fault = f"FMU state could not be restored: {type(e).__name__}: {e}"
            self.log(f"{self.instance_name}: {self._fault}", Fmi2Status.error)

    # ---- model description: units, dependencies, initial unknowns ------------
    def to_xml(self, model_options: Dict[str, str] = dict()) -> Element:
        root = super().to_xml(model_options)
        units = sorted({v.unit for v in self.vars.values() if getattr(v, "unit", None)})
        if units:
            defs = Element("UnitDefinitions")
            for name in units:
                unit = SubElement(defs, "Unit", {"name": name})
                attrs = base_unit(name)
                if attrs is not None:
                    SubElement(unit, "BaseUnit", attrs)
            # schema order: CoSimulation, UnitDefinitions, ..., LogCategories
            pos = list(root).index(root.find("CoSimulation")) + 1
            root.insert(pos, defs)
        structure = root.find("ModelStructure")
        for child in list(structure):
            structure.remove(child)
        outs = [i + 1 for i, v in enumerate(self.vars.values())
                if v.causality == Fmi2Causality.output]
        ins = [i + 1 for i, v in enumerate(self.vars.values())
                if v.causality == Fmi2Causality.input]
        # dependencies="" means: depends on no input at a communication point
        # (see the class docstring); same at initialization.
        deps = " ".join(map(str, ins)) if self._feedthrough else ""
        for tag in ("Outputs", "InitialUnknowns"):
            if outs:
                node = SubElement(structure, tag)
                for i in outs:
                    SubElement(node, "Unknown", {"index": str(i), "dependencies": deps})
        return root


class FonbwModelSlave(FonbwSlaveBase):
    """Common part of the hysteresis and compensator FMUs: the FONBW parameter
    set as FMU parameters, start values from the build-time parameter set."""

    def _register_fonbw_parameters(self) -> Dict[str, Any]:
        # Resource file written by build_fmu.py: {"model": <fonbw model dict>, "dt": s}
        res = read_json(Path(self.resources) / MODEL_RESOURCE)
        p = fonbw_parameters(res["model"])
        # the model's record (training range, invertibility); its start is a parameter below
        self._meta = {k: res["model"][k] for k in ("u_range", "invertibility") if k in res["model"]}
        self._n_ku = len(p["ku"])
        for i, k in enumerate(p["ku"], start=1):
            unit = "um/V" if i == 1 else f"um/V{i}"
            self._parameter(f"ku{i}", k, unit,
                            f"Coefficient of u^{i} in the polynomial g(u) = sum_i ku_i u^i "
                            f"(eq. 10), {unit}")
        self._parameter("kh", p["kh"], "um",
                        "Gain of the normalized hysteretic state: y = g(u) + kh*h (eq. 9)")
        self._parameter("rho", p["rho"], "1/V",
                        "Shape parameter rho of the normalized Bouc-Wen equation (eq. 11); "
                        "with fractional orders its time unit is s^(lam2-lam1), not shown")
        self._parameter("sigma", p["sigma"], "1",
                        "Shape parameter sigma of the normalized Bouc-Wen equation (eq. 11)")
        self._parameter("n", p["n"], "1",
                        "Exponent n >= 1 of the normalized Bouc-Wen equation (eq. 11)")
        self._parameter("lam1", p["lam1"], "1",
                        "Fractional order lambda1 in (0, 1] of the input derivative (eq. 11)")
        self._parameter("lam2", p["lam2"], "1",
                        "Fractional order lambda2 in (0, 1] of the hysteretic-state "
                        "derivative (eq. 11)")
        self._string_parameter("memory", p["memory"],
                               "Grunwald-Letnikov memory engine: fast (default, truncated "
                               "history + geometric tail modes), exact (full history, O(k) "
                               "per step), short (short-memory window, inaccurate), "
                               "oustaloup (refined Oustaloup filter of the paper's toolbox)")
        use_bundled_fonbw(self.resources)  # before the first `import fonbw`
        from fonbw.compensate.rest import REST_PARAMETERS, rest_values  # bundled copy
        for (name, unit, doc), v in zip(REST_PARAMETERS, rest_values(res["model"])):
            self._parameter(name, v, unit, doc)
        self._parameter("dt", float(res.get("dt", 1e-4)), "s",
                        "Internal fixed step of the GL discretization; every communication "
                        "step must be a whole multiple of it")
        return res

    def _model_kwargs(self) -> Dict[str, Any]:
        return dict(ku=[getattr(self, f"ku{i}") for i in range(1, self._n_ku + 1)],
                    kh=self.kh, rho=self.rho, sigma=self.sigma, n=self.n,
                    lam1=self.lam1, lam2=self.lam2, memory=self.memory)

    def _check_parameters(self) -> List[str]:
        # Only what must hold for any memory engine; the library checks the rest.
        kw = self._model_kwargs()
        problems = [f"{k} = {v!r} is not finite" for k, v in kw.items()
                    if k not in ("ku", "memory") and not math.isfinite(v)]
        problems += [f"ku{i} = {v!r} is not finite" for i, v in enumerate(kw["ku"], 1)
                     if not math.isfinite(v)]
        if math.isfinite(self.n) and self.n < 1.0:
            problems.append(f"n = {self.n!r} must be >= 1")
        for k in ("lam1", "lam2"):
            v = kw[k]
            if math.isfinite(v) and not (0.0 < v <= 1.0):
                problems.append(f"{k} = {v!r} must lie in (0, 1]")
        from fonbw.compensate.rest import REST_MAX_STEPS  # bundled copy (put first at instantiation)

        lo, hi, T = self.rest_lo, self.rest_hi, self.rest_T
        if not (math.isfinite(T) and T >= 0.0 and (T == 0.0 or (math.isfinite(lo) and math.isfinite(hi)
                                                                and lo < hi))):
            problems.append(f"rest_T = {T!r} s must be >= 0 (0: start from rest), and with a rest cycle "
                            f"rest_lo = {lo!r} V < rest_hi = {hi!r} V")
        elif T > 0.0 and isinstance(self.dt, float) and self.dt > 0.0 and T / self.dt > REST_MAX_STEPS:
            problems.append(f"rest_T = {T!r} s is more than {REST_MAX_STEPS:g} steps of dt")
        if self.memory not in MEMORY_ENGINES:
            problems.append(f"memory = {self.memory!r} is not one of {', '.join(MEMORY_ENGINES)}")
        return problems

    def _fonbw_model(self):
        import fonbw  # the bundled copy (use_bundled_fonbw)
        from fonbw.compensate.rest import start_from_values

        m = fonbw.FONBW(**self._model_kwargs())
        start = start_from_values(self.rest_lo, self.rest_hi, self.rest_T)
        m.meta = {**self._meta, **({"start": start} if start else {})}
        return m
