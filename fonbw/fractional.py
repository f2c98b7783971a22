"""Grünwald–Letnikov fractional derivatives with fixed step and their memory engines.

Every engine evaluates, at step k, the fractional derivative of a sampled
signal in the affine form

    D^λ x_k = a · x_k + h_k                                           (*)

where ``a`` multiplies the current (still unknown) sample and ``h_k`` depends
only on the past. The hysteresis models need this split because eq. (11)
contains the current ħ_k on both sides and is solved for it each step.

Engines (``memory=``):

``exact``
    the full GL sum of eq. (A1) with the weights of eq. (A2): ``a = dt^-λ``,
    ``h_k = dt^-λ Σ_{j=1..k} w_j x_{k-j}``. O(k) per step, O(N²) per run;
    the reference, and the stepper's exact engine. Long batch runs use
    :func:`blocked_solve` instead (Hairer, Lubich & Schlichte 1985): the
    history of a finished block reaches the following block through one FFT
    convolution, O(N log² N) per run, equal to the direct sum to round-off
    (about 1e-13 of the output on the Table-1 model; the hysteresis models
    switch to it from ``EXACT_BLOCKED_MIN`` steps).
``fast``
    the first K lags exactly, the older tail by M geometric modes. For
    0 < λ < 1 and j ≥ 1 the GL weights satisfy exactly

        w_j = -(sin πλ / π) ∫_0^∞ e^{-s j} (e^s - 1)^λ ds,

    and the trapezoid rule in x = ln s turns the integral into
    ``w_{K+m} ≈ Σ_i c_i r_i^m`` with ``0 < r_i = e^{-s_i} < 1`` (the
    backward-Euler case of Banjai & López-Fernández, Numer. Math. 2019). Each
    mode is updated recursively, so a step costs O(K + M) with fixed memory.
    The tail error ``E1 = Σ_{j>K} |w_j − ŵ_j|`` is computed per λ
    (:func:`tail_error`) and bounds the error of the history sum by
    ``E1 · dt^-λ · max|x|``. The nodes span s ∈ [1e-9, 40/(K+1−λ)], and the
    trapezoid nodes below 1e-9 are summed into the lowest one (without that,
    small λ plateau at E1 ≈ 3e-8 over 1e5 lags, whatever M).

    Defaults K = 32, M = 56 (modes are updated eight at a time, so M is a
    multiple of 8). Measured (``benchmarks/bench_memory.py --sweep``): the
    FONBW output with the Table-1 parameters on the eq.-19 input over 1e5
    steps at dt = 1e-4 s differs from the exact engine by at most 8.8e-10
    of max|y| over the grid λ1, λ2 ∈ {0.3, 0.4, …, 0.9, 0.9557, 0.99, 1},
    worst at small λ1 (λ1 = 0.3, λ2 = 0.9); 6.2e-8 with M = 48 and 2.4e-6
    with M = 40. E1 over 1e6 lags is 1.3e-10 at λ = 0.3 and 2.2e-11 at
    λ = 0.622. A step of the whole FONBW model costs about 85 ns, the
    direct full sum about 19 µs at 1e5 steps (BENCHMARKS.md, "Memory
    engines").
``short``
    the short-memory principle: only the last L lags. Kept for comparison
    only: it is inaccurate (about 12 % error at L = 1000 for λ = 0.9), because
    the GL weights decay only like j^(-1-λ).
``oustaloup``
    the refined Oustaloup filter of FOMCON's ``new_fod`` (N = 5, 0.01–1000
    rad/s, b = 10, d = 9: 2N+3 states, constant gain (d·ωh/b)^λ), discretized
    with the bilinear rule at ``dt`` (a zero-order hold is wrong here: the
    filter's gain keeps rising past the Nyquist frequency, so the staircase
    ripple aliases into the output, doubling it near λ = 1). It reproduces the
    paper's toolbox implementation, not the GL derivative: in band its gain is
    about 0.9^λ of |ω|^λ, so it differs from GL by 3–10 %.

λ = 1 is the backward difference whatever the engine (the GL weights beyond
lag 1 vanish), so every model then reduces exactly to backward Euler.

The compiled part is a handful of numba functions operating on plain arrays
(an *operator*, see :class:`FracOp`), shared by the batch simulators, the
population kernels of identification and the per-step steppers of the FMUs.
The same compiled code runs in all of them and no floating-point operation
is reordered by the compiler (no fastmath; the vector loops are written as
explicit SIMD with a fixed summation order), so a stepper and a batch run
give bit-identical numbers.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import numba as nb
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

__all__ = [
    "ENGINES",
    "gl_weights",
    "gl_derivative",
    "tail_modes",
    "tail_error",
    "oustaloup_ss",
    "FracOp",
    "make_op",
    "blocked_solve",
]

ENGINES = ("fast", "exact", "short", "oustaloup")

#: Defaults of the fast engine: exact lags and number of geometric modes.
FAST_K = 32
FAST_M = 56
#: Default window of the short-memory engine.
SHORT_L = 1000
#: Horizon over which :func:`tail_error` sums |w_j − ŵ_j| by default (lags).
E1_HORIZON = 1_000_000

#: Operator kinds of the compiled kernels.
KIND_GL = 0
KIND_OUSTALOUP = 1


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
    s_hi = 40.0 / (K + 1.0 - lam)
    s_lo = 1e-9
    x = np.linspace(math.log(s_lo), math.log(s_hi), M)
    hx = x[1] - x[0] if M > 1 else math.log(s_hi / s_lo)
    s = np.exp(x)
    # (e^s - 1)^λ e^{-s(K)} computed in logs: e^s overflows for large s only in
    # principle, but expm1 keeps the small-s end accurate.
    logf = lam * np.log(np.expm1(s)) - s * K
    q = -(math.sin(math.pi * lam) / math.pi) * hx * s * np.exp(logf)
    # The trapezoid nodes below s_lo, continued to -∞: there (e^s − 1)^λ ≈ s^λ
    # and e^{-s j} ≈ e^{-s_lo j} for every lag j ≪ 1/s_lo, so they sum to a
    # geometric series carried by the lowest node. Dropping it costs about
    # j·s_lo^(1+λ) per lag: 4e-8 of E1 over 1e5 lags at λ = 0.3.
    g = math.exp(-hx * (1.0 + lam))
    q[0] += -(math.sin(math.pi * lam) / math.pi) * hx * s_lo ** (1.0 + lam) * g / (1.0 - g)
    return q, np.exp(-s)


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


@dataclasses.dataclass
class FracOp:
    """Compiled-kernel description of one fractional derivative D^λ at step dt.

    Attributes
    ----------
    kind : int
        ``KIND_GL`` (window of exact weights plus optional geometric modes)
        or ``KIND_OUSTALOUP``.
    a : float
        Coefficient of the current sample in (*).
    w : ndarray
        Scaled weights ``dt^-λ w_j`` for lags j = 1..W (index j-1).
    c, r : ndarray
        Scaled tail modes (``fast``); empty otherwise.
    A, B, C : ndarray
        Oustaloup state space (empty for GL).
    engine : str
    lam : float
    growable : bool
        True for the exact engine in a stepper: the window grows with the run.
    """

    kind: int
    a: float
    w: np.ndarray
    c: np.ndarray
    r: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    engine: str
    lam: float
    dt: float
    growable: bool = False

    @property
    def window(self) -> int:
        return len(self.w)

    @property
    def nz(self) -> int:
        return len(self.r) if self.kind == KIND_GL else len(self.B)

    def grown(self, window: int) -> "FracOp":
        """The same exact-engine operator with a longer window."""
        w = gl_weights(self.lam, window + 1)[1:] * self.dt ** (-self.lam)
        return dataclasses.replace(self, w=w)


_EMPTY = np.zeros(0)
_EMPTY2 = np.zeros((0, 0))


def make_op(lam: float, dt: float, memory: str = "fast", *, n_steps: int | None = None,
            K: int = FAST_K, M: int = FAST_M, L: int = SHORT_L) -> FracOp:
    """Build the operator of D^λ for an engine.

    Parameters
    ----------
    lam : float
        Order, 0 < λ ≤ 1.
    dt : float
        Fixed step [s].
    memory : {"fast", "exact", "short", "oustaloup"}
    n_steps : int, optional
        Known run length (batch): sizes the exact engine's window. Without it
        the exact window starts small and grows (steppers).
    K, M : int
        Fast engine: exact lags and geometric modes.
    L : int
        Short engine: window length.
    """
    lam = _check_lam(lam)
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"step dt must be a positive finite number of seconds, got {dt!r}")
    if memory not in ENGINES:
        raise ValueError(f"unknown memory engine {memory!r}; choose one of {', '.join(ENGINES)}")
    scale = dt ** (-lam)
    if lam == 1.0:
        # Backward difference: exact for every engine.
        return FracOp(KIND_GL, scale, np.array([-scale]), _EMPTY, _EMPTY, _EMPTY2, _EMPTY, _EMPTY,
                      memory, lam, dt)
    if memory == "oustaloup":
        A, B, C, D = oustaloup_ss(lam, dt)
        return FracOp(KIND_OUSTALOUP, D, _EMPTY, _EMPTY, _EMPTY, A, B, C, memory, lam, dt)
    if memory == "exact":
        W = int(n_steps) if n_steps else 1024
        w = gl_weights(lam, W + 1)[1:] * scale
        return FracOp(KIND_GL, scale, w, _EMPTY, _EMPTY, _EMPTY2, _EMPTY, _EMPTY, memory, lam, dt,
                      growable=n_steps is None)
    if memory == "short":
        w = gl_weights(lam, L + 1)[1:] * scale
        return FracOp(KIND_GL, scale, w, _EMPTY, _EMPTY, _EMPTY2, _EMPTY, _EMPTY, memory, lam, dt)
    c, r = tail_modes(lam, K, M)
    w = gl_weights(lam, K + 1)[1:] * scale
    return FracOp(KIND_GL, scale, w, c * scale, r, _EMPTY2, _EMPTY, _EMPTY, memory, lam, dt)


# ---------------------------------------------------------------------------
# Compiled kernels.
#
# An operator is packed into a flat float64 parameter block and a flat state
# block so that a whole model travels to numba as two arrays (cheap dispatch
# per FMU step) and batch, population and per-step code all run the same
# function.
#
# parameter block: [kind, a, W, M, m, w(W), c(M), r(M), A(m*m), B(m), C(m)]
# state block:     [pos, count, hz, buf(2*max(W,1)), z(nz), tmp(m)]
#   nz = M (GL) or m (Oustaloup); tmp (scratch) only for Oustaloup;
#   hz = the modes' part of the history (Σ c_i z_i, or C·z), refreshed by
#   every push, so a history evaluation (several per step in the
#   compensator) only sums the exact window.
#
# The kernels address both blocks through integer offsets (a descriptor
# tuple of plain numbers, :func:`op_desc`), never through array views: a
# tuple of two dozen views pays a reference-count round trip per view each
# time it crosses a call, about 150 ns a model step — more than all the
# arithmetic of the fast engine.

def pack(op: FracOp) -> np.ndarray:
    """Flat parameter block of an operator (see the layout above)."""
    m = len(op.B) if op.kind == KIND_OUSTALOUP else 0
    M = len(op.r)
    head = np.array([op.kind, op.a, op.window, M, m], dtype=float)
    return np.concatenate([head, op.w, op.c, op.r, op.A.ravel() if m else [], op.B if m else [],
                           op.C if m else []])


def state_size(op: FracOp) -> int:
    """Length of an operator's state block (layout above)."""
    extra = op.nz if op.kind == KIND_GL else 2 * op.nz
    return 3 + 2 * max(op.window, 1) + extra


