"""Bouc-Wen hysteresis models of a piezoelectric actuator, fixed step.

Units everywhere: input voltage u [V], displacement [µm], time [s].

Models (equation numbers of the paper):

* :class:`CBW` — classical Bouc-Wen, eqs. (1)–(2), with the exact
  normalization :meth:`CBW.to_nbw` of eqs. (7)–(8).
* :class:`NBW` — normalized Bouc-Wen, eqs. (7)–(8); with a list ``ku`` it is
  the asymmetric NBW of eqs. (9)–(10) with the polynomial g(u) of any order N.
* :class:`FONBW` — eqs. (9)–(11), two Grünwald–Letnikov derivatives of orders
  0 < λ1, λ2 ≤ 1 (:mod:`fonbw.fractional`).
* :class:`Zhu2016` — the rate-dependent baseline of eq. (20) as written.

Discretization (the same for batch and per-step use):

* Fixed step dt, zero-order-hold input, everything at rest before t = 0: the
  input is taken to have been at its first value u_0 forever, so the
  fractional derivative acts on u − u_0 (for λ1 = 1 this is the plain
  backward difference with Δu_0 = 0).
* The Bouc-Wen state is advanced implicitly. For FONBW, eq. (11) with the GL
  sums becomes, for the unknown x = ħ_k, the scalar equation

      F(x) = x − b + c1 |x|^(n−1) x + c2 |x|^n = 0,
      b  = (ρ D1 − h2)/a2,  c1 = ρσ|D1|/a2,  c2 = ρ(1−σ) D1/a2,

  where D^λ1 u_k = D1 and D^λ2 ħ_k = a2 ħ_k + h2 (h2 from the history). It is
  solved by a safeguarded Newton iteration (bracket + bisection fallback) for
  any real n ≥ 1. For σ ≥ 1/2 the root is unique and lies between 0 and b.
  λ1 = λ2 = 1 gives exactly backward-Euler NBW; CBW and Zhu use backward
  Euler on their own state h with the same solver.

Every model has ``simulate(u, dt)`` (batch, compiled) and ``stepper(dt)``
(one sample at a time for FMUs and closed loops); both run the same compiled
step function and give bit-identical results.
"""
from __future__ import annotations

import json
import math
import os

import numba as nb
import numpy as np

from . import fractional as fr
from .io import atomic_open

__all__ = [
    "CBW",
    "NBW",
    "FONBW",
    "Zhu2016",
    "Stepper",
    "load_model",
    "model_from_dict",
    "param_names",
    "model_from_vector",
    "simulate_population",
    "KINDS",
]

KINDS = ("fonbw", "nbw", "cbw", "zhu")


# ---------------------------------------------------------------------------
# compiled numerics

@nb.njit(cache=True)
def _powm1(ax, n):
    """|x|^(n-1) for ax = |x| ≥ 0, n ≥ 1, with the common integer cases cheap."""
    if n == 1.0:
        return 1.0
    if ax == 0.0:
        return 0.0
    if n == 2.0:
        return ax
    if n == 3.0:
        return ax * ax
    return ax ** (n - 1.0)


@nb.njit(cache=True)
def _bw_residual(x, b, c1, c2, n):
    ax = abs(x)
    p = _powm1(ax, n)
    return x - b + c1 * p * x + c2 * p * ax


#: Newton stops when its own error estimate is below this fraction of |ħ|
#: (half an ulp): the result is the root to round-off.
NEWTON_RTOL = 2.0 ** -53


@nb.njit(cache=True)
def solve_bw(b, c1, c2, n, x0):
    """Root of F(x) = x − b + c1|x|^(n−1)x + c2|x|^n (see :func:`solve_bw_p`)."""
    return solve_bw_p(b, c1, c2, n, x0, -1.0)


@nb.njit(cache=True, inline="always")
def solve_bw_p(b, c1, c2, n, x0, p0):
    """Root of F(x) = x − b + c1|x|^(n−1)x + c2|x|^n by safeguarded Newton
    (:func:`solve_bw_full`), with its most common case inlined: F increasing
    (c1 ≥ |c2|), the predictor ``x0`` ≠ 0 in the bracket with its power
    ``p0`` known, and the first Newton step accepted. That case is exactly
    the first iteration of the full solver, so the result is the same; any
    other case is handed to it from the start.
    """
    lo = min(0.0, b)
    hi = max(0.0, b)
    if p0 >= 0.0 and lo <= x0 <= hi and x0 != 0.0 and c1 >= abs(c2) and math.isfinite(b) and math.isfinite(c1):
        ax = abs(x0)
        g = c1 + c2 if x0 >= 0.0 else c1 - c2
        f = x0 - b + c1 * p0 * x0 + c2 * p0 * ax
        if f == 0.0:
            return x0
        if f < 0.0:
            lo = x0
        else:
            hi = x0
        d = 1.0 + n * p0 * g
        if d > 0.0:
            xn = x0 - f / d
            s = xn - x0
            if lo <= xn <= hi and (xn > 0.0) == (x0 > 0.0) and \
                    n * (n - 1.0) * abs(g) * p0 * s * s <= 2.0 * NEWTON_RTOL * d * ax * abs(xn):
                return xn
    return solve_bw_full(b, c1, c2, n, x0, p0)


