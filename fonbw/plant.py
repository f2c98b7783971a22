"""Linear dynamics of the PEA chain and discrete feedback controllers.

Every linear system here is a python-control object; time stepping uses the
zero-order-hold discretization from :func:`control.c2d`.

Signal chain and units (Sec. IV of the paper: a DAQ D/A channel, a voltage
amplifier of gain 12, the PEA, a laser sensor, all sampled at 10 kHz)::

    DAQ command [V] --amplifier--> actuator voltage [V]
        --(hysteresis, nonlinear, elsewhere)--> quasi-static displacement [µm]
        --mechanics [µm/µm]--> displacement [µm] --sensor [µm/µm]--> reading [µm]

The hysteresis output is the displacement the actuator would reach at rest;
the mechanics only filter it, so their DC gain is 1 µm/µm. For a linear
design model the hysteresis is replaced by a static slope ``k_pea`` [µm/V]
(:func:`pea_dynamics`).

Defaults, and why:

* amplifier: output resistance 20 Ω driving the PEA capacitance 3.6 µF (a
  7 mm x 7 mm x 20 mm stack) gives a first-order pole at 1/(2π R C) = 2.2 kHz;
* mechanics: resonance 1.5 kHz, damping ratio 0.1 (a stack carrying a small
  stage; the bare stack rings far higher);
* sensor: first-order 5 kHz (the conditioner's averaging filter).

With these the chain has unit gain to within 0.02 % at 20 Hz but lags by
0.9°, which opens a 20 Hz loop by about sin 0.9° = 1.6 % of the stroke: small,
as the paper assumes when it leaves the dynamics out (Sec. IV-B), but not below
its 1.4–3.7 % model errors.

Controllers (:class:`PIDStepper`) are the textbook parallel PID with a
first-order derivative filter and anti-windup by back-calculation or clamping
(Åström & Hägglund, *Advanced PID Control*, ISA 2006, ch. 3); their linear
part is available as a discrete transfer function (:meth:`PIDStepper.to_tf`)
built with :func:`control.c2d`, so closed loops can be checked against
:func:`control.feedback`.
"""
from __future__ import annotations

import dataclasses
import math
import warnings

import control as ct
import numpy as np
from numba import njit

__all__ = [
    "amplifier",
    "mechanics",
    "sensor",
    "pea_dynamics",
    "LinearStepper",
    "PIDStepper",
    "pi_controller",
    "pid_controller",
    "PIDesign",
    "design_pi",
    "AMP_GAIN",
    "R_OUT",
    "C_LOAD",
    "F_RES",
    "ZETA",
    "SENSOR_BW",
    "K_PEA",
]

#: Voltage gain of the amplifier (paper, Sec. IV-A) [V/V].
AMP_GAIN = 12.0
#: Amplifier output resistance [Ω].
R_OUT = 20.0
#: PEA capacitance [F].
C_LOAD = 3.6e-6
#: Mechanical resonance [Hz].
F_RES = 1500.0
#: Mechanical damping ratio [-].
ZETA = 0.1
#: Sensor bandwidth (first-order) [Hz].
SENSOR_BW = 5000.0
#: Mean slope of the paper's PEA, 20 µm over 120 V [µm/V].
K_PEA = 20.0 / 120.0


def _positive(name, value):
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    return v


def amplifier(gain: float = AMP_GAIN, R_out: float = R_OUT, C_load: float = C_LOAD) -> ct.TransferFunction:
    """Voltage amplifier driving the capacitive PEA load.

    G(s) = gain / (R_out C_load s + 1): the output resistance and the PEA
    capacitance form a first-order low pass with bandwidth 1/(2π R_out C_load)
    (2.2 kHz by default). Slew-rate limits and output rails are nonlinear and
    are modelled by the bench (:mod:`fonbw.bench`), not here.

    Parameters
    ----------
    gain : float
        DC voltage gain [V/V] (12 in the paper).
    R_out : float
        Output resistance [Ω].
    C_load : float
        PEA capacitance [F].

    Returns
    -------
    control.TransferFunction
        Continuous time, input DAQ voltage [V], output actuator voltage [V].
    """
    g = float(gain)
    if not (math.isfinite(g) and g != 0):
        raise ValueError(f"gain must be finite and non-zero, got {gain!r}")
    tau = _positive("R_out", R_out) * _positive("C_load", C_load)
    return ct.tf([g], [tau, 1.0], inputs="v_daq", outputs="v_pea", name="amplifier")


