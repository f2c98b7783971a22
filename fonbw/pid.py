"""Discrete PID controllers for the PEA loop, and a PI design rule.

Controllers (:class:`PIDStepper`) are the textbook parallel PID with a
first-order derivative filter and anti-windup by back-calculation or clamping
(Åström & Hägglund, *Advanced PID Control*, ISA 2006, ch. 3); their linear
part is available as a discrete transfer function (:meth:`PIDStepper.to_tf`)
built with :func:`control.c2d`, so closed loops can be checked against
:func:`control.feedback`. :func:`design_pi` picks PI gains for a plant of
:mod:`fonbw.plant` by loop shaping at a given bandwidth.

Units: error and measurement [µm], controller output [V], time [s].
"""
from __future__ import annotations

import dataclasses
import math
import warnings

import control as ct
import numpy as np

__all__ = ["PIDStepper", "pi_controller", "pid_controller", "PIDesign", "design_pi"]


def _positive(name, value):
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    return v


_INTEGRATORS = {"forward": "euler", "backward": "backward_diff", "tustin": "tustin"}
_ANTI_WINDUP = ("back-calculation", "clamping", "none")


class PIDStepper:
    """Discrete PID with derivative filter and anti-windup, one sample at a time.

    Linear law (no saturation), with e = r - y::

        u = kp e + ki ∫e dt + kd s/(Tf s + 1) e

    The integral is discretized by `integrator` (``"forward"`` Euler — the
    integral uses errors up to k-1, as Simulink's default; ``"backward"``;
    ``"tustin"``) and the filtered derivative by backward difference, which is
    stable for every Tf ≥ 0. :meth:`to_tf` returns exactly this linear law as
    a discrete transfer function made with :func:`control.c2d`.

    The output is clipped to [u_min, u_max]. Anti-windup:

    * ``"back-calculation"``: the integrator is driven by
      (u_sat - u_unsat)/Tt in addition to ki e (Åström & Hägglund 2006,
      sec. 3.5); Tt defaults to max(kp/ki, dt), i.e. Tt ≈ Ti, capped so the
      discrete tracking gain dt/Tt stays ≤ 1;
    * ``"clamping"``: the integrator holds while the output is saturated and
      the error would drive it further into saturation;
    * ``"none"``: plain integration (winds up).

    Parameters
    ----------
    kp, ki, kd : float
        Gains [V/µm, V/(µm s), V s/µm].
    dt : float
        Sampling period [s].
    u_min, u_max : float
        Output limits [V] (e.g. 0 and 120 V).
    Tf : float, optional
        Derivative filter time constant [s] (default: kd/(10 kp) if kp > 0,
        else 10 dt).
    integrator : {"forward", "backward", "tustin"}
    anti_windup : {"back-calculation", "clamping", "none"}
    Tt : float, optional
        Tracking time constant for back-calculation [s].
    """

    def __init__(
        self,
        kp: float,
        ki: float = 0.0,
        kd: float = 0.0,
        dt: float = 1e-4,
        u_min: float = -math.inf,
        u_max: float = math.inf,
        Tf: float | None = None,
        integrator: str = "forward",
        anti_windup: str = "back-calculation",
        Tt: float | None = None,
    ):
        self.kp, self.ki, self.kd = (float(v) for v in (kp, ki, kd))
        for name, v in (("kp", self.kp), ("ki", self.ki), ("kd", self.kd)):
            if not math.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be finite and ≥ 0, got {v!r}")
        if self.kp == 0 and self.ki == 0 and self.kd == 0:
            raise ValueError("at least one of kp, ki, kd must be positive")
        self.dt = _positive("dt", dt)
        self.u_min, self.u_max = float(u_min), float(u_max)
        if math.isnan(self.u_min) or math.isnan(self.u_max) or not self.u_min < self.u_max:
            raise ValueError(f"need u_min < u_max, got u_min={u_min!r}, u_max={u_max!r}")
        if integrator not in _INTEGRATORS:
            raise ValueError(f"integrator must be one of {sorted(_INTEGRATORS)}, got {integrator!r}")
        if anti_windup not in _ANTI_WINDUP:
            raise ValueError(f"anti_windup must be one of {list(_ANTI_WINDUP)}, got {anti_windup!r}")
        self.integrator, self.anti_windup = integrator, anti_windup
        if Tf is None:
            Tf = self.kd / (10 * self.kp) if self.kp > 0 else 10 * self.dt
        self.Tf = float(Tf)
        if not (math.isfinite(self.Tf) and self.Tf >= 0):
            raise ValueError(f"Tf must be finite and ≥ 0, got {Tf!r}")
        if Tt is None:
            Tt = max(self.kp / self.ki, self.dt) if self.ki > 0 else self.dt
        self.Tt = _positive("Tt", Tt)
        if self.Tt < self.dt:
            raise ValueError(f"Tt={self.Tt!r} must be ≥ dt={self.dt!r} (dt/Tt > 1 makes the tracking loop oscillate)")
        self.reset()

    # state: integrator I, previous error, previous filtered derivative
    def reset(self) -> None:
        self._i = 0.0
        self._e1 = 0.0
        self._d1 = 0.0

    def get_state(self) -> np.ndarray:
        return np.array([self._i, self._e1, self._d1])

    def set_state(self, arr) -> None:
        a = np.asarray(arr, dtype=float).reshape(-1)
        if a.shape != (3,) or not np.all(np.isfinite(a)):
            raise ValueError(f"PID state must be 3 finite numbers, got {arr!r}")
        self._i, self._e1, self._d1 = (float(v) for v in a)

    def step(self, a: float, b: float | None = None) -> float:
        """Control output for this sample.

        ``step(e)`` takes the error e = r - y; ``step(r, y)`` the reference
        and the measurement. Returns the saturated output u [V].
        """
        e = float(a) if b is None else float(a) - float(b)
        dt = self.dt
        # filtered derivative, backward difference
        if self.kd > 0:
            d = (self.Tf * self._d1 + self.kd * (e - self._e1)) / (self.Tf + dt)
        else:
            d = 0.0
        if self.integrator == "forward":
            i_out = self._i  # integral of errors up to k-1
            inc = self.ki * dt * e  # for the next sample
        elif self.integrator == "backward":
            inc = self.ki * dt * e
            i_out = self._i + inc
        else:
            inc = 0.5 * self.ki * dt * (e + self._e1)
            i_out = self._i + inc
        v = self.kp * e + i_out + d
        u = min(max(v, self.u_min), self.u_max)
        aw = self.anti_windup
        if aw == "clamping" and u != v and (inc > 0) == (v > u) and inc != 0:
            # the increment would push further into saturation: hold
            if self.integrator != "forward":
                i_out = self._i
                v = self.kp * e + i_out + d
                u = min(max(v, self.u_min), self.u_max)
            inc = 0.0
        if self.integrator == "forward":
            new_i = self._i + inc
        else:
            new_i = i_out
        if aw == "back-calculation":
            new_i += (dt / self.Tt) * (u - v)
        self._i = new_i
        self._e1 = e
        self._d1 = d
        return u

    def to_tf(self) -> ct.TransferFunction:
        """The linear (unsaturated) control law e -> u as a discrete TF.

        Built with :func:`control.c2d` from the continuous terms, so it is an
        independent check of :meth:`step`.
        """
        dt = self.dt
        c = ct.tf([self.kp], [1.0], dt)
        if self.ki > 0:
            c = c + ct.c2d(ct.tf([self.ki], [1.0, 0.0]), dt, method=_INTEGRATORS[self.integrator])
        if self.kd > 0:
            c = c + ct.c2d(ct.tf([self.kd, 0.0], [self.Tf, 1.0]), dt, method="backward_diff")
        return ct.minreal(c, verbose=False) if (self.ki > 0 or self.kd > 0) else c


