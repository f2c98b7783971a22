"""Self-adaptive differential evolution (jDE), vectorized over the population.

This is the optimizer behind model identification (paper Sec. IV-B, Fig. 7:
"a self-adaptive differential evolution (DE) algorithm ... minimizing the RMS
error of eq. (18)"). The algorithm is jDE of Brest, Greiner, Boskovic, Mernik
and Zumer, "Self-adapting control parameters in differential evolution",
IEEE Trans. Evol. Comput. 10(6), 2006:

* strategy DE/rand/1/bin;
* every individual i carries its own scale factor F_i and crossover rate CR_i;
  before producing its trial vector, F_i is regenerated with probability
  tau1 = 0.1 as F_l + rand * F_u (F_l = 0.1, F_u = 0.9, so F in [0.1, 1.0]) and
  CR_i with probability tau2 = 0.1 as rand (CR in [0, 1]);
* the new (F, CR) survive only if the trial vector survives selection.

Differences from `scipy.optimize.differential_evolution`:

* the objective is called once per generation with the whole (P, d) trial
  population, so a compiled objective can parallelize over candidates;
* ``popsize`` is the number of individuals, not a multiplier of d;
* parameters flagged in ``log_scale`` are searched uniformly in log10 of their
  magnitude (sign kept), for parameters spanning decades;
* non-finite costs are +inf (divergent candidates lose every comparison);
* ``max_evals`` is a hard cap on evaluations, polish included; what a polish
  that converged early leaves of its budget goes back to DE (then a last
  polish), when DE had stopped on its budget;
* Ctrl-C returns the best point found so far (``message == "interrupted"``).

Internally every parameter lives on the unit interval [0, 1]; the map to the
user's space is affine (linear parameters) or affine in log10|x| (log-scaled).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from .minpolish import minimize_polish

__all__ = ["DEResult", "JDESolver", "jde_minimize"]

# jDE constants (Brest et al. 2006, Sec. III).
_TAU1 = 0.1     # probability of regenerating F_i
_TAU2 = 0.1     # probability of regenerating CR_i
_F_LOW = 0.1    # F_l
_F_UP = 0.9     # F_u: F = F_l + rand * F_u lies in [0.1, 1.0]

_BUDGET_MSG = "maximum number of evaluations reached"


@dataclass
class DEResult:
    """Outcome of :func:`jde_minimize`.

    Attributes
    ----------
    x : ndarray, shape (d,)
        Best parameter vector found, in the user's (natural) space.
    fun : float
        Objective value at ``x`` (``inf`` if no finite value was ever seen).
    nfev : int
        Number of objective evaluations (rows passed to ``func_pop``), polish
        included.
    nit : int
        Number of DE generations performed (the initial population is not a
        generation).
    success : bool
        True when the run stopped on its convergence criterion (stagnation or a
        collapsed population); False when the evaluation budget ran out, the
        callback asked to stop, the run was interrupted, or no finite cost was
        found.
    message : str
        Why the run stopped.
    history : ndarray, shape (nit + 1,)
        Best objective value after the initial population and after every
        generation (non-increasing). The polish result is not in it.
    """

    x: np.ndarray
    fun: float
    nfev: int
    nit: int
    success: bool
    message: str
    history: np.ndarray = field(repr=False)


class _Space:
    """Affine / log-affine map between the unit hypercube and the user's box."""

    def __init__(self, bounds, log_scale):
        b = np.asarray(bounds, dtype=float)
        if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] < 1:
            raise ValueError(
                f"bounds must be a sequence of (lo, hi) pairs, got shape {b.shape}")
        if not np.all(np.isfinite(b)):
            raise ValueError("bounds must be finite")
        if np.any(b[:, 0] > b[:, 1]):
            bad = int(np.nonzero(b[:, 0] > b[:, 1])[0][0])
            raise ValueError(
                f"bounds[{bad}] = {tuple(b[bad])}: lower bound exceeds upper bound")
        d = b.shape[0]
        if log_scale is None:
            log = np.zeros(d, dtype=bool)
        else:
            log = np.asarray(log_scale, dtype=bool).reshape(-1)
            if log.shape[0] != d:
                raise ValueError(
                    f"log_scale has {log.shape[0]} entries for {d} parameters")
        for j in np.nonzero(log)[0]:
            lo, hi = b[j]
            # A log-scaled range must keep one sign and exclude 0.
            if lo == 0.0 or hi == 0.0 or (lo < 0.0) != (hi < 0.0):
                raise ValueError(
                    f"bounds[{j}] = ({lo}, {hi}) is log-scaled but contains or "
                    "touches zero; a log-scaled range must be strictly positive "
                    "or strictly negative")
        self.d = d
        self.bounds = b
        self.log = log
        self.sign = np.where(b[:, 0] < 0.0, -1.0, 1.0)
        # Linear parameters: x = off + z * span.
        # Log parameters:    x = sign * 10**(off + z * span), off/span in log10|x|.
        mag = np.abs(b)
        with np.errstate(divide="ignore"):
            lmin = np.log10(np.minimum(mag[:, 0], mag[:, 1]))
            lmax = np.log10(np.maximum(mag[:, 0], mag[:, 1]))
        self.off = np.where(log, lmin, b[:, 0])
        self.span = np.where(log, lmax - lmin, b[:, 1] - b[:, 0])

    def to_natural(self, Z):
        Z = np.asarray(Z, dtype=float)
        lin = self.off + Z * self.span
        X = np.where(self.log, self.sign * 10.0 ** np.where(self.log, lin, 0.0), lin)
        # Pin exact bound values (avoid 10**log10(x) round-off leaving the box).
        return np.clip(X, self.bounds[:, 0], self.bounds[:, 1])

    def to_unit(self, X):
        X = np.asarray(X, dtype=float)
        X = np.clip(X, self.bounds[:, 0], self.bounds[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            val = np.where(self.log, np.log10(np.abs(np.where(self.log, X, 1.0))), X)
            Z = np.where(self.span > 0.0, (val - self.off) / np.where(
                self.span > 0.0, self.span, 1.0), 0.5)
        return np.clip(Z, 0.0, 1.0)


def _latin_hypercube(rng, P, d):
    """P points, one in each of P equal strata per coordinate."""
    Z = (rng.random((P, d)) + np.arange(P)[:, None]) / P
    for j in range(d):
        Z[:, j] = Z[rng.permutation(P), j]
    return Z


def _three_distinct_others(rng, P):
    """Indices r1, r2, r3 mutually distinct and different from i, for each i."""
    # Random keys with the diagonal pushed last: the 3 smallest keys in row i
    # are a uniform random 3-subset of {0..P-1} \ {i}.
    keys = rng.random((P, P))
    keys[np.arange(P), np.arange(P)] = 2.0
    idx = np.argpartition(keys, 3, axis=1)[:, :3]
    # argpartition does not randomize order within the 3; shuffle roles anyway.
    perm = rng.permuted(np.broadcast_to(np.arange(3), (P, 3)), axis=1)
    return np.take_along_axis(idx, perm, axis=1).T


def jde_minimize(func_pop: Callable[[np.ndarray], np.ndarray],
                 bounds: Sequence[tuple[float, float]], *,
                 log_scale: Sequence[bool] | None = None,
                 popsize: int | None = None,
                 max_evals: int = 20000,
                 seed: int | np.random.Generator | None = None,
                 tol_stagnation: float = 1e-6,
                 patience: int = 50,
                 polish: bool | str = True,
                 polish_maxfev: int | None = None,
                 polish_rtol: float | None = None,
                 progress: bool = False,
                 callback: Callable | None = None,
                 x0: Sequence[float] | None = None) -> DEResult:
    """Minimize ``func_pop`` over a box with self-adaptive DE (jDE).

    Parameters
    ----------
    func_pop : callable
        ``func_pop(X) -> costs``: ``X`` is an (P, d) float array of candidate
        vectors in the user's (natural) space, one per row; returns P costs.
        NaN or inf costs (e.g. a divergent simulation) count as +inf.
    bounds : sequence of (lo, hi)
        Box, one pair per parameter, in natural units; ``lo == hi`` fixes a
        parameter.
    log_scale : sequence of bool, optional
        Parameters flagged True are searched uniformly in log10|x| with the
        sign of the range kept: (1e-8, 1e-3) or (-1e5, -1e2) are fine, a range
        containing 0 is refused.
    popsize : int, optional
        Number of individuals P (not a multiplier). Default ``clip(10 d, 20, 100)``.
    max_evals : int
        Hard cap on the number of objective evaluations (rows), polish included.
    seed : int or numpy.random.Generator, optional
        Same seed, same objective -> same result, bit for bit.
    tol_stagnation, patience : float, int
        Stop (success) when the best cost improved by no more than
        ``tol_stagnation * |best|`` over the last ``patience`` generations.
    polish : bool, {"L-BFGS-B", "Nelder-Mead"} or callable
        Refine the best point with ``scipy.optimize.minimize`` in the internal
        unit-cube coordinates. True means L-BFGS-B, with central-difference
        gradients evaluated as one (2d + 1, d) population call. A callable
        ``polish(z0, f0, budget) -> (z, f, nfev)`` refines in the unit-cube
        coordinates itself (e.g. Gauss-Newton on residuals), using at most
        ``budget`` evaluations and returning a point no worse than (z0, f0).
    polish_maxfev : int, optional
        Evaluation budget of the polish, taken out of ``max_evals``.
        Default ``min(40 (2d + 1), max_evals // 10)``.
    polish_rtol : float, optional
        Relative tolerance of an L-BFGS-B polish: it stops once an iteration
        lowers the cost by at most ``polish_rtol`` times the cost before it,
        and the run ends there; the evaluations it leaves are not spent.
        Default None: the polish goes on to its budget or to round-off, and
        what it leaves goes back to DE (:meth:`JDESolver.resume`).
    progress : bool
        Show a tqdm progress bar counting evaluations.
    callback : callable, optional
        ``callback(x, fun, nit)`` after every generation with the current best
        (natural space); a truthy return stops the run (success False).
    x0 : sequence of float, optional
        A starting guess placed in the initial population (clipped to bounds).

    Returns
    -------
    DEResult
    """
    return JDESolver(func_pop, bounds, log_scale=log_scale, popsize=popsize,
                     max_evals=max_evals, seed=seed, tol_stagnation=tol_stagnation,
                     patience=patience, polish=polish, polish_maxfev=polish_maxfev,
                     polish_rtol=polish_rtol, progress=progress, callback=callback,
                     x0=x0).solve()


def _check_options(space, popsize, max_evals, tol_stagnation, patience, polish,
                   polish_maxfev, x0, polish_rtol=None):
    """Validated (P, max_evals, polish_method, polish_budget, x0) of a run."""
    d = space.d
    if int(max_evals) != max_evals or max_evals < 1:
        raise ValueError(f"max_evals must be a positive integer, got {max_evals!r}")
    max_evals = int(max_evals)
    if popsize is None:
        P = int(np.clip(10 * d, 20, 100))
    else:
        P = int(popsize)
        if P != popsize or P < 4:
            raise ValueError(f"popsize must be an integer >= 4 (DE/rand/1 needs "
                             f"3 others), got {popsize!r}")
    if not (tol_stagnation >= 0.0):
        raise ValueError(f"tol_stagnation must be >= 0, got {tol_stagnation!r}")
    if int(patience) != patience or patience < 1:
        raise ValueError(f"patience must be a positive integer, got {patience!r}")
    if polish is True:
        polish_method = "L-BFGS-B"
    elif polish is False or polish is None:
        polish_method = None
    elif polish in ("L-BFGS-B", "Nelder-Mead") or callable(polish):
        polish_method = polish
    else:
        raise ValueError(
            f"polish must be True, False, 'L-BFGS-B', 'Nelder-Mead' or a callable, got {polish!r}")
    if polish_method is None:
        polish_budget = 0
    elif polish_maxfev is None:
        polish_budget = min(40 * (2 * d + 1), max_evals // 10)
    else:
        polish_budget = int(polish_maxfev)
        if polish_budget < 0:
            raise ValueError(f"polish_maxfev must be >= 0, got {polish_maxfev!r}")
    de_budget = max_evals - polish_budget
    if de_budget < P:
        raise ValueError(
            f"max_evals={max_evals} leaves {de_budget} evaluations for DE after the "
            f"polish budget ({polish_budget}); need at least one population ({P})")
    if polish_rtol is not None:
        if not (polish_rtol > 0.0):
            raise ValueError(f"polish_rtol must be > 0, got {polish_rtol!r}")
        if polish_method != "L-BFGS-B":
            raise ValueError(f"polish_rtol applies to the L-BFGS-B polish only, not to "
                             f"polish={polish!r}")
    if x0 is not None:
        x0 = np.asarray(x0, dtype=float).reshape(-1)
        if x0.shape[0] != d or not np.all(np.isfinite(x0)):
            raise ValueError(f"x0 must hold {d} finite values, got {x0!r}")
    return P, max_evals, polish_method, polish_budget, x0


class JDESolver:
    """One jDE run: the state of the population and the steps of the algorithm.

    :func:`jde_minimize` is the front door; it builds a solver and calls
    :meth:`solve`. The steps, in the order :meth:`solve` calls them:
    :meth:`init_population`, then per generation :meth:`evolve` (which calls
    :meth:`adapt_controls`, :meth:`mutate`, :meth:`crossover`, the objective
    and :meth:`select`) and :meth:`check_stop`, finally :meth:`polish_best`
    and :meth:`result`. The random numbers are drawn in that order, which is
    what makes a seed reproduce a run bit for bit.

    Parameters
    ----------
    func_pop, bounds, log_scale, popsize, max_evals, seed, tol_stagnation, \
patience, polish, polish_maxfev, polish_rtol, progress, callback, x0
        As in :func:`jde_minimize`.

    Attributes
    ----------
    pop : ndarray, shape (P, d)
        Individuals in unit-cube coordinates.
    cost : ndarray, shape (P,)
        Their objective values (+inf for divergent ones).
    F, CR : ndarray, shape (P,)
        Each individual's scale factor and crossover rate.
    nfev, nit : int
        Evaluations and generations so far.
    history : list of float
        Best cost after the initial population and after every generation.
    message : str or None
        Why the run stopped (None while it runs).
    success : bool
        Whether it stopped on its convergence criterion.
    """

    def __init__(self, func_pop, bounds, *, log_scale=None, popsize=None, max_evals=20000,
                 seed=None, tol_stagnation=1e-6, patience=50, polish=True,
                 polish_maxfev=None, polish_rtol=None, progress=False, callback=None,
                 x0=None):
        self.space = _Space(bounds, log_scale)
        (self.P, self.max_evals, self.polish_method, self.polish_budget,
         self.x0) = _check_options(self.space, popsize, max_evals, tol_stagnation,
                                   patience, polish, polish_maxfev, x0, polish_rtol)
        self.polish_rtol = polish_rtol
        self.de_budget = self.max_evals - self.polish_budget
        self.func_pop = func_pop
        self.tol_stagnation = tol_stagnation
        self.patience = patience
        self.callback = callback
        self.rng = (seed if isinstance(seed, np.random.Generator)
                    else np.random.default_rng(seed))
        self.progress = progress
        self._pbar = None
        self.nfev = 0
        self.nit = 0
        self.history = []
        self.message = None
        self.success = False
        self.pop = self.cost = self.F = self.CR = None

    def evaluate(self, Z):
        """Costs of unit-cube points Z (m, d); non-finite costs become +inf."""
        X = self.space.to_natural(Z)
        f = np.asarray(self.func_pop(X), dtype=float).reshape(-1)
        if f.shape[0] != X.shape[0]:
            raise ValueError(
                f"func_pop returned {f.shape[0]} costs for {X.shape[0]} candidates")
        self.nfev += X.shape[0]
        if self._pbar is not None:
            self._pbar.update(X.shape[0])
        # Divergent candidates (NaN/inf) must lose every comparison.
        return np.where(np.isfinite(f), f, np.inf)

    def init_population(self):
        """Latin hypercube population (with ``x0`` as its first member); not evaluated."""
        P, d = self.P, self.space.d
        self.pop = _latin_hypercube(self.rng, P, d)
        if self.x0 is not None:
            self.pop[0] = self.space.to_unit(self.x0)
        self.F = np.full(P, 0.5)      # jDE initial F and CR (Brest et al. 2006)
        self.CR = np.full(P, 0.9)
        self.cost = np.full(P, np.inf)

    def adapt_controls(self):
        """jDE self-adaptation: candidate (F, CR) of each individual for this generation."""
        P, rng = self.P, self.rng
        F_new = np.where(rng.random(P) < _TAU1, _F_LOW + rng.random(P) * _F_UP, self.F)
        CR_new = np.where(rng.random(P) < _TAU2, rng.random(P), self.CR)
        return F_new, CR_new

    def mutate(self, F_new):
        """DE/rand/1 mutants, bounced back into the unit cube."""
        pop, rng = self.pop, self.rng
        r1, r2, r3 = _three_distinct_others(rng, self.P)
        base = pop[r1]
        mutant = base + F_new[:, None] * (pop[r2] - pop[r3])
        # Bounce back between the base vector and the violated bound: keeps
        # diversity near the boundary better than clipping.
        low = mutant < 0.0
        high = mutant > 1.0
        u = rng.random((self.P, self.space.d))
        mutant = np.where(low, u * base, mutant)
        return np.where(high, base + u * (1.0 - base), mutant)

    def crossover(self, mutant, CR_new):
        """Binomial crossover of the mutants with the population (one forced gene each)."""
        P, d, rng = self.P, self.space.d, self.rng
        cross = rng.random((P, d)) < CR_new[:, None]
        cross[np.arange(P), rng.integers(0, d, P)] = True   # j_rand
        return np.where(cross, mutant, self.pop)

    def select(self, trial, f_trial, F_new, CR_new):
        """One-to-one selection: the first ``len(f_trial)`` trials replace their parents
        when not worse, and bring their (F, CR) with them."""
        idx = np.arange(f_trial.shape[0])
        better = f_trial <= self.cost[idx]
        win = idx[better]
        self.pop[win] = trial[win]
        self.cost[win] = f_trial[better]
        self.F[win] = F_new[win]
        self.CR[win] = CR_new[win]

    def evolve(self):
        """One generation; False (and ``message`` set) when the budget is spent."""
        remaining = self.de_budget - self.nfev
        if remaining <= 0:
            self.message = _BUDGET_MSG
            return False
        # The last generation may be partial so the budget is used exactly.
        m = min(self.P, remaining)
        F_new, CR_new = self.adapt_controls()
        trial = self.crossover(self.mutate(F_new), CR_new)
        f_trial = self.evaluate(trial[np.arange(m)])
        self.select(trial, f_trial, F_new, CR_new)
        self.nit += 1
        self.history.append(self.cost.min())
        return True

    def check_stop(self):
        """Callback, stagnation and collapse tests after a generation; True to stop."""
        best = self.history[-1]
        if self.callback is not None:
            ib = int(np.argmin(self.cost))
            if self.callback(self.space.to_natural(self.pop[ib]), float(self.cost[ib]),
                             self.nit):
                self.message = "stopped by callback"
                return True
        if self.nit >= self.patience and np.isfinite(best):
            old = self.history[-1 - self.patience]
            if old - best <= self.tol_stagnation * abs(old):
                self.message = (f"stagnation: relative improvement <= "
                                f"{self.tol_stagnation:g} over {self.patience} generations")
                self.success = True
                return True
        if np.isfinite(best) and np.ptp(self.pop, axis=0).max() < 1e-12:
            self.message = "converged: population collapsed"
            self.success = True
            return True
        return False

    def run_generations(self):
        """Evaluate the initial population and evolve until a stop; Ctrl-C stops too."""
        try:
            self.cost = self.evaluate(self.pop)
            self.history.append(self.cost.min())
        except KeyboardInterrupt:
            self.message = "interrupted"
            self.success = False
            return
        self.more_generations()

    def more_generations(self):
        """Evolve the current population until a stop; Ctrl-C stops too."""
        try:
            while self.message is None:
                if not self.evolve() or self.check_stop():
                    break
        except KeyboardInterrupt:
            self.message = "interrupted"
            self.success = False

    def polish_best(self, budget=None):
        """Best (z, f) of the population, locally refined (within `budget`
        evaluations, default ``polish_budget``) unless polish is off or the run
        was interrupted."""
        budget = self.polish_budget if budget is None else budget
        ib = int(np.argmin(self.cost))
        z_best = self.pop[ib].copy()
        f_best = float(self.cost[ib])
        if (self.message != "interrupted" and self.polish_method is not None
                and budget > 0 and np.isfinite(f_best)):
            try:
                if callable(self.polish_method):
                    z_best, f_best, used = self.polish_method(z_best, f_best, budget)
                    self.nfev += int(used)
                    if self._pbar is not None:
                        self._pbar.update(int(used))
                else:
                    z_best, f_best = minimize_polish(self.evaluate, z_best, f_best, self.polish_method,
                                                     budget, lambda: self.nfev, self.polish_rtol)
            except KeyboardInterrupt:
                self.message = "interrupted"
                self.success = False
        return z_best, f_best

    def resume(self, z_best, f_best):
        """Spend what a polish left of its budget: the polished point joins the
        population, DE goes on with half of the rest and a polish gets the other half.

        A polish that stops early has settled in a local minimum; when DE had
        stopped on its budget (not on stagnation or a collapse), the evaluations
        left are worth more to the global search than unused. Returns the best
        (z, f) of the last polish.
        """
        while (self.message == _BUDGET_MSG and self.polish_method is not None
               and self.polish_rtol is None and self.max_evals - self.nfev >= 2 * self.P):
            ib = int(np.argmin(self.cost))
            self.pop[ib], self.cost[ib] = z_best, f_best
            left = self.max_evals - self.nfev
            self.de_budget = self.nfev + left - min(self.polish_budget, left // 2)
            self.message = None
            self.more_generations()
            z_best, f_best = self.polish_best(self.max_evals - self.nfev)
        return z_best, f_best

    def solve(self) -> DEResult:
        """Run jDE to the end and return the result."""
        if self.progress:
            from tqdm.auto import tqdm
            self._pbar = tqdm(total=self.max_evals, unit="eval", desc="jDE")
        self.init_population()
        self.run_generations()
        z_best, f_best = self.resume(*self.polish_best())
        if self._pbar is not None:
            self._pbar.close()
        if not np.isfinite(f_best):
            self.success = False
            self.message = (self.message or "") + "; no finite cost found"
        return DEResult(x=self.space.to_natural(z_best), fun=f_best, nfev=self.nfev,
                        nit=self.nit, success=self.success, message=self.message,
                        history=np.asarray(self.history, dtype=float))