@nb.njit(cache=True)
def solve_bw_full(b, c1, c2, n, x0, p0):
    """Root of F(x) = x − b + c1|x|^(n−1)x + c2|x|^n by safeguarded Newton.

    For c1 ≥ |c2| (σ ≥ 1/2, or β ≥ |γ| for CBW) F is increasing and the root
    lies between 0 and b; otherwise the bracket is widened until F changes
    sign. Newton starts from ``x0`` (a predictor of the root) and falls back
    to bisection whenever a step leaves the bracket. Returns NaN when no
    bracket exists (a divergent parameter set).

    Stopping rule: after a Newton step of length s from x the error of the new
    iterate is ≈ |F''|/(2F') s² with F'' = n(n−1)(c1 ± c2)|x|^(n−2) (no new
    power needed); the iterate is returned as soon as that is below
    ``NEWTON_RTOL``·|x|, on the same side of 0 (F is smooth there; for n = 1
    it is linear on each side, so one such step is exact). With a good
    predictor one evaluation of |x|^(n−1) per step is the rule, and ``p0``
    (≥ 0) passes |x0|^(n−1) when the caller has it already: computed before
    the history sums, the power overlaps them instead of lengthening the
    step's dependency chain (a negative ``p0`` means "not known").
    """
    if not (math.isfinite(b) and math.isfinite(c1) and math.isfinite(c2)):
        return math.nan
    if b == 0.0:
        return 0.0  # F(0) = -b = 0
    lo = min(0.0, b)
    hi = max(0.0, b)
    if c1 < abs(c2):
        flo = _bw_residual(lo, b, c1, c2, n)
        fhi = _bw_residual(hi, b, c1, c2, n)
        it = 0
        while flo > 0.0 and it < 200:
            lo = 2.0 * lo - 1.0
            flo = _bw_residual(lo, b, c1, c2, n)
            it += 1
        it = 0
        while fhi < 0.0 and it < 200:
            hi = 2.0 * hi + 1.0
            fhi = _bw_residual(hi, b, c1, c2, n)
            it += 1
        if flo > 0.0 or fhi < 0.0 or not (math.isfinite(flo) and math.isfinite(fhi)):
            return math.nan
    # a predictor just outside the bracket (the root can sit within round-off
    # of b) is moved onto it, not to the midpoint
    x = min(max(x0, lo), hi) if math.isfinite(x0) else 0.5 * (lo + hi)
    known = p0 >= 0.0 and x == x0
    k2 = n * (n - 1.0)
    for _ in range(200):
        ax = abs(x)
        if known:
            p = p0
            known = False
        else:
            p = _powm1(ax, n)
        g = c1 + c2 if x >= 0.0 else c1 - c2
        f = x - b + c1 * p * x + c2 * p * ax
        if f == 0.0:
            return x
        if f < 0.0:
            lo = x
        else:
            hi = x
        d = 1.0 + n * p * g
        xn = x - f / d if d > 0.0 else 0.5 * (lo + hi)
        if lo <= xn <= hi:
            s = xn - x
            if ax > 0.0 and (xn > 0.0) == (x > 0.0) and k2 * abs(g) * p * s * s <= 2.0 * NEWTON_RTOL * d * ax * abs(xn):
                return xn
        else:
            xn = 0.5 * (lo + hi)
        if hi - lo <= 4.4e-16 * max(abs(lo), abs(hi)) or abs(xn - x) <= 1e-300:
            return xn
        x = xn
    return x


# Packed layouts (one parameter block P and one state block S per model, so a
# model crosses into compiled code as two arrays):
#   FONBW  P = [kh, rho, sigma, n, N, ku(N), op1, op2]
#          S = [u0, started, ħ_{k-1}, ħ_k, ħ_{k-2}, x0, |x0|^(n-1), c, op1 state, op2 state]
#          (x0: Newton's start for the next step, c: steps since its power
#          was computed exactly; see fonbw_predict)
#   CBW    P = [ka, kb, D, A, beta, gamma, n]            S = [u_{k-1}, started, h_{k-1}, h_k]
#   Zhu    P = [dt, k1, tau, A, beta, gamma, delta, n, x0, Φ(2x2), Γ(2)]
#          S = [u_{k-1}, started, h_{k-1}, h_k, x−x0, v, k]
# S[3] always holds the hysteretic state of the last evaluated (possibly
# uncommitted) step. The FONBW views are the two blocks plus the operators'
# offset descriptors (plain numbers: no array views cross the calls).

#: Start of the first operator's state block in a FONBW state block.
FONBW_S0 = 8


@nb.njit(cache=True, inline="always")
def fonbw_views(P, S):
    N = int(P[4])
    o1 = 5 + N
    s1 = fr._sizes(P, o1)
    o2 = o1 + s1[3]
    # binomial coefficients of (1 + d)^(n−1), for fonbw_predict
    a = P[3] - 1.0
    b2 = a * (a - 1.0) / 2.0
    b3 = b2 * (a - 2.0) / 3.0
    b4 = b3 * (a - 3.0) / 4.0
    b5 = b4 * (a - 4.0) / 5.0
    b6 = b5 * (a - 5.0) / 6.0
    b7 = b6 * (a - 6.0) / 7.0
    return (P, S, N, fr.op_desc(P, o1, FONBW_S0), fr.op_desc(P, o2, FONBW_S0 + s1[4]),
            (a, b2, b3, b4, b5, b6, b7))


#: Steps between exact powers in :func:`fonbw_predict` (bounds the drift of
#: the series updates to a few ulps).
POW_REFRESH = 32.0
#: Largest relative move of the predictor updated by the binomial series
#: (eight terms: truncation |b8| d^8 below 1e-19 for n ≤ 8).
POW_SERIES_D = 2.0 ** -7


@nb.njit(cache=True, inline="always")
def fonbw_predict(P, S, B):
    """Newton start for the step after the current one, and its power:
    ``(x0, |x0|^(n−1), counter)`` with x0 = 3ħ_{k−1} − 2ħ_{k−2` (linear
    extrapolation two steps ahead).

    Built from values known when step k begins, so it is off the dependency
    chain from ħ_{k−1} to ħ_k, and step k+1 starts Newton where the power is
    known: one Newton step is the rule. The power itself (a libm ``pow``
    costs ~25 ns) is carried from the previous predictor x0' by the binomial
    series p' (1 + d)^(n−1), d = x0/x0' − 1, while |d| ≤ 2^-7, and computed
    afresh every ``POW_REFRESH`` steps, on larger moves and for the integer
    orders that :func:`_powm1` does exactly; either way it is |x0|^(n−1) to
    a few ulps.
    """
    xq = 3.0 * S[2] - 2.0 * S[4]
    n = P[3]
    if S[7] < POW_REFRESH and S[5] != 0.0 and S[1] != 0.0 and n != 1.0 and n != 2.0 and n != 3.0:
        d = xq / S[5] - 1.0
        if abs(d) <= POW_SERIES_D:
            a, b2, b3, b4, b5, b6, b7 = B
            ser = 1.0 + d * (a + d * (b2 + d * (b3 + d * (b4 + d * (b5 + d * (b6 + d * b7))))))
            return xq, S[6] * ser, S[7] + 1.0
    return xq, _powm1(abs(xq), n), 0.0