def mechanics(f_res: float = F_RES, zeta: float = ZETA, dc_gain: float = 1.0) -> ct.TransferFunction:
    """Second-order mechanical resonance of the actuator and its load.

    G(s) = dc_gain ωn² / (s² + 2 ζ ωn s + ωn²), ωn = 2π f_res.

    Parameters
    ----------
    f_res : float
        Undamped natural frequency [Hz].
    zeta : float
        Damping ratio [-], > 0.
    dc_gain : float
        Static gain [µm/µm] (1: the input is the quasi-static displacement).

    Returns
    -------
    control.TransferFunction
        Continuous time, quasi-static displacement [µm] -> displacement [µm].
    """
    wn = 2 * math.pi * _positive("f_res", f_res)
    z = _positive("zeta", zeta)
    k = float(dc_gain)
    if not math.isfinite(k):
        raise ValueError(f"dc_gain must be finite, got {dc_gain!r}")
    return ct.tf([k * wn * wn], [1.0, 2 * z * wn, wn * wn], inputs="h", outputs="x", name="mechanics")


def sensor(bandwidth: float = SENSOR_BW) -> ct.TransferFunction:
    """First-order displacement sensor, G(s) = 1 / (s / (2π bandwidth) + 1).

    Parameters
    ----------
    bandwidth : float
        -3 dB bandwidth [Hz].

    Returns
    -------
    control.TransferFunction
        Continuous time, displacement [µm] -> reading [µm].
    """
    w = 2 * math.pi * _positive("bandwidth", bandwidth)
    return ct.tf([w], [1.0, w], inputs="x", outputs="y", name="sensor")


def pea_dynamics(
    k_pea: float = K_PEA,
    input: str = "actuator",
    gain: float = AMP_GAIN,
    R_out: float = R_OUT,
    C_load: float = C_LOAD,
    f_res: float = F_RES,
    zeta: float = ZETA,
    sensor_bandwidth: float | None = SENSOR_BW,
) -> ct.StateSpace:
    """Linearized PEA chain: amplifier, static slope, mechanics, sensor in series.

    Parameters
    ----------
    k_pea : float
        Static slope standing in for the hysteresis [µm/V] (default 20 µm /
        120 V; the real local slope varies by about ±30 % along a loop).
    input : {"actuator", "daq"}
        ``"actuator"``: the input is the nominal actuator voltage (DAQ command
        times `gain`, 0–120 V, as the paper's u and the controllers use), so the
        amplifier enters with unit DC gain. ``"daq"``: the input is the DAQ
        command [V] and the amplifier gain is `gain`.
    gain, R_out, C_load : float
        See :func:`amplifier`.
    f_res, zeta : float
        See :func:`mechanics`.
    sensor_bandwidth : float or None
        See :func:`sensor`; None leaves the sensor out.

    Returns
    -------
    control.StateSpace
        Continuous time, SISO, input ``u`` [V], output ``y`` [µm]; DC gain
        ``k_pea`` (actuator input) or ``k_pea * gain`` (DAQ input).
    """
    if input not in ("actuator", "daq"):
        raise ValueError(f"input must be 'actuator' or 'daq', got {input!r}")
    k = float(k_pea)
    if not (math.isfinite(k) and k != 0):
        raise ValueError(f"k_pea must be finite and non-zero, got {k_pea!r}")
    amp = amplifier(gain if input == "daq" else 1.0, R_out, C_load)
    chain = ct.series(amp, ct.tf([k], [1.0]), mechanics(f_res, zeta))
    if sensor_bandwidth is not None:
        chain = ct.series(chain, sensor(sensor_bandwidth))
    return ct.ss(chain, inputs="u", outputs="y", name="pea_dynamics")


