"""Joint refit of the nominal FONBW model and candidate effect blocks.

:class:`Fitter` evaluates a nominal model (eqs. 9-11) with effect blocks of
:mod:`fonbw.gap.effects` added, for a population of candidate parameter rows,
by variable projection: the nonlinear parameters (the hysteresis' ρ,
σ^(1/n)ρ, n, λ1, λ2 and each effect's own) are searched, the linear ones (ku,
kh, creep gains, drift coefficients) are solved by least squares at every
evaluation, or by Gauss-Newton with the saturation block, which bends the
model's own output. :meth:`Fitter.refit` searches the nonlinear parameters
with :func:`fonbw.de.jde_minimize`: globally over the search space's bounds,
or locally (a gradient polish in a box around a start).
"""
from __future__ import annotations

import collections
import math

import numpy as np

from .. import hysteresis as hyst
from ..de import jde_minimize
from ..io import Record
from ..io import decimate as io_decimate
from . import knee, prelimit
from .cores import FonbwCore

__all__ = ["KIND", "Fitter", "simulate_rows", "x_from_model", "decimate", "nominal_search"]

KIND = "fonbw"
# A local refit ends once an L-BFGS-B iteration gains less than this share of
# its cost. On the reference core the refits settle within 1e-9 after 14 to 47
# of their 95 evaluations and then spent the rest for nothing; candidates
# are told apart by gaps of per cent.
REFIT_RTOL = 1e-9