#: A predictor this close (relative) beyond the bracket end b is moved onto b
#: with its power carried by three series terms (truncation below 1e-17).
BRACKET_SNAP = 2.0 ** -15


@nb.njit(cache=True, inline="always")
def fonbw_solve(D1, h2, a2, P, S, B):
    """ħ_k of eq. (11) from D1 = D^λ1 u_k and the ħ-history h2 (D^λ2 ħ_k =
    a2 ħ_k + h2), Newton from the predictor stored by the previous step.
    Shared by the step kernel and the blocked exact run.

    On a loading branch (sign D1 = sign ħ) the σ terms cancel and the root
    lies within ~1e-10 (relative) of the bracket end b, so the predictor
    often falls just beyond it; it is then moved onto b, its power updated
    by the series, instead of letting the solver start over from b with a
    fresh ``pow``.
    """
    rho = P[1]
    sigma = P[2]
    ia2 = 1.0 / a2
    b = (rho * D1 - h2) * ia2
    x0 = S[5]
    p0 = S[6] if S[1] != 0.0 else -1.0
    if p0 >= 0.0 and x0 != 0.0 and (x0 > b if b > 0.0 else x0 < b):
        d = b / x0 - 1.0
        if abs(d) <= BRACKET_SNAP:
            a, b2, b3 = B[0], B[1], B[2]
            p0 = p0 * (1.0 + d * (a + d * (b2 + d * b3)))
            x0 = b
    return solve_bw_p(b, rho * sigma * abs(D1) * ia2, rho * (1.0 - sigma) * D1 * ia2, P[3], x0, p0)


@nb.njit(cache=True, inline="always")
def fonbw_advance(S, hb, pred):
    """Commit ħ_k and the predictor of the next step (state layout above)."""
    S[4] = S[2]
    S[2] = hb
    S[5] = pred[0]
    S[6] = pred[1]
    S[7] = pred[2]


@nb.njit(cache=True, inline="always")
def fonbw_output(u, hb, P, N):
    """H = g(u) + kh ħ (eqs. 9–10), g(u) = Σ ku_i u^i by Horner."""
    g = 0.0
    for i in range(N - 1, -1, -1):
        g = (g + P[5 + i]) * u
    return g + P[0] * hb


@nb.njit(cache=True, inline="always")
def fonbw_core(u, commit, V):
    """One step of eqs. (9)–(11) on the views of :func:`fonbw_views`.

    Returns H(u_k) [µm]. With ``commit`` False nothing is stored (the
    compensator's trial evaluations); ħ_k is left in S[3] either way.
    """
    P, S, N, d1, d2, B = V
    pred = fonbw_predict(P, S, B)
    xk = u - (u if S[1] == 0.0 else S[0])
    D1 = d1[13] * xk + fr.op_history(P, S, d1)
    hb = fonbw_solve(D1, fr.op_history(P, S, d2), d2[13], P, S, B)
    S[3] = hb
    if commit:
        if S[1] == 0.0:
            S[0] = u
            S[1] = 1.0
        fr.op_push(P, S, d1, xk)
        fr.op_push(P, S, d2, hb)
        fonbw_advance(S, hb, pred)
    return fonbw_output(u, hb, P, N)


@nb.njit(cache=True)
def fonbw_exact_leaf(lo, hi, u, x1, h1, wr, hist2, P, S, hb, out):
    """Steps [lo, hi) of FONBW with exact GL sums supplied from outside.

    ``h1[k]`` is the complete u-side history and ``hist2[k]`` the ħ-side
    history of the steps before ``lo`` (:func:`fonbw.fractional.blocked_solve`);
    the ħ terms of [lo, k) are summed here, with the ħ-side weights reversed,
    ``wr[t] = w2[L − t]`` (L = len(wr) − 1 ≥ hi − lo), so that the sum is a
    forward dot product (the SIMD one of the memory kernels). Writes ħ into
    ``hb`` and H into ``out``; returns the number of steps done (less than
    ``hi`` at the first non-finite output). S is a FONBW state block without
    operators.
    """
    _, _, N, d1, d2, B = fonbw_views(P, S)
    a1 = d1[13]
    a2 = d2[13]
    L = wr.shape[0] - 1
    for k in range(lo, hi):
        r = k - lo
        acc = fr._dot_off(wr, fr._U(L - r), hb, fr._U(lo), fr._U(r))
        pred = fonbw_predict(P, S, B)
        D1 = a1 * x1[k] + h1[k]
        h = fonbw_solve(D1, hist2[k] + acc, a2, P, S, B)
        hb[k] = h
        out[k] = fonbw_output(u[k], h, P, N)
        S[1] = 1.0
        S[3] = h
        fonbw_advance(S, h, pred)
        if not math.isfinite(out[k]):
            return k
    return hi


@nb.njit(cache=True)
def fonbw_step(u, commit, P, S):
    """One step of eqs. (9)–(11) on the packed blocks (per-step callers)."""
    return fonbw_core(u, commit, fonbw_views(P, S))


@nb.njit(cache=True)
def plain_views(P, S):
    return (P, S)


@nb.njit(cache=True)
def cbw_core(u, commit, V):
    return cbw_step(u, commit, V[0], V[1])


@nb.njit(cache=True)
def zhu_core(u, commit, V):
    return zhu_step(u, commit, V[0], V[1])


@nb.njit(cache=True)
def cbw_step(u, commit, P, S):
    """Backward-Euler step of eqs. (1)–(2). Returns H(u_k) [µm]."""
    ka = P[0]
    kb = P[1]
    D = P[2]
    du = 0.0 if S[1] == 0.0 else u - S[0]
    h = solve_bw(S[2] + P[3] / D * du, P[4] / D * abs(du), P[5] / D * du, P[6], S[2])
    S[3] = h
    if commit:
        S[0] = u
        S[1] = 1.0
        S[2] = h
    return ka * u + kb * D * h


