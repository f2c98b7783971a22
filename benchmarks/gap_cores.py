"""Truth hysteresis cores for the blind test of the gap diagnosis.

A real actuator's hysteresis is not exactly a FONBW. This module draws truth
cores at random from four families, written here apart from the library's
models (only the ``fonbw`` family uses :class:`fonbw.FONBW`), so that a
diagnosis whose reference hysteresis is a threshold-grid operator is not
tested against its own discretization.

=========  ==================================================================
family     truth core
=========  ==================================================================
fonbw      :class:`fonbw.FONBW` around :data:`fonbw.data.DEFAULT_MODEL` with
           λ1, λ2, n, σ (and a few per cent of ku, kh) drawn
preisach   Preisach operator with a smooth asymmetric density on α ≥ β,
           evaluated through its closed-form Everett function on the memory
           staircase of dominant reversal points (:mod:`gap_preisach`); plus a
           quadratic reversible part and a mild quadratic output nonlinearity
pi         Prandtl–Ishlinskii: plays with random (non-uniform) thresholds and
           random non-negative weights, plus a linear term, passed through a
           random monotone envelope (w + b tanh((w − w0)/c) or a cubic)
rate       elasto-visco-plastic Maxwell-slip bank: each element a spring in
           series with a Bingham slider (Coulomb threshold and viscous
           overstress), solved exactly for a piecewise-linear input; its loop
           widens and its stroke drops with frequency, and at slow rates it
           tends to a rate-independent Prandtl–Ishlinskii loop
=========  ==================================================================

Every draw is calibrated on the 1 Hz sine 60 − 60 cos(2πt) V so that the
stroke is 10–25 µm and the loop width (largest vertical gap between the
branches) is 5–20 % of the stroke (approximately, for the envelopes and for
the rate family, whose calibration uses its slow limit). A core is fully
defined by its JSON-able ``params``: :func:`make_core` rebuilds it.

Usage::

    rng = np.random.default_rng(7)
    core = draw_core("preisach", rng)
    y = core.simulate(u, dt)                       # from rest
    hist, rec = mid_drive_record(u_full, start)
    y_rec = core.simulate(rec, dt, history=hist)   # state not at rest
"""
from __future__ import annotations

import hashlib
import json
import math

import numba as nb
import numpy as np

# everett and preisach_density stay importable from here, with the other names of the family
from gap_preisach import (calibrated_params, density_table, draw_density, everett, everett_mass,
                          preisach_density, preisach_run)

__all__ = ["FAMILIES", "Core", "draw_core", "make_core", "clip_input", "mid_drive_record",
           "loop_metrics", "everett", "preisach_density"]

FAMILIES = ("fonbw", "preisach", "pi", "rate")

_CAL_DT = 2e-4  # calibration sampling [s] (the harness' 5 kHz)


# --------------------------------------------------------------------------- helpers

def clip_input(u, lo, hi, knee=0.0):
    """The amplifier's rail: clip the input voltage to [lo, hi].

    Parameters
    ----------
    u : array_like
        Command [V].
    lo, hi : float
        Rails [V], lo < hi.
    knee : float
        Width of a soft knee [V]; 0 (default) is a hard clip. With a knee the
        clip is a softplus on each side, so the output approaches each rail
        smoothly and is within knee·ln 2 of it at the rail.

    Returns
    -------
    ndarray
        Clipped voltage [V].
    """
    u = np.asarray(u, dtype=float)
    if not lo < hi:
        raise ValueError(f"need lo < hi, got {lo}, {hi}")
    if knee < 0:
        raise ValueError("knee must be >= 0")
    if knee == 0:
        return np.clip(u, lo, hi)
    v = lo + knee * np.logaddexp(0.0, (u - lo) / knee)
    return hi - knee * np.logaddexp(0.0, (hi - v) / knee)


