"""Linear dynamics of the PEA chain (amplifier, mechanics, sensor) and their stepper.

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

The PID controllers and their design (:class:`~fonbw.pid.PIDStepper`,
:func:`~fonbw.pid.design_pi`, …) live in :mod:`fonbw.pid`; this module
re-exports them, so ``fonbw.plant.PIDStepper`` and the others keep working.
"""
from __future__ import annotations

import math

import control as ct
import numpy as np
from numba import njit

from .pid import PIDesign, PIDStepper, design_pi, pi_controller, pid_controller  # noqa: F401  (re-exported)

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

    def run(self, u) -> np.ndarray:
        """Outputs for the input block `u` (1-D), advancing the stepper's state.

        The block form of :meth:`step`: the same numbers as one :meth:`step`
        call per sample, in one compiled call.
        """
        u = np.ascontiguousarray(u, dtype=float)
        y = np.empty_like(u)
        _ss_run(self._A, self._B, self._C, self._D, self._x, u, y)
        return y

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