def pi_controller(kp, ki, dt, u_min=0.0, u_max=120.0, **kw) -> PIDStepper:
    """PI controller (see :class:`PIDStepper`), output limits 0–120 V by default."""
    return PIDStepper(kp, ki, 0.0, dt, u_min, u_max, **kw)


def pid_controller(kp, ki, kd, dt, u_min=0.0, u_max=120.0, **kw) -> PIDStepper:
    """PID controller (see :class:`PIDStepper`), output limits 0–120 V by default."""
    return PIDStepper(kp, ki, kd, dt, u_min, u_max, **kw)


# ---------------------------------------------------------------------------
# Design


@dataclasses.dataclass
class PIDesign:
    """Result of :func:`design_pi`.

    Attributes
    ----------
    kp, ki : float
        Gains [V/µm], [V/(µm s)].
    dt : float
        Sampling period [s].
    gm : float
        Gain margin (ratio) of the discrete loop; inf if the phase never
        crosses -180°.
    pm : float
        Phase margin [deg].
    wcp : float
        Gain crossover frequency [rad/s].
    loop : control.TransferFunction
        Discrete open loop C(z) P(z).
    """

    kp: float
    ki: float
    dt: float
    gm: float
    pm: float
    wcp: float
    loop: object
    integrator: str = "forward"

    def controller(self, u_min=0.0, u_max=120.0, **kw) -> PIDStepper:
        """A :class:`PIDStepper` with these gains."""
        kw.setdefault("integrator", self.integrator)
        return pi_controller(self.kp, self.ki, self.dt, u_min, u_max, **kw)


