"""A virtual piezo bench: a configurable "real" actuator for demos and tests.

The bench is deliberately *not* built from the FONBW equations, so that
identifying FONBW (or CBW, NBW, Zhu) on its records shows a real modelling
gap, as on a physical stage. It imitates the setup of Sec. IV of the paper
(DAQ with 16-bit D/A and A/D, amplifier of gain 12, 0–120 V, about 20 µm
stroke, laser sensor, 10 kHz sampling).

Signal chain (each block can be switched off; all default values below)::

    u [V]  commanded actuator voltage (DAQ command x amp_gain), what the
      |    CSV records carry, as the paper's u(t)
    delay  transport delay of `delay` samples (DAQ latency)
    clip   amplifier rails [u_min, u_max]                     (saturation)
    DAC    command u/amp_gain quantized to `dac_bits` over ±10 V
    slew   optional slew-rate limit [V/s]
    amp    fonbw.plant.amplifier: gain amp_gain, pole 1/(2π R C)   (amplifier)
      v [V]  voltage on the PEA
    RD-PI  rate-dependent Prandtl–Ishlinskii operator: play operators with
           thresholds r_i (1 + alpha * |v'|_f), |v'|_f = |dv/dt| low-passed
           with time constant rate_tau                     (rate_dependent)
    poly   asymmetric output y_h = a1 w + a2 w² + a3 w³     (asymmetric)
    creep  y_c = y_h + Σ g_j x_j,  tau_j x_j' = y_h - x_j   (creep)
    mech   fonbw.plant.mechanics, 2nd order, 1.5 kHz, ζ = 0.1 (dynamics)
    drift  + d(t) = drift_rate tau_th (1 - e^(-t/tau_th)), not input-driven
      x [µm] true displacement                           (true_output)
    sensor fonbw.plant.sensor, 5 kHz first order            (dynamics)
    noise  + Gaussian, std noise_std [µm]
    ADC    quantized to `quant_bits` over adc_range [µm]    -> y (run)

The play operator (Krasnosel'skii & Pokrovskii 1989; Kuhnen, Eur. J.
Control 9, 2003) is z_k = max(v_k - r, min(v_k + r, z_{k-1})). Making the
thresholds grow with the filtered input rate widens the loop with frequency,
a simple form of the rate-dependent PI models (Ang et al., IEEE/ASME Trans.
Mechatronics 12, 2007 use rate-dependent weights instead). The weights
p_i ∝ exp(-r_i / 10 V) are scaled so that the quasi-static 0 → 120 V
ascending branch spans w = 0 … 120 V. The operator starts "at rest after a
previous full cycle": z_i = r_i (the end of a descending branch at 0 V), and
the output is zeroed there, as the sensor is zeroed before an experiment —
so there is no virgin curve.

Creep uses three first-order modes (0.1, 1, 10 s, gain 1 % each): after a
step the displacement rises by about 1 % of the step per decade of time
between 0.1 s and 10 s, Y Σ g_j (1 - e^(-t/tau_j)) in closed form.

Signature of the defaults (measured by tests/test_bench.py): stroke 19.9 µm
at 120 V; loop width at 1 Hz 13.6 % of the stroke for the operator alone and
14.6 % for the full bench, at 20 Hz 15.8 % and 21.7 % (the amplifier,
mechanics, sensor and the one-sample delay add 1.6° of lag at 20 Hz);
asymmetry (departure from point symmetry) 6 % of the stroke; noise 0.015 µm;
16-bit ADC over ±40 µm (1.2 nm steps); 16-bit D/A over ±10 V (3.7 mV at the
PEA); one sample of delay; drift off (when on: 0.01 µm/s initially, bending
over with tau_th = 60 s).

Randomness (noise) comes from one generator seeded with `seed`; every call of
:meth:`Bench.run` draws fresh noise, like repeating a measurement, and the
sequence of calls is reproducible. Every run starts from rest.
:meth:`Bench.stepper` gives the same bench one sample at a time
(:class:`BenchStepper`, bit-identical to :meth:`Bench.run`) for feedback loops.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, asdict

import control as ct
import numpy as np
from numba import njit

from . import plant as _plant
from .io import Record, as_signal, write_csv
from .paper import FS, SINE_FREQS, U_RANGE
from .signals import EQ19_T, bipolar_input, eq19_input, multi_input, sine_input, step_hold_input

__all__ = ["Bench", "BenchStepper", "BenchParams", "play_thresholds"]



def play_thresholds(n: int = 12, r_max: float = 55.0) -> np.ndarray:
    """Equally spaced play thresholds 0, r_max/(n-1), …, r_max [V]."""
    return np.linspace(0.0, float(r_max), int(n))


def _default_weights(r: np.ndarray, r_c: float = 10.0, span: float = U_RANGE[1]) -> np.ndarray:
    # From rest at z_i = r_i, the ascending branch to `span` gives
    # w - w0 = Σ p_i (span - 2 r_i); scale so that this equals span.
    p = np.exp(-r / r_c)
    return p * span / np.sum(p * (span - 2 * r))


@dataclass
class BenchParams:
    """Numbers of the virtual bench (units in brackets).

    Hysteresis: thresholds [V], weights [-], poly = (a1 [µm/V], a2 [µm/V²],
    a3 [µm/V³]), rate_alpha [s/V], rate_tau [s]. Creep: creep_tau [s],
    creep_gain [-]. Amplifier: amp_gain [V/V], R_out [Ω], C_load [F],
    slew_rate [V/s] or None. Mechanics: f_res [Hz], zeta [-]. Sensor:
    sensor_bw [Hz], adc_range [µm]. Drift: drift_rate [µm/s], drift_tau [s].

    A :class:`Bench` reads these once when it is built; changing them
    afterwards does not reach its linear blocks, so build a new bench.
    """

    thresholds: np.ndarray = field(default_factory=play_thresholds)
    weights: np.ndarray | None = None
    poly: tuple = (0.185, -1.5e-4, -1.0e-7)
    rate_alpha: float = 5e-5
    rate_tau: float = 0.02
    creep_tau: tuple = (0.1, 1.0, 10.0)
    creep_gain: tuple = (0.01, 0.01, 0.01)
    amp_gain: float = _plant.AMP_GAIN
    R_out: float = _plant.R_OUT
    C_load: float = _plant.C_LOAD
    slew_rate: float | None = None
    f_res: float = _plant.F_RES
    zeta: float = _plant.ZETA
    sensor_bw: float = _plant.SENSOR_BW
    adc_range: tuple = (-40.0, 40.0)
    drift_rate: float = 0.01
    drift_tau: float = 60.0

    def __post_init__(self):
        self.thresholds = np.ascontiguousarray(self.thresholds, dtype=float)
        r = self.thresholds
        if r.ndim != 1 or r.size == 0 or np.any(r < 0) or not np.all(np.isfinite(r)):
            raise ValueError("thresholds must be a non-empty 1-D array of finite values ≥ 0 [V]")
        if self.weights is None:
            self.weights = _default_weights(r)
        self.weights = np.ascontiguousarray(self.weights, dtype=float)
        if self.weights.shape != r.shape or not np.all(np.isfinite(self.weights)) or np.any(self.weights < 0):
            # negative weights can make the loop non-monotone: not a physical stack
            raise ValueError(f"weights must be {r.size} finite numbers ≥ 0, one per threshold")
        if len(self.poly) != 3 or not all(math.isfinite(a) for a in self.poly):
            raise ValueError("poly must be three finite coefficients (a1, a2, a3)")
        if len(self.creep_tau) != len(self.creep_gain) or any(t <= 0 for t in self.creep_tau):
            raise ValueError("creep_tau and creep_gain need equal length and positive time constants")
        if not self.rate_alpha >= 0 or not self.rate_tau > 0:
            raise ValueError("need rate_alpha ≥ 0 [s/V] and rate_tau > 0 [s]")
        lo, hi = self.adc_range
        if not lo < hi:
            raise ValueError(f"adc_range must be (low, high) with low < high, got {self.adc_range!r}")
        if self.slew_rate is not None and not self.slew_rate > 0:
            raise ValueError(f"slew_rate must be positive [V/s] or None, got {self.slew_rate!r}")

    def to_dict(self) -> dict:
        d = asdict(self)
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in d.items()}


# ---------------------------------------------------------------------------
# compiled kernels


@njit(cache=True)
def _rdpi_kernel(v, dt, r0, p, alpha, tau, z, state, out):  # pragma: no cover - compiled
    # state = [previous input, filtered |rate|]; z = play outputs, updated in place
    a = math.exp(-dt / tau)
    vp = state[0]
    rate = state[1]
    n = r0.shape[0]
    for k in range(v.shape[0]):
        vk = v[k]
        rate = a * rate + (1.0 - a) * abs(vk - vp) / dt
        vp = vk
        s = 1.0 + alpha * rate
        w = 0.0
        for i in range(n):
            r = r0[i] * s
            zi = z[i]
            lo = vk - r
            hi = vk + r
            if zi < lo:
                zi = lo
            elif zi > hi:
                zi = hi
            z[i] = zi
            w += p[i] * zi
        out[k] = w
    state[0] = vp
    state[1] = rate


@njit(cache=True)
def _slew_kernel(v, max_step, v0):  # pragma: no cover - compiled
    out = np.empty_like(v)
    prev = v0
    for k in range(v.shape[0]):
        d = v[k] - prev
        if d > max_step:
            d = max_step
        elif d < -max_step:
            d = -max_step
        prev = prev + d
        out[k] = prev
    return out


def _as_input(u) -> np.ndarray:
    return as_signal(u, "command u [V]", empty_ok=False)


# ---------------------------------------------------------------------------


class Bench:
    """The virtual PEA bench.

    Parameters
    ----------
    seed : int
        Seed of the noise generator (and of the logger's timestamp jitter).
    fs : float
        Sampling frequency [Hz].
    rate_dependent, asymmetric, creep, dynamics, amplifier, drift : bool
        Switch the effects of the module docstring on or off. ``asymmetric=False``
        replaces the polynomial by the straight line through its 0 and 120 V
        values (same stroke); ``dynamics`` covers mechanics and sensor filter.
    delay : int
        Transport delay [samples].
    noise_std : float
        Sensor noise standard deviation [µm].
    quant_bits : int or None
        ADC resolution over ``params.adc_range``; None: no quantization.
    dac_bits : int or None
        D/A resolution over ±10 V at the DAQ (before the amplifier gain).
    u_min, u_max : float
        Amplifier output rails [V]; must lie within ±10 V x amp_gain.
    params : BenchParams, optional
        The numbers; defaults described in :class:`BenchParams`.
    """

    def __init__(
        self,
        seed: int = 0,
        fs: float = FS,
        *,
        rate_dependent: bool = True,
        asymmetric: bool = True,
        creep: bool = True,
        dynamics: bool = True,
        amplifier: bool = True,
        drift: bool = False,
        delay: int = 1,
        noise_std: float = 0.015,
        quant_bits: int | None = 16,
        dac_bits: int | None = 16,
        u_min: float = U_RANGE[0],
        u_max: float = U_RANGE[1],
        params: BenchParams | None = None,
    ):
        self.fs = float(fs)
        if not (math.isfinite(self.fs) and self.fs > 0):
            raise ValueError(f"fs must be a positive sampling frequency [Hz], got {fs!r}")
        self.dt = 1.0 / self.fs
        self.seed = seed
        self.params = params if params is not None else BenchParams()
        pr = self.params
        self.rate_dependent, self.asymmetric = bool(rate_dependent), bool(asymmetric)
        self.creep, self.dynamics, self.amplifier, self.drift = bool(creep), bool(dynamics), bool(amplifier), bool(drift)
        if int(delay) != delay or delay < 0:
            raise ValueError(f"delay must be a whole number of samples ≥ 0, got {delay!r}")
        self.delay = int(delay)
        if not (math.isfinite(noise_std) and noise_std >= 0):
            raise ValueError(f"noise_std must be ≥ 0 [µm], got {noise_std!r}")
        self.noise_std = float(noise_std)
        for name, b in (("quant_bits", quant_bits), ("dac_bits", dac_bits)):
            if b is not None and (int(b) != b or not 1 <= b <= 32):
                raise ValueError(f"{name} must be an integer 1..32 or None, got {b!r}")
        self.quant_bits = None if quant_bits is None else int(quant_bits)
        self.dac_bits = None if dac_bits is None else int(dac_bits)
        self.u_min, self.u_max = float(u_min), float(u_max)
        vmax = 10.0 * abs(pr.amp_gain)
        if not (-vmax - 1e-9 <= self.u_min < self.u_max <= vmax + 1e-9):
            raise ValueError(
                f"need -{vmax:g} ≤ u_min < u_max ≤ {vmax:g} V (±10 V DAQ x amp_gain {pr.amp_gain:g}), "
                f"got u_min={u_min!r}, u_max={u_max!r}"
            )
        self._rng = np.random.default_rng(seed)
        # linear blocks, python-control, ZOH at the bench rate
        self._amp = _plant.LinearStepper(_plant.amplifier(pr.amp_gain, pr.R_out, pr.C_load), self.dt)
        self._mech = _plant.LinearStepper(_plant.mechanics(pr.f_res, pr.zeta), self.dt)
        self._sens = _plant.LinearStepper(_plant.sensor(pr.sensor_bw), self.dt)
        tau = np.asarray(pr.creep_tau, dtype=float)
        g = np.asarray(pr.creep_gain, dtype=float)
        creep_sys = ct.ss(np.diag(-1.0 / tau), (1.0 / tau).reshape(-1, 1), g.reshape(1, -1), [[1.0]])
        self._creep = _plant.LinearStepper(creep_sys, self.dt)
        a1, a2, a3 = pr.poly
        self._line = (a1 * 120 + a2 * 120**2 + a3 * 120**3) / 120.0

    # -- effect chain -------------------------------------------------------

    def config(self) -> dict:
        """Every setting, JSON-serializable (the ground truth for gap studies)."""
        return {
            "seed": self.seed, "fs": self.fs, "rate_dependent": self.rate_dependent,
            "asymmetric": self.asymmetric, "creep": self.creep, "dynamics": self.dynamics,
            "amplifier": self.amplifier, "drift": self.drift, "delay": self.delay,
            "noise_std": self.noise_std, "quant_bits": self.quant_bits, "dac_bits": self.dac_bits,
            "u_min": self.u_min, "u_max": self.u_max, "params": self.params.to_dict(),
        }

    @property
    def adc_step(self) -> float:
        """ADC quantization step [µm]: adc_range width / 2**quant_bits (0 if off)."""
        if self.quant_bits is None:
            return 0.0
        lo, hi = self.params.adc_range
        return (hi - lo) / 2.0**self.quant_bits

    # The chain is written once, as four stages acting on a block of samples
    # from a _ChainState: run() passes the whole record as one block, the
    # stepper one sample at a time, so the two agree bit for bit.

    def _voltage(self, u, st: "_ChainState") -> np.ndarray:
        """PEA voltage [V] for a block of commands `u` [V]: delay, rails, D/A, slew, amplifier."""
        pr = self.params
        if self.delay:
            ext = np.concatenate([st.buf, u])
            u, st.buf = ext[:u.size], ext[u.size:]
        v = np.clip(u, self.u_min, self.u_max)
        g = pr.amp_gain
        if self.dac_bits is not None:
            # the D/A quantizes the DAQ command u/g over ±10 V
            q = 20.0 / 2.0**self.dac_bits
            v = np.round(v / g / q) * (q * g)
        if pr.slew_rate is not None:
            v = _slew_kernel(v, pr.slew_rate * self.dt, st.slew)
            st.slew = float(v[-1])
        if self.amplifier:
            # simplification: the slew limit acts before the output pole
            return st.amp.run(v / g)
        return v

    def _operator(self, v, st: "_ChainState") -> np.ndarray:
        """Bare hysteresis [µm] for a block of PEA voltages `v` [V]: RD-PI, then the polynomial."""
        pr = self.params
        w = np.empty_like(v)
        alpha = pr.rate_alpha if self.rate_dependent else 0.0
        _rdpi_kernel(v, self.dt, pr.thresholds, pr.weights, alpha, pr.rate_tau, st.z, st.rate, w)
        w -= float(pr.weights @ pr.thresholds)
        if not self.asymmetric:
            return self._line * w
        a1, a2, a3 = pr.poly
        return w * (a1 + w * (a2 + w * a3))

    def _displacement(self, u, st: "_ChainState") -> np.ndarray:
        """True displacement [µm] for a block of commands `u` [V] (before the sensor)."""
        v = self._voltage(u, st)
        y = self._operator(v, st)
        if self.creep:
            y = st.creep.run(y)
        if self.dynamics:
            y = st.mech.run(y)
        y = y + self.drift_signal(y.size, st.k)
        st.k += y.size
        st.voltage, st.displacement = float(v[-1]), float(y[-1])
        return y

    def _measure(self, x, st: "_ChainState", noiseless: bool) -> np.ndarray:
        """Reading [µm] of a block of displacements `x` [µm]: sensor filter, noise, ADC."""
        if self.dynamics:
            x = st.sens.run(x)
        if noiseless:
            return x
        if self.noise_std > 0:
            x = x + self._rng.normal(0.0, self.noise_std, x.size)
        if self.quant_bits is not None:
            x = self._adc(x)
        return x

    def actuator_voltage(self, u) -> np.ndarray:
        """Voltage on the PEA [V] for the commanded actuator voltage `u` [V]."""
        return self._voltage(_as_input(u), _ChainState(self))

    def hysteresis(self, v) -> np.ndarray:
        """Bare hysteresis: rate-dependent PI and output polynomial [µm] for PEA voltage `v` [V].

        From rest after a previous full cycle, zeroed there (see module docstring).
        """
        return self._operator(_as_input(v), _ChainState(self))

    def drift_signal(self, n: int, k0: int = 0) -> np.ndarray:
        """Thermal drift d(t) [µm] over `n` samples from sample `k0` (zeros if drift is off)."""
        if not self.drift:
            return np.zeros(n)
        pr = self.params
        t = (k0 + np.arange(n)) * self.dt
        return pr.drift_rate * pr.drift_tau * -np.expm1(-t / pr.drift_tau)

    def true_output(self, u) -> np.ndarray:
        """True displacement [µm] for the command `u` [V]: before the sensor."""
        return self._displacement(_as_input(u), _ChainState(self))

    def run(self, u, noiseless: bool = False) -> np.ndarray:
        """Measured displacement [µm] for the command `u` [V], from rest.

        Sensor filter (if ``dynamics``), noise and ADC quantization included;
        ``noiseless=True`` leaves out noise and quantization (and draws no
        random numbers).
        """
        st = _ChainState(self)
        return self._measure(self._displacement(_as_input(u), st), st, noiseless)

    def _adc(self, x):
        lo, _ = self.params.adc_range
        q = self.adc_step
        code = np.clip(np.round((x - lo) / q), 0, 2**self.quant_bits - 1)
        return lo + code * q

    def stepper(self, noiseless: bool = False) -> "BenchStepper":
        """A sample-by-sample bench from rest, for closed loops (see :class:`BenchStepper`)."""
        return BenchStepper(self, noiseless)

    # -- records ------------------------------------------------------------

    def record(self, u, name: str = "bench") -> Record:
        """Run `u` and return a :class:`fonbw.io.Record` (t from 0, uniform)."""
        u = _as_input(u)
        y = self.run(u)
        return Record.from_arrays(u=u, y=y, dt=self.dt, path=f"<bench:{name}>")

    def logger_record(
        self,
        u,
        name: str = "logger",
        rest: float = 0.5,
        offset: float = 0.8,
        jitter: float = 1e-4,
        t0: float = 12.3456,
    ) -> Record:
        """A record as a real data logger writes it.

        Differences from :meth:`record`: `rest` seconds at 0 V precede the
        drive; the sensor reads `offset` µm at rest (not zeroed); timestamps
        start at `t0` s and carry jitter, Gaussian with std ``jitter * dt``
        and cut at ±3 std (so steps stay within 6e-4 dt of the median at the
        default, inside the reader's tolerance).
        """
        u = _as_input(u)
        if not (math.isfinite(rest) and rest >= 0):
            raise ValueError(f"rest must be ≥ 0 [s], got {rest!r}")
        if not (math.isfinite(jitter) and 0 <= jitter < 0.1):
            raise ValueError(f"jitter must be in [0, 0.1) (relative to dt), got {jitter!r}")
        u = np.concatenate([np.zeros(int(round(rest * self.fs))), u])
        y = self.run(u) + float(offset)
        k = np.arange(u.size)
        e = np.clip(self._rng.standard_normal(u.size), -3, 3) * jitter * self.dt
        t = float(t0) + k * self.dt + e
        return Record(t=t, u=u, y=y, dt=self.dt, path=f"<bench:{name}>")

    def write_experiments(self, directory, T_eq19: float = EQ19_T, periods: int = 5,
                          extra: bool = True, logger: bool = False) -> list[str]:
        """Write the paper's experiments as CSV files (columns t, u, y).

        ``eq19.csv`` (identification input, eq. 19, `T_eq19` s) and
        ``sine_01hz.csv`` … ``sine_20hz.csv`` (u = 60 - 60 cos 2πft V, `periods`
        periods each, Table III frequencies); with `extra` also ``multi.csv``
        and ``step_hold.csv``; with `logger` also ``logger_bipolar.csv`` from a
        bipolar ±150 V logger bench (:meth:`bipolar_logger`) with the same seed.

        Returns
        -------
        list of str
            The paths written, in that order.
        """
        os.makedirs(directory, exist_ok=True)
        jobs = [("eq19", eq19_input(self.fs, T_eq19)[1])]
        for f in SINE_FREQS:
            jobs.append((f"sine_{int(f):02d}hz", sine_input(f, self.fs, periods=periods)[1]))
        if extra:
            jobs.append(("multi", multi_input(fs=self.fs)[1]))
            jobs.append(("step_hold", step_hold_input(fs=self.fs)[1]))
        paths = []
        for name, u in jobs:
            rec = self.record(u, name)
            path = os.path.join(os.fspath(directory), f"{name}.csv")
            write_csv(path, {"t": rec.t, "u": rec.u, "y": rec.y})
            paths.append(path)
        if logger:
            lb = Bench.bipolar_logger(seed=self.seed, fs=self.fs)
            rec = lb.logger_record(bipolar_input(fs=self.fs)[1], "logger_bipolar")
            path = os.path.join(os.fspath(directory), "logger_bipolar.csv")
            write_csv(path, {"t": rec.t, "u": rec.u, "y": rec.y})
            paths.append(path)
        return paths

    @classmethod
    def ideal(cls, seed: int = 0, fs: float = FS, **kw) -> "Bench":
        """Every effect off: the output is the bare hysteresis operator."""
        base = dict(creep=False, dynamics=False, amplifier=False, drift=False, delay=0,
                    noise_std=0.0, quant_bits=None, dac_bits=None)
        base.update(kw)
        return cls(seed, fs, **base)

    @classmethod
    def bipolar_logger(cls, seed: int = 0, fs: float = FS, **kw) -> "Bench":
        """A bench with a bipolar ±150 V amplifier (gain 15) and thermal drift."""
        pr = kw.pop("params", None) or BenchParams(amp_gain=15.0)
        base = dict(u_min=-150.0, u_max=150.0, drift=True, params=pr)
        base.update(kw)
        return cls(seed, fs, **base)


class _ChainState:
    """Where the bench's signal chain stands: what a block of samples needs to
    continue it. A new one is at rest (see the module docstring)."""

    def __init__(self, bench: Bench):
        self.amp, self.creep, self.mech, self.sens = (
            _plant.LinearStepper(s.sys) for s in (bench._amp, bench._creep, bench._mech, bench._sens))
        self.buf = np.zeros(bench.delay)  # the delayed commands [V], oldest first
        self.slew = 0.0  # last slew-limited voltage [V]
        self.z = bench.params.thresholds.copy()  # play operator outputs [V]
        self.rate = np.zeros(2)  # previous PEA voltage [V], filtered |rate| [V/s]
        self.k = 0  # samples done
        self.voltage = 0.0  # PEA voltage [V] of the last sample
        self.displacement = 0.0  # true displacement [µm] of the last sample

    def get(self) -> dict:
        return {"k": self.k, "z": self.z.copy(), "rate": self.rate.copy(), "buf": self.buf.copy(),
                "slew_prev": self.slew, "voltage": self.voltage, "displacement": self.displacement,
                "lin": [s.get_state() for s in (self.amp, self.creep, self.mech, self.sens)]}

    def set(self, st: dict) -> None:
        self.k = int(st["k"])
        self.z, self.rate, self.buf = st["z"].copy(), st["rate"].copy(), st["buf"].copy()
        self.slew = float(st["slew_prev"])
        self.voltage, self.displacement = float(st["voltage"]), float(st["displacement"])
        for s, x in zip((self.amp, self.creep, self.mech, self.sens), st["lin"]):
            s.set_state(x)


class BenchStepper:
    """The bench one sample at a time, for feedback loops around it.

    ``y_k = step(u_k)`` gives the measured displacement [µm] for the command
    u_k [V]; the sequence equals :meth:`Bench.run` on the same input (bit for
    bit, noise included: both run the bench's one chain definition and draw
    from the bench's generator in the same order). With the default chain
    y_k does not depend on u_k (the amplifier and mechanics are strictly
    proper and there is a one-sample delay); with every effect off it does.
    In a feedback loop use the value returned by the previous call as the
    measurement, the one-sample computational delay of a real DAQ loop::

        y = 0.0
        for r_k in r:
            y = st.step(controller.step(r_k, y))

    Attributes
    ----------
    voltage : float
        PEA voltage [V] of the last step.
    displacement : float
        True displacement [µm] of the last step (before the sensor).
    """

    def __init__(self, bench: Bench, noiseless: bool = False):
        self.bench = bench
        self.noiseless = bool(noiseless)
        self.reset()

    k = property(lambda self: self._st.k, doc="Samples done.")
    voltage = property(lambda self: self._st.voltage, doc="PEA voltage [V] of the last step.")
    displacement = property(lambda self: self._st.displacement,
                            doc="True displacement [µm] of the last step (before the sensor).")

    def reset(self) -> None:
        """Back to rest (the noise generator is not rewound)."""
        self._st = _ChainState(self.bench)

    def get_state(self) -> dict:
        """Everything needed to replay from here, the generator state included."""
        return {**self._st.get(), "rng": self.bench._rng.bit_generator.state}

    def set_state(self, st: dict) -> None:
        self._st.set(st)
        self.bench._rng.bit_generator.state = st["rng"]

    def step(self, u: float) -> float:
        """Apply the command u_k [V]; return the measured displacement y_k [µm]."""
        u = float(u)
        if not math.isfinite(u):
            raise ValueError(f"command at sample {self.k} is not finite: {u!r}")
        b, st = self.bench, self._st
        return float(b._measure(b._displacement(np.array([u]), st), st, self.noiseless)[0])
