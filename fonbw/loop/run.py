"""The front door of the closed loop: :func:`run_cosim` fills the defaults,
wires the loop, runs one master and measures the tracking in a
:class:`CosimResult`.

Units: u [V], y, r [µm], t [s].
"""
from __future__ import annotations

import dataclasses
import json
import math
import os

import numpy as np

from ..data import DEFAULT_MODEL
from ..fmu.build import loop_plant_resource
from ..hysteresis import FONBW, load_model
from ..signals import SCENARIOS
from .controller import CONTROLLER_KEYS, controller_spec, design_controller, linear_gain, plant_system
from .fmus import build_fmus
from .masters import run_master
from .spec import BANDWIDTH_HZ, CONVENTION, DT, MASTERS, MODES
from .wiring import Wiring, steps

__all__ = ["CosimResult", "run_cosim", "as_model"]

_ARRAYS = ("t", "r", "u", "y", "e", "outputs")


@dataclasses.dataclass(frozen=True, eq=False)
class CosimResult:
    """One closed-loop run: what ran, its trace, and how well it tracked.

    Attributes
    ----------
    scenario, mode, master : str
        The run's trajectory, loop structure and master.
    plant : str
        The plant's name (:data:`fonbw.loop.PLANTS`), ``"custom"`` for a
        control system.
    t : ndarray
        Sample times [s], one per completed communication step.
    r : ndarray
        Reference [µm].
    u : ndarray
        Input of the actuator (of the plant without one) [V].
    y : ndarray
        Measured output after each step [µm].
    e : ndarray
        Tracking error r - y [µm].
    outputs : dict of str to ndarray
        Every block's output after each step: ``comp``, ``ctrl`` [V],
        ``hyst``, ``plant`` [µm].
    rms_error, max_error : float
        RMS and largest absolute e [µm] (NaN without a completed step).
    rms_input : float
        RMS of u [V].
    sim_time_s : float
        Simulated time [s] (steps x dt).
    wall_s, cpu_s : float
        Wall time and process CPU time (all threads) of the stepping loop
        [s]; CPU time is less sensitive to other jobs on the machine.
    setup_s : float
        Instantiation and initialization of the blocks [s].
    rtf : float
        Real-time factor, sim_time_s / wall_s.
    steps : int
        Completed communication steps.
    error : str or None
        Why the run stopped early (the trace then ends there), or None.
    diagnostics : dict
        Reference master: the compensator's saturated and unconverged
        sample counts under ``"compensator"``.
    config : dict
        Everything needed to repeat the run (step, models, controller,
        blocks, alignment, FMU paths).
    """

    scenario: str
    mode: str
    master: str
    plant: str
    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    e: np.ndarray
    outputs: dict
    rms_error: float
    max_error: float
    rms_input: float
    sim_time_s: float
    wall_s: float
    cpu_s: float
    setup_s: float
    rtf: float
    steps: int
    error: str | None
    diagnostics: dict
    config: dict

    @property
    def trace(self) -> dict:
        """The arrays by name: t, r, out_<block>, u, y, e (as written to CSV)."""
        out = {"t": self.t, "r": self.r}
        out.update({"out_" + b: v for b, v in self.outputs.items()})
        out.update(u=self.u, y=self.y, e=self.e)
        return out

    def summary(self) -> dict:
        """Everything but the arrays, JSON-ready (what ``fonbw cosim --json`` writes)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in _ARRAYS}


def as_model(m, what):
    """A FONBW model from `m`: None (the default model), a JSON path, or a
    FONBW/NBW model (an NBW becomes the FONBW with lam1 = lam2 = 1, the form
    the FMUs wrap); `what` names the argument in errors."""
    if m is None:
        return load_model(DEFAULT_MODEL)
    if isinstance(m, (str, os.PathLike)):
        m = load_model(m)
    if not isinstance(m, FONBW):  # NBW is a FONBW
        raise ValueError(f"{what} must be a FONBW/NBW model (the FMUs wrap FONBW), got {type(m).__name__}")
    return m.as_fonbw()


def _check_run(scenario, mode, master, T, dt):
    """(dt, T) [s] as floats, T defaulting to the scenario's duration."""
    if master not in MASTERS:
        raise ValueError(f"master must be one of {', '.join(MASTERS)}, got {master!r}")
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
    T = float(SCENARIOS[scenario][1] if T is None else T)
    if not (math.isfinite(T) and T >= dt):
        raise ValueError(f"T must be at least one step dt = {dt!r} s, got {T!r}")
    return dt, T