@nb.njit(cache=True, inline="always")
def _sizes(P, o):
    """(W, M, m, parameter-block length, state-block length) of the operator at P[o]."""
    W = int(P[o + 2])
    M = int(P[o + 3])
    m = int(P[o + 4])
    psize = 5 + W + 2 * M + m * m + 2 * m
    ssize = 3 + 2 * max(W, 1) + (M if P[o] == KIND_GL else 2 * m)
    return W, M, m, psize, ssize


#: Index type of the kernels: unsigned, so numba emits no negative-index
#: wraparound (a compare and a select on every access, which also blocks
#: vectorization).
_U = nb.uint64


@nb.njit(cache=True, inline="always")
def op_desc(P, o, q):
    """Descriptor of the operator with parameter block at ``P[o]`` and state
    block at ``S[q]``, built once per run (or once per stepper call).

    Returns ``(kind, W, M, m, ow, oc, orr, oA, oB, oC, q, qb, qz, a, Wf)``:
    sizes, offsets of w, c, r, A, B, C in P, of the counters, ring buffer and
    modes in S (all unsigned), the coefficient ``a`` of the current sample in
    (*), and W as a float (for comparing with the float counter). The ring holds the newest sample at ``qb + pos`` and lag j at
    ``qb + pos + j − 1`` with a mirrored copy behind, so the window is always
    contiguous.
    """
    W, M, m, _, _ = _sizes(P, o)
    ow = o + 5
    oc = ow + W
    orr = oc + M
    oA = orr + M
    oB = oA + m * m
    oC = oB + m
    qb = q + 3
    qz = qb + 2 * max(W, 1)
    return (int(P[o]), _U(W), _U(M), _U(m), _U(ow), _U(oc), _U(orr), _U(oA), _U(oB), _U(oC),
            _U(q), _U(qb), _U(qz), P[o + 1], float(W))