@nb.njit(cache=True)
def zhu_step(u, commit, P, S):
    """One step of eq. (20). Returns x_k [µm].

    The BW state is advanced by backward Euler (δ·u·sgn(u̇) integrated as
    δ u_k sgn(Δu) dt); the mechanics exactly (matrix exponential) with the
    force (k1/τ)e^{-t_k/τ} u_k + h_k held over the step that ends at t_k.
    """
    dt = P[0]
    du = 0.0 if S[1] == 0.0 else u - S[0]
    sg = 0.0
    if du > 0.0:
        sg = 1.0
    elif du < 0.0:
        sg = -1.0
    h = solve_bw(S[2] + P[3] * du + P[6] * u * sg * dt, P[4] * abs(du), P[5] * du, P[7], S[2])
    f = P[1] / P[2] * math.exp(-S[6] * dt / P[2]) * u + h
    xr = P[9] * S[4] + P[10] * S[5] + P[13] * f
    v = P[11] * S[4] + P[12] * S[5] + P[14] * f
    S[3] = h
    if commit:
        S[0] = u
        S[1] = 1.0
        S[2] = h
        S[4] = xr
        S[5] = v
        S[6] += 1.0
    return P[8] + xr


#: Model codes of the batch runner (dispatchers cannot be cached as arguments).
CODE_FONBW = 0
CODE_CBW = 1
CODE_ZHU = 2


@nb.njit(cache=True)
def step_code(code, u, commit, P, S):
    """One step of the model with code ``code`` on its packed blocks.

    The cacheable way for other compiled code (compensator, closed loops) to
    call any model: numba cannot cache a function that takes a dispatcher as
    an argument, so pass ``model._code`` instead of ``model._kernels``.
    """
    if code == CODE_FONBW:
        return fonbw_step(u, commit, P, S)
    if code == CODE_CBW:
        return cbw_step(u, commit, P, S)
    return zhu_step(u, commit, P, S)


@nb.njit(cache=True)
def _finish(out, hout, k):
    out[k:] = math.nan
    hout[k:] = math.nan


@nb.njit(cache=True)
def run_kernel(code, u, P, ssize, out, hout):
    """Batch run of a model from rest; NaN from the first non-finite output.

    ``hout`` receives the hysteretic state (ħ or h) after each step.
    """
    S = np.zeros(ssize)
    if code == CODE_FONBW:
        V = fonbw_views(P, S)
        for k in range(u.shape[0]):
            out[k] = fonbw_core(u[k], True, V)
            hout[k] = S[2]
            if not math.isfinite(out[k]):
                _finish(out, hout, k)
                return
    elif code == CODE_CBW:
        for k in range(u.shape[0]):
            out[k] = cbw_step(u[k], True, P, S)
            hout[k] = S[2]
            if not math.isfinite(out[k]):
                _finish(out, hout, k)
                return
    else:
        for k in range(u.shape[0]):
            out[k] = zhu_step(u[k], True, P, S)
            hout[k] = S[2]
            if not math.isfinite(out[k]):
                _finish(out, hout, k)
                return


@nb.njit(cache=True, parallel=True)
def run_population(code, U, Pm, ssizes, out):
    """Rows of Pm (padded packed parameter blocks) in parallel.

    ``U`` holds one input row shared by all candidates, or one row each.
    """
    for p in nb.prange(Pm.shape[0]):
        hd = np.empty(U.shape[1])
        run_kernel(code, U[0] if U.shape[0] == 1 else U[p], Pm[p], ssizes[p], out[p], hd)


# ---------------------------------------------------------------------------
# validation helpers

def _finite(name, v):
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"parameter {name} must be a number, got {v!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"parameter {name} must be finite, got {v!r}")
    return v


def _positive(name, v):
    v = _finite(name, v)
    if v <= 0:
        raise ValueError(f"parameter {name} must be > 0, got {v!r}")
    return v


def _order_n(v):
    v = _finite("n", v)
    if v < 1:
        raise ValueError(f"parameter n must satisfy n ≥ 1, got {v!r}")
    return v


def _lam(name, v):
    v = _finite(name, v)
    if not 0 < v <= 1:
        raise ValueError(f"parameter {name} must satisfy 0 < {name} ≤ 1, got {v!r}")
    return v


def _ku(ku):
    arr = np.atleast_1d(np.asarray(ku, dtype=float)) if not isinstance(ku, str) else None
    if arr is None or arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"parameter ku must be a number or a non-empty list of numbers, got {ku!r}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"parameter ku must be finite, got {list(arr)}")
    return arr


def _input(u):
    u = np.ascontiguousarray(u, dtype=float)
    if u.ndim != 1:
        raise ValueError(f"input u must be a 1-D array, got shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise ValueError("input u contains NaN or infinite values")
    return u


def _dt(dt):
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise ValueError(f"step dt must be a number of seconds, got {dt!r}") from None
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"step dt must be a positive finite number of seconds, got {dt!r}")
    return dt


# ---------------------------------------------------------------------------
# models

class _Model:
    """Common part: parameters, JSON, units."""

    kind = ""
    units: dict = {}
    descriptions: dict = {}

    def to_dict(self) -> dict:
        """JSON-ready description: kind, parameters, units."""
        params = {k: (list(map(float, v)) if isinstance(v, np.ndarray) else v) for k, v in self.params.items()}
        d = {"kind": self.kind, "params": params, "units": {k: self.units[k] for k in params if k in self.units}}
        return d

    def save(self, path) -> None:
        """Write the parameter set as JSON (atomically)."""
        with atomic_open(path, "w", encoding="utf-8") as fh:
            json.dump(self.to_dict(), fh, indent=2, ensure_ascii=False)
            fh.write("\n")

    def __repr__(self):
        inner = ", ".join(f"{k}={v!r}" for k, v in self.to_dict()["params"].items())
        return f"{type(self).__name__}({inner})"

    def __eq__(self, other):
        return type(self) is type(other) and json.dumps(self.to_dict()) == json.dumps(other.to_dict())

    def simulate(self, u, dt) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def stepper(self, dt) -> "Stepper":  # pragma: no cover - abstract
        raise NotImplementedError


