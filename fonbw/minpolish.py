"""Local polish of a jDE optimum with scipy's ``minimize``, in the unit cube.

:class:`fonbw.de.JDESolver` ends with a local refinement of its best point:
L-BFGS-B on central differences (a compiled objective evaluates the 2d + 1
stencil points as one population) or Nelder-Mead, both capped by a hard
budget of evaluations. :mod:`fonbw.gnpolish` is the Gauss-Newton alternative
for least-squares objectives.
"""
from __future__ import annotations

import numpy as np

__all__ = ["minimize_polish"]


class _Spent(Exception):
    """The polish's evaluation budget is used up."""


def minimize_polish(evaluate, z0, f0, method, budget, get_nfev, rtol=None):
    """Local refinement in unit-cube coordinates within ``budget`` evaluations.

    Returns the best (z, f) seen, which is never worse than (z0, f0): every
    evaluated point, finite-difference stencils included, is a candidate.
    With `rtol`, L-BFGS-B stops after an iteration that lowers its cost by
    at most `rtol` times the cost before it. (Dividing the cost by |f0|
    instead, to make ``ftol`` relative, would not do: L-BFGS-B's first step
    is not scale-invariant, its first Cauchy point is x - g.)
    """
    from scipy.optimize import minimize

    d = z0.shape[0]
    start = get_nfev()
    best = [z0.copy(), f0]
    # Step of 1e-6 of the box: central differences then carry ~1e-12 truncation
    # error against ~1e-10 round-off of a simulated cost (relative).
    h = 1e-6

    def consider(Z, f):
        i = int(np.argmin(f))
        if f[i] < best[1]:
            best[0], best[1] = Z[i].copy(), float(f[i])

    def fun_grad(z):
        if get_nfev() - start + 2 * d + 1 > budget:
            raise _Spent
        z = np.clip(z, 0.0, 1.0)
        # Central differences, shifted inward at the bounds.
        zc = np.clip(z, h, 1.0 - h)
        E = np.eye(d) * h
        Z = np.vstack([z[None, :], zc + E, zc - E])
        f = evaluate(Z)
        consider(Z, f)
        if not np.all(np.isfinite(f)):
            # A stencil touching a divergent region: report no descent there.
            return (f[0] if np.isfinite(f[0]) else 1e300), np.zeros(d)
        g = (f[1:d + 1] - f[d + 1:]) / (2.0 * h)
        return f[0], g

    def fun_only(z):
        if get_nfev() - start + 1 > budget:
            raise _Spent
        Z = np.clip(z, 0.0, 1.0)[None, :]
        f = evaluate(Z)
        consider(Z, f)
        return f[0] if np.isfinite(f[0]) else 1e300

    last = [f0]

    def stop_when_flat(intermediate_result):
        f = float(intermediate_result.fun)
        if last[0] - f <= rtol * abs(last[0]):
            raise StopIteration
        last[0] = f

    try:
        if method == "L-BFGS-B":
            minimize(fun_grad, z0, jac=True, method="L-BFGS-B",
                     bounds=[(0.0, 1.0)] * d, callback=None if rtol is None else stop_when_flat,
                     options={"maxfun": budget, "ftol": 1e-15, "gtol": 1e-12})
        else:
            minimize(fun_only, z0, method="Nelder-Mead", bounds=[(0.0, 1.0)] * d,
                     options={"maxfev": budget, "xatol": 1e-10, "fatol": 1e-15,
                              "initial_simplex": _nm_simplex(z0)})
    except _Spent:
        pass
    return best[0], best[1]


def _nm_simplex(z0, step=0.02):
    """A small simplex around z0 inside the unit cube (DE already localized it)."""
    d = z0.shape[0]
    S = np.tile(z0, (d + 1, 1))
    for j in range(d):
        S[j + 1, j] = z0[j] + step if z0[j] + step <= 1.0 else z0[j] - step
    return S
