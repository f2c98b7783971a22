"""Nominal hysteresis cores of the joint refit: FONBW and the reference.

A core gives the :class:`fonbw.gap.fitter.Fitter` its *base columns*: the
regressors of the hysteresis whose weights are solved linearly, for one
record's (possibly transformed) input and one row of the core's nonlinear
search vector X. Every effect block of :mod:`fonbw.gap.effects` composes
with either core in the same four ways (input-side transforms re-run the
core; linear output operators filter every base column; additive regressors
and the output nonlinearity are appended).

:class:`FonbwCore`
    X = identify's search vector (ρ, σ^(1/n)ρ, n, λ1, λ2); base columns
    (u/U)^1..N and the simulated ħ (eqs. 9-11).
:class:`ReferenceCore`
    the generalized Prandtl–Ishlinskii reference of :mod:`fonbw.gap.reference`
    with its rate parameters θ fixed (fitted once by
    :func:`fonbw.gap.form.fit_reference`) and its *active set* fixed: the
    columns with a positive weight in its bounded fit or in its fit beside
    a drift (and the free ones). On the bounded fit's own active columns
    its optimum is the unconstrained least-squares solution, so the refit
    solves plain least squares; every active column counts in the BIC
    (:attr:`ReferenceCore.n_params`). X is empty; Φ of a
    record is built once and cached unless an input-side effect changes
    the input. With a ``basis`` the refit re-weights a few fixed
    combinations of the active columns instead of every one of them.
"""
from __future__ import annotations

import contextlib

import numpy as np

from .. import hysteresis as hyst

__all__ = ["FonbwCore", "ReferenceCore", "reduced_basis", "KIND"]

KIND = "fonbw"


class FonbwCore:
    """The nominal FONBW core (the search space of :func:`fonbw.identify.search_space`).

    Parameters
    ----------
    space : fonbw.identify.SearchSpace
    N : int
        Order of g(u), eq. (10).
    memory : str
        GL memory engine.
    """

    name = "fonbw"

    def __init__(self, space, N=3, memory="fast"):
        self.space, self.N, self.memory = space, N, memory
        self.pnames = hyst.param_names(KIND, N)
        self.nx = len(space.names)
        self.n_base = N + 1
        self.bounds = [tuple(b) for b in space.bounds]
        self.log_scale = list(space.log_scale)
        self._powers = {}

    def __getstate__(self):
        # keyed by the ids of this process's arrays: another process starts it empty
        return {**self.__dict__, "_powers": {}}

    def theta(self, X):
        """Natural basis parameter rows (P, d) of search rows X (P, nx)."""
        p = self.space.basis_params(np.atleast_2d(X))
        return np.column_stack([np.asarray(p[k], dtype=float) for k in self.pnames])

    def local_bounds(self, x0):
        """A box around `x0` (±0.5 decade for log variables, ±15 % of the range otherwise)."""
        out = []
        for (lo, hi), lg, v in zip(self.bounds, self.log_scale, x0):
            if lg:
                a, b = v / 10 ** 0.5, v * 10 ** 0.5
            else:
                w = 0.15 * (hi - lo)
                a, b = v - w, v + w
            out.append((max(lo, min(a, v)), min(hi, max(b, v))))
        return out

    def base(self, rec, X, Us, transformed):
        """Base columns (J, N + 1, n) of search rows X (J, nx) on inputs Us (J, n) [V]."""
        theta = self.theta(X)
        if transformed:
            S = hyst.simulate_population(KIND, theta, np.ascontiguousarray(Us, dtype=float), rec.dt,
                                         memory=self.memory, N=self.N)
            F = [self.space.fixed_columns(Us[j]).T for j in range(len(Us))]
        else:
            S = hyst.simulate_population(KIND, theta, rec.u, rec.dt, memory=self.memory, N=self.N)
            # the record's own input: its powers once per record
            F = [self.powers(rec)] * len(Us)
        S = np.atleast_2d(S)
        return [np.vstack([F[j], S[j][None, :]]) for j in range(len(Us))]

    def powers(self, rec):
        """(u/U)^1..N of a record's own input, (N, n) (a transposed view, as the
        fitter has always stacked it), built once per record."""
        key = (id(rec.u), len(rec.u))
        if key not in self._powers:
            # the cache keeps the input alive, so its id stays unique
            self._powers[key] = (rec.u, self.space.fixed_columns(rec.u).T)
        return self._powers[key][1]


