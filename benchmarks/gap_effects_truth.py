"""Effect equations of the truth simulator (:mod:`gap_truth`) of the blind gap harness.

Written apart from :mod:`fonbw.gap.effects` on purpose: every effect here has
other equations or another discretization than the candidate block the
diagnosis may use to explain it (the table is in :mod:`gap_truth`). The
signal chain is

    command → delay → amplifier → clip (rail) → hysteresis core
            → creep → saturation → dynamics → drift → hum → sensor,

so the input-side effects (delay, amplifier, clip) change what the
hysteresis' memory sees and the output-side ones act on the displacement.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np
from scipy import signal
from scipy.interpolate import PchipInterpolator

from gap_cores import clip_input

__all__ = ["TRUTH_EFFECTS", "LEGACY_POOL", "POOL", "HUM_HZ", "LOWER_RAIL", "input_side", "output_side", "strength",
           "strength_params", "clipped_share"]

TRUTH_EFFECTS = ("creep", "dynamics", "amplifier", "delay", "drift", "saturation", "hum", "clip")
# effects a single, pair or below scenario draws from; hum is the "outside" kind.
# The pool without clip is the one fixed-seed scenarios were drawn from before
# clip existed: drawing from it keeps their records bit for bit
LEGACY_POOL = ("creep", "dynamics", "amplifier", "delay", "drift", "saturation")
POOL = LEGACY_POOL + ("clip",)
# mains pickup [Hz]; the hum adds a third of its amplitude at three times this
HUM_HZ = 50.0
# a piezo amplifier's usual lower rail [V]; the drives never go below 0 V, so
# only the upper rail clips
LOWER_RAIL = -30.0


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


def input_side(u, eff, dt):
    """The voltage [V] reaching the hysteresis for the command u [V].

    Parameters
    ----------
    u : ndarray
        Command [V], the whole drive from rest.
    eff : dict
        ``{name: params}`` of the truth's effects (only delay, amplifier and
        clip act here).
    dt : float
        Sampling step [s].

    Returns
    -------
    ndarray
    """
    v = u
    if "delay" in eff:
        td = eff["delay"]["seconds"]
        t = np.arange(u.size) * dt
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
    if "clip" in eff:
        # the rail limits the amplifier's output stage, so it acts after the
        # amplifier's dynamics; the soft knee is the output stage leaving its
        # linear range before the hard limit
        p = eff["clip"]
        v = clip_input(v, p.get("lo", LOWER_RAIL), p["hi"], p["knee"])
    return v


def output_side(y, eff, dt, rng):
    """The displacement [µm] after the output-side effects, for the core's output y.

    Parameters
    ----------
    y : ndarray
        Core output [µm], the whole drive from rest.
    eff : dict
        ``{name: params}`` (creep, saturation, dynamics, drift and hum act here).
    dt : float
        Sampling step [s].
    rng : numpy.random.Generator
        Source of the drift's random walk and the hum's phases (drawn in that
        order, each only when its effect is present).

    Returns
    -------
    ndarray
    """
    t = np.arange(y.size) * dt
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
        walk = np.cumsum(rng.standard_normal(y.size)) * p["walk"] * math.sqrt(dt)
        y = y + p["amp"] * -np.expm1(-t / p["tau"]) + _lowpass_tustin(walk, 0.5, dt)
    if "hum" in eff:
        a = eff["hum"]["amp"]
        ph = rng.uniform(0, 2 * math.pi, 2)
        y = y + a * np.sin(2 * math.pi * HUM_HZ * t + ph[0]) + a / 3 * np.sin(2 * math.pi * 3 * HUM_HZ * t + ph[1])
    return y


def strength_params(name, rng, y_top, u_records):
    """Random shape parameters of effect `name`, fixed during its bisection.

    Parameters
    ----------
    name : str
    rng : numpy.random.Generator
    y_top : float
        Top of the stroke the records dwell at [µm] (saturation's reference).
    u_records : list of ndarray
        The commands of the records the magnitude is measured on [V] (clip's
        reference).

    Returns
    -------
    dict
    """
    rp = {"zeta": float(rng.uniform(0.05, 0.3)), "slew_k": float(rng.choice([0.0, rng.uniform(0.3, 1.0)])),
          "tau": float(rng.uniform(20, 200)), "ymax": float(y_top)}
    if name == "clip":
        # drawn last and only for clip, so the other effects' draws (and the
        # fixed-seed scenarios made before clip existed) do not move
        u = np.concatenate(u_records)
        rp.update(knee=float(rng.uniform(0.2, 1.5)), u_peak=float(u.max()), u_mid=float(np.median(u)))
    return rp


def strength(name, s, rp):
    """Effect parameters for strength s ∈ [0, 1] (monotone in magnitude)."""
    p = rp
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
    if name == "clip":
        # s = 0: the rail 5 knees above the peak (the soft knee then moves the
        # peak by e^-5 knee, nothing); s = 1: at the median command, where
        # about half the samples are clipped
        top = p["u_peak"] + 5.0 * p["knee"]
        return {"hi": top - s * (top - p["u_mid"]), "lo": LOWER_RAIL, "knee": p["knee"]}
    raise ValueError(name)


def clipped_share(params, u_records):
    """Share of the command samples above the rail of clip `params`."""
    u = np.concatenate([np.asarray(x, dtype=float) for x in u_records])
    return float(np.mean(u > params["hi"]))