# Explicit SIMD for the two inner loops. Without fastmath LLVM vectorizes no
# floating-point reduction (it may not reassociate), and fastmath would let
# the summation order depend on where the compiler inlines the loop, which
# would break the bit-identity of stepper and batch runs. These intrinsics
# emit the vector IR directly: eight lane accumulators (two <4 x double>),
# lane t summing the terms j ≡ t (mod 8), combined in a fixed tree. Every
# operation is a plain IEEE add or multiply (no contraction into fma), so the
# result is the same wherever it is inlined, with or without AVX.

_F64 = ir.DoubleType()
_V4 = ir.VectorType(_F64, 4)
_V4ZERO = ir.Constant(_V4, [ir.Constant(_F64, 0.0)] * 4)


def _v4ptr(builder, base, off):
    return builder.bitcast(builder.gep(base, [off]), _V4.as_pointer())


def _lanes_sum(builder, v0, v1):
    """((s0+s1)+(s2+s3)) + ((s4+s5)+(s6+s7)) of the lanes of v0 ‖ v1."""
    s = [builder.extract_element(v, ir.Constant(ir.IntType(32), t)) for v in (v0, v1) for t in range(4)]
    return builder.fadd(builder.fadd(builder.fadd(s[0], s[1]), builder.fadd(s[2], s[3])),
                        builder.fadd(builder.fadd(s[4], s[5]), builder.fadd(s[6], s[7])))