def _models(models):
    """(compensator model, true actuator, controller spec or None) from the
    `models` argument of :func:`run_cosim`."""
    models = dict(models or {})
    unknown = set(models) - {"compensator", "hysteresis", "controller"}
    if unknown:
        raise ValueError(f"unknown models key(s) {sorted(unknown)}; use compensator, hysteresis, controller")
    model = as_model(models.get("compensator"), "models['compensator']")
    truth = model
    if models.get("hysteresis") is not None:
        truth = as_model(models["hysteresis"], "models['hysteresis']")
    return model, truth, models.get("controller")


def _controller(ctrl, mode, k_lin, plant, dt, bandwidth_hz, hysteresis):
    """The controller spec: the given one completed (its design notes kept),
    or designed for the feedback modes, or None (no controller in the loop)."""
    if ctrl is None:
        if mode in ("fb", "ff+fb"):
            return design_controller(k_lin, plant, dt, bandwidth_hz, hysteresis)
        return None
    design = ctrl.get("design")
    spec = controller_spec(**{k: ctrl[k] for k in CONTROLLER_KEYS if k in ctrl})
    if design:
        spec["design"] = design
    return spec


def _plant_mats(sys_, hysteresis):
    """A, B, C, D of the plant exactly as its FMU reads them (through the
    JSON resource), so the reference master steps the same numbers."""
    res = json.loads(json.dumps(loop_plant_resource(sys_, hysteresis)))
    return [np.array(res[x], dtype=float).reshape(res["shape"][x]) for x in "ABCD"]


def _config(T, dt, hysteresis, k_lin, w, ctrl, model, truth, fmus):
    return {"T": T, "dt": dt, "hysteresis": bool(hysteresis), "k_lin_um_per_V": k_lin,
            "blocks": list(w.blocks), "measured": w.measured, "preview_steps": w.preview,
            "controller": ctrl, "compensator_model": model.to_dict(),
            "hysteresis_model": truth.to_dict(), "convention": CONVENTION,
            "fmus": {k: str(v) for k, v in fmus.items()}}


def _result(scenario, mode, master, plant, stepped, dt, config) -> CosimResult:
    """Measure a master's run: error and input statistics, timing."""
    tr = stepped.trace
    e, u = tr["e"], tr["u"]
    n = len(tr["t"])
    sim = n * dt
    wall = stepped.wall_s
    with np.errstate(over="ignore", invalid="ignore"):  # a loop that diverged: its RMS is inf or nan
        rms_error = float(np.sqrt(np.mean(e * e))) if n else math.nan
        rms_input = float(np.sqrt(np.mean(u * u))) if n else math.nan
    return CosimResult(
        scenario=scenario, mode=mode, master=master,
        plant=plant if isinstance(plant, str) else "custom",
        t=tr["t"], r=tr["r"], u=u, y=tr["y"], e=e,
        outputs={k[4:]: v for k, v in tr.items() if k.startswith("out_")},
        rms_error=rms_error,
        max_error=float(np.max(np.abs(e))) if n else math.nan,
        rms_input=rms_input,
        sim_time_s=sim, wall_s=wall, cpu_s=stepped.cpu_s, setup_s=stepped.setup_s,
        rtf=(sim / wall) if wall > 0 else math.inf,
        steps=n, error=stepped.error, diagnostics=stepped.diagnostics, config=config)