# ---------------------------------------------------------------------------
# Discrete state-space stepping


@njit(cache=True)
def _ss_run(A, B, C, D, x, u, y):  # pragma: no cover - compiled
    # One kernel for both the batch and the per-sample path, so the two give
    # bit-identical numbers.
    n = x.shape[0]
    xn = np.empty(n)
    for k in range(u.shape[0]):
        uk = u[k]
        acc = D * uk
        for i in range(n):
            acc += C[i] * x[i]
        y[k] = acc
        for i in range(n):
            s = B[i] * uk
            for j in range(n):
                s += A[i, j] * x[j]
            xn[i] = s
        for i in range(n):
            x[i] = xn[i]


def _as_siso_ss(sys) -> ct.StateSpace:
    if not isinstance(sys, (ct.StateSpace, ct.TransferFunction)):
        raise ValueError(f"expected a control.StateSpace or control.TransferFunction, got {type(sys).__name__}")
    if sys.ninputs != 1 or sys.noutputs != 1:
        raise ValueError(f"expected a SISO system, got {sys.ninputs} input(s) and {sys.noutputs} output(s)")
    return ct.ss(sys)


class LinearStepper:
    """Sample-by-sample simulation of a SISO linear system under zero-order hold.

    Convention: with state x_k and input u_k, the output is
    ``y_k = C x_k + D u_k`` and the state advances as
    ``x_{k+1} = A x_k + B u_k`` — the same convention as
    :func:`control.forced_response` on the discrete system with ``X0 = 0``.
    A system with D = 0 has no direct feedthrough, so it can close a loop
    with a controller that has one.

    Parameters
    ----------
    sys : control.StateSpace or control.TransferFunction
        SISO system. Continuous systems are discretized with
        ``control.c2d(sys, dt, method)``; discrete ones are used as they are.
    dt : float, optional
        Sampling period [s]; required for a continuous system; for a discrete
        one it must equal ``sys.dt`` (or fix it if ``sys.dt`` is True).
    method : str
        Discretization method for :func:`control.c2d` (``"zoh"`` default).
    """

    def __init__(self, sys, dt: float | None = None, method: str = "zoh"):
        ss = _as_siso_ss(sys)
        if ss.isctime(strict=True):
            if dt is None:
                raise ValueError("dt is required to discretize a continuous-time system")
            dt = _positive("dt", dt)
            ss = ct.c2d(ss, dt, method=method)
        else:
            sdt = ss.dt
            if sdt is True or sdt is None:
                if dt is None:
                    raise ValueError("the discrete system has an unspecified sampling period; give dt")
                dt = _positive("dt", dt)
                ss = ct.ss(ss.A, ss.B, ss.C, ss.D, dt)
            else:
                if dt is not None and not math.isclose(float(dt), float(sdt), rel_tol=1e-12):
                    raise ValueError(f"dt={dt!r} differs from the discrete system's sampling period {sdt!r}")
                dt = float(sdt)
        self.sys: ct.StateSpace = ss
        self.dt = float(dt)
        self._A = np.ascontiguousarray(ss.A, dtype=float)
        self._B = np.ascontiguousarray(np.asarray(ss.B, dtype=float).reshape(-1))
        self._C = np.ascontiguousarray(np.asarray(ss.C, dtype=float).reshape(-1))
        self._D = float(np.asarray(ss.D).reshape(()))
        self._x = np.zeros(self._A.shape[0])
        self._u1 = np.zeros(1)
        self._y1 = np.zeros(1)

    A = property(lambda self: self._A.copy(), doc="Discrete state matrix (copy).")
    B = property(lambda self: self._B.reshape(-1, 1).copy(), doc="Discrete input matrix, n x 1 (copy).")
    C = property(lambda self: self._C.reshape(1, -1).copy(), doc="Output matrix, 1 x n (copy).")
    D = property(lambda self: np.array([[self._D]]), doc="Feedthrough, 1 x 1.")

    @property
    def nstates(self) -> int:
        return self._A.shape[0]

    def step(self, u: float) -> float:
        """Output for input `u` at the current sample, then advance one step."""
        self._u1[0] = u
        _ss_run(self._A, self._B, self._C, self._D, self._x, self._u1, self._y1)
        return float(self._y1[0])

    def output(self, u: float = 0.0) -> float:
        """Output C x_k + D u of the current sample without advancing.

        In a loop with a controller, read ``y_k = output()`` (exact when
        D = 0), compute ``u_k``, then call ``step(u_k)``.
        """
        return float(self._C @ self._x + self._D * float(u))

    def simulate(self, u, x0=None) -> np.ndarray:
        """Batch response to the input sequence `u` (1-D), from rest or `x0`.

        Does not touch the stepper's own state. Same numbers as repeated
        :meth:`step` calls from the same state.
        """
        u = np.ascontiguousarray(u, dtype=float)
        if u.ndim != 1:
            raise ValueError(f"u must be a 1-D array, got shape {u.shape}")
        x = np.zeros(self.nstates) if x0 is None else self._check_state(x0).copy()
        y = np.empty_like(u)
        _ss_run(self._A, self._B, self._C, self._D, x, u, y)
        return y

    def _check_state(self, arr) -> np.ndarray:
        a = np.asarray(arr, dtype=float).reshape(-1)
        if a.shape != (self.nstates,):
            raise ValueError(f"state must have {self.nstates} entries, got {a.size}")
        if not np.all(np.isfinite(a)):
            raise ValueError("state contains non-finite values")
        return a

    def get_state(self) -> np.ndarray:
        """Copy of the state vector x_k."""
        return self._x.copy()

    def set_state(self, arr) -> None:
        """Restore a state from :meth:`get_state`."""
        self._x[:] = self._check_state(arr)

    def reset(self) -> None:
        """Back to rest (x = 0)."""
        self._x[:] = 0.0

    def dcgain(self) -> float:
        return float(ct.dcgain(self.sys))


