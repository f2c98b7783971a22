"""Bounded linear least squares on tall, narrow designs.

The reference hysteresis' weights (:mod:`fonbw.gap.reference`) are solved
thousands of times per diagnosis on designs of ~10⁵ rows and ~10² columns.
The columns are scaled to unit norm and reduced to a p x p triangular factor,
so the bounded solve (BVLS) costs nothing next to building the design.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

from .blas import single_thread

__all__ = ["bounded_lstsq"]

#: Largest ratio of the Gram-Cholesky factor's diagonal for which the normal
#: equations are trusted (about cond(Φ); squared it must stay well inside 1e16).
GRAM_COND = 1e4


def bounded_lstsq(Phi, y, lo, hi) -> tuple:
    """Solve y ≈ Φ c with lo ≤ c ≤ hi; returns (c, residual sum of squares).

    The factor comes from the Cholesky decomposition of the Gram matrix,
    with one step of iterative refinement on the free weights, when that is
    well conditioned; otherwise (nearly collinear columns, e.g. plays that
    barely move) from a blocked QR of [Φ y], which loses only cond(Φ), not
    cond(Φ)², digits.

    Parameters
    ----------
    Phi : ndarray, shape (n, p)
    y : ndarray, shape (n,)
    lo, hi : ndarray, shape (p,)
        Bounds of c (±inf for none), in the units of c.
    """
    Phi = np.asarray(Phi, dtype=float)
    y = np.asarray(y, dtype=float)
    p = Phi.shape[1]
    s = np.linalg.norm(Phi, axis=0)
    s[s == 0] = 1.0
    A = Phi / s
    # bounds on c are bounds on c·s of the scaled columns
    lo, hi = np.asarray(lo, dtype=float) * s, np.asarray(hi, dtype=float) * s
    G = A.T @ A
    try:
        R = np.linalg.cholesky(G).T
        d = np.abs(np.diag(R))
        gram = d.min() * GRAM_COND > d.max()
    except np.linalg.LinAlgError:
        gram = False
    if gram:
        b = np.linalg.solve(R.T, A.T @ y)
    else:
        Rb = _tsqr(np.column_stack([A, y]))
        R, b = Rb[:p, :p], Rb[:p, p]
    # BVLS may leave a weight on its bound off by round-off; a p x p
    # problem runs on one BLAS thread (the same numbers, see fonbw.gap.blas)
    with single_thread():
        c = np.maximum(lsq_linear(R, b, bounds=(lo, hi), method="bvls", tol=1e-12).x, lo)
    e = y - A @ c
    rss = float(e @ e)
    free = (c > lo) | ~np.isfinite(lo)
    if gram and np.any(free):
        c2 = c.copy()
        c2[free] = np.maximum(c[free] + np.linalg.solve(G[np.ix_(free, free)], A[:, free].T @ e), lo[free])
        e2 = y - A @ c2
        if e2 @ e2 <= rss:
            c, rss = c2, float(e2 @ e2)
    return c / s, rss


def _tsqr(A, chunk=2048):
    # QR by row blocks: the same R (up to signs), several times faster than one
    # LAPACK call on a tall, narrow matrix (better cache use). One BLAS
    # thread: the blocks are small, and a second thread gave the same R
    # at 20 times the wall time on a busy machine (fonbw.gap.blas)
    with single_thread():
        Rs = [np.linalg.qr(A[i:i + chunk], mode="r") for i in range(0, A.shape[0], chunk)]
        return np.linalg.qr(np.vstack(Rs), mode="r")