def run_cosim(scenario="sine5", mode="ff+fb", master="reference", T=None, dt=DT, models=None,
              plant="none", hysteresis=True, bandwidth_hz=BANDWIDTH_HZ, fmu_dir=None,
              fmu_overrides=None, native=False) -> CosimResult:
    """Run the closed loop once and measure the tracking.

    Parameters
    ----------
    scenario : str
        Trajectory name in :data:`fonbw.signals.SCENARIOS` (``sine5`` and
        ``multi`` are the paper's Table 4 trajectories).
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
        its JSON; default models/fonbw_default.json); ``"hysteresis"``:
        the "true" actuator (default: the compensator's model);
        ``"controller"``: a :func:`fonbw.loop.controller_spec` dict (default:
        :func:`fonbw.loop.design_controller` at `bandwidth_hz`).
    plant : str or control system
        Linear dynamics after the actuator, see :func:`fonbw.loop.plant_system`.
    hysteresis : bool
        False drops the actuator block: the controller drives the plant
        directly (mode fb only; for checks against python-control).
    bandwidth_hz : float
        Crossover of the designed controller [Hz].
    fmu_dir : path, optional
        Where FMUs are built/reused (default: a per-user cache).
    fmu_overrides : dict, optional
        ``{block: {parameter: value}}`` set on the FMUs after the model's
        own parameters (fmpy and libcosim masters; e.g. a faulty internal
        step ``{"hyst": {"dt": 2e-4}}``).
    native : bool
        The fmpy and libcosim masters run the native C FMUs
        (:mod:`fonbw.fmu.native`: FonbwHysteresisNative, FonbwCompensatorNative,
        FonbwLinearPlantNative and, in libcosim, FonbwPIDNative) instead of the
        pythonfmu ones; no Python runs inside the FMUs. The reference master
        has no FMUs and ignores it.

    Returns
    -------
    CosimResult
        The trace (t, r, u, y, e and every block's output), the tracking
        metrics, the timing, why the run stopped early if it did, and the
        configuration.
    """
    dt, T = _check_run(scenario, mode, master, T, dt)
    model, truth, ctrl = _models(models)
    sys_ = plant_system(plant)
    if not hysteresis and sys_ is None:
        raise ValueError("without the hysteresis block the loop needs a plant")
    k_lin = linear_gain(model, dt)
    ctrl = _controller(ctrl, mode, k_lin, plant, dt, bandwidth_hz, hysteresis)
    n, rest = steps(T, dt)
    # one more sample of every input sequence for a final partial step
    w = Wiring(mode, scenario, n + (1 if rest else 0), dt, sys_ is not None, hysteresis, k_lin)
    cfg = {"model": model, "truth": truth, "controller": ctrl, "dt": dt,
           "overrides": {b: dict(v) for b, v in (fmu_overrides or {}).items()}}
    if sys_ is not None:
        cfg["plant_mats"] = _plant_mats(sys_, hysteresis)
    if master != "reference":
        # absolute: the masters hand FMU locations to fmpy and libcosim as file URIs
        fmu_dir = None if fmu_dir is None else os.path.abspath(fmu_dir)
        cfg["fmus"] = build_fmus(fmu_dir, sys_, hysteresis, native=native, models=(model, truth))
    bad = set(cfg["overrides"]) - set(w.blocks)
    if bad:
        raise ValueError(f"fmu_overrides for block(s) {sorted(bad)} not in the loop {w.blocks}")
    stepped = run_master(master, w, cfg, n, rest, dt)
    config = _config(T, dt, hysteresis, k_lin, w, ctrl, model, truth, cfg.get("fmus", {}))
    config["native"] = bool(native) and master != "reference"
    return _result(scenario, mode, master, plant, stepped, dt, config)