def design_pi(
    plant,
    dt: float,
    bandwidth_hz: float,
    zero_ratio: float = 30.0,
    pm_min: float = 45.0,
    gm_min: float = 2.0,
    integrator: str = "forward",
) -> PIDesign:
    """Pick PI gains for a plant with a static gain (and hysteresis).

    Method (I-dominant loop shaping): a piezo stage below its resonance is a
    static gain, whose local slope the hysteresis changes along the loop, so
    the integral action does the work and the proportional part only adds
    phase near crossover. The PI zero is placed at ``zero_ratio`` times the
    crossover ωc = 2π `bandwidth_hz` (kp = ki / (zero_ratio ωc)): far above
    crossover, because the proportional gain reaches the lightly damped
    resonance undiminished (with ζ = 0.1 its peak is 14 dB; a zero at 3 ωc
    already destabilizes the default chain at any bandwidth). ki is
    set so that |C(e^{jωc dt}) P(e^{jωc dt})| = 1 exactly on the ZOH-sampled
    plant. The margins are then computed with :func:`control.margin` on the
    discrete loop (sampling delay included).

    Parameters
    ----------
    plant : control LTI
        SISO plant, continuous (sampled here with ZOH) or discrete with `dt`.
        Input the actuator voltage [V], output the displacement [µm].
    dt : float
        Sampling period [s].
    bandwidth_hz : float
        Desired gain-crossover frequency [Hz], below the Nyquist frequency.
    zero_ratio : float
        PI zero relative to crossover (larger: closer to pure I). The
        default 30 gives gain margins of 4–9 on :func:`pea_dynamics` for
        20–150 Hz bandwidth.
    pm_min, gm_min : float
        Required phase margin [deg] and gain margin (ratio). Keep gm ≥ 2:
        the hysteresis slope varies by about ±30 % around the mean.
    integrator : str
        Discretization of the integral (see :class:`PIDStepper`).

    Returns
    -------
    PIDesign

    Raises
    ------
    ValueError
        If the margins are not met (lower the bandwidth) or inputs are bad.
    """
    # imported here: fonbw.plant re-exports this module's names, so a
    # module-level import of it would be circular
    from .plant import LinearStepper

    dt = _positive("dt", dt)
    bw = _positive("bandwidth_hz", bandwidth_hz)
    if bw >= 0.5 / dt:
        raise ValueError(f"bandwidth_hz={bw} must be below the Nyquist frequency {0.5 / dt} Hz")
    zr = _positive("zero_ratio", zero_ratio)
    pd = LinearStepper(plant, dt).sys
    wc = 2 * math.pi * bw
    kp, ki = _pi_gains(pd, dt, wc, zr, integrator)
    loop = ct.series(PIDStepper(kp, ki, 0.0, dt, integrator=integrator).to_tf(), pd)
    gm, pm, wcp = _margins(loop)
    cl = ct.feedback(loop, 1)
    if np.any(np.abs(ct.poles(cl)) >= 1.0):
        raise ValueError(f"closed loop is unstable at {bw} Hz bandwidth; lower bandwidth_hz")
    if pm < pm_min or gm < gm_min:
        raise ValueError(
            f"margins not met at {bw} Hz bandwidth: phase margin {pm:.1f}° (need {pm_min}°), "
            f"gain margin {gm:.2f} (need {gm_min}); lower bandwidth_hz"
        )
    return PIDesign(kp=kp, ki=ki, dt=dt, gm=gm, pm=pm, wcp=wcp, loop=loop, integrator=integrator)


def _pi_gains(pd, dt: float, wc: float, zr: float, integrator: str) -> tuple[float, float]:
    """PI gains (kp [V/µm], ki [V/(µm s)]) with the zero at ``zr`` x ``wc``
    [rad/s] and unit loop gain at ``wc`` on the sampled plant ``pd``."""
    kp0, ki0 = 1.0 / (zr * wc), 1.0
    c0 = PIDStepper(kp0, ki0, 0.0, dt, integrator=integrator).to_tf()
    l0 = ct.series(c0, pd)
    mag = abs(complex(np.squeeze(l0(np.exp(1j * wc * dt)))))
    if not (math.isfinite(mag) and mag > 0):
        raise ValueError("the plant has no gain at the requested crossover frequency")
    s = 1.0 / mag
    return kp0 * s, ki0 * s


def _margins(loop) -> tuple[float, float, float]:
    """Gain margin (ratio, inf without a -180° crossing), phase margin [deg]
    and gain crossover [rad/s] of a discrete loop."""
    with warnings.catch_warnings():
        # margin() falls back to its frequency-grid method for sampled
        # lightly damped loops and says so; the fallback is what we want.
        warnings.filterwarnings("ignore", message="stability_margins: Falling back")
        gm, pm, _wcg, wcp = ct.margin(loop)
    gm = float(gm) if gm is not None and np.isfinite(gm) else math.inf
    return gm, float(pm), float(wcp)
