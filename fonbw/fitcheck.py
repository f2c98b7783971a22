"""How well the data determine an identified model's parameters.

After the search, :func:`parameter_check` looks at each search variable of
:mod:`fonbw.identify` (the nonlinear parameters; the linear ones are solved
for each candidate):

* at a bound: within 0.1 % of the search range of its lower or upper bound,
  so the data pushed it there and the optimum may lie outside the range;
* its interval from the local curvature of eq. (18): the Gauss-Newton
  Hessian JᵀJ of the projected residual (the residual with the linear
  parameters solved, so they follow each change) by central differences. The
  interval is where, to second order, the training RMS error rises by less
  than :data:`RMS_RISE` (1 %) with the other variables re-optimized. A
  statistical 95 % interval would need independent errors; a model's errors
  are correlated over whole cycles, so this tolerance interval (the 95 %
  interval for about 190 independent errors) says more;
* poorly determined: its interval spans more than a decade (a variable
  searched on a log scale) or more than half its search range (a linear one),
  or the curvature along it is nil.
"""
from __future__ import annotations

import numpy as np

__all__ = ["parameter_check", "BOUND_TOL", "RMS_RISE"]

#: Share of the search range within which a variable counts as at its bound.
BOUND_TOL = 1e-3
#: Relative rise of the training RMS error that bounds a parameter's interval.
RMS_RISE = 0.01
#: Central-difference step in the unit-cube coordinates of the search.
STEP = 1e-3


def parameter_check(proj, x) -> tuple[dict, list]:
    """Intervals and warnings for the search variables at the optimum `x`.

    Parameters
    ----------
    proj : fonbw.objective.Projected
        The projected objective of the identification.
    x : ndarray, shape (d,)
        Best search vector (natural units).

    Returns
    -------
    intervals : dict
        ``{name: (lo, hi)}`` intervals of a 1 % rise of the RMS error (natural units;
        ``(nan, nan)`` when the curvature is nil).
    warnings : list of str
        One sentence per variable at a bound or poorly determined.
    """
    from .de import _Space

    space = proj.space
    box = _Space(space.bounds, space.log_scale)
    z = box.to_unit(np.asarray(x, dtype=float)[None, :])[0]
    half = _half_widths(proj, box, z)
    intervals, warns = {}, []
    for j, name in enumerate(space.names):
        lo_b, hi_b = space.bounds[j]
        val = float(x[j])
        if hi_b > lo_b and (z[j] <= BOUND_TOL or z[j] >= 1 - BOUND_TOL):
            side = "lower" if z[j] <= BOUND_TOL else "upper"
            warns.append(f"{name} = {val:.4g} is at the {side} bound of its search range [{lo_b:.4g}, {hi_b:.4g}]: "
                         "the data push it there, so the model may extrapolate poorly")
        if not hi_b > lo_b:
            intervals[name] = (val, val)  # fixed by the caller's bounds
            continue
        w = half[j] * box.span[j]  # half-width in log10|x| (log scale) or in x
        if not np.isfinite(w):
            intervals[name] = (float("nan"), float("nan"))
            warns.append(f"{name} = {val:.4g} is not determined by the data (no curvature of the error along it)")
            continue
        if box.log[j]:
            w = min(w, 300.0)  # beyond that the interval is (0, inf) anyway
            intervals[name] = (float(val / 10 ** w), float(val * 10 ** w))
            bad = 2 * w > 1.0
            spread = f"spans {2 * w:.2g} decades"
        else:
            intervals[name] = (float(val - w), float(val + w))
            bad = 2 * w > 0.5 * (hi_b - lo_b)
            spread = f"is wider than half the search range [{lo_b:.4g}, {hi_b:.4g}]"
        if bad:
            a, b = intervals[name]
            warns.append(f"{name} = {val:.4g} is poorly determined: over [{a:.3g}, {b:.3g}] the training "
                         f"RMS error changes by less than {100 * RMS_RISE:g} % (the interval {spread})")
    return intervals, warns


def _half_widths(proj, box, z) -> np.ndarray:
    """Half-widths in unit-cube coordinates (inf along flat directions)."""
    d = z.size
    Z = np.repeat(z[None, :], 2 * d, axis=0)
    steps = np.empty(d)
    for j in range(d):
        # one-sided room at a bound: the difference stays inside the box
        up, down = min(STEP, 1 - z[j]), min(STEP, z[j])
        Z[2 * j, j] += up
        Z[2 * j + 1, j] -= down
        steps[j] = up + down
    R = proj.residuals(box.to_natural(Z))
    r0 = proj.residuals(box.to_natural(z[None, :]))[0]
    fixed = np.asarray(box.span) == 0
    J = np.column_stack([(R[2 * j] - R[2 * j + 1]) / steps[j] if steps[j] > 0 and not fixed[j]
                         else np.zeros_like(r0) for j in range(d)])
    # SSR rises by (1 + RMS_RISE)² − 1 of itself at the interval's ends
    s2 = float(np.dot(r0, r0)) * ((1 + RMS_RISE) ** 2 - 1)
    H = J.T @ J
    if not np.all(np.isfinite(H)):
        return np.full(d, np.inf)
    ev, V = np.linalg.eigh(H)
    tiny = ev <= 1e-12 * max(float(ev.max()), 1e-300)
    inv = np.where(tiny, 0.0, 1.0 / np.where(tiny, 1.0, ev))
    half = np.sqrt(np.maximum(s2 * (V ** 2) @ inv, 0.0))
    # a direction with no curvature leaves every variable along it undetermined
    flat = (np.abs(V[:, tiny]) > 0.1).any(axis=1) if tiny.any() else np.zeros(d, bool)
    return np.where(flat, np.inf, half)