_FONBW_UNITS = {
    "ku": "µm/V^i (coefficient of u^i)", "kh": "µm", "rho": "1/V", "sigma": "1", "n": "1",
    "lam1": "1", "lam2": "1", "memory": "-",
}


class FONBW(_Model):
    """Fractional-order normalized Bouc-Wen model, eqs. (9)–(11).

    H(u,t) = Σ_i ku_i u^i + kh ħ(t),
    D^λ2 ħ = ρ (D^λ1 u − σ |D^λ1 u| |ħ|^(n−1) ħ + (σ−1) D^λ1 u |ħ|^n).

    Parameters
    ----------
    ku : float or sequence of float
        Polynomial coefficients k_u1 … k_uN of g(u) [µm/V^i] (eq. 10).
    kh : float
        Hysteretic gain [µm].
    rho : float
        ρ > 0 [1/V] (with λ1 = λ2 = 1; in general [s^(λ1−λ2)/V]).
    sigma : float
        σ (shape; σ ≥ 1/2 gives the bounded, unique-step case).
    n : float
        Sharpness, real n ≥ 1.
    lam1, lam2 : float
        Orders of the derivatives of u and of ħ, 0 < λ ≤ 1.
    memory : {"fast", "exact", "short", "oustaloup"}
        GL memory engine (:mod:`fonbw.fractional`).
    K, M, L : int
        Engine options (fast: exact lags K and modes M; short: window L).
    """

    kind = "fonbw"
    units = _FONBW_UNITS

    def __init__(self, ku, kh, rho, sigma, n, lam1=1.0, lam2=1.0, memory="fast",
                 K=fr.FAST_K, M=fr.FAST_M, L=fr.SHORT_L):
        self.ku = _ku(ku)
        self.kh = _finite("kh", kh)
        self.rho = _positive("rho", rho)
        self.sigma = _finite("sigma", sigma)
        self.n = _order_n(n)
        self.lam1 = _lam("lam1", lam1)
        self.lam2 = _lam("lam2", lam2)
        if memory not in fr.ENGINES:
            raise ValueError(f"unknown memory engine {memory!r}; choose one of {', '.join(fr.ENGINES)}")
        self.memory = memory
        self.K, self.M, self.L = int(K), int(M), int(L)
        if self.K < 1 or self.M < 0 or self.L < 1:
            raise ValueError(f"engine sizes must satisfy K ≥ 1, M ≥ 0, L ≥ 1, got K={K}, M={M}, L={L}")

    @property
    def params(self) -> dict:
        p = {"ku": self.ku, "kh": self.kh, "rho": self.rho, "sigma": self.sigma, "n": self.n,
             "lam1": self.lam1, "lam2": self.lam2, "memory": self.memory}
        # engine sizes only when they differ from the defaults, so saved files stay short
        for name, default in (("K", fr.FAST_K), ("M", fr.FAST_M), ("L", fr.SHORT_L)):
            if getattr(self, name) != default:
                p[name] = getattr(self, name)
        return p

    def _ops(self, dt, n_steps=None):
        kw = dict(K=self.K, M=self.M, L=self.L, n_steps=n_steps)
        return fr.make_op(self.lam1, dt, self.memory, **kw), fr.make_op(self.lam2, dt, self.memory, **kw)

    _step = staticmethod(fonbw_step)
    _code = CODE_FONBW
    _kernels = (fonbw_views, fonbw_core)

    def _pack(self, dt, n_steps=None, ops=None):
        """Packed parameter block and state size (layout above the kernels)."""
        o1, o2 = ops if ops is not None else self._ops(dt, n_steps)
        P = np.concatenate([[self.kh, self.rho, self.sigma, self.n, len(self.ku)], self.ku,
                            fr.pack(o1), fr.pack(o2)])
        return P, FONBW_S0 + fr.state_size(o1) + fr.state_size(o2)

    def simulate(self, u, dt, return_state=False):
        """Output H [µm] for the input u [V] sampled at step dt [s], from rest.

        With ``return_state`` also returns the hysteretic variable ħ. With
        the exact engine, runs of ``EXACT_BLOCKED_MIN`` steps or more sum
        the GL history by blocked FFT convolutions (O(N log² N), equal to
        the direct sum to round-off).
        """
        u = _input(u)
        if self.memory == "exact" and len(u) >= EXACT_BLOCKED_MIN and min(self.lam1, self.lam2) < 1.0:
            return _simulate_exact_blocked(self, u, _dt(dt), return_state)
        return _simulate(self, u, dt, return_state)

    def stepper(self, dt) -> "Stepper":
        """Per-sample stepper at step dt [s] (same numbers as :meth:`simulate`)."""
        return _FONBWStepper(self, _dt(dt))

    def tail_error(self, dt=None):
        """Fast-engine tail errors E1 of the two derivatives (0 for other engines)."""
        if self.memory != "fast":
            return (0.0, 0.0)
        return (fr.tail_error(self.lam1, self.K, self.M), fr.tail_error(self.lam2, self.K, self.M))


class NBW(FONBW):
    """Normalized Bouc-Wen model, eqs. (7)–(8); asymmetric with a list ``ku`` (eqs. 9–10).

    Backward Euler, i.e. FONBW with λ1 = λ2 = 1 (no memory engine involved).

    Parameters
    ----------
    ku : float or sequence of float
        k_u [µm/V] or the polynomial coefficients k_u1 … k_uN.
    kh : float
        [µm].
    rho : float
        ρ > 0 [1/V].
    sigma, n : float
        σ, n ≥ 1.
    """

    kind = "nbw"

    def __init__(self, ku, kh, rho, sigma, n):
        super().__init__(ku, kh, rho, sigma, n, 1.0, 1.0, memory="exact")

    @property
    def params(self) -> dict:
        ku = float(self.ku[0]) if len(self.ku) == 1 else self.ku
        return {"ku": ku, "kh": self.kh, "rho": self.rho, "sigma": self.sigma, "n": self.n}