def nominal_search(budget):
    """Search settings of the diagnosis' nominal FONBW identifications.

    jDE's population of 10 d = 50 (fewer for budgets under about 350
    evaluations) and an L-BFGS-B polish, rather than :func:`fonbw.identify`'s
    defaults (a population sized for 40 generations, a Gauss-Newton polish).
    The candidates' joint refit undoes what the nominal absorbed of an effect
    only within its own, shorter global search; identify's defaults drive
    the nominal deeper into such basins (an RC amplifier taken in as λ2 at its
    bound: gap closed 0.72 against 0.85 with these settings on the
    amplifier-lag test case), and the diagnosis' thresholds and blind runs
    were measured with these.
    """
    de_budget = int(budget) - (3 * int(budget)) // 10
    return {"popsize": int(min(50, max(4, de_budget // 5))), "polish": "L-BFGS-B"}


def simulate_rows(theta, U, dt, memory="fast", N=3):
    """FONBW outputs [µm] for parameter rows `theta` (P, d), each with its own input row of `U` (P, n).

    Rows whose parameters are invalid or diverge are NaN
    (:func:`fonbw.hysteresis.simulate_population`, which runs them).
    """
    theta = np.atleast_2d(theta)
    return hyst.simulate_population(KIND, theta, np.ascontiguousarray(U, dtype=float), dt, memory=memory, N=N)


class Fitter:
    """Nominal model plus effect blocks, fitted by variable projection.

    Parameters
    ----------
    records : list of Record
        Training records (same dt).
    space : fonbw.identify.SearchSpace
        FONBW search space (gives the basis parameters, the fixed regressors
        (u/U)^i and the map back to natural parameters).
    N : int
        Order of g(u), eq. (10).
    memory : str
        GL memory engine.
    core : FonbwCore or ReferenceCore, optional
        The nominal hysteresis (:mod:`fonbw.gap.cores`); default the FONBW
        core of `space`.
    skip : sequence of int, optional
        Leading samples of each record left out of every fit and score (a
        burn-in, :func:`fonbw.start.start_state`); the model still runs
        through them.
    """

    def __init__(self, records, space=None, N=3, memory="fast", core=None, skip=None):
        self.records = records
        self.space = space
        self.N = N
        self.memory = memory
        self.core = core if core is not None else FonbwCore(space, N, memory)
        self.dt = records[0].dt
        self.pnames = hyst.param_names(KIND, N)
        self.y_all = np.concatenate([r.y for r in records])
        self.keep = None
        if skip is not None and any(int(b) > 0 for b in skip):
            self.keep = np.concatenate([np.arange(len(r.y)) >= int(b) for r, b in zip(records, skip)])
        # y: the samples every fit and score uses
        self.y = self.y_all if self.keep is None else self.y_all[self.keep]
        self.nx = self.core.nx
        self._sims, self._sim_bytes, self._fixed = collections.OrderedDict(), 0, collections.OrderedDict()

    def __getstate__(self):
        # the caches are keyed by the ids of this process's arrays: another
        # process (fonbw.gap.workers) starts them empty
        state = dict(self.__dict__)
        state["_sims"], state["_sim_bytes"], state["_fixed"] = collections.OrderedDict(), 0, collections.OrderedDict()
        return state

    #: Bytes of simulated base columns kept between evaluations.
    cache_bytes = 128 * 2**20

    def rows(self, A):
        """The rows of a design matrix over all samples that the fits use."""
        return A if self.keep is None else A[self.keep]

    # -- design -----------------------------------------------------------

    def design(self, records, X, effects, TH, yrefs):
        """Regressor matrices, one (n_total, q) array per candidate row.

        ``TH`` holds one (P, k_e) array per effect; ``yrefs`` the nominal
        output of each record (creep's driving signal). Column order:
        (u/U)^1..N, ħ, then each effect's additive regressors, the output
        nonlinearity's start column last (filtered by the output operators
        when it acts ahead of them, :meth:`designs`).
        """
        return list(self.designs(records, X, effects, TH, yrefs))

    def designs(self, records, X, effects, TH, yrefs, limits=False):
        """The matrices of :meth:`design`, built one row at a time (a generator).

        A caller that needs one row at a time holds one matrix, not P. The
        base columns of a row (a simulation) come from :meth:`base_columns`,
        shared by every row with the same X and input-side parameters. With
        `limits`, each matrix comes with the row's output nonlinearity (the
        `outer` of :meth:`fit_linear`): None, (effect, parameters), or, beside
        an output operator (a resonance), a :class:`~fonbw.gap.prelimit.PreLimit`
        that acts ahead of it, whose start column is filtered too.
        """
        X = np.atleast_2d(X)
        P = X.shape[0]
        inp = [(e, th) for e, th in zip(effects, TH) if e.input_side]
        # rows that share X and input-side parameters share one simulation
        key = np.hstack([X] + [th for _, th in inp]) if inp else X
        if key.shape[1] == 0:
            first, inv = np.zeros(1, dtype=int), np.zeros(P, dtype=int)
        else:
            uniq, inv = np.unique(key, axis=0, return_inverse=True)
            inv = np.ravel(inv)
            first = np.array([int(np.flatnonzero(inv == j)[0]) for j in range(len(uniq))])
        pre = prelimit.ahead_of_operators(effects)
        lens, dts = [len(rec.u) for rec in records], [rec.dt for rec in records]
        parts = []
        for rec, yref in zip(records, yrefs):
            B = self.base_columns(rec, X, key, first, inp)
            ctx = {"t": np.arange(len(rec.u)) * rec.dt, "y_ref": yref, "dt": rec.dt, "core": self.core.name}
            # regressors of blocks without nonlinear parameters are the same for every row
            fixed = {id(e): self.fixed_columns(e, ctx) for e in effects if not e.names}
            parts.append((rec, ctx, B, fixed))
        # The stacking below fixes the memory order of each matrix (numpy's
        # concatenation follows its inputs'), and with it the order of the
        # sums in the least-squares products: it is kept as it is, so the
        # fits' numbers do not depend on how the matrices were cached.
        for p in range(P):
            m, m_pre = [], []
            for rec, ctx, B, fixed in parts:
                filt, plain, last = [B[inv[p]]], [], []
                for e, th in zip(effects, TH):
                    C = fixed[id(e)] if id(e) in fixed else e.columns(ctx, th[p])
                    if C is not None:
                        (last if e.output_nonlinear else filt if e.filtered_columns else plain).append(C.T)
                M = np.vstack(filt) if len(filt) > 1 else filt[0]
                if pre:
                    m_pre.append(M)
                    last = [prelimit.operate(np.vstack(last), effects, TH, p, rec.dt)]
                M = prelimit.operate(M, effects, TH, p, rec.dt)
                m.append(np.vstack([M] + plain + last) if plain or last else M)
            A = np.hstack(m).T
            if not limits:
                yield A
            elif pre:
                yield A, prelimit.PreLimit(pre[0], TH[pre[1]][p], np.hstack(m_pre).T,
                                           lambda v, p=p: prelimit.operate_stacked(v, effects, TH, p, lens, dts))
            else:
                yield A, self._outer(effects, TH, p)

    def base_columns(self, rec, X, key, first, inp):
        """Base columns (q, n) of the unique rows ``first`` of X on one record.

        Simulations are kept (least recently used first out, up to
        :attr:`cache_bytes`) by the record, the row's `key` (X and the
        input-side parameters) and the input-side blocks: a refit evaluates
        its start, its optimum and the nominal's X again and again.
        """
        ids = tuple(id(e) for e, _ in inp)
        keys = [(id(rec.u), len(rec.u), rec.dt, ids, key[p].tobytes()) for p in first]
        miss = [j for j, k in enumerate(keys) if k not in self._sims]
        if miss:
            rows = first[miss]
            n = len(rec.u)
            Us = np.empty((len(rows), n))
            for j, p in enumerate(rows):
                u = rec.u
                for e, th in inp:
                    u = e.transform_input(u, rec.dt, th[p])
                Us[j] = u
            got = self.core.base(rec, X[rows], Us, bool(inp))
            for j, blocks in zip(miss, got):
                # the entry holds the record's input and the blocks, so their ids stay unique
                self._sims[keys[j]] = (rec.u, [e for e, _ in inp], blocks, blocks.nbytes)
                self._sim_bytes += blocks.nbytes
        out = []
        for k in keys:
            self._sims.move_to_end(k)
            out.append(self._sims[k][2])
        while self._sim_bytes > self.cache_bytes and len(self._sims) > len(keys):
            self._sim_bytes -= self._sims.popitem(last=False)[1][3]
        return out

    def fixed_columns(self, e, ctx):
        """Regressors of a block without nonlinear parameters, built once per driving signal."""
        key = (id(e), id(ctx["y_ref"]), len(ctx["t"]), ctx["dt"])
        if key not in self._fixed:
            # the entry holds the block and the driving signal, so their ids stay unique
            self._fixed[key] = (e, ctx["y_ref"], e.columns(ctx, ()))
            if len(self._fixed) > 64:
                self._fixed.popitem(last=False)
        return self._fixed[key][2]

    def lin_slices(self, effects):
        """Where each effect's linear parameters sit in the coefficient vector.

        The column order of :meth:`design`: the base columns (N + 1), the
        filtered regressors, the plain ones, the output nonlinearity last.
        """
        k = self.core.n_base
        out = [None] * len(effects)
        groups = ([i for i, e in enumerate(effects) if e.filtered_columns and not e.output_nonlinear],
                  [i for i, e in enumerate(effects) if not e.filtered_columns and not e.output_nonlinear],
                  [i for i, e in enumerate(effects) if e.output_nonlinear])
        for g in groups:
            for i in g:
                q = len(effects[i].lin_names_on(self.core.name))
                out[i] = slice(k, k + q)
                k += q
        return out

    def nonneg(self, effects):
        """Indices of the coefficients bounded below by 0 (the gains of the
        ``lin_nonneg`` blocks among `effects`), or None."""
        idx = [j for e, sl in zip(effects, self.lin_slices(effects)) if e.lin_nonneg
               for j in range(sl.start, sl.stop)]
        return idx or None

    def design_limit(self, records, X, effects, TH, yrefs):
        """The design matrix of the first row of `X` with its output
        nonlinearity (:meth:`designs` with ``limits``)."""
        return next(self.designs(records, X, effects, TH, yrefs, limits=True))

    @staticmethod
    def limit_on(outer, rows):
        """An output nonlinearity seen on `rows` of the stacked records (None: all):
        a limit ahead of the output operators filters whole records first."""
        if rows is None or not isinstance(outer, prelimit.PreLimit):
            return outer
        return outer.on(rows)

    @staticmethod
    def _outer(effects, TH, p):
        """The output nonlinearity of row `p` as (effect, parameters), or None:
        the limit after the output operators; :meth:`designs` with ``limits``
        gives the one that goes with a design."""
        for e, th in zip(effects, TH):
            if e.output_nonlinear:
                return e, np.asarray(th[p], dtype=float)
        return None

    # -- costs ------------------------------------------------------------

    @staticmethod
    def _excited(s):
        """The columns of norms `s` that the fit solves for: a regressor these
        samples do not excite (a saturation knee above every displacement of
        a subset) gets coefficient 0, not 1/ε."""
        return s > 1e-10 * max(float(s.max()), 1e-300)

    @staticmethod
    def solve(A, y):
        """Least-squares coefficients and residual; non-finite columns -> (None, None).

        Normal equations on unit-norm columns (a few columns, many samples:
        far cheaper than a QR of A); the residual is formed explicitly, so
        its accuracy does not suffer from the squared condition number
        beyond second order.
        """
        s = np.sqrt(np.einsum("ij,ij->j", A, A))
        # finite norms imply finite columns (a non-finite entry makes its
        # column's sum of squares inf or nan); only an overflowing norm
        # needs the look at every entry
        if not np.all(np.isfinite(s)) and not np.all(np.isfinite(A)):
            return None, None
        on = Fitter._excited(s)
        # A[:, on] is a Fortran-ordered copy (whatever the order of A), and
        # a slow one: with every column on, the same array by one division
        As = np.divide(A, s, order="F") if on.all() else A[:, on] / s[on]
        G = As.T @ As
        try:
            bs = np.linalg.solve(G, As.T @ y)
        except np.linalg.LinAlgError:
            bs, *_ = np.linalg.lstsq(As, y, rcond=None)
        b = np.zeros(A.shape[1])
        b[on] = bs / s[on]
        return b, y - A @ b

    @classmethod
    def fit_linear(cls, A, y, outer=None, iters=8, nonneg=None):
        """Linear coefficients and residual of ``y ≈ A b``, or of the output
        nonlinearity ``y ≈ z + c f(z)``, ``z = A[:, :-1] b[:-1]``, ``c = b[-1]``.

        The nonlinear form starts from the plain least-squares solution (the
        last column of `A` is f driven by the nominal output) and takes
        Gauss-Newton steps with the Jacobian [(1 + c f'(z)) A[:, :-1], f(z)],
        halving a step that does not lower the residual. c stays at or above
        the block's ``c_min``: a step that would cross it is cut short where
        c reaches it, and at the bound a step that would lower c moves the
        rest alone. A ``compressive`` block whose optimum has c > 0 gets
        c = 0 and the plain least squares of the rest. The coefficients
        indexed by `nonneg` (:meth:`nonneg`) are bounded below by 0: while
        one is negative, the most negative (in units of its column's norm) is
        held at 0 and the rest refit, a backward elimination that needs no
        extra solve when the bounds are inactive. Returns (None, None) for non-finite columns.

        `outer` is the output nonlinearity as (effect, parameters), or a
        :class:`~fonbw.gap.prelimit.PreLimit` for a limit ahead of the output
        operators: the same Gauss-Newton on its own residual and Jacobian
        (:class:`~fonbw.gap.prelimit.Steps`). Use the one :meth:`designs`
        gives with ``limits``.
        """
        b, r = cls._fit_free(A, y, outer, iters)
        if nonneg is None or b is None:
            return b, r
        free = np.ones(A.shape[1], dtype=bool)
        for _ in range(len(nonneg)):
            neg = [j for j in nonneg if free[j] and b[j] < 0.0]
            if not neg:
                break
            free[min(neg, key=lambda j: b[j] * np.linalg.norm(A[:, j]))] = False
            o = outer.select(free[:outer.q]) if isinstance(outer, prelimit.PreLimit) else outer
            bf, r = cls._fit_free(A[:, free], y, o, iters)
            if bf is None:
                return None, None
            b = np.zeros(A.shape[1])
            b[free] = bf
        return b, r

    @classmethod
    def _fit_free(cls, A, y, outer, iters):
        """:meth:`fit_linear` without the bounds of `nonneg`."""
        b, r = cls.solve(A, y)
        if outer is None or b is None:
            return b, r
        if isinstance(outer, prelimit.PreLimit):
            steps = prelimit.Steps(A, y, outer)
        else:
            steps = knee.Steps(A, y, outer)
        b = b.copy()
        b[-1] = max(b[-1], steps.e.c_min)
        b, r = cls._gauss_newton(b, steps, iters)
        if steps.e.compressive and b[-1] > 0.0:
            # the bound c ≤ 0 is active: the block is off, the rest linear again
            return steps.off(cls.solve)
        return b, r

    @classmethod
    def _gauss_newton(cls, b, steps, iters):
        """Gauss-Newton from `b` on the output nonlinearity's problem `steps`
        (its ``residual(b, into)`` returning the sum of squares, its
        ``normal(b, state)``, and its block ``e``), halving a step that does
        not lower the residual; c (the last coefficient) is held at or above
        the block's ``c_min``. Returns (b, residual)."""
        c_min = steps.e.c_min
        cur, nxt = steps.buffers(), steps.buffers()
        sse = steps.residual(b, cur)
        for _ in range(iters):
            G, g = steps.normal(b, cur)
            step = cls._gn_step(G, g)
            if step is not None and b[-1] <= c_min + 1e-12 and step[-1] < 0.0:
                # the bound is active: c stays, the rest takes the step
                sub = cls._gn_step(G[:-1, :-1], g[:-1])
                step = None if sub is None else np.r_[sub, 0.0]
            if step is None:
                break
            # a step that crosses the bound stops where c reaches it: clipped
            # instead, the rest would move as if c went on, and no halving
            # of that lowers the residual
            lam, better = 1.0, False
            if b[-1] + step[-1] < c_min:
                lam = (c_min - b[-1]) / step[-1]
            for _ in range(6):
                bn = b + lam * step
                bn[-1] = max(bn[-1], c_min)
                sn = steps.residual(bn, nxt)
                if sn < sse:
                    better = True
                    break
                lam *= 0.5
            if not better:
                break
            gain = (sse - sn) / max(sse, 1e-300)
            b, sse = bn, sn
            cur, nxt = nxt, cur
            if gain < 1e-9:
                break
        return b, cur[0]

    @staticmethod
    def _gn_step(G, g):
        """Gauss-Newton step from the normal equations G x = g, on unit-norm
        columns as in :meth:`solve`; None for non-finite columns."""
        s = np.sqrt(np.diag(G))
        if not np.all(np.isfinite(s)):
            return None
        on = Fitter._excited(s)
        so = s[on]
        Gs, gs = G[np.ix_(on, on)] / np.outer(so, so), g[on] / so
        try:
            xs = np.linalg.solve(Gs, gs)
        except np.linalg.LinAlgError:
            xs = np.linalg.lstsq(Gs, gs, rcond=None)[0]
        x = np.zeros(len(g))
        x[on] = xs / so
        return x

    @staticmethod
    def output(A, b, outer=None):
        """Model output of coefficients `b` on design `A` (see :meth:`fit_linear`)."""
        if outer is None:
            return A @ b
        if isinstance(outer, prelimit.PreLimit):
            return prelimit.output(A, b, outer)
        z = A[:, :-1] @ b[:-1]
        return z + b[-1] * outer[0].shape(z, outer[1])[0]

    def cost(self, X, effects, TH, yrefs):
        """Training RMS [µm] of each candidate row (inf for divergent rows)."""
        out = np.full(np.atleast_2d(X).shape[0], np.inf)
        for p, (A, o) in enumerate(self.designs(self.records, X, effects, TH, yrefs, limits=True)):
            b, r = self.fit_linear(self.rows(A), self.y, self.limit_on(o, self.keep), nonneg=self.nonneg(effects))
            if b is not None:
                out[p] = math.sqrt(float(np.mean(r * r)))
        return out

    def cost_at(self, x, effects, th, yrefs):
        """Training RMS [µm] of one configuration: search vector `x`, effect parameters `th`."""
        return float(self.cost(np.asarray(x, dtype=float)[None, :], effects,
                               [np.asarray(t, dtype=float)[None, :] for t in th], yrefs)[0])

    def best_grid_point(self, x, effects, th, yrefs, new):
        """The grid point of the block ``effects[new]`` with the lowest training
        cost, everything else held at (`x`, `th`): (`th` with it, that cost)."""
        G = effects[new].grid
        X = np.repeat(np.asarray(x, dtype=float)[None, :], len(G), axis=0)
        TH = [np.repeat(np.asarray(t, dtype=float)[None, :], len(G), axis=0) for t in th]
        TH[new] = G
        c = self.cost(X, effects, TH, yrefs)
        j = int(np.argmin(c))
        th = list(th)
        th[new] = G[j]
        return th, float(c[j])

    def split(self, Z, effects):
        Z = np.atleast_2d(Z)
        X = Z[:, :self.nx]
        TH, k = [], self.nx
        for e in effects:
            TH.append(Z[:, k:k + len(e.names)])
            k += len(e.names)
        return X, TH

    # -- refit ------------------------------------------------------------

    def refit(self, effects, x0, th0, yrefs, evals=90, seed=0, new=None, local=True, popsize=4):
        """Joint refit of the nominal and the effects' nonlinear parameters.

        Parameters
        ----------
        effects : list of Effect
        x0 : ndarray
            Nominal search vector to start from.
        th0 : list of ndarray
            Starting parameters of each effect; for the effect at index
            `new` (if given) its grid is tried first with everything else fixed.
        evals : int
            Evaluation budget (each evaluation simulates every record once).
        local : bool
            True: gradient polish in a box around `x0` (±0.5 decade for
            log-scaled variables, ±15 % of the range otherwise), ended by
            the budget or by an iteration that gains less than
            :data:`REFIT_RTOL` of the cost. False: jDE
            over the full bounds of the search space with `x0` in the
            initial population, then a polish (a fifth of the budget).
        popsize : int
            jDE population (local: 4, only the start matters).

        Returns
        -------
        dict with ``x``, ``th`` (list), ``beta``, ``rms`` (training), ``nfev``.
        """
        th0 = [np.asarray(t, dtype=float) for t in th0]
        nfev = 0
        if new is not None and len(effects[new].names):
            th0, _ = self.best_grid_point(x0, effects, th0, yrefs, new)
            nfev += len(effects[new].grid)
        bounds = list(self.core.local_bounds(x0)) if local else list(self.core.bounds)
        logs = list(self.core.log_scale)
        for e in effects:
            bounds += e.bounds
            logs += e.log_scale
        z0 = np.concatenate([np.asarray(x0, dtype=float)] + th0)
        z0 = np.clip(z0, [b[0] for b in bounds], [b[1] for b in bounds])

        def fun(Z):
            X, TH = self.split(Z, effects)
            return self.cost(X, effects, TH, yrefs)

        if local:
            max_evals, polish = popsize + int(evals), int(evals)
        else:
            max_evals, polish = int(evals), int(evals) // 5
        z = z0
        if bounds:  # nothing to search on a reference core without nonlinear effect parameters
            res = jde_minimize(fun, bounds, log_scale=logs, popsize=popsize, max_evals=max_evals,
                               polish=True, polish_maxfev=polish, seed=seed, x0=z0,
                               polish_rtol=REFIT_RTOL if local else None)
            nfev += res.nfev
            f0 = float(fun(z0[None, :])[0])
            if res.fun <= f0:
                z = res.x
        X, TH = self.split(z, effects)
        return self._fit_at(X, TH, effects, yrefs, nfev + 1)

    def fit_at(self, x, effects, th, yrefs):
        """The configuration at the nominal search vector `x` and effect
        parameters `th`, only its linear weights solved (no search)."""
        X = np.array(x, dtype=float)[None, :]  # a copy: the fit is a new configuration
        TH = [np.array(t, dtype=float)[None, :] for t in th]
        return self._fit_at(X, TH, effects, yrefs, 1)

    def _fit_at(self, X, TH, effects, yrefs, nfev):
        A, o = self.design_limit(self.records, X, effects, TH, yrefs)
        beta, r = self.fit_linear(self.rows(A), self.y, self.limit_on(o, self.keep), nonneg=self.nonneg(effects))
        return {"x": X[0], "th": [t[0] for t in TH], "beta": beta,
                "rms": math.sqrt(float(np.mean(r * r))) if beta is not None else math.inf,
                "nfev": nfev}

    def predict(self, records, fit, effects, yrefs):
        """Outputs [µm] of a fitted configuration on `records` (list of arrays);
        NaN throughout for a fit with no coefficients (:meth:`refit` of a
        configuration whose training design is not finite: rms inf), which the
        callers take as a model that diverges."""
        if fit["beta"] is None:
            return [np.full(len(r.u), np.nan) for r in records]
        X = fit["x"][None, :]
        TH = [t[None, :] for t in fit["th"]]
        A, o = self.design_limit(records, X, effects, TH, yrefs)
        y = self.output(A, fit["beta"], o)
        out, k = [], 0
        for r in records:
            out.append(y[k:k + len(r.u)])
            k += len(r.u)
        return out

    def model(self, fit):
        """The FONBW model (natural parameters) of a fitted configuration (FONBW core only)."""
        c = fit["beta"][:self.N]
        G = float(fit["beta"][self.N])
        p = self.space.final_params(fit["x"], c, G)
        theta = np.array([p[k] for k in self.pnames], dtype=float)
        return hyst.model_from_vector(KIND, theta, self.N, self.memory)

    def effect_params(self, fit, effects):
        out = {}
        for e, th, sl in zip(effects, fit["th"], self.lin_slices(effects)):
            out[e.name] = e.describe(th, fit["beta"][sl], self.core.name)
        return out


def x_from_model(model, space):
    """Search vector (identify's reparametrization) of a FONBW/NBW model."""
    from ..identify import search_vector

    try:
        return search_vector(model, space)
    except ValueError as exc:
        raise ValueError(f"diagnose: {exc}; the nominal model cannot be refit") from None


def decimate(records, q):
    """Every q-th sample of each record (the global search runs on these; the
    inputs of the paper's experiments are far below the new Nyquist frequency)."""
    return [io_decimate(r, max(1, q)) for r in records]