def mid_drive_record(u_full, start):
    """Split a drive so that a record starts at sample `start`.

    Parameters
    ----------
    u_full : array_like
        The whole drive [V].
    start : int
        First sample of the record, 0 ≤ start ≤ len(u_full).

    Returns
    -------
    history, u_record : ndarray
        Everything before `start` (run first and discarded by
        :meth:`Core.simulate`) and the record's input.
    """
    u_full = np.asarray(u_full, dtype=float)
    start = int(start)
    if not 0 <= start <= u_full.size:
        raise ValueError(f"start must be in [0, {u_full.size}], got {start}")
    return u_full[:start].copy(), u_full[start:].copy()


def _sine(f, dt=_CAL_DT, periods=2, lo=0.0, hi=120.0):
    n = int(round(periods / (f * dt)))
    t = np.arange(n) * dt
    return 0.5 * (lo + hi) - 0.5 * (hi - lo) * np.cos(2 * np.pi * f * t)


def _last_loop(u, y, n_period):
    """The last period of a periodic run split at its input maximum."""
    uu, yy = u[-n_period:], y[-n_period:]
    k = int(np.argmax(uu))
    # the period starts at the input minimum (60 − 60 cos): ascending then descending
    return uu[:k + 1], yy[:k + 1], uu[k:], yy[k:]


def _loop_stats(u, y, n_period, lo, hi):
    ua, ya, ud, yd = _last_loop(u, y, n_period)
    g = np.linspace(lo + 0.02 * (hi - lo), hi - 0.02 * (hi - lo), 400)
    asc = np.interp(g, ua, ya)
    desc = np.interp(g, ud[::-1], yd[::-1])
    uu, yy = u[-n_period:], y[-n_period:]
    uc, yc = np.append(uu, uu[0]), np.append(yy, yy[0])
    area = 0.5 * abs(float(np.sum(uc[:-1] * yc[1:] - uc[1:] * yc[:-1])))
    stroke = float(yy.max() - yy.min())
    width = float(np.max(desc - asc))
    return {"stroke": stroke, "width": width, "width_frac": width / stroke if stroke > 0 else math.nan,
            "area": area}


def loop_metrics(core, f, dt=_CAL_DT, lo=0.0, hi=120.0, periods=3):
    """Steady-loop measures of a core on the sine lo + (hi − lo)(1 − cos 2πft)/2.

    Parameters
    ----------
    core : Core
    f : float
        Frequency [Hz].
    dt : float
        Sampling step [s].
    lo, hi : float
        Input range [V].
    periods : int
        Periods run; the last one is measured.

    Returns
    -------
    dict
        ``stroke`` [µm] (output peak to peak), ``width`` [µm] (largest
        descending − ascending gap at equal input, over the inner 96 % of the
        range), ``width_frac`` (width / stroke) and ``area`` [V·µm] (area
        enclosed by the loop in the (u, y) plane).
    """
    u = _sine(f, dt, periods, lo, hi)
    y = core.simulate(u, dt)
    return _loop_stats(u, y, int(round(1.0 / (f * dt))), lo, hi)


# --------------------------------------------------------------------------- core base

class Core:
    """A truth hysteresis core: input voltage [V] to displacement [µm].

    Attributes
    ----------
    name : str
        ``family:`` and a short digest of the parameters.
    family : str
        One of :data:`FAMILIES`.
    params : dict
        JSON-able parameters; :func:`make_core` rebuilds the same core.
    """

    family = ""

    def __init__(self, params):
        self.params = json.loads(json.dumps(params))  # a JSON-able, private copy
        digest = hashlib.sha256(json.dumps(self.params, sort_keys=True).encode()).hexdigest()[:8]
        self.name = f"{self.family}:{digest}"

    def simulate(self, u, dt, history=None):
        """Displacement [µm] for the input u [V] sampled at step dt [s].

        Parameters
        ----------
        u : array_like
            Input [V].
        dt : float
            Sampling step [s].
        history : array_like, optional
            Input [V] run first from rest and discarded, so that the record
            starts with the core's internal state where this input left it.
            None (or empty) starts from rest.

        Returns
        -------
        ndarray
            Displacement [µm], one value per sample of u; equal bit for bit
            to the tail of ``simulate(concat(history, u), dt)``.
        """
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive step [s], got {dt!r}")
        u = np.asarray(u, dtype=float).ravel()
        h = np.zeros(0) if history is None else np.asarray(history, dtype=float).ravel()
        full = np.ascontiguousarray(np.concatenate([h, u]))
        if not np.all(np.isfinite(full)):
            raise ValueError("input must be finite")
        if full.size == 0:
            return np.zeros(0)
        # the history is run through the same kernel as the record: the record's
        # samples are computed by the very same operations as in one long run
        return np.asarray(self._run(full, dt), dtype=float)[h.size:].copy()

    def _run(self, u, dt):  # pragma: no cover - abstract
        raise NotImplementedError

    def __repr__(self):
        return f"<Core {self.name}>"


