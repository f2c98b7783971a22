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
    ``h_k = dt^-λ Σ_{j=1..k} w_j x_{k-j}``. O(k) per step; the reference.
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
    ``E1 · dt^-λ · max|x|``.
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
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import numba as nb

__all__ = [
    "ENGINES",
    "gl_weights",
    "gl_derivative",
    "tail_modes",
    "tail_error",
    "oustaloup_ss",
    "FracOp",
    "make_op",
]

ENGINES = ("fast", "exact", "short", "oustaloup")

#: Defaults of the fast engine: exact lags and number of geometric modes.
FAST_K = 32
FAST_M = 48
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
    hx = x[1] - x[0]
    s = np.exp(x)
    # (e^s - 1)^λ e^{-s(K)} computed in logs: e^s overflows for large s only in
    # principle, but expm1 keeps the small-s end accurate.
    logf = lam * np.log(np.expm1(s)) - s * K
    q = -(math.sin(math.pi * lam) / math.pi) * hx * s * np.exp(logf)
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
# state block:     [pos, count, buf(2*max(W,1)), z(nz)]   nz = M (GL) or m (Oustaloup)

def pack(op: FracOp) -> np.ndarray:
    """Flat parameter block of an operator (see the layout above)."""
    m = len(op.B) if op.kind == KIND_OUSTALOUP else 0
    M = len(op.r)
    head = np.array([op.kind, op.a, op.window, M, m], dtype=float)
    return np.concatenate([head, op.w, op.c, op.r, op.A.ravel() if m else [], op.B if m else [],
                           op.C if m else []])


def state_size(op: FracOp) -> int:
    return 2 + 2 * max(op.window, 1) + op.nz


@nb.njit(cache=True)
def _sizes(P, o):
    W = int(P[o + 2])
    M = int(P[o + 3])
    m = int(P[o + 4])
    psize = 5 + W + 2 * M + m * m + 2 * m
    ssize = 2 + 2 * max(W, 1) + (M if P[o] == KIND_GL else m)
    return W, M, m, psize, ssize


@nb.njit(cache=True, inline="always")
def _dot_at(a, b, off, n):
    """Σ_{j<n} a_j b_{off+j} (see :func:`_dot`; no slice is built: in the
    hot path building a slice costs more than a short window)."""
    h0 = 0.0
    h1 = 0.0
    h2 = 0.0
    h3 = 0.0
    j = 0
    while j + 3 < n:
        h0 += a[j] * b[off + j]
        h1 += a[j + 1] * b[off + j + 1]
        h2 += a[j + 2] * b[off + j + 2]
        h3 += a[j + 3] * b[off + j + 3]
        j += 4
    while j < n:
        h0 += a[j] * b[off + j]
        j += 1
    return (h0 + h1) + (h2 + h3)


@nb.njit(cache=True, inline="always")
def _dot(a, b, n):
    """Σ_{j<n} a_j b_j with four accumulators (no fastmath: results must not
    depend on where the compiler inlines this; four chains still break the
    add latency)."""
    h0 = 0.0
    h1 = 0.0
    h2 = 0.0
    h3 = 0.0
    j = 0
    while j + 3 < n:
        h0 += a[j] * b[j]
        h1 += a[j + 1] * b[j + 1]
        h2 += a[j + 2] * b[j + 2]
        h3 += a[j + 3] * b[j + 3]
        j += 4
    while j < n:
        h0 += a[j] * b[j]
        j += 1
    return (h0 + h1) + (h2 + h3)


@nb.njit(cache=True, inline="always")
def op_views(P, o, S, q):
    """Views of one operator's blocks, built once per run (slicing per step
    costs more than the arithmetic of a short window).

    Returns ``(kind, a, W, w, c, r, A, B, C, ctr, buf, z)``; ``ctr = [pos,
    count]``. The ring holds the newest sample at ``pos`` and lag j at
    ``pos + j − 1`` with a mirrored copy behind, so the window is the
    contiguous slice ``buf[pos:pos+W]``.
    """
    W, M, m, _, _ = _sizes(P, o)
    Wb = max(W, 1)
    zo = q + 2 + 2 * Wb
    w = P[o + 5:o + 5 + W]
    c = P[o + 5 + W:o + 5 + W + M]
    r = P[o + 5 + W + M:o + 5 + W + 2 * M]
    Ao = o + 5 + W + 2 * M
    A = P[Ao:Ao + m * m].reshape((m, m))
    B = P[Ao + m * m:Ao + m * m + m]
    C = P[Ao + m * m + m:Ao + m * m + 2 * m]
    nz = M if P[o] == KIND_GL else m
    return (int(P[o]), P[o + 1], W, w, c, r, A, B, C, S[q:q + 2], S[q + 2:q + 2 + 2 * Wb], S[zo:zo + nz])


@nb.njit(cache=True, inline="always")
def op_history(v):
    """History part h_k of (*) from the state before step k (views ``v``)."""
    kind, a, W, w, c, r, A, B, C, ctr, buf, z = v
    if kind == KIND_GL:
        pos = int(ctr[0])
        cnt = int(ctr[1])
        n = W if cnt > W else cnt
        h = _dot_at(w, buf, pos, n)
        if c.shape[0] > 0:
            h += _dot(c, z, c.shape[0])
        return h
    return _dot(C, z, C.shape[0])


@nb.njit(cache=True, inline="always")
def _modes(r, z, old):
    for i in range(r.shape[0]):
        z[i] = r[i] * (z[i] + old)


@nb.njit(cache=True, inline="always")
def op_push(v, x):
    """Advance the operator's state with the sample x_k (views ``v``)."""
    kind, a, W, w, c, r, A, B, C, ctr, buf, z = v
    if kind == KIND_GL:
        pos = int(ctr[0]) - 1
        if pos < 0:
            pos = W - 1
        if r.shape[0] > 0:
            # buf[pos] still holds lag W, the sample leaving the exact window
            _modes(r, z, buf[pos])
        buf[pos] = x
        buf[pos + W] = x
        ctr[0] = pos
    else:
        m = B.shape[0]
        tmp = np.empty(m)
        for i in range(m):
            tmp[i] = B[i] * x + _dot(A[i], z, m)
        z[:] = tmp
    ctr[1] += 1.0


@nb.njit(cache=True)
def _apply_op(P, x):
    out = np.empty(x.shape[0])
    _, _, _, _, ss = _sizes(P, 0)
    S = np.zeros(ss)
    v = op_views(P, 0, S, 0)
    a = P[1]
    for k in range(x.shape[0]):
        out[k] = a * x[k] + op_history(v)
        op_push(v, x[k])
    return out


def apply_op(op: FracOp, x) -> np.ndarray:
    """Run an operator over a whole explicit signal (zero before the first sample)."""
    x = np.ascontiguousarray(x, dtype=float)
    if op.growable and len(x) > op.window:
        op = op.grown(len(x))
    return _apply_op(pack(op), x)
