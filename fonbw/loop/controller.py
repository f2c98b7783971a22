"""What the feedback loop controls and the controller itself: the linear plant
after the actuator, the actuator's mean gain, the discrete loop model the
controller is designed on, the PI design, and the PID with feedforward.

Units: u [V], y, r [µm], t [s].
"""
from __future__ import annotations

import math
import warnings

import control as ct
import numpy as np

from .. import plant as _plant
from .spec import BANDWIDTH_HZ, DT, NO_LIMIT, PLANTS, U_LIMITS

__all__ = ["plant_system", "linear_gain", "controller_spec", "loop_plant", "design_controller",
           "LoopController", "CONTROLLER_KEYS"]

#: The parameters of a :class:`LoopController` (and of the FonbwPID FMU).
CONTROLLER_KEYS = ("kp", "ki", "kd", "dt", "u_min", "u_max", "Tf", "Tt", "integrator", "anti_windup")


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
    from ..bench import BenchParams

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


def linear_gain(model, dt=DT, u_range=None) -> float:
    """Mean slope of a hysteresis model [µm/V] (what an uncompensated open
    loop uses): its change over a 1 s ramp from rest (the point of `u_range`
    nearest 0 V) to the top of `u_range` [V] (to its bottom for a range
    below 0 V), divided by the ramp's span.

    The ramp runs from the model's recorded start (its rest cycle, as
    ``validate`` and the loop's actuator run it); `u_range` defaults to the
    model's training input range (:func:`fonbw.compensate.default_limits`),
    else 0–120 V. `dt` [s] is the simulation step.
    """
    from ..compensate import default_limits
    from ..objective import simulate_record

    lo, hi = (float(a) for a in (default_limits(model) if u_range is None else u_range))
    if not hi > lo:
        raise ValueError(f"linear_gain: u_range must be (low, high) with low < high [V], got {(lo, hi)}")
    rest = min(max(0.0, lo), hi)
    end = hi if hi > rest else lo
    u = np.linspace(rest, end, max(int(round(1.0 / dt)), 2))
    y = simulate_record(model, u, dt)
    return float((y[-1] - y[0]) / (end - rest))


def controller_spec(kp, ki=0.0, kd=0.0, dt=DT, u_min=U_LIMITS[0], u_max=U_LIMITS[1], Tf=None,
                    Tt=None, integrator="forward", anti_windup="back-calculation") -> dict:
    """Complete, JSON-ready parameter set of a :class:`LoopController`.

    Same meaning and units as :class:`fonbw.plant.PIDStepper` (gains in V/µm,
    V/(µm s), V s/µm; dt, Tf, Tt in s; limits in V); Tf and Tt resolved to
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
    the measurement alignment, see :mod:`fonbw.loop`) x k_lin [µm/V] x
    ZOH(plant); without hysteresis the actuator block and its gain are absent
    (z^-1 x ZOH(plant), plant input in V). `dt` is the sample time [s]."""
    sys_ = None if plant is None else plant_system(plant)
    z1 = ct.tf([1.0], [1.0, 0.0], dt)
    L = z1 * z1 * float(k_lin) if hysteresis else z1
    if sys_ is not None:
        L = ct.series(L, _plant.LinearStepper(sys_, dt).sys)
    return L


def design_controller(k_lin, plant=None, dt=DT, bandwidth_hz=BANDWIDTH_HZ, hysteresis=True,
                      u_min=U_LIMITS[0], u_max=U_LIMITS[1]) -> dict:
    """PI gains for the co-simulated loop by :func:`fonbw.plant.design_pi` on
    :func:`loop_plant` (crossover `bandwidth_hz` [Hz], margins checked there).

    Creep is left out of the design model (``"dynamics+creep"`` is designed
    on ``"dynamics"``, ``"creep"`` on no plant): it is a slow, 3 % gain drift
    that the integrator rejects, and its poles at 1 - 1e-5 next to the
    integrator's make the margin computation ill-conditioned.

    Returns a :func:`controller_spec` dictionary with the margins added
    under ``"design"``.
    """
    if isinstance(plant, str):
        plant = {"creep": None, "dynamics+creep": "dynamics", "none": None}.get(plant, plant)
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

    _KEYS = CONTROLLER_KEYS

    def __init__(self, spec: dict):
        s = {k: spec[k] for k in CONTROLLER_KEYS if k in spec}
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