# ---------------------------------------------------------------------------
# PID controllers

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
    dt = _positive("dt", dt)
    bw = _positive("bandwidth_hz", bandwidth_hz)
    if bw >= 0.5 / dt:
        raise ValueError(f"bandwidth_hz={bw} must be below the Nyquist frequency {0.5 / dt} Hz")
    zr = _positive("zero_ratio", zero_ratio)
    pd = LinearStepper(plant, dt).sys
    wc = 2 * math.pi * bw
    kp0, ki0 = 1.0 / (zr * wc), 1.0
    c0 = PIDStepper(kp0, ki0, 0.0, dt, integrator=integrator).to_tf()
    l0 = ct.series(c0, pd)
    mag = abs(complex(np.squeeze(l0(np.exp(1j * wc * dt)))))
    if not (math.isfinite(mag) and mag > 0):
        raise ValueError("the plant has no gain at the requested crossover frequency")
    s = 1.0 / mag
    kp, ki = kp0 * s, ki0 * s
    loop = ct.series(PIDStepper(kp, ki, 0.0, dt, integrator=integrator).to_tf(), pd)
    with warnings.catch_warnings():
        # margin() falls back to its frequency-grid method for sampled
        # lightly damped loops and says so; the fallback is what we want.
        warnings.filterwarnings("ignore", message="stability_margins: Falling back")
        gm, pm, _wcg, wcp = ct.margin(loop)
    gm = float(gm) if gm is not None and np.isfinite(gm) else math.inf
    pm = float(pm)
    cl = ct.feedback(loop, 1)
    if np.any(np.abs(ct.poles(cl)) >= 1.0):
        raise ValueError(f"closed loop is unstable at {bw} Hz bandwidth; lower bandwidth_hz")
    if pm < pm_min or gm < gm_min:
        raise ValueError(
            f"margins not met at {bw} Hz bandwidth: phase margin {pm:.1f}° (need {pm_min}°), "
            f"gain margin {gm:.2f} (need {gm_min}); lower bandwidth_hz"
        )
    return PIDesign(kp=kp, ki=ki, dt=dt, gm=gm, pm=pm, wcp=float(wcp), loop=loop, integrator=integrator)