# --------------------------------------------------------------------------- fonbw

class FonbwCore(Core):
    """The library's FONBW, ``fonbw.FONBW(**params)`` (memory engine "fast")."""

    family = "fonbw"

    def __init__(self, params):
        super().__init__(params)
        from fonbw import FONBW
        self.model = FONBW(**self.params)

    def _run(self, u, dt):
        return self.model.simulate(u, dt)


def _draw_fonbw(rng):
    from fonbw import load_model
    from fonbw.data import DEFAULT_MODEL

    base = load_model(DEFAULT_MODEL).params
    for _ in range(40):
        p = {
            "ku": [float(k) for k in np.asarray(base["ku"]) * (1 + 0.05 * rng.standard_normal(len(base["ku"])))],
            "kh": float(base["kh"] * (1 + 0.05 * rng.standard_normal())),
            "rho": float(base["rho"]),
            "sigma": float(base["sigma"] * 2.0 ** rng.uniform(-1, 1)),
            "n": float(rng.uniform(1.5, 3.0)),
            "lam1": float(rng.uniform(0.9, 1.0)),
            "lam2": float(rng.uniform(0.55, 0.78)),
            "memory": "fast",
        }
        core = FonbwCore(p)
        m = loop_metrics(core, 1.0, periods=2)
        if 10 <= m["stroke"] <= 25 and 0.05 <= m["width_frac"] <= 0.2:
            return core
    raise RuntimeError("no FONBW draw met the stroke and loop-width ranges")


# --------------------------------------------------------------------------- preisach

class PreisachCore(Core):
    """Rate-independent Preisach core with a reversible part.

    h = G (P[u] − P0) + k1 u + k2 u²,   y = h + q h² / S,

    where P[u] is the Preisach output (relays 0/1, mass of the density over
    the "up" region, from negative saturation), P0 the value of the first
    ascending branch at 0 V, G [µm] the gain, k1 [µm/V], k2 [µm/V²], q the
    output nonlinearity and S [µm] the calibrated stroke.
    """

    family = "preisach"

    def __init__(self, params):
        super().__init__(params)
        p = self.params
        self._T = density_table(p["density"])
        self._P0 = float(everett_mass(0.0, -np.inf, self._T))

    def raw(self, u):
        """P[u]: the Preisach output in density mass units, from negative saturation."""
        return preisach_run(np.ascontiguousarray(u, dtype=float), self._T)

    def _run(self, u, dt):
        p = self.params
        h = p["gain"] * (self.raw(u) - self._P0) + p["k1"] * u + p["k2"] * u * u
        return h + p["q"] * h * h / p["S"]