class CBW(_Model):
    """Classical Bouc-Wen model, eqs. (1)–(2), backward Euler in h.

    H = α k u + (1−α) D k h,  ḣ = D⁻¹(A u̇ − β|u̇||h|^(n−1)h − γ u̇|h|^n).

    Give either ``alpha`` and ``k`` or the paper's identification constants
    ``ka = αk`` [µm/V] and ``kb = (1−α)k`` (Sec. IV-B).

    Parameters
    ----------
    alpha, k : float
        Elastic ratio [-] and gain [µm/V].
    D : float
        D > 0 [V].
    A, beta, gamma : float
        A [-], β, γ [1/V^n].
    n : float
        n ≥ 1.
    """

    kind = "cbw"
    units = {"alpha": "1", "k": "µm/V", "ka": "µm/V", "kb": "µm/V", "D": "V", "A": "1",
             "beta": "1/V^n", "gamma": "1/V^n", "n": "1"}

    def __init__(self, alpha=None, k=None, D=1.0, A=1.0, beta=0.5, gamma=0.5, n=1.0, *, ka=None, kb=None):
        if (alpha is None) == (ka is None) or (alpha is None) != (k is None) or (ka is None) != (kb is None):
            raise ValueError("CBW needs either alpha and k, or ka and kb")
        if alpha is not None:
            self.alpha, self.k = _finite("alpha", alpha), _finite("k", k)
            self.ka, self.kb = self.alpha * self.k, (1.0 - self.alpha) * self.k
            self._form = "alpha"
        else:
            self.ka, self.kb = _finite("ka", ka), _finite("kb", kb)
            self.k = self.ka + self.kb
            self.alpha = self.ka / self.k if self.k != 0 else math.nan
            self._form = "ka"
        self.D = _positive("D", D)
        self.A = _finite("A", A)
        self.beta = _finite("beta", beta)
        self.gamma = _finite("gamma", gamma)
        self.n = _order_n(n)

    @property
    def params(self) -> dict:
        head = {"alpha": self.alpha, "k": self.k} if self._form == "alpha" else {"ka": self.ka, "kb": self.kb}
        return {**head, "D": self.D, "A": self.A, "beta": self.beta, "gamma": self.gamma, "n": self.n}

    def to_nbw(self) -> NBW:
        """The exactly equivalent NBW model (Sec. II-B).

        h0 = (A/(β+γ))^(1/n), ρ = A/(D h0), σ = β/(β+γ), k_u = αk,
        k_h = (1−α) D k h0; needs A/(β+γ) > 0.
        """
        s = self.beta + self.gamma
        if s == 0 or self.A / s <= 0:
            raise ValueError(f"CBW → NBW needs A/(β+γ) > 0, got A={self.A}, β+γ={s}")
        h0 = (self.A / s) ** (1.0 / self.n)
        return NBW(ku=self.ka, kh=self.kb * self.D * h0, rho=self.A / (self.D * h0), sigma=self.beta / s, n=self.n)

    _step = staticmethod(cbw_step)
    _code = CODE_CBW
    _kernels = (plain_views, cbw_core)

    def _pack(self, dt, n_steps=None):
        return np.array([self.ka, self.kb, self.D, self.A, self.beta, self.gamma, self.n]), 4

    def simulate(self, u, dt=1.0, return_state=False):
        """Output H [µm] from rest; dt only checks the time step (CBW is rate independent)."""
        return _simulate(self, u, dt, return_state)

    def stepper(self, dt=1.0) -> "Stepper":
        return Stepper(self, _dt(dt))


def _zhu_discrete(m0, c0, k0, dt):
    """Exact ZOH discretization of m0 ẍ + c0 ẋ + k0 x = f: (Φ, Γ)."""
    from scipy.linalg import expm

    Ac = np.array([[0.0, 1.0], [-k0 / m0, -c0 / m0]])
    Bc = np.array([0.0, 1.0 / m0])
    Mx = np.zeros((3, 3))
    Mx[:2, :2] = Ac * dt
    Mx[:2, 2] = Bc * dt
    E = expm(Mx)
    return np.ascontiguousarray(E[:2, :2]), np.ascontiguousarray(E[:2, 2])


class Zhu2016(_Model):
    """Rate-dependent Bouc-Wen model of Zhu et al. (2016), eq. (20) as written.

    m0 ẍ + c0 ẋ + k0 (x − x0) = (k1/τ) e^(−t/τ) u + h,
    ḣ = A u̇ − β|u̇||h|^(n−1)h − γ u̇|h|^n + δ u sgn(u̇).

    As written, the direct input term decays with absolute time t: after a few
    τ (τ = 2e-5 s in Table 1) only the hysteretic force h drives the
    mechanics. Output x [µm] starts at x0.
    """

    kind = "zhu"
    names = ("m0", "c0", "k0", "k1", "x0", "tau", "A", "beta", "gamma", "delta", "n")
    units = {"m0": "kg", "c0": "N s/m", "k0": "N/m", "k1": "-", "x0": "µm", "tau": "s", "A": "-",
             "beta": "-", "gamma": "-", "delta": "1/s", "n": "1"}

    def __init__(self, m0, c0, k0, k1, x0, tau, A, beta, gamma, delta, n):
        self.m0 = _positive("m0", m0)
        self.c0 = _finite("c0", c0)
        if self.c0 < 0:
            raise ValueError(f"parameter c0 must be ≥ 0, got {c0!r}")
        self.k0 = _positive("k0", k0)
        self.k1 = _finite("k1", k1)
        self.x0 = _finite("x0", x0)
        self.tau = _positive("tau", tau)
        self.A = _finite("A", A)
        self.beta = _finite("beta", beta)
        self.gamma = _finite("gamma", gamma)
        self.delta = _finite("delta", delta)
        self.n = _order_n(n)

    @property
    def params(self) -> dict:
        return {k: getattr(self, k) for k in self.names}

    _step = staticmethod(zhu_step)
    _code = CODE_ZHU
    _kernels = (plain_views, zhu_core)

    def _pack(self, dt, n_steps=None):
        Phi, Gam = _zhu_discrete(self.m0, self.c0, self.k0, dt)
        head = [dt, self.k1, self.tau, self.A, self.beta, self.gamma, self.delta, self.n, self.x0]
        return np.concatenate([head, Phi.ravel(), Gam]), 7

    def simulate(self, u, dt, return_state=False):
        """Displacement x [µm] from rest (x = x0) for the input u [V] at step dt [s]."""
        return _simulate(self, u, dt, return_state)

    def stepper(self, dt) -> "Stepper":
        return Stepper(self, _dt(dt))


