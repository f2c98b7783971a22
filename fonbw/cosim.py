"""Closed-loop co-simulation of the PEA: compensator, hysteresis, plant, controller.

Three masters run the same fixed-step loop and give the same numbers (to
round-off; tests/test_cosim.py checks it sample by sample):

* ``"reference"`` — pure Python on the library's own steppers
  (``FONBW.stepper``, ``fonbw.compensator``, :class:`fonbw.plant.LinearStepper`,
  :class:`LoopController`);
* ``"fmpy"`` — the FMUs of ``build_fmu.py`` (FonbwCompensator, FonbwHysteresis,
  FonbwLinearPlant) through fmpy's FMI 2 API (``FMU2Slave``: instantiate,
  setupExperiment, enter/exitInitializationMode, setReal, doStep, getReal); the
  controller runs in the master as library code;
* ``"libcosim"`` — the same FMUs plus the controller FMU FonbwPID
  (``fmu_src/fonbw_pid_fmu.py``) in libcosim (Open Simulation Platform, through
  libcosimpy), an independent master.

Loop (``mode``)::

    open :  r/k_lin ------------------------------> hyst -> [plant] -> y
    ff   :  r -> comp ----------------------------> hyst -> [plant] -> y
    fb   :  r, y -> ctrl -------------------------> hyst -> [plant] -> y
    ff+fb:  r -> comp -> u_ff; r, y, u_ff -> ctrl -> hyst -> [plant] -> y

``hyst`` is the "true" actuator (a FONBW model), ``comp`` the eq. (16)-(17)
inverse of the identified model, ``plant`` optional linear dynamics
(mechanics, creep; :func:`plant_system`), ``ctrl`` a PI(D) with output limits,
anti-windup and the feedforward added before the limits (:class:`LoopController`).
``k_lin`` is the model's mean slope (:func:`linear_gain`).

Convention (stated once, used by all three masters; it is libcosim's fixed-step
algorithm): **Jacobi**, every connection carries the value an output had after
the previous communication step, every block is stepped once per
communication step, and no output depends on an input set at the same
communication point (all FMUs declare ``dependencies=""``; the controller
has the one-sample computational delay of a real DAQ loop). So each
connection is a one-step delay and no loop is algebraic. Exogenous inputs
(reference, open-loop voltage) are set before the step they belong to.

Alignment: a block that is ``d`` connections upstream of the measured output
gets the reference ``d`` steps ahead (a known trajectory, fed with preview,
so the pipeline latency is not counted as tracking error: in ``ff`` without a
plant, the measured output after step k is exactly the library chain
``H(C(r_0..r_k))``). The controller compares the reference with the
measurement of the same sample: at step k it gets ``r_{k-1}`` and the output
after step k-1. The error of sample k is ``e_k = r_k - y_k``, ``y_k`` the
measured output after step k (``t_{k+1}``).

Limits: the libcosim master needs T to be a whole multiple of dt (no shorter
final step); the FMU masters load the FMUs into the calling process, so the
FMUs use that process's ``fonbw`` if it is already imported (see
fmu_src/README.md; the FMUs' own bundled copy is tested by tests/test_fmu.py).
Speed (BENCHMARKS.md, "Closed loop"): fmpy runs the 10 kHz loop faster than
real time; libcosim is about 7x slower, as it steps the Python slaves on
worker threads that must share the GIL.

Units: u [V], y, r [µm], t [s].
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time
from pathlib import Path

import control as ct
import numpy as np

from . import plant as _plant
from .hysteresis import FONBW, load_model
from .paper import U_RANGE
from .signals import SCENARIOS, trajectory  # noqa: F401

__all__ = [
    "MODES",
    "MASTERS",
    "PLANTS",
    "SCENARIOS",
    "trajectory",
    "plant_system",
    "linear_gain",
    "controller_spec",
    "loop_plant",
    "design_controller",
    "LoopController",
    "build_fmus",
    "run_cosim",
    "ff_fb_study",
    "add_cosim_arguments",
    "cosim_command",
    "cosim_main",
    "CosimError",
]

MODES = ("open", "ff", "fb", "ff+fb")
MASTERS = ("reference", "fmpy", "libcosim")
PLANTS = ("none", "dynamics", "creep", "dynamics+creep")
DT = 1e-4
#: Output limits of the controller [V] (the amplifier's 0-120 V range).
U_LIMITS = U_RANGE
#: Stand-in for "no limit" in the controller's limits (FMU parameters must be finite).
NO_LIMIT = 1e300
#: Default crossover of the feedback loop [Hz] (see :func:`design_controller`).
BANDWIDTH_HZ = 100.0

from .data import DEFAULT_MODEL  # noqa: E402
from .fmu.build import loop_plant_resource  # noqa: E402


class CosimError(ValueError):
    """The co-simulation could not run: bad or refused FMU, missing dependency,
    a run stopped by a block (a ValueError, so the CLI reports it in one line)."""


# ---------------------------------------------------------------------------
# plant, gain, controller

def plant_system(kind="dynamics"):
    """Linear part of the actuator after the hysteresis, h [µm] -> x [µm].

    ``"none"`` -> None; ``"dynamics"`` -> :func:`fonbw.plant.mechanics`
    (1.5 kHz, ζ = 0.1); ``"creep"`` -> the three creep modes of the virtual
    bench, 1 + Σ g_j / (τ_j s + 1) with τ = 0.1, 1, 10 s and g_j = 1 %
    (:class:`fonbw.bench.BenchParams`); ``"dynamics+creep"`` -> creep, then
    mechanics (the bench's order). A python-control system is returned as is.
    """
    if isinstance(kind, (ct.StateSpace, ct.TransferFunction)):
        return kind
    if kind not in PLANTS:
        raise ValueError(f"plant must be one of {', '.join(PLANTS)} or a control system, got {kind!r}")
    if kind == "none":
        return None
    from .bench import BenchParams

    bp = BenchParams()
    tau = np.asarray(bp.creep_tau, dtype=float)
    g = np.asarray(bp.creep_gain, dtype=float)
    creep = ct.ss(np.diag(-1.0 / tau), (1.0 / tau).reshape(-1, 1), g.reshape(1, -1), [[1.0]])
    mech = ct.ss(_plant.mechanics())
    if kind == "dynamics":
        return mech
    if kind == "creep":
        return creep
    return ct.series(creep, mech)


def linear_gain(model, dt=DT, u_max=U_LIMITS[1]) -> float:
    """Mean slope of a hysteresis model [µm/V]: its output after a 1 s ramp
    0 -> `u_max`, divided by `u_max` (what an uncompensated open loop uses)."""
    n = max(int(round(1.0 / dt)), 2)
    u = np.linspace(0.0, float(u_max), n)
    return float(model.simulate(u, dt)[-1] / u_max)


def controller_spec(kp, ki=0.0, kd=0.0, dt=DT, u_min=U_LIMITS[0], u_max=U_LIMITS[1], Tf=None,
                    Tt=None, integrator="forward", anti_windup="back-calculation") -> dict:
    """Complete, JSON-ready parameter set of a :class:`LoopController`.

    Same meaning as :class:`fonbw.plant.PIDStepper`; Tf and Tt resolved to
    the numbers PIDStepper would pick; infinite limits replaced by ±1e300
    (the FMU parameters must be finite; no output ever reaches them).
    """
    lo = -NO_LIMIT if u_min is None or u_min == -math.inf else float(u_min)
    hi = NO_LIMIT if u_max is None or u_max == math.inf else float(u_max)
    p = _plant.PIDStepper(kp, ki, kd, dt, lo, hi, Tf=Tf, integrator=integrator,
                          anti_windup=anti_windup, Tt=Tt)
    return dict(kp=p.kp, ki=p.ki, kd=p.kd, dt=p.dt, u_min=p.u_min, u_max=p.u_max, Tf=p.Tf,
                Tt=p.Tt, integrator=p.integrator, anti_windup=p.anti_windup)


def loop_plant(k_lin, plant=None, dt=DT, hysteresis=True):
    """Discrete linear model of what the controller drives, as the co-simulation
    sees it: z^-2 (one step for the controller->actuator connection, one for
    the measurement alignment, see the module docstring) x k_lin x ZOH(plant);
    without hysteresis the actuator block and its gain are absent (z^-1 x
    ZOH(plant), plant input in V)."""
    sys_ = None if plant is None else plant_system(plant)
    z1 = ct.tf([1.0], [1.0, 0.0], dt)
    L = z1 * z1 * float(k_lin) if hysteresis else z1
    if sys_ is not None:
        L = ct.series(L, _plant.LinearStepper(sys_, dt).sys)
    return L


def design_controller(k_lin, plant=None, dt=DT, bandwidth_hz=BANDWIDTH_HZ, hysteresis=True,
                      u_min=U_LIMITS[0], u_max=U_LIMITS[1]) -> dict:
    """PI gains for the co-simulated loop by :func:`fonbw.plant.design_pi` on
    :func:`loop_plant` (crossover `bandwidth_hz`, margins checked there).

    Creep is left out of the design model (``"dynamics+creep"`` is designed
    on ``"dynamics"``, ``"creep"`` on no plant): it is a slow, 3 % gain drift
    that the integrator rejects, and its poles at 1 - 1e-5 next to the
    integrator's make the margin computation ill-conditioned.

    Returns a :func:`controller_spec` dictionary with the margins added
    under ``"design"``.
    """
    if isinstance(plant, str):
        plant = {"creep": None, "dynamics+creep": "dynamics", "none": None}.get(plant, plant)
    import warnings

    with warnings.catch_warnings():
        # scipy warns on the tf conversion of the sampled resonance; the
        # margins are checked on the result (design_pi raises if not met)
        warnings.filterwarnings("ignore", message="Badly conditioned filter coefficients")
        d = _plant.design_pi(loop_plant(k_lin, plant, dt, hysteresis), dt, bandwidth_hz)
    spec = controller_spec(d.kp, d.ki, 0.0, dt, u_min, u_max, integrator=d.integrator)
    spec["design"] = {"bandwidth_hz": float(bandwidth_hz), "gain_margin": d.gm,
                      "phase_margin_deg": d.pm, "crossover_rad_s": d.wcp}
    return spec


class LoopController:
    """u = sat(u_ff + PID(r - y)): :class:`fonbw.plant.PIDStepper` with a
    feedforward input added before the output limits.

    The PID's limits are shifted by u_ff each sample, so its saturation and
    anti-windup act on the sum (the integrator does not wind up against a
    limit that the feedforward already reaches). With u_ff = 0 this is the
    plain PIDStepper, bit for bit. The FMU FonbwPID runs this class.

    Parameters
    ----------
    spec : dict
        Keyword arguments of :func:`controller_spec` (extra keys ignored).
    """

    _KEYS = ("kp", "ki", "kd", "dt", "u_min", "u_max", "Tf", "Tt", "integrator", "anti_windup")

    def __init__(self, spec: dict):
        s = {k: spec[k] for k in self._KEYS if k in spec}
        self.pid = _plant.PIDStepper(s.pop("kp"), s.pop("ki", 0.0), s.pop("kd", 0.0), **s)
        self.dt = self.pid.dt
        self._lo, self._hi = self.pid.u_min, self.pid.u_max

    def step(self, r: float, y: float, u_ff: float = 0.0) -> float:
        """Output [V] for reference r [µm], measurement y [µm], feedforward u_ff [V]."""
        p = self.pid
        p.u_min = self._lo - u_ff
        p.u_max = self._hi - u_ff
        return u_ff + p.step(r, y)

    def reset(self) -> None:
        self.pid.reset()

    def get_state(self) -> np.ndarray:
        return self.pid.get_state()

    def set_state(self, arr) -> None:
        self.pid.set_state(arr)


def _compensator(model, dt):
    from .compensate import compensator

    return compensator(model, dt)


# ---------------------------------------------------------------------------
# loop wiring, shared by the three masters

class _Wiring:
    """Blocks in stepping order, where each input comes from, the exogenous
    input sequences, and the measured output (see the module docstring)."""

    IO = {"comp": (("y_ref",), "u"), "ctrl": (("r", "y", "u_ff"), "u"),
          "hyst": (("u",), "y"), "plant": (("h",), "x")}

    def __init__(self, mode, scenario, n, dt, has_plant, hysteresis, k_lin):
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        act = "hyst" if hysteresis else None
        blocks = {"open": [], "ff": ["comp"], "fb": ["ctrl"], "ff+fb": ["comp", "ctrl"]}[mode]
        blocks = blocks + ([act] if act else []) + (["plant"] if has_plant else [])
        if mode == "open" and not act:
            raise ValueError("mode 'open' needs the hysteresis block")
        if mode in ("ff", "ff+fb") and not act:
            raise ValueError(f"mode {mode!r} needs the hysteresis block (the compensator inverts it)")
        if not blocks or blocks[-1] in ("comp", "ctrl"):
            raise ValueError("the loop needs an actuator or a plant block")
        self.blocks = blocks
        self.measured = blocks[-1]
        # the blocks form a chain in this order: each one feeds the next
        nxt = dict(zip(blocks, blocks[1:]))
        self.src = {}  # (block, input) -> ("out", block) | ("ext", key)
        # who drives the actuator (or the plant when there is no actuator)
        drive = "ctrl" if mode in ("fb", "ff+fb") else ("comp" if mode == "ff" else None)
        target = act or "plant"
        self.src[(target, self.IO[target][0][0])] = ("ext", "u_open") if drive is None else ("out", drive)
        if act and has_plant:
            self.src[("plant", "h")] = ("out", act)
        if "ctrl" in blocks:
            self.src[("ctrl", "r")] = ("ext", "r_ctrl")
            self.src[("ctrl", "y")] = ("out", self.measured)
            self.src[("ctrl", "u_ff")] = ("out", "comp") if "comp" in blocks else ("ext", "zero")
        if "comp" in blocks:
            self.src[("comp", "y_ref")] = ("ext", "r_comp")

        def hops(b):
            d = 0
            while b != self.measured:
                b = nxt[b]
                d += 1
            return d

        self.preview = {b: hops(b) for b in blocks}
        k = np.arange(n)
        t = k * dt
        self.t = t
        self.r = trajectory(scenario, t)
        self.ext = {"zero": np.zeros(n)}
        if "comp" in blocks:
            self.ext["r_comp"] = trajectory(scenario, (k + self.preview["comp"]) * dt)
        if "ctrl" in blocks:
            self.ext["r_ctrl"] = trajectory(scenario, (k - 1) * dt)
        if drive is None:
            self.ext["u_open"] = trajectory(scenario, (k + self.preview[target]) * dt) / k_lin
        self.drive = "u_open" if drive is None else drive
        self.actuator = target

    def inputs(self, block):
        return [(name, self.src[(block, name)]) for name in self.IO[block][0]]


def _new_trace(w, n):
    tr = {"t": w.t, "r": w.r}  # u, y, e are derived in _finish
    for b in w.blocks:
        tr["out_" + b] = np.full(n, np.nan)
    return tr


def _finish(tr, k_done, w):
    """Cut the trace at the completed steps; u = actuator (or plant) input."""
    out = {key: np.asarray(v[:k_done], dtype=float).copy() for key, v in tr.items()}
    if w.drive == "u_open":
        out["u"] = w.ext["u_open"][:k_done].copy()
    else:
        src = tr["out_" + w.drive][:k_done]
        out["u"] = np.concatenate([[0.0], src[:-1]]) if k_done else np.zeros(0)
    out["y"] = out["out_" + w.measured].copy()
    out["e"] = out["r"] - out["y"]
    return out


def _check_multiple(h, dt):
    m = h / dt
    k = round(m)
    return k >= 1 and abs(m - k) <= 1e-6, int(k)


def _steps(T, dt):
    """Communication steps: n_full steps of dt, plus a final shorter one if T
    is not a whole multiple of dt (the blocks then refuse it)."""
    n = int(math.floor(T / dt + 1e-9))
    rest = T - n * dt
    return n, (rest if rest > 1e-9 * dt else 0.0)


# ---------------------------------------------------------------------------
# master 1: pure Python reference

class _RefBlock:
    def __init__(self, name, step, dt):
        self.name, self._step, self.dt = name, step, dt
        self.out = 0.0


def _run_reference(w, cfg, n, rest, dt):
    blocks = {}
    for b in w.blocks:
        if b == "hyst":
            st = cfg["truth"].stepper(dt)
            f = (lambda st: lambda u: st.step(u))(st)
        elif b == "comp":
            c = _compensator(cfg["model"], dt)
            cfg["_comp"] = c  # its saturation counts go into the result
            f = (lambda c: lambda r: c.step(r))(c)
        elif b == "ctrl":
            lc = LoopController(cfg["controller"])
            f = lc.step
        else:
            mats = cfg["plant_mats"]
            ls = _plant.LinearStepper(ct.ss(*mats), dt)

            def f(h, ls=ls):
                ls.step(h)
                return ls.output(h)
        blocks[b] = _RefBlock(b, f, dt)
    tr = _new_trace(w, len(w.t))
    ins = {b: w.inputs(b) for b in w.blocks}
    ext = w.ext
    t0, c0 = time.perf_counter(), time.process_time()
    error = None
    for k in range(n + (1 if rest else 0)):
        h = dt if k < n else rest
        vals = {}
        for b in w.blocks:
            vals[b] = [ext[s[1]][k] if s[0] == "ext" else blocks[s[1]].out for _, s in ins[b]]
        if k == n:  # the final partial step: every block has dt as its step
            ok, _ = _check_multiple(h, dt)
            if not ok:
                error = (f"co-simulation stopped at t={k * dt!r} s (step {k}): block "
                         f"{w.blocks[0]!r} refused the communication step {h!r} s: not a whole "
                         f"multiple of its step dt = {dt!r} s")
                break
        for b in w.blocks:
            blocks[b].out = blocks[b]._step(*vals[b])
        for b in w.blocks:
            tr["out_" + b][k] = blocks[b].out
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    k_done = k if error else k + 1
    return _finish(tr, k_done, w), error, wall, 0.0, cpu


# ---------------------------------------------------------------------------
# FMUs: build and cache

def build_fmus(out_dir=None, plant=None, hysteresis=True) -> dict:
    """Build (or reuse) the FMUs of the loop; returns {role: path}.

    Roles: ``hyst``, ``comp``, ``ctrl`` and ``plant`` (the FonbwLinearPlant of
    :func:`plant_system` of `plant`, if any); see :func:`fonbw.fmu.build.loop_fmus`.
    """
    from .fmu.build import loop_fmus

    spec = controller_spec(1e-3, 100.0)
    return loop_fmus({k: spec[k] for k in LoopController._KEYS}, out_dir,
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
        return {k: cfg["controller"][k] for k in LoopController._KEYS}
    return {"dt": cfg["dt"]}


def _fmu_settings(role, cfg) -> dict:
    return {**_fmu_parameters(role, cfg), **cfg.get("overrides", {}).get(role, {})}


# ---------------------------------------------------------------------------
# master 2: fmpy (FMI 2 API)

class _FmpyBlock:
    """One FMU instance stepped through fmpy's FMU2Slave, with preallocated
    ctypes buffers (the per-step calls are fmi2SetReal/DoStep/GetReal)."""

    def __init__(self, role, fmu, unzip, params, logs, in_names, out_name):
        from fmpy import read_model_description
        from fmpy.fmi1 import calloc, free
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2ValueReference,
                               fmi2Real)

        md = read_model_description(str(fmu))
        self.role, self.identifier = role, md.coSimulation.modelIdentifier
        vr = {v.name: v for v in md.modelVariables}
        ins = [v.name for v in md.modelVariables if v.causality == "input"]
        outs = [v.name for v in md.modelVariables if v.causality == "output"]
        if role == "plant":  # any SISO plant FMU: its own variable names
            in_names, out_name = ins[:1], outs[0]
        for nm in list(in_names) + [out_name]:
            if nm not in vr:
                raise CosimError(f"{fmu}: no variable {nm!r} (has {', '.join(vr)})")
        kus = [n for n in vr if n.startswith("ku") and n[2:].isdigit()]
        if role in ("hyst", "comp"):
            want = [k for k in params if k.startswith("ku")]
            if len(want) != len(kus):
                raise CosimError(f"{fmu} has {len(kus)} polynomial coefficients, the model {len(want)}")

        def log(env, inst, status, cat, msg):
            logs.append((self.role, int(status), msg.decode(errors="replace") if msg else ""))

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(log)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._cb = cb  # keep the callbacks alive as long as the instance
        s = FMU2Slave(guid=md.guid, unzipDirectory=str(unzip), modelIdentifier=self.identifier,
                      instanceName=role)
        s.instantiate(callbacks=cb, loggingOn=True)
        self.slave = s
        try:
            s.setupExperiment(startTime=0.0)
            s.enterInitializationMode()
            for k, v in params.items():
                if k not in vr:
                    raise CosimError(f"{fmu}: no parameter {k!r}")
                if isinstance(v, str):
                    s.setString([vr[k].valueReference], [v])
                else:
                    s.setReal([vr[k].valueReference], [float(v)])
            s.exitInitializationMode()
        except Exception:
            self.close()  # not yet known to the caller: free it here
            raise
        n = len(in_names)
        self._ivr = (fmi2ValueReference * n)(*[vr[x].valueReference for x in in_names])
        self._ival = (fmi2Real * n)()
        self._ovr = (fmi2ValueReference * 1)(vr[out_name].valueReference)
        self._oval = (fmi2Real * 1)()
        self._n = n
        self._set = s.fmi2SetReal
        self._get = s.fmi2GetReal
        self._do = s.fmi2DoStep
        self._c = s.component
        self.out = self.get()

    def set(self, values):
        iv = self._ival
        for i, v in enumerate(values):
            iv[i] = v
        self._set(self._c, self._ivr, self._n, iv)

    def step(self, t, h):
        self._do(self._c, t, h, 1)

    def get(self):
        self._get(self._c, self._ovr, 1, self._oval)
        return self._oval[0]

    def close(self):
        try:
            self.slave.terminate()
        except Exception:  # a failed instance may refuse terminate; free it anyway
            pass
        self.slave.freeInstance()


def _unzip(fmu: Path) -> Path:
    """Extract once next to the FMU and reuse (numba's cache then lives there)."""
    from fmpy import extract

    d = fmu.with_suffix(".unzipped")
    stamp = d / ".fonbw-stamp"
    key = f"{fmu.stat().st_mtime_ns}-{fmu.stat().st_size}"
    if not (stamp.is_file() and stamp.read_text() == key):
        if d.exists():
            shutil.rmtree(d)
        extract(str(fmu), str(d))
        stamp.write_text(key)
    return d


def _run_fmpy(w, cfg, n, rest, dt):
    from fmpy.fmi1 import FMICallException

    logs = []
    blocks = {}
    t_setup = time.perf_counter()
    try:
        for b in w.blocks:
            if b == "ctrl":  # the controller runs in the master as library code
                lc = LoopController(cfg["controller"])
                blk = _RefBlock(b, lc.step, lc.dt)
            else:
                fmu = Path(cfg["fmus"][b])
                in_names = [x for x, _ in w.inputs(b)]
                blk = _FmpyBlock(b, fmu, _unzip(fmu), _fmu_settings(b, cfg), logs, in_names,
                                 _Wiring.IO[b][1])
            blocks[b] = blk
        setup = time.perf_counter() - t_setup
        order = w.blocks
        pos = {b: j for j, b in enumerate(order)}
        ext = {key: arr.tolist() for key, arr in w.ext.items()}  # Python floats: cheaper per sample
        # per block: (is_fmu, block, [(sequence or None, source position)], ctypes input buffer)
        plan = []
        for b in order:
            blk = blocks[b]
            srcs = [(ext[s[1]], -1) if s[0] == "ext" else (None, pos[s[1]]) for _, s in w.inputs(b)]
            plan.append((isinstance(blk, _FmpyBlock), blk, srcs,
                         blk._ival if isinstance(blk, _FmpyBlock) else [0.0] * len(srcs)))
        outs = [blocks[b].out for b in order]
        rec = [[] for _ in order]
        nb = len(order)
        error = None
        k = -1
        t0, c0 = time.perf_counter(), time.process_time()
        for k in range(n + (1 if rest else 0)):
            h = dt if k < n else rest
            t = k * dt
            # Jacobi: every block's inputs from the outputs after the previous step
            for is_fmu, blk, srcs, buf in plan:
                i = 0
                for seq, sp in srcs:
                    buf[i] = seq[k] if seq is not None else outs[sp]
                    i += 1
                if is_fmu:
                    blk._set(blk._c, blk._ivr, blk._n, buf)
            for j in range(nb):
                is_fmu, blk, srcs, buf = plan[j]
                if is_fmu:
                    try:
                        blk._do(blk._c, t, h, 1)
                    except FMICallException as e:
                        b = order[j]
                        msgs = "; ".join(m for r, _, m in logs if r == b) or "no log message"
                        label = {2: "fmi2Discard", 3: "fmi2Error", 4: "fmi2Fatal"}.get(e.status, str(e.status))
                        error = (f"co-simulation stopped at t={t!r} s (step {k}): FMU "
                                 f"{blk.identifier} (instance {b!r}) returned {label} from "
                                 f"fmi2DoStep: {msgs}")
                        break
                else:
                    ok, m = _check_multiple(h, blk.dt) if k >= n else (True, 1)
                    if not ok:
                        error = (f"co-simulation stopped at t={t!r} s (step {k}): controller "
                                 f"refused the communication step {h!r} s: not a whole multiple "
                                 f"of its sample time {blk.dt!r} s")
                        break
                    for _ in range(m):
                        blk.pending = blk._step(*buf)
            if error:
                break
            for j in range(nb):
                is_fmu, blk = plan[j][0], plan[j][1]
                if is_fmu:
                    blk._get(blk._c, blk._ovr, 1, blk._oval)
                    v = blk._oval[0]
                else:
                    v = blk.pending
                outs[j] = v
                rec[j].append(v)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        for blk in blocks.values():
            if isinstance(blk, _FmpyBlock):
                blk.close()
    k_done = k if error else k + 1
    tr = _new_trace(w, len(w.t))
    for j, b in enumerate(order):
        tr["out_" + b][:len(rec[j])] = rec[j]
    return _finish(tr, k_done, w), error, wall, setup, cpu


# ---------------------------------------------------------------------------
# master 3: libcosim (libcosimpy)

def _run_libcosim(w, cfg, n, rest, dt):
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave
    from libcosimpy._internal import get_last_error_message

    if rest:
        raise ValueError(f"the libcosim master needs T to be a whole multiple of dt = {dt!r} s "
                         f"(its fixed-step algorithm takes no shorter final step)")
    ns = round(dt * 1e9)
    if abs(ns * 1e-9 - dt) > 1e-12 * dt:
        raise ValueError(f"dt = {dt!r} s is not a whole number of nanoseconds (libcosim's time unit)")
    log_output_level(CosimLogLevel.ERROR)
    t_setup = time.perf_counter()
    ex = CosimExecution.from_step_size(ns)
    idx, vr = {}, {}
    for b in w.blocks:
        idx[b] = ex.add_local_slave(CosimLocalSlave(fmu_path=str(cfg["fmus"][b]), instance_name=b))
        if idx[b] < 0:
            raise CosimError(f"libcosim cannot load {cfg['fmus'][b]}: {get_last_error_message()}")
        vars_ = ex.slave_variables(idx[b])
        vr[b] = {v.name.decode(): v.reference for v in vars_}
        if b == "plant":
            ins = [v.name.decode() for v in vars_ if v.causality == 0]   # INPUT
            outs = [v.name.decode() for v in vars_ if v.causality == 2]  # OUTPUT
            vr[b]["h"], vr[b]["x"] = vr[b][ins[0]], vr[b][outs[0]]
        for k, v in _fmu_settings(b, cfg).items():
            ok = (ex.string_initial_value(idx[b], vr[b][k], v) if isinstance(v, str)
                  else ex.real_initial_value(idx[b], vr[b][k], float(v)))
            if not ok:
                raise CosimError(f"libcosim: cannot set parameter {k} of {b}: {get_last_error_message()}")
    man = CosimManipulator.create_override()
    ex.add_manipulator(man)
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    ext_in = []
    for b in w.blocks:
        for name, s in w.inputs(b):
            if s[0] == "out":
                src = s[1]
                rc = ex.connect_real_variables(idx[src], vr[src][_Wiring.IO[src][1]], idx[b], vr[b][name])
                if rc != 0:  # libcosimpy returns the C status here, not a bool
                    raise CosimError(f"libcosim: cannot connect {src} -> {b}.{name}: "
                                     f"{get_last_error_message()}")
            elif s[1] != "zero":
                ext_in.append((idx[b], vr[b][name], w.ext[s[1]]))
    outs = [(b, idx[b], vr[b][_Wiring.IO[b][1]]) for b in w.blocks]
    setup = time.perf_counter() - t_setup
    tr = _new_trace(w, n)
    error = None
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n):
        if k == 1:
            # libcosim initializes the slaves inside the first step: count that
            # step as setup, so wall_s is the stepping alone as for fmpy
            t1 = time.perf_counter()
            setup += t1 - t0
            t0, c0 = t1, time.process_time()
        for i, ref, arr in ext_in:
            man.slave_real_values(i, [ref], [float(arr[k])])
        if not ex.step(1):
            error = (f"co-simulation stopped at t={k * dt!r} s (step {k}): libcosim step failed: "
                     f"{get_last_error_message()}")
            break
        for b, i, ref in outs:
            tr["out_" + b][k] = obs.last_real_values(i, [ref])[0]
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    k_done = k if error else n
    del ex
    return _finish(tr, k_done, w), error, wall, setup, cpu


_MASTER_FUNCS = {"reference": _run_reference, "fmpy": _run_fmpy, "libcosim": _run_libcosim}


# ---------------------------------------------------------------------------
# public entry point

def _as_model(m, what):
    if m is None:
        return load_model(DEFAULT_MODEL)
    if isinstance(m, (str, os.PathLike)):
        m = load_model(m)
    if not isinstance(m, FONBW):  # NBW is a FONBW
        raise ValueError(f"{what} must be a FONBW/NBW model (the FMUs wrap FONBW), got {type(m).__name__}")
    p = dict(m.params)
    p.setdefault("lam1", 1.0)
    p.setdefault("lam2", 1.0)
    return FONBW(**p)


def run_cosim(scenario="sine5", mode="ff+fb", master="reference", T=None, dt=DT, models=None,
              plant="none", hysteresis=True, bandwidth_hz=BANDWIDTH_HZ, fmu_dir=None,
              fmu_overrides=None) -> dict:
    """Run the closed loop once and measure the tracking.

    Parameters
    ----------
    scenario : str
        Trajectory name in :data:`SCENARIOS` (``sine5`` and ``multi`` are the
        paper's Table 4 trajectories).
    mode : {"open", "ff", "fb", "ff+fb"}
        Uncompensated (u = r/k_lin), feedforward compensator (eqs. 16-17),
        PI feedback, or both (the feedforward added inside the controller's
        limits).
    master : {"reference", "fmpy", "libcosim"}
    T : float, optional
        Duration [s] (scenario default). With the reference and fmpy masters
        a T that is not a whole multiple of dt ends with a shorter step, which
        the blocks refuse (the run stops there, see ``error``).
    dt : float
        Communication step = sample time of every block [s].
    models : dict, optional
        ``"compensator"``: model the compensator inverts (FONBW, or path of
        its JSON; default models/fonbw_default.json); ``"hysteresis"``: the
        "true" actuator (default: the compensator's model); ``"controller"``:
        a :func:`controller_spec` dict (default: :func:`design_controller`
        at `bandwidth_hz`).
    plant : str or control system
        Linear dynamics after the actuator, see :func:`plant_system`.
    hysteresis : bool
        False drops the actuator block: the controller drives the plant
        directly (modes fb only; for checks against python-control).
    fmu_dir : path, optional
        Where FMUs are built/reused (default: a per-user cache).
    fmu_overrides : dict, optional
        ``{block: {parameter: value}}`` set on the FMUs after the model's
        own parameters (fmpy and libcosim masters; e.g. a faulty internal
        step ``{"hyst": {"dt": 2e-4}}``).

    Returns
    -------
    dict
        ``rms_error``, ``max_error`` [µm] (e = r - y), ``rms_input`` [V]
        (actuator input), ``sim_time_s`` [s] simulated, ``wall_s`` [s] of the
        stepping loop, ``setup_s`` [s] (instantiation/initialization),
        ``cpu_s`` [s] (process CPU time of that loop, all threads: less
        sensitive to other jobs on the machine than wall_s), ``rtf``
        (sim_time_s / wall_s), ``steps`` completed, ``error`` (None,
        or why the run stopped early; the trace then ends there), ``trace``
        (arrays t [s], r [µm], u [V], y [µm], e [µm], out_<block>),
        ``diagnostics`` (reference master: the compensator's saturated and
        unconverged sample counts),
        ``config`` (everything needed to repeat the run).
    """
    if master not in MASTERS:
        raise ValueError(f"master must be one of {', '.join(MASTERS)}, got {master!r}")
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
    T = float(SCENARIOS[scenario][1] if T is None else T)
    if not (math.isfinite(T) and T >= dt):
        raise ValueError(f"T must be at least one step dt = {dt!r} s, got {T!r}")
    models = dict(models or {})
    unknown = set(models) - {"compensator", "hysteresis", "controller"}
    if unknown:
        raise ValueError(f"unknown models key(s) {sorted(unknown)}; use compensator, hysteresis, controller")
    model = _as_model(models.get("compensator"), "models['compensator']")
    truth = _as_model(models.get("hysteresis"), "models['hysteresis']") if models.get("hysteresis") is not None else model
    sys_ = plant_system(plant)
    if not hysteresis and sys_ is None:
        raise ValueError("without the hysteresis block the loop needs a plant")
    k_lin = linear_gain(model, dt)
    ctrl = models.get("controller")
    if ctrl is None and mode in ("fb", "ff+fb"):
        ctrl = design_controller(k_lin, plant, dt, bandwidth_hz, hysteresis)
    elif ctrl is not None:
        design = ctrl.get("design")
        ctrl = controller_spec(**{k: ctrl[k] for k in LoopController._KEYS if k in ctrl})
        if design:
            ctrl["design"] = design
    n, rest = _steps(T, dt)
    # one more sample of every input sequence for a final partial step
    w = _Wiring(mode, scenario, n + (1 if rest else 0), dt, sys_ is not None, hysteresis, k_lin)
    cfg = {"model": model, "truth": truth, "controller": ctrl, "dt": dt}
    if sys_ is not None:
        # the matrices exactly as the plant FMU reads them (through its JSON resource)
        res = json.loads(json.dumps(loop_plant_resource(sys_, hysteresis)))
        cfg["plant_mats"] = [np.array(res[x], dtype=float).reshape(res["shape"][x]) for x in "ABCD"]
    if master != "reference":
        cfg["fmus"] = build_fmus(fmu_dir, sys_, hysteresis)
    cfg["overrides"] = {b: dict(v) for b, v in (fmu_overrides or {}).items()}
    bad = set(cfg["overrides"]) - set(w.blocks)
    if bad:
        raise ValueError(f"fmu_overrides for block(s) {sorted(bad)} not in the loop {w.blocks}")
    trace, error, wall, setup, cpu = _MASTER_FUNCS[master](w, cfg, n, rest, dt)
    steps = len(trace["t"])
    e, u = trace["e"], trace["u"]
    diagnostics = {}
    comp = cfg.get("_comp")
    if comp is not None:  # reference master: why a feedforward may fail
        diagnostics["compensator"] = {"saturated_samples": int(comp.n_saturated),
                                      "unconverged_samples": int(comp.n_not_converged)}
    sim = steps * dt
    result = {
        "scenario": scenario, "mode": mode, "master": master,
        "plant": plant if isinstance(plant, str) else "custom",
        "rms_error": float(np.sqrt(np.mean(e * e))) if steps else math.nan,
        "max_error": float(np.max(np.abs(e))) if steps else math.nan,
        "rms_input": float(np.sqrt(np.mean(u * u))) if steps else math.nan,
        "sim_time_s": sim, "wall_s": wall, "cpu_s": cpu, "setup_s": setup,
        "rtf": (sim / wall) if wall > 0 else math.inf,
        "steps": steps, "error": error, "diagnostics": diagnostics,
        "trace": trace,
        "config": {
            "T": T, "dt": dt, "hysteresis": bool(hysteresis), "k_lin_um_per_V": k_lin,
            "blocks": list(w.blocks), "measured": w.measured, "preview_steps": w.preview,
            "controller": ctrl, "compensator_model": model.to_dict(),
            "hysteresis_model": truth.to_dict(),
            "convention": "Jacobi, one-step delay per connection, no direct feedthrough; "
                          "reference fed d steps ahead to a block d connections upstream "
                          "of the measured output; controller sees r_{k-1}, y_{k-1}",
            "fmus": {k: str(v) for k, v in cfg.get("fmus", {}).items()},
        },
    }
    return result


# ---------------------------------------------------------------------------
# feedforward / feedback study (paper Table 4 + its future work)

def default_truth(model=None):
    """The "true" actuator of the study: the model with 10 % more hysteretic
    gain kh and 3 % less linear gain k_u1 (a model error of the order the
    paper reports, 1.4-3.7 % of the stroke, so that feedforward alone leaves a
    residual for feedback to remove).

    Not an error in λ2: with λ2 < λ1 the discrete model's immediate response
    to a voltage step scales with dt^(λ2-λ1) (21.6 for the default model at
    10 kHz) and is negative (the one-sample map u_k -> y_k decreases), so a
    truth with λ2 lowered by 0.03 already makes the 100 Hz PI loop oscillate
    (RMS error 2.3 µm on sine5; stable at 50 Hz) -- a finding, not a study
    setting."""
    m = _as_model(model, "model")
    p = dict(m.params)
    p["kh"] = 1.10 * p["kh"]
    p["ku"] = [0.97 * p["ku"][0]] + list(p["ku"][1:])
    return FONBW(**p)


def ff_fb_study(out_dir=None, master="reference", trajectories=("sine5", "multi"),
                plants=("none", "dynamics+creep"), modes=MODES, T=2.0, dt=DT, model=None,
                truth="default", bandwidth_hz=BANDWIDTH_HZ, fmu_dir=None, plots=True) -> list:
    """The four modes on the paper's two trajectories, with and without the
    plant's dynamics and creep.

    Parameters
    ----------
    out_dir : path, optional
        Writes ``cosim_study.json``, ``cosim_study.csv``, ``cosim_study.md``
        (the table) and, with `plots`, ``cosim_<trajectory>_<plant>.png``.
    truth : FONBW, "default" or None
        True actuator; "default": :func:`default_truth`; None: the model
        itself (feedforward then only meets the plant's dynamics and creep).

    Returns
    -------
    list of dict
        One row per (trajectory, plant, mode): rms_error_um, max_error_um,
        rms_input_V, rel_rms_error (rms_error / peak-to-peak of H_d), steps,
        comp_saturated (compensator samples at a voltage limit, reference
        master), error.
    """
    model = _as_model(model, "model")
    tr_model = default_truth(model) if isinstance(truth, str) and truth == "default" else (
        model if truth is None else _as_model(truth, "truth"))
    rows, traces = [], {}
    for traj in trajectories:
        for pl in plants:
            for mode in modes:
                res = run_cosim(traj, mode, master, T=T, dt=dt, plant=pl, bandwidth_hz=bandwidth_hz,
                                models={"compensator": model, "hysteresis": tr_model},
                                fmu_dir=fmu_dir)
                r = res["trace"]["r"]
                rows.append({"trajectory": traj, "plant": pl, "mode": mode,
                             "rms_error_um": res["rms_error"], "max_error_um": res["max_error"],
                             "rms_input_V": res["rms_input"],
                             "rel_rms_error": res["rms_error"] / float(np.ptp(r)),
                             "steps": res["steps"],
                             "comp_saturated": res["diagnostics"].get("compensator", {}).get(
                                 "saturated_samples"),
                             "error": res["error"]})
                traces[(traj, pl, mode)] = res["trace"]
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        from .io import atomic_open

        meta = {"master": master, "T": T, "dt": dt, "bandwidth_hz": bandwidth_hz,
                "model": model.to_dict(), "truth": tr_model.to_dict(), "rows": rows}
        with atomic_open(out / "cosim_study.json", "w", encoding="utf-8") as fh:
            json.dump(meta, fh, indent=1)
        keys = list(rows[0])
        with atomic_open(out / "cosim_study.csv", "w", encoding="utf-8") as fh:
            fh.write(",".join(keys) + "\n")
            for r in rows:
                fh.write(",".join("" if r[k] is None else str(r[k]) for k in keys) + "\n")
        with atomic_open(out / "cosim_study.md", "w", encoding="utf-8") as fh:
            fh.write(study_table(rows))
        if plots:
            _study_plots(out, traces, trajectories, plants, modes)
    return rows


def study_table(rows) -> str:
    """Markdown table of :func:`ff_fb_study` rows."""
    lines = ["| trajectory | plant | mode | RMS error [µm] | max error [µm] | RMS input [V] |",
             "|---|---|---|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['trajectory']} | {r['plant']} | {r['mode']} | {r['rms_error_um']:.4f} "
                     f"| {r['max_error_um']:.4f} | {r['rms_input_V']:.2f} |")
    return "\n".join(lines) + "\n"


def _study_plots(out, traces, trajectories, plants, modes):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for traj in trajectories:
        for pl in plants:
            fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
            first = traces[(traj, pl, modes[0])]
            a1.plot(first["t"], first["r"], "k", lw=1.5, label="H_d")
            for mode in modes:
                tr = traces[(traj, pl, mode)]
                a1.plot(tr["t"], tr["y"], lw=0.8, label=mode)
                a2.plot(tr["t"], tr["e"], lw=0.8, label=mode)
            a1.set_ylabel("displacement [µm]")
            a2.set_ylabel("error r - y [µm]")
            a2.set_xlabel("t [s]")
            a1.legend(loc="upper right", fontsize=8)
            a1.set_title(f"{traj}, plant: {pl}")
            fig.tight_layout()
            fig.savefig(out / f"cosim_{traj}_{pl.replace('+', '_')}.png", dpi=110)
            plt.close(fig)


# ---------------------------------------------------------------------------
# command line

def add_cosim_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``fonbw cosim``."""
    parser.add_argument("--scenario", default="sine5", choices=sorted(SCENARIOS))
    parser.add_argument("--mode", default="ff+fb", choices=MODES)
    parser.add_argument("--master", default="reference", choices=MASTERS)
    parser.add_argument("--plant", default="none", choices=PLANTS,
                        help="linear dynamics after the actuator (default none)")
    parser.add_argument("--T", type=float, default=None, help="duration [s] (scenario default)")
    parser.add_argument("--dt", type=float, default=DT, help="communication step [s] (default 1e-4)")
    parser.add_argument("--model", default=None, help="FONBW model JSON the compensator inverts "
                        "(default models/fonbw_default.json)")
    parser.add_argument("--truth", default=None, help="FONBW model JSON of the true actuator "
                        "(default: the model)")
    parser.add_argument("--bandwidth", type=float, default=BANDWIDTH_HZ,
                        help="feedback crossover [Hz] (default 100)")
    parser.add_argument("--fmu-dir", default=None, help="build/reuse FMUs here (default: a cache)")
    parser.add_argument("--json", dest="json_out", default=None, help="write the result (no trace) as JSON")
    parser.add_argument("--csv", dest="csv_out", default=None, help="write the trace as CSV")


def cosim_command(ns) -> int:
    """Run ``fonbw cosim`` from parsed arguments; prints a one-line summary,
    writes --json/--csv (also for a run stopped early: the trace up to the
    stop), then raises CosimError if the run stopped. Bad arguments raise
    ValueError."""
    res = run_cosim(ns.scenario, ns.mode, ns.master, T=ns.T, dt=ns.dt, plant=ns.plant,
                    models={"compensator": ns.model, "hysteresis": ns.truth},
                    bandwidth_hz=ns.bandwidth, fmu_dir=ns.fmu_dir)
    from .io import atomic_open, write_csv

    if ns.json_out:
        with atomic_open(ns.json_out, "w", encoding="utf-8") as fh:
            json.dump({k: v for k, v in res.items() if k != "trace"}, fh, indent=1, default=str)
    if ns.csv_out:
        tr = res["trace"]
        write_csv(ns.csv_out, {k: tr[k] for k in ("t", "r", "u", "y", "e")})
    print(f"{ns.scenario} {ns.mode} {ns.master} plant={ns.plant}: rms_error {res['rms_error']:.4f} um, "
          f"max_error {res['max_error']:.4f} um, rms_input {res['rms_input']:.2f} V, "
          f"{res['steps']} steps, wall {res['wall_s']:.2f} s (rtf {res['rtf']:.2f})")
    if res["error"]:
        # outputs above hold the trace up to the stop; the CLI reports this in one line, exit 2
        raise CosimError(res["error"])
    return 0


def cosim_main(argv=None) -> int:
    """Stand-alone ``fonbw cosim`` (errors: one line on stderr, exit code 2)."""
    ap = argparse.ArgumentParser(prog="fonbw cosim", description="closed-loop co-simulation")
    add_cosim_arguments(ap)
    ns = ap.parse_args(argv)
    try:
        return cosim_command(ns)
    except (ValueError, CosimError, OSError) as e:
        print(f"fonbw cosim: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(cosim_main())