@intrinsic
def _vdot8(typingctx, a, ao, b, bo, nblk):
    """Σ_{j<8·nblk} a[ao+j] b[bo+j] in eight lanes (see above); unsigned offsets."""
    sig = types.float64(a, ao, b, bo, nblk)

    def codegen(context, builder, signature, args):
        av, ao_, bv, bo_, n_ = args
        pa = builder.gep(context.make_array(signature.args[0])(context, builder, av).data, [ao_])
        pb = builder.gep(context.make_array(signature.args[2])(context, builder, bv).data, [bo_])
        acc0 = cgutils.alloca_once_value(builder, _V4ZERO)
        acc1 = cgutils.alloca_once_value(builder, _V4ZERO)
        i64 = n_.type
        with cgutils.for_range(builder, n_) as loop:
            o0 = builder.shl(loop.index, ir.Constant(i64, 3))
            o1 = builder.add(o0, ir.Constant(i64, 4))
            p0 = builder.fmul(builder.load(_v4ptr(builder, pa, o0), align=8),
                              builder.load(_v4ptr(builder, pb, o0), align=8))
            p1 = builder.fmul(builder.load(_v4ptr(builder, pa, o1), align=8),
                              builder.load(_v4ptr(builder, pb, o1), align=8))
            builder.store(builder.fadd(builder.load(acc0), p0), acc0)
            builder.store(builder.fadd(builder.load(acc1), p1), acc1)
        return _lanes_sum(builder, builder.load(acc0), builder.load(acc1))

    return sig, codegen


@intrinsic
def _vmodes8(typingctx, P, oc, orr, S, qz, nblk, old):
    """For i < 8·nblk: z_i ← r_i (z_i + old) (z at S[qz+i], r at P[orr+i]);
    returns Σ c_i z_i (c at P[oc+i]) in eight lanes (see above)."""
    sig = types.float64(P, oc, orr, S, qz, nblk, old)

    def codegen(context, builder, signature, args):
        Pv, oc_, or_, Sv, qz_, n_, old_ = args
        pdata = context.make_array(signature.args[0])(context, builder, Pv).data
        pc = builder.gep(pdata, [oc_])
        pr = builder.gep(pdata, [or_])
        pz = builder.gep(context.make_array(signature.args[3])(context, builder, Sv).data, [qz_])
        vold = cgutils.alloca_once_value(builder, _V4ZERO)
        v = builder.load(vold)
        for t in range(4):
            v = builder.insert_element(v, old_, ir.Constant(ir.IntType(32), t))
        acc0 = cgutils.alloca_once_value(builder, _V4ZERO)
        acc1 = cgutils.alloca_once_value(builder, _V4ZERO)
        i64 = n_.type
        with cgutils.for_range(builder, n_) as loop:
            for acc, k in ((acc0, 0), (acc1, 4)):
                o = builder.add(builder.shl(loop.index, ir.Constant(i64, 3)), ir.Constant(i64, k))
                zp = _v4ptr(builder, pz, o)
                z = builder.fmul(builder.load(_v4ptr(builder, pr, o), align=8),
                                 builder.fadd(builder.load(zp, align=8), v))
                builder.store(z, zp, align=8)
                builder.store(builder.fadd(builder.load(acc),
                                           builder.fmul(builder.load(_v4ptr(builder, pc, o), align=8), z)), acc)
        return _lanes_sum(builder, builder.load(acc0), builder.load(acc1))

    return sig, codegen