#: From this many steps on, a batch run with the exact engine sums the GL
#: history by blocked FFT convolutions (O(N log² N)) instead of directly
#: (O(N²)); the two agree to round-off (about 1e-13 relative), and below
#: this length the direct sum is as fast and stays bit-identical to the
#: stepper.
EXACT_BLOCKED_MIN = 8192


def _simulate_exact_blocked(model, u, dt, return_state):
    """FONBW with memory="exact" by :func:`fonbw.fractional.blocked_solve`."""
    from scipy import fft as sfft

    n = len(u)
    P, _ = model._pack(dt, n_steps=1)  # operator windows unused: the weights come from here
    x1 = u - u[0]
    w1 = fr.gl_weights(model.lam1, n) * dt ** (-model.lam1)
    w2 = fr.gl_weights(model.lam2, n) * dt ** (-model.lam2)
    # u is explicit: its whole history sum is one FFT convolution (lags ≥ 1)
    nfft = sfft.next_fast_len(2 * n - 1, real=True)
    w1[0] = 0.0
    h1 = sfft.irfft(sfft.rfft(x1, nfft) * sfft.rfft(w1, nfft), nfft)[:n]
    S = np.zeros(FONBW_S0)
    hb = np.zeros(n)
    out = np.empty(n)

    L = fr.EXACT_LEAF
    wr = np.zeros(L + 1)
    wr[:min(n, L + 1)] = w2[:L + 1]
    wr = wr[::-1].copy()  # wr[t] = w2[L - t]

    def leaf(lo, hi, hist2):
        return fonbw_exact_leaf(lo, hi, u, x1, h1, wr, hist2, P, S, hb, out)

    done = fr.blocked_solve(w2, hb, leaf)
    out[done:] = math.nan
    hb[done:] = math.nan
    return (out, hb) if return_state else out


def _simulate(model, u, dt, return_state):
    u = _input(u)
    dt = _dt(dt)
    P, ss = model._pack(dt, n_steps=len(u))
    out = np.empty(len(u))
    hout = np.empty(len(u))
    if len(u):
        run_kernel(model._code, u, P, ss, out, hout)
    return (out, hout) if return_state else out


# ---------------------------------------------------------------------------
# steppers

class Stepper:
    """One sample at a time: ``y_k = s.step(u_k)``.

    ``peek(u)`` returns the output the next step would give for ``u`` without
    advancing; ``get_state()``/``set_state()`` copy the whole state (fractional
    memory included) as one float64 array, so a rollback replays bit for bit.
    The numbers are those of the model's ``simulate``: both run the same
    compiled step function.
    """

    def __init__(self, model, dt):
        self.model = model
        self.dt = dt
        self._kernel = model._step
        self.reset()

    def reset(self) -> None:
        """Back to rest at t = 0."""
        self.P, ss = self.model._pack(self.dt)
        self.S = np.zeros(ss)
        self._steps = 0

    def step(self, u: float) -> float:
        """Advance one step with input u [V]; returns the output [µm]."""
        y = self._kernel(float(u), True, self.P, self.S)
        self._steps += 1
        return y

    def peek(self, u: float) -> float:
        """Output for input u [V] at the next step, without advancing."""
        return self._kernel(float(u), False, self.P, self.S)

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def state_variable(self) -> float:
        """Hysteretic state (ħ or h) after the last committed step."""
        return float(self.S[2])

    def get_state(self) -> np.ndarray:
        return np.concatenate([[float(self._steps), len(self.P)], self.P, self.S])

    def set_state(self, state) -> None:
        s = np.asarray(state, dtype=float)
        if s.ndim != 1 or len(s) < 2:
            raise ValueError("state must be a 1-D array from get_state()")
        npar = int(s[1])
        P = s[2:2 + npar]
        if len(P) != npar or not self._compatible(P):
            raise ValueError("state does not belong to this stepper (model, engine or step differ)")
        self._steps = int(s[0])
        self.P = P.copy()
        self.S = s[2 + npar:].copy()

    def _compatible(self, P):
        return len(P) == len(self.P) and np.array_equal(P, self.P)


class _FONBWStepper(Stepper):
    """FONBW stepper; the exact engine's window grows with the run."""

    def reset(self):
        self.ops = self.model._ops(self.dt)
        super().reset()

    def step(self, u):
        if any(op.growable and self._count(i) >= op.window for i, op in enumerate(self.ops)):
            self._grow()
        return super().step(u)

    def _offsets(self):
        sz = [fr.state_size(op) for op in self.ops]
        return [FONBW_S0, FONBW_S0 + sz[0]], sz

    def _count(self, i):
        q = self._offsets()[0][i]
        return int(self.S[q + 1])

    def _grow(self):
        (q1, q2), (s1, s2) = self._offsets()
        blocks = [self.S[q1:q1 + s1], self.S[q2:q2 + s2]]
        new_ops, new_blocks = [], []
        for op, blk in zip(self.ops, blocks):
            if op.growable and int(blk[1]) >= op.window:
                W = op.window
                new = op.grown(2 * W)
                pos = int(blk[0])
                vals = blk[3 + pos:3 + pos + W]  # newest first (lag 1 … W)
                nbuf = np.zeros(2 * new.window)
                nbuf[:W] = vals
                nbuf[new.window:new.window + W] = vals
                blk = np.concatenate([[0, blk[1], blk[2]], nbuf, blk[3 + 2 * W:]])
                op = new
            new_ops.append(op)
            new_blocks.append(blk)
        self.ops = tuple(new_ops)
        self.P, _ = self.model._pack(self.dt, ops=self.ops)
        self.S = np.concatenate([self.S[:FONBW_S0], *new_blocks])

    def set_state(self, state):
        s = np.asarray(state, dtype=float)
        npar = int(s[1]) if len(s) > 1 else -1
        if any(op.growable for op in self.ops) and npar > 0:
            # the exact window may have grown: rebuild the operators to match
            N = len(self.model.ku)
            P = s[2:2 + npar]
            W1 = int(P[5 + N + 2])
            o2 = 5 + N + fr._sizes(P, 5 + N)[3]
            W2 = int(P[o2 + 2])
            ops = tuple(op.grown(W) if op.growable and W != op.window else op for op, W in zip(self.ops, (W1, W2)))
            self.ops = ops
            self.P, _ = self.model._pack(self.dt, ops=ops)
        super().set_state(state)


