"""A stroke limit ahead of the stage's mechanics.

A piezo stack's strain saturates before the stage's mechanics filter it, so
at a step edge the displacement rings past the limit. The saturation block
as the fitter applies it alone bends the model's own output, y = z + c f(z)
(:class:`fonbw.gap.limits.Saturation`), which cannot ring past its knee;
with a resonance among the blocks, a rail on the voltage (ahead of the
hysteresis, so of the resonance) could, and was named instead. Here the
limit acts first:

    y = H[z + c f(z)] + P b_P,    z = M b_M,

M the regressors the output's linear operators H filter (the core's base
columns and the filtered effect columns), P the plain ones, H the
operators of the candidate row (a resonance), record by record.

The fit is Gauss-Newton, as the limit after the operators is
(:meth:`fonbw.gap.fitter.Fitter.fit_linear`), with the Jacobian's columns
of b_M, H[(1 + c f'(z)) M], filtered afresh at every step. Fitted by a
fixed point instead (g from the last coefficients, then linear least
squares), noise-free records of a hard stop ahead of a resonance took 25
iterations to reach the truth, and the first one raised the residual.
"""
from __future__ import annotations

import numpy as np

__all__ = ["PreLimit", "Steps", "output", "ahead_of_operators", "operate", "operate_stacked"]


class PreLimit:
    """The output limit of one candidate row, ahead of its linear operators.

    Parameters
    ----------
    e : Effect
        The output-nonlinear block (its ``shape``, ``c_min``, ``compressive``).
    th : ndarray
        Its parameters (knee, width).
    M : ndarray, shape (n, q_M)
        The filtered regressors before filtering, all records stacked.
    filt : callable
        Applies the row's output operators to stacked signals, (n,) or (k, n), record by record.
    rows : index or mask, optional
        The rows of the stacked records the fit sees (None: all).
    """

    def __init__(self, e, th, M, filt, rows=None):
        self.e, self.th, self.M, self.filt, self.rows = e, np.asarray(th, dtype=float), M, filt, rows

    def on(self, rows):
        """The same limit seen on `rows` of all the stacked rows (not of :attr:`rows`)."""
        return PreLimit(self.e, self.th, self.M, self.filt, rows)

    def select(self, cols):
        """The limit with only the columns `cols` (a mask) of M."""
        return PreLimit(self.e, self.th, self.M[:, cols], self.filt, self.rows)

    def merged(self, k, w):
        """The limit with M's first `k` columns merged into one, weighted by `w`."""
        return PreLimit(self.e, self.th, np.column_stack([self.M[:, :k] @ w, self.M[:, k:]]), self.filt, self.rows)

    @property
    def q(self) -> int:
        return self.M.shape[1]

    def column(self, bM):
        """g = H[f(M b_M)] on the rows seen."""
        return self.evaluate(bM)[0]

    def evaluate(self, bM):
        """(g on the rows seen, f'(z) on all rows) at z = M b_M."""
        f, df = self.e.shape(self.M @ bM, self.th)
        g = self.filt(f)
        return (g if self.rows is None else g[self.rows]), df


class Steps:
    """The Gauss-Newton problem of a :class:`PreLimit` (for
    :meth:`fonbw.gap.fitter.Fitter._gauss_newton`): `A` holds [H M, P, g0],
    the filtered regressors, the plain ones and a start for the limit's
    column (H f driven by the nominal output), c the last coefficient. The
    Jacobian's columns of b_M, H M + c H[f'(z) M], are filtered afresh at
    every step (one filter call per record for all of them)."""

    def __init__(self, A, y, pre):
        self.e, self.pre = pre.e, pre
        self.F = np.asarray(A[:, :-1], dtype=float)
        self.y = np.asarray(y, dtype=float)

    def buffers(self):
        """(r, f'(z) on all rows, g) of one evaluation, filled by :meth:`residual`."""
        return [None, None, None]

    def residual(self, b, into):
        g, df = self.pre.evaluate(b[:self.pre.q])
        r = self.y - self.F @ b[:-1] - b[-1] * g
        into[:] = [r, df, g]
        return float(r @ r)

    def normal(self, b, state):
        pre = self.pre
        r, df, g = state
        D = pre.filt((df[:, None] * pre.M).T).T
        D = D if pre.rows is None else D[pre.rows]
        q = pre.q
        J = np.column_stack([self.F[:, :q] + b[-1] * D, self.F[:, q:], g])
        return J.T @ J, J.T @ r

    def off(self, solve):
        """The fit with the limit off (c = 0): the rest's plain least squares."""
        b0, r0 = solve(self.F, self.y)
        return (None, None) if b0 is None else (np.r_[b0, 0.0], r0)


def output(A, b, pre):
    """Model output of coefficients `b` on design `A` with the limit `pre` ahead of H."""
    return A[:, :-1] @ b[:-1] + b[-1] * pre.column(b[:pre.q])


def ahead_of_operators(effects):
    """(block, its index) of the output-nonlinear block among `effects` when
    an output operator (a resonance) is there too, so that the limit acts
    ahead of it (a :class:`PreLimit`); None otherwise."""
    if not any(e.output_linear for e in effects):
        return None
    return next(((e, i) for i, e in enumerate(effects) if e.output_nonlinear), None)


def operate(M, effects, TH, p, dt):
    """The output operators of candidate row `p` applied to the rows of `M` (one record)."""
    for e, th in zip(effects, TH):
        M = e.output_op(M, dt, th[p])
    return M


def operate_stacked(v, effects, TH, p, lens, dts):
    """:func:`operate` on signals of stacked records (lengths `lens`, steps
    `dts`): `v` of shape (n,) or (k, n)."""
    V = np.atleast_2d(v)
    out, k = np.empty(V.shape), 0
    for n, dt in zip(lens, dts):
        out[:, k:k + n] = operate(V[:, k:k + n], effects, TH, p, dt)
        k += n
    return out if np.ndim(v) == 2 else out[0]