def _draw_preisach(rng):
    u = _sine(1.0, periods=2)
    for _ in range(40):
        dens = draw_density(rng)
        st = _loop_stats(u, preisach_run(u, density_table(dens)), u.size // 2, 0.0, 120.0)
        p = calibrated_params(dens, st["stroke"], st["width"], rng)
        if p is not None:
            return PreisachCore(p)
    raise RuntimeError("no Preisach draw met the stroke and loop-width ranges")


# --------------------------------------------------------------------------- prandtl-ishlinskii

@nb.njit(cache=True)
def _play_sum(u, r, w, w0):
    """w0 u + Σ_i w_i z_i, z_i = max(u − r_i, min(u + r_i, z_i)), plays relaxed (z = 0) at rest."""
    n, m = u.size, r.size
    z = np.zeros(m)
    out = np.empty(n)
    for k in range(n):
        v = u[k]
        s = w0 * v
        for i in range(m):
            zi = min(v + r[i], z[i])
            zi = max(v - r[i], zi)
            z[i] = zi
            s += w[i] * zi
        out[k] = s
    return out


def _envelope(x, env):
    """Monotone envelope g(x) of a normalized input x (derivative > 0 everywhere)."""
    if env["kind"] == "identity":
        return x
    if env["kind"] == "tanh":
        return x + env["b"] * np.tanh((x - env["x0"]) / env["c"])
    if env["kind"] == "cubic":
        return x + env["c2"] * x * x + env["c3"] * x ** 3
    raise ValueError(f"unknown envelope {env['kind']!r}")


def _draw_envelope(rng):
    if rng.random() < 0.5:
        c = float(rng.uniform(0.15, 0.6))
        # g' = 1 + (b/c) sech² ≥ 1 − 0.7 > 0
        return {"kind": "tanh", "b": float(c * rng.uniform(-0.7, 1.0)), "x0": float(rng.uniform(0.2, 0.8)), "c": c}
    c2 = float(rng.uniform(-0.35, 0.35))
    # g' = 1 + 2 c2 x + 3 c3 x² > 0 for all x when c3 > c2²/3
    return {"kind": "cubic", "c2": c2, "c3": float(c2 * c2 / 3.0 * 1.2 + rng.uniform(0.0, 0.1))}


class PICore(Core):
    """Prandtl–Ishlinskii core with a monotone output envelope.

    z = w0 u + Σ_i w_i play_{r_i}[u]   [V],   x = z / Z,
    y = S (g(x) − g(0)) / (g(x_top) − g(x_bot))   [µm],

    with thresholds r_i [V], weights w_i ≥ 0, the envelope g of
    ``params["envelope"]`` and Z, x_top, x_bot, S from the calibration.
    """

    family = "pi"

    def __init__(self, params):
        super().__init__(params)
        p = self.params
        self._r = np.ascontiguousarray(p["r"], dtype=float)
        self._w = np.ascontiguousarray(p["w"], dtype=float)
        if np.any(self._r < 0) or np.any(self._w < 0) or self._r.shape != self._w.shape:
            raise ValueError("thresholds and weights must be non-negative and of equal length")

    def z(self, u):
        """The play sum z [V] (before the envelope)."""
        return _play_sum(np.ascontiguousarray(u, dtype=float), self._r, self._w, float(self.params["w0"]))

    def _out(self, z):
        p = self.params
        g = _envelope(z / p["Z"], p["envelope"])
        return p["S"] * (g - p["g0"]) / p["gspan"]

    def _run(self, u, dt):
        return self._out(self.z(u))


def _draw_thresholds(rng, m, top=55.0):
    """m distinct thresholds in (0, ~top] V, denser near 0, plus some spread for bipolar drives."""
    r = top * np.sort(rng.beta(0.9, 1.8, m))
    r = np.maximum(r, 0.3)
    if m >= 4 and rng.random() < 0.6:
        r[-1] = float(rng.uniform(60.0, 110.0))  # acts on bipolar drives only
    return [float(v) for v in np.sort(r)]


def _calibrate_pi(r, w, env, S, W):
    """Linear weight w0 and the envelope normalization for stroke S and width fraction W."""
    u = _sine(1.0, periods=2)
    n1 = u.size // 2
    H = _play_sum(u, np.asarray(r), np.asarray(w), 0.0)
    st = _loop_stats(u, H, n1, 0.0, 120.0)
    w0 = (st["width"] / W - st["stroke"]) / 120.0
    if w0 < 0.0:
        return None
    z = H + w0 * u
    zz = z[-n1:]
    Z = float(zz.max() - zz.min())
    p = {"r": r, "w": w, "w0": float(w0), "envelope": env, "Z": Z, "S": S}
    g = _envelope(np.array([0.0, zz.min() / Z, zz.max() / Z]), env)
    p["g0"], p["gspan"] = float(g[0]), float(g[2] - g[1])
    return p


def _draw_pi(rng):
    for _ in range(40):
        m = int(rng.integers(5, 13))
        r = _draw_thresholds(rng, m)
        w = [float(v) for v in rng.gamma(1.5, 1.0, m) * np.exp(-np.asarray(r) / rng.uniform(20, 80))]
        p = _calibrate_pi(r, w, _draw_envelope(rng), float(rng.uniform(10, 25)), float(rng.uniform(0.05, 0.2)))
        if p is not None:
            return PICore(p)
    raise RuntimeError("no PI draw met the loop-width range")


# --------------------------------------------------------------------------- rate dependent

@nb.njit(cache=True)
def _bingham_step(e, v, h, r, tau):
    """Exact elastic stretch e [V] after h [s] of input rate v [V/s].

    Element: spring in series with a Bingham slider x; e = u − x,
    dx/dt = sign(e) max(|e| − r, 0) / τ. Inside |e| ≤ r the slider sticks
    (de/dt = v); outside, e − (±r) relaxes exponentially towards v τ. The
    crossing times between the regimes are solved in closed form.
    """
    for _ in range(4):  # at most: plastic → elastic → plastic
        if h <= 0.0:
            return e
        if e > r or (e == r and v > 0.0):
            tgt = r + v * tau
            if v >= 0.0:
                return tgt + (e - tgt) * math.exp(-h / tau)
            ts = tau * math.log((e - r - v * tau) / (-v * tau))
            if ts >= h:
                return tgt + (e - tgt) * math.exp(-h / tau)
            e = r
            h -= ts
        elif e < -r or (e == -r and v < 0.0):
            tgt = -r + v * tau
            if v <= 0.0:
                return tgt + (e - tgt) * math.exp(-h / tau)
            ts = tau * math.log((e + r - v * tau) / (-v * tau))
            if ts >= h:
                return tgt + (e - tgt) * math.exp(-h / tau)
            e = -r
            h -= ts
        else:
            if v > 0.0:
                ts = (r - e) / v
            elif v < 0.0:
                ts = (-r - e) / v
            else:
                return e
            if ts >= h:
                return e + v * h
            e = r if v > 0.0 else -r
            h -= ts
    return e


@nb.njit(cache=True)
def _maxwell_slip(u, dt, r, tau, w, w0):
    """w0 u + Σ_i w_i x_i, slider positions x_i = u − e_i, for u linear between samples.

    At rest (u = 0 before the first sample) every e_i = 0; the first
    interval ramps from 0 V to u[0].
    """
    n, m = u.size, r.size
    e = np.zeros(m)
    out = np.empty(n)
    prev = 0.0
    for k in range(n):
        v = (u[k] - prev) / dt
        s = w0 * u[k]
        for i in range(m):
            e[i] = _bingham_step(e[i], v, dt, r[i], tau[i])
            s += w[i] * (u[k] - e[i])
        out[k] = s
        prev = u[k]
    return out


class RateCore(Core):
    """Elasto-visco-plastic Maxwell-slip core (rate dependent).

    z = w0 u + Σ_i w_i x_i   [V],   y = S (x + q x²) / (1 + q) with x = z / Z   [µm],

    with slider positions x_i: dx_i/dt = sign(u − x_i) max(|u − x_i| − r_i, 0) / τ_i
    (thresholds r_i [V], r_i = 0 for purely viscous elements, time constants
    τ_i [s]). As τ → 0, x_i → play_{r_i}[u], the Prandtl–Ishlinskii limit.
    """

    family = "rate"

    def __init__(self, params):
        super().__init__(params)
        p = self.params
        self._r = np.ascontiguousarray(p["r"], dtype=float)
        self._tau = np.ascontiguousarray(p["tau"], dtype=float)
        self._w = np.ascontiguousarray(p["w"], dtype=float)
        if np.any(self._tau <= 0) or np.any(self._r < 0) or np.any(self._w < 0):
            raise ValueError("need τ > 0, r ≥ 0, w ≥ 0")

    def z(self, u, dt):
        """The element sum z [V] (before the output nonlinearity)."""
        return _maxwell_slip(np.ascontiguousarray(u, dtype=float), float(dt), self._r, self._tau, self._w,
                             float(self.params["w0"]))

    def z_slow(self, u):
        """The rate-independent limit of :meth:`z` (plays; τ → 0)."""
        return _play_sum(np.ascontiguousarray(u, dtype=float), self._r, self._w, float(self.params["w0"]))

    def _out(self, z):
        p = self.params
        x = z / p["Z"]
        return p["S"] * (x + p["q"] * x * x) / (1.0 + p["q"])

    def _run(self, u, dt):
        return self._out(self.z(u, dt))


def _draw_rate(rng):
    for _ in range(40):
        m = int(rng.integers(4, 9))
        r = _draw_thresholds(rng, m, top=50.0)
        wp = rng.gamma(1.5, 1.0, m) * np.exp(-np.asarray(r) / rng.uniform(20, 80))
        tau = list(np.exp(rng.uniform(math.log(2e-4), math.log(3e-3), m)))
        # purely viscous elements: a lag of the reversible part (the loop tilts)
        mv = int(rng.integers(1, 3))
        r += [0.0] * mv
        tau += list(np.exp(rng.uniform(math.log(3e-3), math.log(3e-2), mv)))
        S, W = float(rng.uniform(10, 25)), float(rng.uniform(0.05, 0.14))
        # calibrate the slow limit: the viscous elements count as linear there
        u = _sine(1.0, periods=2)
        n1 = u.size // 2
        H = _play_sum(u, np.asarray(r[:m]), wp, 0.0)
        st = _loop_stats(u, H, n1, 0.0, 120.0)
        lin = (st["width"] / W - st["stroke"]) / 120.0
        if lin <= 0:
            continue
        fv = float(rng.uniform(0.4, 0.8))  # share of the linear part that is viscous
        wv = [lin * fv / mv] * mv
        w = [float(v) for v in wp] + wv
        z = H + lin * u
        Z = float(z[-n1:].max() - z[-n1:].min())
        p = {"r": [float(v) for v in r], "tau": [float(v) for v in tau], "w": w, "w0": float(lin * (1 - fv)),
             "Z": Z, "q": float(rng.uniform(-0.12, 0.12)), "S": S}
        return RateCore(p)
    raise RuntimeError("no rate-dependent draw met the loop-width range")


# --------------------------------------------------------------------------- registry

_CLASSES = {"fonbw": FonbwCore, "preisach": PreisachCore, "pi": PICore, "rate": RateCore}
_DRAWS = {"fonbw": _draw_fonbw, "preisach": _draw_preisach, "pi": _draw_pi, "rate": _draw_rate}


def make_core(family, params):
    """Rebuild the core of `family` from its ``params``."""
    if family not in _CLASSES:
        raise ValueError(f"unknown family {family!r}; choose one of {', '.join(FAMILIES)}")
    return _CLASSES[family](params)


def draw_core(family, rng):
    """A random core of `family`.

    Parameters
    ----------
    family : {"fonbw", "preisach", "pi", "rate"}
    rng : numpy.random.Generator or int
        Source of randomness (an int seeds a new generator).

    Returns
    -------
    Core
    """
    if family not in _DRAWS:
        raise ValueError(f"unknown family {family!r}; choose one of {', '.join(FAMILIES)}")
    if not isinstance(rng, np.random.Generator):
        rng = np.random.default_rng(rng)
    return _DRAWS[family](rng)
