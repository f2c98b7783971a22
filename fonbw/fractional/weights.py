"""The mathematics of the memory engines, in numpy and scipy.

Grünwald–Letnikov weights (eq. A2) and the GL derivative of a whole signal;
the fast engine's geometric tail modes and their error bound E1; the refined
Oustaloup filter as a discrete state space; and :func:`blocked_solve`, the
O(N log² N) exact history sum of long batch runs. The engine defaults live
here too. Only the tail modes' nodes are compiled (numba), as every model
built builds them. Orders λ are dimensionless, steps in seconds.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

ENGINES = ("fast", "exact", "short", "oustaloup")

#: Defaults of the fast engine: exact lags and number of geometric modes.
FAST_K = 32
FAST_M = 56
#: Default window of the short-memory engine.
SHORT_L = 1000
#: Horizon over which :func:`tail_error` sums |w_j − ŵ_j| by default (lags).
E1_HORIZON = 1_000_000



def _check_lam(lam):
    lam = float(lam)
    if not (math.isfinite(lam) and 0.0 < lam <= 1.0):
        raise ValueError(f"fractional order must satisfy 0 < λ ≤ 1, got {lam!r}")
    return lam


def gl_weights(lam: float, n: int) -> np.ndarray:
    """GL weights ``w_j = (-1)^j binom(λ, j)`` for j = 0..n-1 by eq. (A2).

    Parameters
    ----------
    lam : float
        Order λ (any real; the models use 0 < λ ≤ 1).
    n : int
        Number of weights.

    Returns
    -------
    ndarray, shape (n,)
    """
    n = int(n)
    w = np.empty(n)
    if n == 0:
        return w
    w[0] = 1.0
    j = np.arange(1, n, dtype=float)
    w[1:] = np.cumprod(1.0 - (lam + 1.0) / j)
    return w


def gl_derivative(x, dt: float, lam: float) -> np.ndarray:
    """GL fractional derivative (eq. A1) of samples ``x`` at every sample.

    The signal is taken as zero before the first sample (lower terminal at
    the first sample); the sum is exact (an FFT convolution, O(N log N)).

    Parameters
    ----------
    x : array_like
        Samples at ``t_k = k dt``.
    dt : float
        Step [s].
    lam : float
        Order, 0 < λ ≤ 1.

    Returns
    -------
    ndarray
        ``dt^-λ Σ_{j=0..k} w_j x_{k-j}`` for each k.
    """
    from scipy.signal import fftconvolve

    x = np.asarray(x, dtype=float)
    w = gl_weights(_check_lam(lam), len(x))
    return fftconvolve(w, x)[: len(x)] * dt ** (-lam)


def tail_modes(lam: float, K: int = FAST_K, M: int = FAST_M):
    """Geometric modes ``(c, r)`` with ``w_{K+m} ≈ Σ_i c_i r_i^m`` for m ≥ 1.

    The trapezoid rule is applied in x = ln s to the exact integral
    representation of the GL weights (module docstring). The nodes span
    s ∈ [s_lo, s_hi]: above s_hi the integrand is below 1e-17 of its peak for
    every lag > K; below s_lo only lags beyond ~1e9 would feel the cut.

    Parameters
    ----------
    lam : float
        0 < λ < 1 (λ = 1 has no tail: returns empty arrays).
    K : int
        Exact lags.
    M : int
        Number of modes.

    Returns
    -------
    c, r : ndarray, shape (M,)
    """
    lam = _check_lam(lam)
    if lam == 1.0 or M == 0:
        return np.zeros(0), np.zeros(0)
    c, r = np.empty(int(M)), np.empty(int(M))
    _tail_nodes(lam, int(K), int(M), c, r)
    return c, r


@nb.njit(cache=True)
def _tail_nodes(lam, K, M, c, r):
    """The nodes of :func:`tail_modes`, written into c and r.

    Compiled because every model the identification tries builds two sets of
    modes: 163 µs a set as Python loops, 8 µs compiled. libm per node, as numba's math functions are: numpy's
    vectorized exp/log/expm1 differ from libm in the last bit on some CPUs,
    and the native FMUs (C, libm) build the same modes and must match the
    library bit for bit on every machine. The nodes' positions repeat
    numpy.linspace's arithmetic, as the C code does.
    """
    s_hi = 40.0 / (K + 1.0 - lam)
    s_lo = 1e-9
    xlo, xhi = math.log(s_lo), math.log(s_hi)
    A = math.sin(math.pi * lam) / math.pi
    if M > 1:
        step = (xhi - xlo) / (M - 1)
        hx = (1.0 * step + xlo) - (0.0 * step + xlo)
    else:
        step = 0.0
        hx = math.log(s_hi / s_lo)
    for i in range(M):
        x = xhi if (M > 1 and i == M - 1) else i * step + xlo
        s = math.exp(x)
        # (e^s - 1)^λ e^{-s K} computed in logs: e^s overflows for large s
        # only in principle, but expm1 keeps the small-s end accurate.
        logf = lam * math.log(math.expm1(s)) - s * K
        c[i] = -A * hx * s * math.exp(logf)
        r[i] = math.exp(-s)
    # The trapezoid nodes below s_lo, continued to -∞: there (e^s − 1)^λ ≈ s^λ
    # and e^{-s j} ≈ e^{-s_lo j} for every lag j ≪ 1/s_lo, so they sum to a
    # geometric series carried by the lowest node. Dropping it costs about
    # j·s_lo^(1+λ) per lag: 4e-8 of E1 over 1e5 lags at λ = 0.3.
    g = math.exp(-hx * (1.0 + lam))
    c[0] += -A * hx * s_lo ** (1.0 + lam) * g / (1.0 - g)


def tail_error(lam: float, K: int = FAST_K, M: int = FAST_M, horizon: int = E1_HORIZON) -> float:
    """Tail error ``E1 = Σ_{j=K+1}^{K+horizon} |w_j − ŵ_j|`` of the fast engine.

    The history sum of the fast engine differs from the exact one by at most
    ``E1 · dt^-λ · max|x|`` over ``horizon`` steps.
    """
    lam = _check_lam(lam)
    if lam == 1.0:
        return 0.0
    c, r = tail_modes(lam, K, M)
    w = gl_weights(lam, K + horizon + 1)[K + 1:]
    approx = np.zeros(horizon)
    m = np.arange(1, horizon + 1, dtype=float)
    for ci, ri in zip(c, r):
        approx += ci * np.exp(m * math.log(ri))
    return float(np.sum(np.abs(w - approx)))


def oustaloup_ss(lam: float, dt: float, N: int = 5, wb: float = 0.01, wh: float = 1000.0,
                 b: float = 10.0, d: float = 9.0):
    """Discrete state space of FOMCON's refined Oustaloup filter for s^λ.

    ``new_fod``: s^λ ≈ (d·wh/b)^λ · (d s² + b wh s) / (d(1-λ) s² + b wh s + dλ)
    · Π_{k=-N..N} (s + w'_k)/(s + w_k), with
    w'_k = wb μ^((k+N+½−½λ)/(2N+1)), w_k = wb μ^((k+N+½+½λ)/(2N+1)), μ = wh/wb.
    Realized as a cascade of first-order sections and one second-order
    section (well conditioned, unlike a companion form of degree 13), then
    discretized with the bilinear (Tustin) rule.

    Returns
    -------
    A, B, C : ndarray, shapes (m, m), (m,), (m,)
    D : float
        So that ``y_k = C z_k + D x_k`` and ``z_{k+1} = A z_k + B x_k``.
    """
    from scipy.signal import cont2discrete

    lam = _check_lam(lam)
    if lam == 1.0:
        raise ValueError("the Oustaloup filter is not defined for λ = 1 (use the exact derivative)")
    mu = wh / wb
    k = np.arange(-N, N + 1)
    wz = wb * mu ** ((k + N + 0.5 - 0.5 * lam) / (2 * N + 1))
    wp = wb * mu ** ((k + N + 0.5 + 0.5 * lam) / (2 * N + 1))
    gain = (d * wh / b) ** lam
    sections = []
    # (s + z)/(s + p) = 1 + (z - p)/(s + p): A=-p, B=1, C=z-p, D=1
    for z, p in zip(wz, wp):
        sections.append((np.array([[-p]]), np.array([[1.0]]), np.array([[z - p]]), np.array([[1.0]])))
    # (d s^2 + b wh s) / (d(1-λ) s^2 + b wh s + d λ): divide by d(1-λ)
    a2 = d * (1.0 - lam)
    n1, n0 = d / a2, 0.0  # numerator / a2: n1 s^2 + (b wh/a2) s
    nb1 = b * wh / a2
    den1, den0 = b * wh / a2, d * lam / a2
    # proper part: n1 + ((nb1 - n1*den1) s + (0 - n1*den0)) / (s^2 + den1 s + den0)
    Dq = n1
    c1 = nb1 - n1 * den1
    c0 = n0 - n1 * den0
    Aq = np.array([[0.0, 1.0], [-den0, -den1]])
    Bq = np.array([[0.0], [1.0]])
    Cq = np.array([[c0, c1]])
    sections.append((Aq, Bq, Cq, np.array([[Dq]])))
    # series connection: x -> sec1 -> sec2 -> ...
    A, B, C, D = sections[0]
    for A2, B2, C2, D2 in sections[1:]:
        n1_, n2_ = A.shape[0], A2.shape[0]
        A = np.block([[A, np.zeros((n1_, n2_))], [B2 @ C, A2]])
        B = np.vstack([B, B2 @ D])
        C = np.hstack([D2 @ C, C2])
        D = D2 @ D
    C = C * gain
    D = D * gain
    Ad, Bd, Cd, Dd, _ = cont2discrete((A, B, C, D), dt, method="bilinear")
    return Ad, Bd[:, 0].copy(), Cd[0].copy(), float(Dd[0, 0])


#: Leaf block of :func:`blocked_solve`: blocks this short sum their own
#: history terms directly (cheaper than an FFT below a few hundred lags).
EXACT_LEAF = 512


def blocked_solve(w, x, leaf, leaf_size: int = EXACT_LEAF) -> int:
    """Exact GL history sums for a sequence that is solved step by step, in
    O(N log² N) (Hairer, Lubich & Schlichte, SIAM J. Sci. Stat. Comput. 6,
    1985: divide and conquer with FFT convolutions).

    The unknown sequence x_0 … x_{n−1} is produced block by block by
    ``leaf(lo, hi, hist)``; on entry ``hist[k]`` (k in [lo, hi)) holds the
    history terms ``Σ_{j<lo} w[k−j] x_j`` of all finished blocks; the leaf
    adds the terms j in [lo, k) of its own block directly, writes
    ``x[lo:hi]`` and returns the number of steps done so far (``hi`` to go
    on; less stops the run, e.g. at a non-finite value). Between leaves, the contribution of a finished left
    half to its right half is added by one FFT convolution; all halves of
    one size reuse the transform of the same weight segment.

    Parameters
    ----------
    w : ndarray
        Weights by lag, ``w[0]`` unused (the current-sample coefficient is
        the leaf's business); at least ``len(x)`` entries.
    x : ndarray
        The sequence, written by the leaves (its length is the run length).
    leaf : callable
        ``leaf(lo, hi, hist) -> int`` as above.
    leaf_size : int
        Block length summed directly.

    Returns
    -------
    int
        Number of steps completed (n unless a leaf stopped early).
    """
    from scipy import fft as sfft

    n = len(x)
    hist = np.zeros(n)
    size = int(leaf_size)
    while size < n:
        size *= 2
    wspec = {}

    def weights(s):
        if s not in wspec:
            seg = np.zeros(s)
            m = min(s, n)
            seg[1:m] = w[1:m]
            wspec[s] = sfft.rfft(seg)
        return wspec[s]

    def run(lo, s):
        hi = min(lo + s, n)
        if s <= leaf_size:
            return leaf(lo, hi, hist)
        half = s // 2
        mid = lo + half
        done = run(lo, half)
        if done < min(mid, n) or mid >= n:
            return done
        # left half [lo, mid) → right half [mid, hi): lags 1 … s−1; a circular
        # convolution of length s aliases only outputs below `half`
        conv = sfft.irfft(sfft.rfft(x[lo:mid], s) * weights(s), s)
        hist[mid:hi] += conv[half:half + hi - mid]
        return run(mid, half)

    return run(0, size)
