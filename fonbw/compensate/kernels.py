"""Compiled per-step solver of the compensator.

Each step evaluates the model's compiled step with ``commit=False`` inside a
safeguarded root finder (secant from the previous voltage with the previous
local slope, Brent's method once a sign change brackets the root, a bracket
over the whole voltage range as the fallback), then commits one step with the
root: model and compensator share their numerics, memory engine included.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from .. import hysteresis as _hy

#: Per-sample status codes of a compensation.
OK, SAT_LOW, SAT_HIGH, NOT_CONVERGED = 0, 1, 2, 3
_EPS = 2.220446049250313e-16


@nb.njit(cache=True)
def _same_sign(a, b):
    return (a > 0.0) == (b > 0.0)


@nb.njit(cache=True)
def _brent(core, V, hd, a, fa, b, fb, tol, maxit):
    """Brent's zeroin on a bracket (fa, fb of opposite signs).

    Stops when |f| ≤ tol or the bracket has shrunk to a few ulps. Returns
    (x, f(x), contrapoint, f(contrapoint), evaluations).
    """
    c, fc = a, fa
    d = b - a
    e = d
    n = 0
    for _ in range(maxit):
        if _same_sign(fb, fc):
            c, fc = a, fa
            d = b - a
            e = d
        if abs(fc) < abs(fb):
            a, fa = b, fb
            b, fb = c, fc
            c, fc = a, fa
        tol1 = 2.0 * _EPS * abs(b) + 1e-300
        xm = 0.5 * (c - b)
        if abs(fb) <= tol or abs(xm) <= tol1:
            break
        if abs(e) >= tol1 and abs(fa) > abs(fb):
            s = fb / fa
            if a == c:
                p = 2.0 * xm * s
                q = 1.0 - s
            else:
                q = fa / fc
                r = fb / fc
                p = s * (2.0 * xm * q * (q - r) - (b - a) * (r - 1.0))
                q = (q - 1.0) * (r - 1.0) * (s - 1.0)
            if p > 0.0:
                q = -q
            p = abs(p)
            if 2.0 * p < min(3.0 * xm * q - abs(tol1 * q), abs(e * q)):
                e = d
                d = p / q
            else:
                d = xm
                e = d
        else:
            d = xm
            e = d
        a, fa = b, fb
        if abs(d) > tol1:
            b = b + d
        else:
            b = b + (tol1 if xm > 0.0 else -tol1)
        fb = core(b, False, V) - hd
        n += 1
        if not math.isfinite(fb):
            break
    return b, fb, c, fc, n


@nb.njit(cache=True)
def _bracketed(core, V, hd, a, fa, b, fb, tol, maxit, n, bx, bf, slope):
    """Brent on a sign-change bracket; the best point so far if it does not converge."""
    x, fx, c, fc, m = _brent(core, V, hd, a, fa, b, fb, tol, maxit)
    n += m
    if abs(fx) <= tol:
        return x, fx, OK, n, ((fx - fc) / (x - c) if x != c else slope)
    if abs(fx) < abs(bf):
        bx, bf = x, fx
    return bx, bf, NOT_CONVERGED, n, slope


@nb.njit(cache=True)
def _solve(core, V, hd, lo, hi, x0, slope, tol, maxit):
    """Root u of H(u; history) = hd in [lo, hi] by trial steps (commit=False).

    Returns (u, residual H(u) − hd, status, evaluations, new slope estimate).
    """
    x0 = min(max(x0, lo), hi)
    f0 = core(x0, False, V) - hd
    n = 1
    if abs(f0) <= tol:
        return x0, f0, OK, n, slope
    bx = x0
    bf = f0 if math.isfinite(f0) else math.inf
    if not (math.isfinite(slope) and slope != 0.0):
        # first step or lost estimate: one-sided difference into the range
        h = 1e-3 * (hi - lo)
        xb = x0 + h if x0 + h <= hi else x0 - h
        fb = core(xb, False, V) - hd
        n += 1
        slope = (fb - f0) / (xb - x0)
    # local secant search from the previous voltage (keeps the solution on
    # the branch the trajectory is on when the step map is not monotone)
    a, fa = x0, f0
    if math.isfinite(f0) and math.isfinite(slope) and slope != 0.0:
        dx = -f0 / slope
        for _ in range(12):
            b = min(max(a + dx, lo), hi)
            if b == a:
                break  # pushing against a limit: decided by the fallback
            fb = core(b, False, V) - hd
            n += 1
            if not math.isfinite(fb):
                break
            if abs(fb) < abs(bf):
                bx, bf = b, fb
            if abs(fb) <= tol:
                return b, fb, OK, n, (fb - fa) / (b - a)
            if not _same_sign(fa, fb):
                return _bracketed(core, V, hd, a, fa, b, fb, tol, maxit, n, bx, bf, slope)
            if abs(fb) >= abs(fa):
                break  # no progress: the fallback brackets the whole range
            dx = -fb * (b - a) / (fb - fa)
            slope = (fb - fa) / (b - a)
            a, fa = b, fb
    # fallback: the whole voltage range
    flo = core(lo, False, V) - hd
    fhi = core(hi, False, V) - hd
    n += 2
    if math.isfinite(flo) and math.isfinite(fhi) and not _same_sign(flo, fhi):
        if math.isfinite(f0) and lo < x0 < hi:
            if _same_sign(f0, flo):
                a, fa, b, fb = x0, f0, hi, fhi
            else:
                a, fa, b, fb = lo, flo, x0, f0
        else:
            a, fa, b, fb = lo, flo, hi, fhi
        return _bracketed(core, V, hd, a, fa, b, fb, tol, maxit, n, bx, bf, slope)
    # no sign change over [lo, hi]: the target is out of reach
    alo = abs(flo) if math.isfinite(flo) else math.inf
    ahi = abs(fhi) if math.isfinite(fhi) else math.inf
    if alo <= ahi and alo <= abs(bf):
        return lo, flo, SAT_LOW, n, slope
    if ahi < alo and ahi <= abs(bf):
        return hi, fhi, SAT_HIGH, n, slope
    return bx, bf, NOT_CONVERGED, n, slope


@nb.njit(cache=True)
def _explicit(S, hd, lo, hi, uprev, ku, kh):
    """Eq. (16)/(21) with G from the previous step (state S[2] = ħ_(k−1) or h_(k−1))."""
    g = 0.0
    for i in range(ku.shape[0] - 1, 0, -1):
        g = (g + ku[i]) * uprev
    g *= uprev  # Σ_{i≥2} ku_i u^i
    u = (hd - kh * S[2] - g) / ku[0]
    if not math.isfinite(u):
        return uprev, NOT_CONVERGED
    if u < lo:
        return lo, SAT_LOW
    if u > hi:
        return hi, SAT_HIGH
    return u, OK


@nb.njit(cache=True)
def _one(core, V, S, hd, lo, hi, tol, maxit, explicit, ku, kh, ctl):
    """Voltage for one sample (not committed). ctl = [u_(k−1), slope]."""
    if explicit:
        u, st = _explicit(S, hd, lo, hi, ctl[0], ku, kh)
        return u, st, 0
    # half the tolerance: the output is reported relative to the zero of a
    # history (H − y0), whose rounding must not take it past tol
    u, f, st, n, s = _solve(core, V, hd, lo, hi, ctl[0], ctl[1], 0.5 * tol, maxit)
    ctl[1] = s
    return u, st, n


@nb.njit(cache=True, inline="always")
def _run_on(views, core, hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh, pre, u, y, status, nfev):
    """Batch compensation from rest, after the voltage history `pre` (the
    model runs through it first; outputs are counted from its last one, as a
    sensor zeroed there)."""
    S = np.zeros(ssize)
    V = views(P, S)
    y0 = 0.0
    for k in range(pre.shape[0]):
        y0 = core(pre[k], True, V)
    u_rest = pre[pre.shape[0] - 1] if pre.shape[0] else min(max(0.0, lo), hi)
    ctl = np.array([u_rest, math.nan])
    for k in range(hd.shape[0]):
        uk, st, n = _one(core, V, S, hd[k] + y0, lo, hi, tol, maxit, explicit, ku, kh, ctl)
        y[k] = core(uk, True, V) - y0
        u[k] = uk
        status[k] = st
        nfev[k] = n
        ctl[0] = uk


@nb.njit(cache=True, inline="always")
def _step_on(views, core, hd, P, S, lo, hi, tol, maxit, explicit, ku, kh, ctl, out, commit):
    """Per-step body on the blocks of a model stepper: out = [u, status, nfev, y]."""
    V = views(P, S)
    uk, st, n = _one(core, V, S, hd, lo, hi, tol, maxit, explicit, ku, kh, ctl)
    out[0] = uk
    out[1] = st
    out[2] = n
    if commit:
        out[3] = core(uk, True, V)
        ctl[0] = uk


# One entry point per kernel pair, batch and per step: the kernels are
# referenced as globals, not passed from Python (numba would type two
# dispatcher objects on every per-step call, ~60 µs, and its cache index
# cannot always pickle dispatcher types).
# numba keys each cached function on its own file only; the package's cache
# folder is named by a hash of every source file (fonbw._numba_cache_dir), so
# an edit of the hysteresis or fractional kernels cannot leave these stale.
@nb.njit(cache=True)
def _run_fonbw(hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh, pre, u, y, status, nfev):
    _run_on(_hy.fonbw_views, _hy.fonbw_core, hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh,
            pre, u, y, status, nfev)


@nb.njit(cache=True)
def _run_cbw(hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh, pre, u, y, status, nfev):
    _run_on(_hy.plain_views, _hy.cbw_core, hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh,
            pre, u, y, status, nfev)


@nb.njit(cache=True)
def _run_zhu(hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh, pre, u, y, status, nfev):
    _run_on(_hy.plain_views, _hy.zhu_core, hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh,
            pre, u, y, status, nfev)


@nb.njit(cache=True)
def _step_fonbw(hd, P, S, lo, hi, tol, maxit, explicit, ku, kh, ctl, out, commit):
    _step_on(_hy.fonbw_views, _hy.fonbw_core, hd, P, S, lo, hi, tol, maxit, explicit, ku, kh,
             ctl, out, commit)


@nb.njit(cache=True)
def _step_cbw(hd, P, S, lo, hi, tol, maxit, explicit, ku, kh, ctl, out, commit):
    _step_on(_hy.plain_views, _hy.cbw_core, hd, P, S, lo, hi, tol, maxit, explicit, ku, kh,
             ctl, out, commit)


@nb.njit(cache=True)
def _step_zhu(hd, P, S, lo, hi, tol, maxit, explicit, ku, kh, ctl, out, commit):
    _step_on(_hy.plain_views, _hy.zhu_core, hd, P, S, lo, hi, tol, maxit, explicit, ku, kh,
             ctl, out, commit)


# Eq. (22) form for Zhu2016: the mechanics are inverted on H_d's derivatives and
# only the force balance is solved per step, for u in
#     (k1/τ) e^(−t_k/τ) u_k + ĥ_k(u_k) = m0 Ḧd_k + c0 Ḣd_k + k0 (H_d,k − x0).
@nb.njit(cache=True)
def _zhu_force_core(u, commit, V):
    """Trial: the force of eq. (20) for u_k (model units). Commit: advance the
    model with u_k and return x_k [µm] (the model output)."""
    if commit:
        return _hy.zhu_core(u, True, V)
    P, S = V
    direct = P[1] / P[2] * math.exp(-S[6] * P[0] / P[2]) * u  # before the trial step, as zhu_step
    _hy.zhu_core(u, False, V)
    return direct + S[3]


# not cached: numba refuses to cache a function that passes another function
# of this module as a value ("dynamic globals"); compiled on first use.
@nb.njit(cache=False)
def _run_zhu22(hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh, pre, u, y, status, nfev):
    _run_on(_hy.plain_views, _zhu_force_core, hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh,
            pre, u, y, status, nfev)


@nb.njit(cache=False)
def _step_zhu22(hd, P, S, lo, hi, tol, maxit, explicit, ku, kh, ctl, out, commit):
    _step_on(_hy.plain_views, _zhu_force_core, hd, P, S, lo, hi, tol, maxit, explicit, ku, kh,
             ctl, out, commit)
