"""Compiled arithmetic of the stroke-saturation block: its softplus knee and
the Gauss-Newton fit that the block's output nonlinearity needs.

The saturation block (:class:`fonbw.gap.limits.Saturation`) bends the
model's own output, y = z + c f(z) with z = B b, so every evaluation of a
candidate with it solves a small nonlinear least-squares problem by
Gauss-Newton (:meth:`fonbw.gap.fitter.Fitter.fit_linear`). Written with numpy
that solve took three quarters of such a candidate's time: each step built
the Jacobian column by column and evaluated two transcendental functions
(``logaddexp`` and ``tanh``) over every sample in separate passes. Here one
pass gives the residual, f and f' (one ``exp`` and one ``log1p`` a sample:
the slope 1/(1 + e^−s) shares the exponential of the softplus) and the
normal equations are summed a block of samples at a time, never with the
whole Jacobian in memory.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from .blas import single_thread

__all__ = ["softplus", "residual", "normal_equations", "Steps"]

# Below 2^−54 (|s| > 37.4) the correction log1p(e) − e ≈ −e²/2 is under half
# an ulp of e, so log1p would return e itself: the call is skipped there.
_TINY = 2.0 ** -54
# Samples per block of the normal equations (the block's Jacobian, 1024 x (q + 1)
# values, stays in cache).
_BLOCK = 1024


@nb.njit(cache=True)
def _knee(s):
    """(softplus(s), d softplus/ds) of one sample, from one exponential."""
    e = math.exp(-abs(s))
    l1 = e if e < _TINY else math.log1p(e)
    if s >= 0.0:
        return s + l1, 1.0 / (1.0 + e)
    return l1, e / (1.0 + e)


@nb.njit(cache=True)
def _softplus(z, knee, w, f, df):
    for i in range(z.size):
        a, d = _knee((z[i] - knee) / w)
        f[i] = w * a
        df[i] = d


def softplus(z, knee, w):
    """f(z) = w softplus((z − knee)/w) and its slope f'(z), both like `z`.

    Parameters
    ----------
    z : array_like
        Displacement [µm].
    knee, w : float
        Knee y_k and corner width [µm], w > 0.
    """
    z = np.ascontiguousarray(z, dtype=float)
    f, df = np.empty_like(z), np.empty_like(z)
    _softplus(z.reshape(-1), float(knee), float(w), f.reshape(-1), df.reshape(-1))
    return f, df


@nb.njit(cache=True)
def _residual(B, b, y, knee, w, r, f, df):
    n, q = B.shape
    c = b[q]
    # z = B b a column at a time: contiguous passes over column-major B (the
    # sum per sample across it was half the time), the same sums in the same
    # order as before, and no BLAS call (see normal_equations).
    zs = np.zeros(n)
    for j in range(q):
        bj = b[j]
        for i in range(n):
            zs[i] += B[i, j] * bj
    sse = 0.0
    for i in range(n):
        z = zs[i]
        a, d = _knee((z - knee) / w)
        f[i] = w * a
        df[i] = d
        ri = y[i] - (z + c * f[i])
        r[i] = ri
        sse += ri * ri
    return sse


def residual(B, b, y, knee, w, r, f, df):
    """Residual of y ≈ z + c f(z), z = B b[:-1], c = b[-1], into `r` (with f and
    f' into `f`, `df`); returns the sum of its squares [µm²]."""
    return _residual(B, b, y, float(knee), float(w), r, f, df)


# The Jacobian is made a block of samples at a time, in cache, and each
# block's JᵀJ and Jᵀr are matrix products (BLAS): the entries summed one by
# one in compiled loops took almost twice as long with 25 base columns.
@nb.njit(cache=True)
def _normal(B, c, df, f, r, G, g):
    n, q = B.shape
    G[:, :] = 0.0
    g[:] = 0.0
    J = np.empty((_BLOCK, q + 1))
    for i0 in range(0, n, _BLOCK):
        m = min(_BLOCK, n - i0)
        for i in range(m):
            a = 1.0 + c * df[i0 + i]
            for j in range(q):
                J[i, j] = B[i0 + i, j] * a
            J[i, q] = f[i0 + i]
        Jm = J[:m]
        G += np.dot(Jm.T, Jm)
        g += np.dot(Jm.T, r[i0:i0 + m])


def normal_equations(B, c, df, f, r):
    """JᵀJ and Jᵀr of the Gauss-Newton Jacobian J = [(1 + c f') B, f] (q + 1 columns)."""
    q = B.shape[1]
    G, g = np.empty((q + 1, q + 1)), np.empty(q + 1)
    # numba's np.dot calls scipy's OpenBLAS, a thread pool of its own beside
    # numpy's; with two threads each on two cores their spinning threads made
    # the whole fit 1.5 times slower. One thread also keeps the sums the same
    # in every process.
    with single_thread():
        _normal(B, float(c), df, f, r, G, g)
    return G, g


class Steps:
    """The Gauss-Newton problem of an output nonlinearity on the model's own
    output, ``y ≈ z + c f(z)``, ``z = A[:, :-1] b[:-1]`` (:meth:`fonbw.gap.fitter.Fitter.fit_linear`):
    compiled residual and normal equations (this module)."""

    def __init__(self, A, y, outer):
        self.e, self.th = outer
        # column-major, so that each entry of the normal equations is one
        # pass over two contiguous columns (_normal)
        self.B = np.asfortranarray(A[:, :-1])
        self.y = np.ascontiguousarray(y, dtype=float)

    def buffers(self):
        """(r, f, f') of one evaluation."""
        return np.empty_like(self.y), np.empty_like(self.y), np.empty_like(self.y)

    def residual(self, b, into):
        r, f, df = into
        return self.e.residual(self.B, b, self.y, self.th, r, f, df)

    def normal(self, b, state):
        r, f, df = state
        return normal_equations(self.B, b[-1], df, f, r)

    def off(self, solve):
        """The fit with the block off (c = 0): the rest's plain least squares."""
        b0, r0 = solve(self.B, self.y)
        return (None, None) if b0 is None else (np.r_[b0, 0.0], r0)
