"""Truth simulator for the blind test of the gap diagnosis.

Used by ``benchmarks/blind_gap.py`` and ``tests/test_gap.py``; it uses the
library's public API only. Written apart from :mod:`fonbw.gap.effects` on
purpose: every effect here has other equations or another discretization
than the candidate block the diagnosis may use to explain it, so the blind
test is not rigged.

=============  =========================================  ===========================================
effect         truth (here)                               candidate block (fonbw.gap.effects)
=============  =========================================  ===========================================
creep          logarithmic creep, γ per decade: 12 modes   4 fixed modes 0.01…10 s, implicit Euler,
               τ = 1 ms … 100 s, Tustin, on the output     gains solved
dynamics       two modes: 0.96 at (f_res, ζ) and 0.04 at    one mode, ζ ≤ 0.5, python-control c2d (FOH)
               (3.3 f_res, 0.1), scipy lsim
amplifier      internal pole at 4 f_c, then the load's RC  one RC stage whose rate is clipped
               with a current (slew) limit, exact ODE      per sample (implicit step)
               solution, 16 sub-steps per sample
delay          continuous transport delay of the input,    input delay, linear interpolation
               monotone cubic (PCHIP) interpolation
drift          A (1 − e^(−t/τ_th)) + integrated random     (t/10 s), (t/10 s)² shared by records
               walk per record
saturation     smooth stroke limit (tanh knee) on the      slope change c over a softplus corner
               displacement                                of width w at the knee, on the model's
                                                           own output, c solved (Gauss-Newton)
hum            50 Hz + 150 Hz mains pickup, random phase   none: outside the library
=============  =========================================  ===========================================

The hysteresis is the library's FONBW (:data:`fonbw.data.DEFAULT_MODEL`
perturbed a few per cent per scenario). Sensor noise is white Gaussian with a
16-bit ADC over ±40 µm. Magnitudes are set by bisection on each effect's
strength so that the RMS change it makes on the validation records equals a
target multiple of the noise standard deviation.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np
from scipy import signal
from scipy.interpolate import PchipInterpolator

from fonbw import FONBW, load_model
from fonbw import signals as _sig
from fonbw.data import DEFAULT_MODEL
from fonbw.io import Record

__all__ = ["TRUTH_EFFECTS", "KINDS", "Truth", "default_experiments", "draw_scenario", "scenario_kind", "magnitude"]

TRUTH_EFFECTS = ("creep", "dynamics", "amplifier", "delay", "drift", "saturation", "hum")
FS = 5000.0
KINDS = ("null", "single", "pair", "outside", "below")
KIND_P = (0.15, 0.45, 0.2, 0.1, 0.1)  # probabilities of KINDS


def default_experiments(fs=FS, scale=1.0):
    """Training and validation inputs shaped like the paper's experiments.

    Training: eq. (19) (8 s), steps with holds (40, 100, 60 V, 1 s each),
    multi-tone 1/5/10/20 Hz (2 s). Validation: 1 Hz and 20 Hz sines
    (60 − 60 cos), multi-tone 2/7/15/25 Hz, steps 80 and 20 V. `scale`
    stretches every duration.

    Returns
    -------
    (list of (name, u)), (list of (name, u))
    """
    s = float(scale)
    train = [
        ("eq19", _sig.eq19_input(fs, 8.0 * s)[1]),
        ("steps", _sig.step_hold_input((40.0, 100.0, 60.0), hold=1.0 * s, fs=fs)[1]),
        ("multi", _sig.multi_input((1.0, 5.0, 10.0, 20.0), fs=fs, T=2.0 * s, weights=(1.0, 0.7, 0.5, 0.5))[1]),
    ]
    val = [
        ("sine01", _sig.sine_input(1.0, fs, periods=None, T=2.0 * s)[1]),
        ("sine20", _sig.sine_input(20.0, fs, periods=None, T=0.5 * s)[1]),
        ("multi_v", _sig.multi_input((2.0, 7.0, 15.0, 25.0), fs=fs, T=2.0 * s)[1]),
        ("steps_v", _sig.step_hold_input((80.0, 20.0), hold=1.0 * s, fs=fs)[1]),
    ]
    return train, val


@nb.njit(cache=True)
def _amplifier_ode(u, dt, f_c, slew, substeps=16):  # pragma: no cover - compiled
    """Amplifier with an internal pole at 4 f_c driving the capacitive load.

    The command u is held over each sample interval (the DAC) and the output
    is read at the interval's end. Internal stage: dw/dt = 8π f_c (u − w),
    exact per sub-step. Load: dv/dt = clip((w − v)/τ, ±slew), τ = 1/(2π f_c):
    the output current is limited, so the voltage slews linearly until it is
    within slew·τ of w and then relaxes exponentially; solved exactly per
    sub-step with w at the sub-step's midpoint. At rest at u_0.
    """
    out = np.empty_like(u)
    h = dt / substeps
    tau = 1.0 / (2.0 * math.pi * f_c)
    aw = math.exp(-h * 4.0 * 2.0 * math.pi * f_c)
    aw2 = math.exp(-0.5 * h * 4.0 * 2.0 * math.pi * f_c)
    band = slew * tau
    w = u[0]
    v = u[0]
    for k in range(u.shape[0]):
        for _ in range(substeps):
            wm = u[k] + (w - u[k]) * aw2
            w = u[k] + (w - u[k]) * aw
            e = wm - v
            rest = h
            if abs(e) > band:
                t1 = (abs(e) - band) / slew
                if t1 >= h:
                    v += math.copysign(slew * h, e)
                    continue
                v += math.copysign(slew * t1, e)
                rest = h - t1
            v = wm - (wm - v) * math.exp(-rest / tau)
        out[k] = v
    return out


def _lowpass_tustin(x, tau, dt):
    c = dt / (2.0 * tau + dt)
    b = [c, c]
    a = [1.0, (dt - 2.0 * tau) / (2.0 * tau + dt)]
    zi = signal.lfilter_zi(b, a) * x[0]
    return signal.lfilter(b, a, x, zi=zi)[0]


class Truth:
    """A "real" actuator: FONBW hysteresis plus the chosen effects.

    Parameters
    ----------
    hyst : FONBW
    effects : dict
        ``{name: params}`` with name in :data:`TRUTH_EFFECTS` (see
        :meth:`apply` for the parameters of each).
    noise_std : float
        Sensor noise [µm].
    fs : float
        Sampling frequency [Hz].
    seed : int
        Seed of the noise, drift random walk and hum phases.
    """

    def __init__(self, hyst, effects=None, noise_std=0.02, fs=FS, seed=0):
        self.hyst = hyst
        self.effects = dict(effects or {})
        for k in self.effects:
            if k not in TRUTH_EFFECTS:
                raise ValueError(f"unknown truth effect {k!r}")
        self.noise_std = float(noise_std)
        self.fs = float(fs)
        self.dt = 1.0 / self.fs
        self.seed = seed

    def output(self, u, rec_index=0, effects=None):
        """Noiseless displacement [µm] for the command u [V]."""
        eff = self.effects if effects is None else effects
        dt = self.dt
        u = np.asarray(u, dtype=float)
        t = np.arange(u.size) * dt
        rng = np.random.default_rng([self.seed, rec_index, 7])
        v = u
        if "delay" in eff:
            td = eff["delay"]["seconds"]
            # monotone cubic (PCHIP) reconstruction of the command: third-order
            # on smooth inputs, and an S-shaped edge without overshoot at a
            # step. A cubic spline rings on both sides of a step (Gibbs), a
            # resonance-like signature no DAC puts out
            cs = PchipInterpolator(t, u)
            ts = t - td
            v = np.where(ts <= 0, u[0], cs(np.clip(ts, 0, None)))
        if "amplifier" in eff:
            p = eff["amplifier"]
            v = _amplifier_ode(np.ascontiguousarray(v), dt, p["f_c"], p.get("slew") or math.inf)
        y = self.hyst.simulate(v, dt)
        if "creep" in eff:
            g = eff["creep"]["gamma"]  # fraction of the step per decade of time
            taus = np.logspace(-3, 2, 12)
            # 12 modes over 5 decades: each carries 5/12 decade of log-creep
            w = g * 5.0 / 12.0
            y = y + sum(w * (_lowpass_tustin(y, tau, dt) - y) for tau in taus)
        if "saturation" in eff:
            knee, width = eff["saturation"]["knee"], eff["saturation"]["width"]
            over = y > knee
            y = np.where(over, knee + width * np.tanh((y - knee) / width), y)
        if "dynamics" in eff:
            wn = 2 * math.pi * eff["dynamics"]["f_res"]
            z = eff["dynamics"]["zeta"]
            w2 = 3.3 * wn
            # a main mode and a weaker second one (a stage on a stack)
            num = np.polyadd(0.96 * wn * wn * np.array([1.0, 2 * 0.1 * w2, w2 * w2]),
                             0.04 * w2 * w2 * np.array([1.0, 2 * z * wn, wn * wn]))
            den = np.polymul([1.0, 2 * z * wn, wn * wn], [1.0, 2 * 0.1 * w2, w2 * w2])
            _, yy, _ = signal.lsim(signal.lti(num, den), y - y[0], t)
            y = yy + y[0]
        if "drift" in eff:
            p = eff["drift"]
            walk = np.cumsum(rng.standard_normal(u.size)) * p["walk"] * math.sqrt(dt)
            y = y + p["amp"] * -np.expm1(-t / p["tau"]) + _lowpass_tustin(walk, 0.5, dt)
        if "hum" in eff:
            a = eff["hum"]["amp"]
            ph = rng.uniform(0, 2 * math.pi, 2)
            y = y + a * np.sin(2 * math.pi * 50 * t + ph[0]) + a / 3 * np.sin(2 * math.pi * 150 * t + ph[1])
        return y

    def record(self, u, name, rec_index):
        """A measured record: noise and 16-bit ADC over ±40 µm added."""
        y = self.output(u, rec_index)
        rng = np.random.default_rng([self.seed, rec_index, 11])
        y = y + rng.normal(0.0, self.noise_std, y.size)
        q = 80.0 / 2 ** 16
        y = -40.0 + np.round((y + 40.0) / q) * q
        return Record.from_arrays(u=u, y=y, dt=self.dt, path=f"<truth:{name}>")


def magnitude(truth, inputs, name, params):
    """RMS change [in noise std] that effect `name` alone makes on `inputs`."""
    num = 0.0
    n = 0
    for i, (_, u) in enumerate(inputs):
        a = truth.output(u, 100 + i, effects={})
        b = truth.output(u, 100 + i, effects={name: params})
        num += float(np.sum((a - b) ** 2))
        n += u.size
    return math.sqrt(num / n) / truth.noise_std


def _strength(name, s, rng_params):
    """Effect parameters for strength s ∈ [0, 1] (monotone in magnitude)."""
    p = rng_params
    if name == "creep":
        return {"gamma": 10 ** (-5 + 4 * s)}
    if name == "dynamics":
        return {"f_res": 10 ** (math.log10(2e4) - s * (math.log10(2e4) - math.log10(60))), "zeta": p["zeta"]}
    if name == "amplifier":
        fc = 10 ** (math.log10(5e4) - s * (math.log10(5e4) - math.log10(5)))
        return {"f_c": fc, "slew": (p["slew_k"] * 2 * math.pi * fc * 120.0) if p["slew_k"] else None}
    if name == "delay":
        return {"seconds": 10 ** (-6 + 3.5 * s)}
    if name == "drift":
        a = 10 ** (-3 + 4.5 * s)
        # the random walk adds ~5 % of the deterministic drift over 10 s
        return {"amp": a, "tau": p["tau"], "walk": 0.16 * a / p["tau"]}
    if name == "saturation":
        return {"knee": p["ymax"] * (1.05 - 0.5 * s), "width": 0.3 + 2.0 * s}
    if name == "hum":
        return {"amp": 10 ** (-4 + 4 * s)}
    raise ValueError(name)


def calibrate(truth, inputs, name, target, rng):
    """Effect parameters whose magnitude on `inputs` is `target` noise stds (bisection)."""
    rp = {"zeta": float(rng.uniform(0.05, 0.3)), "slew_k": float(rng.choice([0.0, rng.uniform(0.3, 1.0)])),
          "tau": float(rng.uniform(20, 200)),
          # the top of the stroke the records dwell at: FONBW answers an
          # instant step with a one-sample spike (the GL derivative of the
          # step), which a plain max would take for the stroke
          "ymax": float(np.quantile(np.concatenate([truth.output(u, effects={}) for _, u in inputs]), 0.999))}
    lo, hi = 0.0, 1.0
    m_hi = magnitude(truth, inputs, name, _strength(name, hi, rp))
    if m_hi < target:
        return _strength(name, hi, rp), m_hi
    for _ in range(14):
        mid = 0.5 * (lo + hi)
        if magnitude(truth, inputs, name, _strength(name, mid, rp)) < target:
            lo = mid
        else:
            hi = mid
    p = _strength(name, hi, rp)
    return p, magnitude(truth, inputs, name, p)


def scenario_kind(seed):
    """The kind :func:`draw_scenario` draws for `seed` (cheap: no simulation)."""
    return str(np.random.default_rng([seed, 2026]).choice(KINDS, p=KIND_P))


def draw_scenario(seed, kind=None, scale=1.0, fs=FS):
    """A random blind scenario.

    Parameters
    ----------
    seed : int
    kind : {"null", "single", "pair", "outside", "below"}, optional
        Drawn (15/45/20/10/10 %) when None.

    Returns
    -------
    dict with ``kind``, ``truth`` (Truth), ``injected`` {name: {"params",
    "magnitude"}}, ``train``, ``validate`` (lists of Record).
    """
    rng = np.random.default_rng([seed, 2026])
    if kind is None:
        kind = rng.choice(KINDS, p=KIND_P)
    base = load_model(DEFAULT_MODEL)
    pr = base.params
    ku = np.asarray(pr["ku"]) * (1 + 0.03 * rng.standard_normal(3))
    hyst = FONBW(ku, pr["kh"] * (1 + 0.03 * rng.standard_normal()), pr["rho"], pr["sigma"],
                 pr["n"], min(1.0, pr["lam1"] + 0.03 * rng.standard_normal()),
                 min(1.0, pr["lam2"] + 0.03 * rng.standard_normal()))
    noise = float(10 ** rng.uniform(-2, math.log10(0.03)))
    truth = Truth(hyst, {}, noise, fs, seed=int(rng.integers(1 << 30)))
    tr_in, va_in = default_experiments(fs, scale)
    lib = [e for e in TRUTH_EFFECTS if e != "hum"]
    if kind == "null":
        names, targets = [], []
    elif kind == "single":
        names, targets = [str(rng.choice(lib))], [10 ** rng.uniform(math.log10(2), 2)]
    elif kind == "pair":
        names = [str(n) for n in rng.choice(lib, 2, replace=False)]
        targets = list(10 ** rng.uniform(math.log10(3), math.log10(60), 2))
    elif kind == "outside":
        names, targets = ["hum"], [10 ** rng.uniform(math.log10(3), math.log10(50))]
    else:
        names, targets = [str(rng.choice(lib))], [10 ** rng.uniform(-1, math.log10(0.4))]
    injected = {}
    for n, m in zip(names, targets):
        p, got = calibrate(truth, va_in, n, m, rng)
        injected[n] = {"params": p, "magnitude": got}
    truth.effects = {n: v["params"] for n, v in injected.items()}
    train = [truth.record(u, name, i) for i, (name, u) in enumerate(tr_in)]
    val = [truth.record(u, name, 50 + i) for i, (name, u) in enumerate(va_in)]
    return {"kind": str(kind), "truth": truth, "injected": injected, "train": train, "validate": val,
            "noise_std": noise}