@nb.njit(cache=True, inline="always")
def _dot_off(a, ao, b, bo, n):
    """Σ_{j<n} a[ao+j] b[bo+j] (unsigned offsets): blocks of eight by
    :func:`_vdot8`, then the remainder in order."""
    nb8 = n >> _U(3)
    s = _vdot8(a, ao, b, bo, nb8) if nb8 > _U(0) else 0.0
    j = nb8 << _U(3)
    while j < n:
        s += a[ao + j] * b[bo + j]
        j += _U(1)
    return s


@nb.njit(cache=True, inline="always")
def _modes_push(P, oc, orr, S, qz, M, old):
    """z_i ← r_i (z_i + old) for the M modes; returns the new Σ c_i z_i
    (blocks of eight by :func:`_vmodes8`, then the remainder in order)."""
    nb8 = M >> _U(3)
    s = _vmodes8(P, oc, orr, S, qz, nb8, old)
    i = nb8 << _U(3)
    while i < M:
        z = P[orr + i] * (S[qz + i] + old)
        s += P[oc + i] * z
        S[qz + i] = z
        i += _U(1)
    return s


@nb.njit(cache=True, inline="always")
def op_history(P, S, d):
    """History part h_k of (*) from the state before step k (descriptor ``d``)."""
    kind, W, M, m, ow, oc, orr, oA, oB, oC, q, qb, qz, a, Wf = d
    if kind == KIND_GL:
        # the counters are floats in S (one state array); they are converted
        # through int64, which is one instruction, unlike float <-> uint64
        cnt = S[q + _U(1)]
        n = W if cnt >= Wf else _U(int(cnt))
        return _dot_off(P, ow, S, qb + _U(int(S[q])), n) + S[q + _U(2)]
    return S[q + _U(2)]


@nb.njit(cache=True, inline="always")
def op_push(P, S, d, x):
    """Advance the operator's state with the sample x_k (descriptor ``d``)."""
    kind, W, M, m, ow, oc, orr, oA, oB, oC, q, qb, qz, a, Wf = d
    if kind == KIND_GL:
        pos = _U(int(S[q]))
        if pos == _U(0):
            pos = W
        pos -= _U(1)
        if M > _U(0):
            # S[qb+pos] still holds lag W, the sample leaving the exact window
            S[q + _U(2)] = _modes_push(P, oc, orr, S, qz, M, S[qb + pos])
        S[qb + pos] = x
        S[qb + pos + W] = x
        S[q] = float(nb.int64(pos))
    else:
        qt = qz + m  # scratch: z ← A z + B x needs the old z throughout
        for i in range(m):
            S[qt + i] = P[oB + i] * x + _dot_off(P, oA + i * m, S, qz, m)
        for i in range(m):
            S[qz + i] = S[qt + i]
        S[q + _U(2)] = _dot_off(P, oC, S, qz, m)
    S[q + _U(1)] += 1.0


@nb.njit(cache=True)
def _apply_op(P, x):
    out = np.empty(x.shape[0])
    _, _, _, _, ss = _sizes(P, 0)
    S = np.zeros(ss)
    d = op_desc(P, 0, 0)
    a = d[13]
    for k in range(x.shape[0]):
        out[k] = a * x[k] + op_history(P, S, d)
        op_push(P, S, d, x[k])
    return out


def apply_op(op: FracOp, x) -> np.ndarray:
    """Run an operator over a whole explicit signal (zero before the first sample)."""
    x = np.ascontiguousarray(x, dtype=float)
    if op.growable and len(x) > op.window:
        op = op.grown(len(x))
    return _apply_op(pack(op), x)
