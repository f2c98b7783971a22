"""Compiled kernels of the hysteresis models (numba, ``cache=True``).

The scalar Bouc-Wen solver of eq. (11) (:func:`solve_bw` and its inlined
fast path), the step functions of FONBW, CBW and Zhu on packed parameter and
state blocks, and the batch runners :func:`run_kernel` (one model) and
:func:`run_population` (many parameter sets in parallel). The model classes
(:mod:`fonbw.hysteresis.models`) pack their parameters for these functions;
batch runs and per-step steppers call the same step code, so their numbers
are bit-identical.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from .. import fractional as fr

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
