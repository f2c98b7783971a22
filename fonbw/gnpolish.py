"""Gauss-Newton polish of an identification: the local refinement after DE.

Eq. (18) is a root mean square of residuals, and with the linear parameters
solved (:class:`fonbw.objective.Projected`) the residual vector of a search
point is at hand. A trust-region Gauss-Newton step (scipy's ``least_squares``,
method "trf", box [0, 1] in the unit-cube coordinates of the search) needs one
forward-difference Jacobian per iteration, d evaluations simulated as one
population, and converges in a few iterations where a quasi-Newton polish on
the RMS value alone (central differences, 2d + 1 evaluations a step) takes
tens. On the eq.-(19) FONBW record at 5 kHz the L-BFGS-B polish spent its
whole budget of 450 evaluations from DE's basin to the noise floor; this one
gets there in a few tens, and what it leaves goes back to DE
(:meth:`fonbw.de.JDESolver.resume`).
"""
from __future__ import annotations

import numpy as np

__all__ = ["gauss_newton_polish"]

#: Forward-difference step in the unit cube (as the L-BFGS-B polish's 1e-6).
STEP = 1e-6
#: What a non-finite residual (a divergent simulation) counts as.
DIVERGED = 1e150


class _Spent(Exception):
    """The polish's evaluation budget is used up."""


def gauss_newton_polish(proj, box):
    """A polish callable for :func:`fonbw.de.jde_minimize` on a projected objective.

    Parameters
    ----------
    proj : fonbw.objective.Projected
        The projected objective: ``proj(X)`` costs [µm] and
        ``proj.residuals(X)`` residual vectors of search points X (natural units).
    box : fonbw.de._Space
        The search's map between the unit cube and natural units (the same
        bounds and log flags as the DE run).

    Returns
    -------
    callable
        ``polish(z0, f0, budget) -> (z, f, nfev)``: unit-cube point, its cost
        (eq. 18 as ``proj`` computes it, never above `f0`) and evaluations used.
    """
    def polish(z0, f0, budget):
        from scipy.optimize import least_squares

        d, used = z0.size, [0]
        z0 = np.asarray(z0, dtype=float)
        cand = [z0.copy(), np.inf]  # least residual norm seen (RMS [µm])
        last = {}
        scale = 1.0 / np.sqrt(proj.M)  # Σ (r scale)² = J², eq. (18) squared

        def residuals(Z, n):
            # one evaluation is kept back for the final check below
            if used[0] + n > budget - 1:
                raise _Spent
            used[0] += n
            with np.errstate(over="ignore", invalid="ignore"):
                R = proj.residuals(box.to_natural(Z)) * scale
            return np.where(np.isfinite(R), R, DIVERGED)

        def fun(z):
            z = np.clip(z, 0.0, 1.0)
            r = residuals(z[None, :], 1)[0]
            last["z"], last["r"] = z.copy(), r
            J = float(np.sqrt(r @ r))
            if J < cand[1]:
                cand[0], cand[1] = z.copy(), J
            return r

        def jac(z):
            z = np.clip(z, 0.0, 1.0)
            r0 = last["r"] if "z" in last and np.array_equal(last["z"], z) else fun(z)
            # forward steps, turned inward at the upper bound
            h = np.where(z + STEP <= 1.0, STEP, -STEP)
            R = residuals(z[None, :] + np.diag(h), d)
            # a step into a divergent region (non-finite residuals): step the other way
            back = np.any(R >= DIVERGED, axis=1) & (h > 0) & (z - STEP >= 0.0)
            if back.any():
                h[back] = -STEP
                R[back] = residuals(z[None, :] + np.diag(h)[back], int(back.sum()))
            return ((R - r0[None, :]) / h[:, None]).T

        try:
            # a trial step into a divergent region overflows scipy's reduction ratio: it
            # is rejected all the same, so say nothing
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                least_squares(fun, z0, jac=jac, bounds=(0.0, 1.0), method="trf", x_scale="jac",
                              xtol=1e-10, ftol=1e-12, gtol=1e-12, max_nfev=max(1, budget))
        except _Spent:
            pass
        except (ValueError, np.linalg.LinAlgError):
            # a Jacobian across a divergent region (residuals replaced by 1e150) can
            # overflow trf's scaling into inf/NaN: keep the best point seen so far
            pass
        if not np.isfinite(cand[1]) or np.array_equal(cand[0], z0):
            return z0, float(f0), used[0]
        # The point's cost through the objective itself, with its guard against
        # cancelling gains (the residuals leave it out).
        f = float(proj(box.to_natural(cand[0][None, :]))[0])
        used[0] += 1
        if np.isfinite(f) and f < f0:
            return cand[0], f, used[0]
        return z0, float(f0), used[0]

    return polish