class ReferenceCore:
    """The reference hysteresis as a nominal core (θ and the active set fixed).

    Parameters
    ----------
    reference : fonbw.gap.reference.ReferenceHysteresis
        With its grid sized (``u_range`` set).
    theta : sequence of float
        Rate parameters (``reference.theta_names``).
    active : ndarray of bool, optional
        Columns kept (default: all).
    basis : ndarray, optional
        (n_active, r) combinations of the active columns that the refit
        weighs (default: each active column on its own); see
        :func:`reduced_basis`.
    """

    name = "reference"
    nx = 0
    bounds: list = []
    log_scale: list = []

    def __init__(self, reference, theta=(), active=None, basis=None):
        self.ref = reference
        self.theta_ = tuple(float(t) for t in theta)
        self.active = (np.ones(reference.n_columns, dtype=bool) if active is None
                       else np.asarray(active, dtype=bool))
        self.basis = None if basis is None else np.asarray(basis, dtype=float)
        if self.basis is not None and self.basis.shape[0] != int(self.active.sum()):
            raise ValueError(f"basis needs {int(self.active.sum())} rows (one per active column), "
                             f"got {self.basis.shape[0]}")
        self.n_base = int(self.active.sum()) if self.basis is None else self.basis.shape[1]
        self._cache = {}

    def __getstate__(self):
        # keyed by the ids of this process's arrays: another process starts it empty
        return {**self.__dict__, "_cache": {}}

    @contextlib.contextmanager
    def transient(self):
        """Inside the block, columns of new inputs are cached only until its
        end: inputs seen once (candidate histories) would otherwise hold
        their columns, and their inputs, for the rest of the diagnosis."""
        known = set(self._cache)
        try:
            yield self
        finally:
            for key in set(self._cache) - known:
                del self._cache[key]

    @property
    def n_params(self) -> int:
        """Parameters a reference fit spends (active weights and θ), for the BIC."""
        return int(self.active.sum()) + len(self.theta_)

    def local_bounds(self, x0):
        return []

    def phi(self, u, dt):
        """Active columns (q, n) of the reference on input `u` [V] at step `dt` [s]
        (with a basis, their combinations, made in the reference's play kernel)."""
        P = self.ref.columns(u, dt, self.theta_, keep=self.active, basis=self.basis)
        return np.ascontiguousarray(P.T)

    def base(self, rec, X, Us, transformed):
        """Base columns (J, q, n); one Φ per record while the input is the record's own."""
        if transformed:
            return [self.phi(Us[j], rec.dt) for j in range(len(Us))]
        key = (id(rec.u), len(rec.u), rec.dt)
        if key not in self._cache:
            # the cache keeps the record's input alive, so its id stays unique
            self._cache[key] = (rec.u, self.phi(rec.u, rec.dt))
        return [self._cache[key][1]] * len(Us)


def reduced_basis(A, c, n_plays, r, also=None):
    """Combinations of a reference's active columns for the joint refits.

    Parameters
    ----------
    A : ndarray
        (n, q) active columns on the training samples, the first `n_plays`
        of them plays.
    c : ndarray
        (q,) their fitted weights.
    n_plays : int
        Active play columns.
    r : int
        Play directions kept besides the fitted one.
    also : ndarray, optional
        (q,) other fitted weights whose play combination is kept too,
        second (the diagnosis's: the weights solved beside a drift's
        columns, a loop that has not taken the drift up).

    Returns
    -------
    ndarray or None
        (q, 1 + a + r + q - n_plays): the fitted play combination, the one
        of `also` (a = 1, or 0 without it), the `r` leading principal
        directions of the (unit-norm) play columns, and each other column
        (polynomial, fractional term) on its own; None when that would not
        be fewer columns.

    The refits keep the fitted loop exactly (the first column) and can
    still reshape it along the directions the training records excite
    most, at a cost that no longer grows with the density's resolution.
    """
    q = A.shape[1]
    fitted = [c] if also is None else [c, also]
    k = len(fitted) + r
    if k >= n_plays:
        return None
    P = A[:, :n_plays]
    s = np.linalg.norm(P, axis=0)
    s[s == 0] = 1.0
    w, V = np.linalg.eigh((P / s).T @ (P / s))
    V = V[:, np.argsort(w)[::-1][:r]] / s[:, None]
    B = np.zeros((q, k + q - n_plays))
    for j, x in enumerate(fitted):
        B[:n_plays, j] = x[:n_plays]
    B[:n_plays, len(fitted):k] = V
    B[n_plays:, k:] = np.eye(q - n_plays)
    return B