# ---------------------------------------------------------------------------
# JSON and parameter vectors

def model_from_dict(d: dict, source: str = "<dict>"):
    """Build a model from :meth:`to_dict` output; errors name the source and field."""
    if not isinstance(d, dict):
        raise ValueError(f"{source}: expected a JSON object with 'kind' and 'params'")
    kind = d.get("kind")
    params = d.get("params")
    if kind not in KINDS:
        raise ValueError(f"{source}: field 'kind': {kind!r} is not one of {', '.join(KINDS)}")
    if not isinstance(params, dict):
        raise ValueError(f"{source}: field 'params' must be an object")
    cls = {"fonbw": FONBW, "nbw": NBW, "cbw": CBW, "zhu": Zhu2016}[kind]
    try:
        return cls(**params)
    except TypeError as exc:
        raise ValueError(f"{source}: field 'params': {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{source}: field 'params': {exc}") from None


def load_model(path):
    """Load a model saved with :meth:`save` (any kind)."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as fh:
            d = json.load(fh)
    except OSError as exc:
        raise ValueError(f"{path}: cannot open: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: line {exc.lineno}: not valid JSON ({exc.msg})") from None
    return model_from_dict(d, source=path)


def param_names(kind: str, N: int = 3) -> list[str]:
    """Order of the parameter vector of :func:`simulate_population` for a kind."""
    ku = [f"ku{i}" for i in range(1, N + 1)]
    if kind == "fonbw":
        return ku + ["kh", "rho", "sigma", "n", "lam1", "lam2"]
    if kind == "nbw":
        return ku + ["kh", "rho", "sigma", "n"]
    if kind == "cbw":
        return ["ka", "kb", "D", "A", "beta", "gamma", "n"]
    if kind == "zhu":
        return list(Zhu2016.names)
    raise ValueError(f"unknown model kind {kind!r}; choose one of {', '.join(KINDS)}")


def model_from_vector(kind: str, theta, N: int = 3, memory: str = "fast"):
    """Model of `kind` from a parameter vector in the order of :func:`param_names`."""
    th = [float(v) for v in theta]
    if len(th) != len(param_names(kind, N)):
        raise ValueError(f"{kind} with N={N} takes {len(param_names(kind, N))} parameters, got {len(th)}")
    if kind == "fonbw":
        return FONBW(th[:N], *th[N:], memory=memory)
    if kind == "nbw":
        return NBW(th[:N], *th[N:])
    if kind == "cbw":
        return CBW(ka=th[0], kb=th[1], D=th[2], A=th[3], beta=th[4], gamma=th[5], n=th[6])
    return Zhu2016(*th)


def simulate_population(kind: str, theta, u, dt, memory: str = "fast", N: int = 3) -> np.ndarray:
    """Simulate many parameter sets in one compiled, parallel call.

    Parameters
    ----------
    kind : {"fonbw", "nbw", "cbw", "zhu"}
    theta : array_like, shape (P, d)
        Parameter vectors in the order of :func:`param_names`.
    u : array_like, shape (n,) or (P, n)
        Input [V]: one input for all candidates, or one row per candidate
        (e.g. when an input-side effect block filters the voltage differently
        for each candidate).
    dt : float
        Step [s].
    memory : str
        GL engine (fonbw). ``oustaloup`` runs the rows one after the other.
    N : int
        Polynomial order (fonbw, nbw).

    Returns
    -------
    ndarray, shape (P, n)
        Outputs [µm]; a row is NaN from the step where its candidate diverged
        (and whole-NaN for an invalid parameter vector).
    """
    th = np.atleast_2d(np.asarray(theta, dtype=float))
    U = np.ascontiguousarray(u, dtype=float)
    if U.ndim == 1:
        U = _input(U)[None, :]
    elif U.ndim != 2 or U.shape[0] != th.shape[0]:
        raise ValueError(f"u must be 1-D or have one row per parameter vector ({th.shape[0]}), got shape {U.shape}")
    elif not np.all(np.isfinite(U)):
        raise ValueError("input u contains NaN or infinite values")
    dt = _dt(dt)
    P = th.shape[0]
    n = U.shape[1]
    d = len(param_names(kind, N))
    if th.shape[1] != d:
        raise ValueError(f"theta must have {d} columns for {kind} with N={N}, got {th.shape[1]}")
    out = np.full((P, n), np.nan)
    models = []
    for p in range(P):
        try:
            models.append((p, model_from_vector(kind, th[p], N, memory)))
        except ValueError:
            pass  # invalid candidate: its row stays NaN
    if not models:
        return out
    if memory == "oustaloup" and kind == "fonbw":
        for p, m in models:
            out[p] = m.simulate(U[0] if U.shape[0] == 1 else U[p], dt)
        return out
    rows = [p for p, _ in models]
    packs = [m._pack(dt, n_steps=n) for _, m in models]
    width = max(len(pk[0]) for pk in packs)
    Pm = np.zeros((len(packs), width))
    for i, (pk, _) in enumerate(packs):
        Pm[i, :len(pk)] = pk
    ss = np.array([pk[1] for pk in packs], dtype=np.int64)
    sub = np.empty((len(packs), n))
    run_population(models[0][1]._code, U if U.shape[0] == 1 else U[rows], Pm, ss, sub)
    out[rows] = sub
    return out
