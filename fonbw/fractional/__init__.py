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

Modules: :mod:`~fonbw.fractional.weights` (GL weights, the fast engine's
tail modes and error, the Oustaloup filter, the blocked FFT solve),
:mod:`~fonbw.fractional.operators` (:class:`FracOp`, :func:`make_op` and the
packed layout) and :mod:`~fonbw.fractional.kernels` (the compiled history
sums and their SIMD intrinsics). This package re-exports the names other
modules use, so ``fonbw.fractional.X`` works for each of them.
"""
from __future__ import annotations

from .kernels import (  # noqa: F401
    _U,
    _apply_op,
    _dot_off,
    _modes_push,
    _sizes,
    apply_op,
    op_desc,
    op_history,
    op_push,
)
from .operators import KIND_GL, KIND_OUSTALOUP, FracOp, make_op, pack, state_size  # noqa: F401
from .weights import (  # noqa: F401
    E1_HORIZON,
    ENGINES,
    EXACT_LEAF,
    FAST_K,
    FAST_M,
    SHORT_L,
    _check_lam,
    blocked_solve,
    gl_derivative,
    gl_weights,
    oustaloup_ss,
    tail_error,
    tail_modes,
)

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
