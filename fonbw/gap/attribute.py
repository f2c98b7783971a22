"""Attribute a sim-to-real gap to candidate effects, and check the finding.

:func:`diagnose` runs the three steps of the design notes on measured records
split into training and validation sets:

1. **Nominal** — the FONBW model (eqs. 9-11) identified on the training
   records with :func:`fonbw.identify.identify` (or a given model), then
   polished by the same joint refit the candidates get, so that a candidate
   is never credited with what a longer optimization of the nominal model
   alone would have given.
2. **Localize** — :func:`fonbw.gap.localize.localize` on the validation
   residual; the noise floor σ² comes from the residual spectrum.
3. **Attribute** — each block of :mod:`fonbw.gap.effects` is added to the
   nominal model and *everything* is refit jointly on the training records:
   the nonlinear parameters of the hysteresis (ρ, σ^(1/n)ρ, n, λ1, λ2) and of
   the effect by a global search (jDE on decimated records) and a
   warm-started local one (a grid over the effect's parameters, then
   :func:`fonbw.de.jde_minimize`'s gradient polish), the linear ones (ku,
   kh, creep gains, drift coefficients) by least squares at every
   evaluation, or by Gauss-Newton with the saturation block, which bends
   the model's own output. On the validation records

       gap_closed = (MSE0 − MSE) / (MSE0 − σ²)

   with MSE0 the nominal model's mean squared error.
4. **Check** — an effect is accepted only if it closes a material part of
   the excess gap (``min_gap_closed``), lowers the Bayesian information
   criterion on the training records, survives a Bayesian block bootstrap over
   segments of the validation records (10th percentile of gap_closed > 0;
   Dirichlet weights, because the evidence of a lag sits in the two or three
   segments with step edges, see :func:`_bootstrap`), and its parameters
   agree across training records: with the linear parameters fitted on all
   but one record, the effect still lowers the error on the held-out
   records over the time and the displacements the other records span
   (leave one record out, pooled). Greedy, at
   most ``max_effects`` effects, strongest first; among passing effects that
   close nearly as much (``tie_margin``) the one with the lowest BIC wins
   (lags of a delay, an amplifier and a resonance look alike on the
   validation sines; the step edges of the training records tell them apart),
   and a block whose fit degenerates into another effect (a resonance above
   the Nyquist frequency or at its damping bound is only a lag) yields to a
   tied block that is identified, or to an identified passing block with a
   lower training BIC. Validation
   conditions the training records never covered (amplitude, rate,
   frequency, hold length) are flagged.

The verdict names nothing when the nominal gap is at the noise floor
(MSE0 ≤ (1 + ``floor_tol``) σ²) and says "unexplained" when the accepted
effects close less than half of the excess gap.
"""
from __future__ import annotations

import math
import time

import numpy as np

from .. import hysteresis as hyst
from ..de import jde_minimize
from ..io import Record
from . import effects as fx
from .localize import localize, noise_floor

__all__ = ["diagnose", "Fitter", "coverage"]

KIND = "fonbw"


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
    """

    def __init__(self, records, space, N=3, memory="fast"):
        self.records = records
        self.space = space
        self.N = N
        self.memory = memory
        self.dt = records[0].dt
        self.pnames = hyst.param_names(KIND, N)
        self.y = np.concatenate([r.y for r in records])
        self.nx = len(space.names)

    # -- design -----------------------------------------------------------

    def _theta(self, X):
        p = self.space.basis_params(np.atleast_2d(X))
        return np.column_stack([np.asarray(p[k], dtype=float) for k in self.pnames])

    def design(self, records, X, effects, TH, yrefs):
        """Regressor matrices, one (n_total, q) array per candidate row.

        ``TH`` holds one (P, k_e) array per effect; ``yrefs`` the nominal
        output of each record (creep's driving signal). Column order:
        (u/U)^1..N, ħ, then each effect's additive regressors.
        """
        X = np.atleast_2d(X)
        P = X.shape[0]
        theta = self._theta(X)
        inp = [(e, th) for e, th in zip(effects, TH) if e.input_side]
        # rows that share X and input-side parameters share one simulation
        key = np.hstack([X] + [th for _, th in inp]) if inp else X
        uniq, inv = np.unique(key, axis=0, return_inverse=True)
        inv = np.ravel(inv)
        first = np.array([int(np.flatnonzero(inv == j)[0]) for j in range(len(uniq))])
        mats = [[] for _ in range(P)]
        for rec, yref in zip(records, yrefs):
            n = len(rec.u)
            Us = np.empty((len(first), n))
            for j, p in enumerate(first):
                u = rec.u
                for e, th in inp:
                    u = e.transform_input(u, rec.dt, th[p])
                Us[j] = u
            if inp:
                S = simulate_rows(theta[first], Us, rec.dt, self.memory, self.N)
            else:
                S = hyst.simulate_population(KIND, theta[first], rec.u, rec.dt, memory=self.memory, N=self.N)
            ctx = {"t": np.arange(n) * rec.dt, "y_ref": yref, "dt": rec.dt}
            # regressors of blocks without nonlinear parameters are the same for every row
            fixed = {id(e): e.columns(ctx, ()) for e in effects if not e.names}
            for p in range(P):
                j = inv[p]
                F = self.space.fixed_columns(Us[j]).T  # (N, n)
                M = np.vstack([F, S[j][None, :]])
                filt, plain, last = [M], [], []
                for e, th in zip(effects, TH):
                    C = fixed[id(e)] if id(e) in fixed else e.columns(ctx, th[p])
                    if C is not None:
                        (last if e.output_nonlinear else filt if e.filtered_columns else plain).append(C.T)
                M = np.vstack(filt)
                for e, th in zip(effects, TH):
                    M = e.output_op(M, rec.dt, th[p])
                mats[p].append(np.vstack([M] + plain + last))
        return [np.hstack(m).T for m in mats]

    def lin_slices(self, effects):
        """Where each effect's linear parameters sit in the coefficient vector.

        The column order of :meth:`design`: the base columns (N + 1), the
        filtered regressors, the plain ones, the output nonlinearity last.
        """
        k = self.N + 1
        out = [None] * len(effects)
        groups = ([i for i, e in enumerate(effects) if e.filtered_columns and not e.output_nonlinear],
                  [i for i, e in enumerate(effects) if not e.filtered_columns and not e.output_nonlinear],
                  [i for i, e in enumerate(effects) if e.output_nonlinear])
        for g in groups:
            for i in g:
                q = len(effects[i].lin_names)
                out[i] = slice(k, k + q)
                k += q
        return out

    @staticmethod
    def outer(effects, TH, p):
        """The output nonlinearity of row `p` as (effect, parameters), or None."""
        for e, th in zip(effects, TH):
            if e.output_nonlinear:
                return e, np.asarray(th[p], dtype=float)
        return None

    # -- costs ------------------------------------------------------------

    @staticmethod
    def solve(A, y):
        """Least-squares coefficients and residual; non-finite columns -> (None, None).

        Normal equations on unit-norm columns (a few columns, many samples:
        far cheaper than a QR of A); the residual is formed explicitly, so
        its accuracy does not suffer from the squared condition number
        beyond second order.
        """
        if not np.all(np.isfinite(A)):
            return None, None
        s = np.sqrt(np.einsum("ij,ij->j", A, A))
        # a regressor these samples do not excite (a saturation knee above
        # every displacement of a subset) gets coefficient 0, not 1/ε
        on = s > 1e-10 * max(float(s.max()), 1e-300)
        As = A[:, on] / s[on]
        G = As.T @ As
        try:
            bs = np.linalg.solve(G, As.T @ y)
        except np.linalg.LinAlgError:
            bs, *_ = np.linalg.lstsq(As, y, rcond=None)
        b = np.zeros(A.shape[1])
        b[on] = bs / s[on]
        return b, y - A @ b

    @classmethod
    def fit_linear(cls, A, y, outer=None, iters=8):
        """Linear coefficients and residual of ``y ≈ A b``, or of the output
        nonlinearity ``y ≈ z + c f(z)``, ``z = A[:, :-1] b[:-1]``, ``c = b[-1]``.

        The nonlinear form starts from the plain least-squares solution (the
        last column of `A` is f driven by the nominal output) and takes
        Gauss-Newton steps with the Jacobian [(1 + c f'(z)) A[:, :-1], f(z)],
        halving a step that does not lower the residual. Returns
        (None, None) for non-finite columns.
        """
        b, r = cls.solve(A, y)
        if outer is None or b is None:
            return b, r
        e, th = outer
        B = A[:, :-1]
        b = b.copy()

        def resid(b):
            f, df = e.shape(B @ b[:-1], th)
            return y - (B @ b[:-1] + b[-1] * f), f, df

        r, f, df = resid(b)
        sse = float(r @ r)
        for _ in range(iters):
            J = np.column_stack([B * (1.0 + b[-1] * df)[:, None], f])
            step, _ = cls.solve(J, r)
            if step is None:
                break
            lam, better = 1.0, False
            for _ in range(6):
                bn = b + lam * step
                rn, fn, dfn = resid(bn)
                sn = float(rn @ rn)
                if sn < sse:
                    better = True
                    break
                lam *= 0.5
            if not better:
                break
            gain = (sse - sn) / max(sse, 1e-300)
            b, r, f, df, sse = bn, rn, fn, dfn, sn
            if gain < 1e-9:
                break
        return b, r

    @staticmethod
    def output(A, b, outer=None):
        """Model output of coefficients `b` on design `A` (see :meth:`fit_linear`)."""
        if outer is None:
            return A @ b
        z = A[:, :-1] @ b[:-1]
        return z + b[-1] * outer[0].shape(z, outer[1])[0]

    def cost(self, X, effects, TH, yrefs):
        """Training RMS [µm] of each candidate row (inf for divergent rows)."""
        out = np.full(np.atleast_2d(X).shape[0], np.inf)
        for p, A in enumerate(self.design(self.records, X, effects, TH, yrefs)):
            b, r = self.fit_linear(A, self.y, self.outer(effects, TH, p))
            if b is not None:
                out[p] = math.sqrt(float(np.mean(r * r)))
        return out

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
            log-scaled variables, ±15 % of the range otherwise). False: jDE
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
            G = effects[new].grid
            X = np.repeat(np.asarray(x0)[None, :], len(G), axis=0)
            TH = [np.repeat(t[None, :], len(G), axis=0) for t in th0]
            TH[new] = G
            c = self.cost(X, effects, TH, yrefs)
            nfev += len(G)
            th0[new] = G[int(np.argmin(c))]
        bounds = list(_nominal_bounds(self.space, x0)) if local else [tuple(b) for b in self.space.bounds]
        logs = list(self.space.log_scale)
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
        res = jde_minimize(fun, bounds, log_scale=logs, popsize=popsize, max_evals=max_evals,
                           polish=True, polish_maxfev=polish, seed=seed, x0=z0)
        nfev += res.nfev
        z = res.x
        f0 = float(fun(z0[None, :])[0])
        if not res.fun <= f0:
            z = z0
        X, TH = self.split(z, effects)
        A = self.design(self.records, X, effects, TH, yrefs)[0]
        beta, r = self.fit_linear(A, self.y, self.outer(effects, TH, 0))
        return {"x": X[0], "th": [t[0] for t in TH], "beta": beta,
                "rms": math.sqrt(float(np.mean(r * r))) if beta is not None else math.inf,
                "nfev": nfev + 1}

    def predict(self, records, fit, effects, yrefs):
        """Outputs [µm] of a fitted configuration on `records` (list of arrays)."""
        X = fit["x"][None, :]
        TH = [t[None, :] for t in fit["th"]]
        A = self.design(records, X, effects, TH, yrefs)[0]
        y = self.output(A, fit["beta"], self.outer(effects, TH, 0))
        out, k = [], 0
        for r in records:
            out.append(y[k:k + len(r.u)])
            k += len(r.u)
        return out

    def model(self, fit):
        """The FONBW model (natural parameters) of a fitted configuration."""
        c = fit["beta"][:self.N]
        G = float(fit["beta"][self.N])
        p = self.space.final_params(fit["x"], c, G)
        theta = np.array([p[k] for k in self.pnames], dtype=float)
        return hyst.model_from_vector(KIND, theta, self.N, self.memory)

    def effect_params(self, fit, effects):
        out = {}
        for e, th, sl in zip(effects, fit["th"], self.lin_slices(effects)):
            out[e.name] = e.describe(th, fit["beta"][sl])
        return out


def _nominal_bounds(space, x0):
    """A box around the nominal search vector (the refit is local)."""
    for (lo, hi), lg, v in zip(space.bounds, space.log_scale, x0):
        if lg:
            a, b = v / 10 ** 0.5, v * 10 ** 0.5
        else:
            w = 0.15 * (hi - lo)
            a, b = v - w, v + w
        yield (max(lo, min(a, v)), min(hi, max(b, v)))


def _x_from_model(model, space):
    """Search vector (identify's reparametrization) of a FONBW/NBW model."""
    p = model.params
    rho, sigma, n = float(p["rho"]), float(p["sigma"]), float(p["n"])
    if sigma <= 0:
        raise ValueError("diagnose: the model's sigma must be > 0 to be refit")
    x = [rho, sigma ** (1.0 / n) * rho, n]
    if len(space.names) == 5:
        x += [float(getattr(model, "lam1", 1.0)), float(getattr(model, "lam2", 1.0))]
    return np.array(x)


def coverage(train, validate, dt):
    """Validation conditions outside the training records' range.

    Returns a list of {"condition", "train", "validate", "record"} for the
    amplitude (max and min u), peak input rate, dominant frequency and
    longest hold (steady input) that exceed the training range by > 10 %.
    """
    def stats(r):
        u = r.u
        rate = np.abs(np.diff(u)) / dt
        hold, run = 0, 0
        for s in np.abs(np.diff(u)) <= 1e-6 * max(np.ptp(u), 1e-9):
            run = run + 1 if s else 0
            hold = max(hold, run)
        U = np.fft.rfft(u - u.mean())
        f = np.fft.rfftfreq(len(u), dt)
        p = np.abs(U) ** 2
        # the frequency below which 95 % of the input's power lies
        cum = np.cumsum(p) / max(p.sum(), 1e-300)
        f95 = float(f[min(int(np.searchsorted(cum, 0.95)), len(f) - 1)])
        return {"u_max": float(u.max()), "u_min": float(u.min()),
                "rate_p99": float(np.quantile(rate, 0.99)) if rate.size else 0.0,
                "f95": f95, "hold_s": hold * dt, "duration_s": len(u) * dt}
    tr = [stats(r) for r in train]
    flags = []
    lims = {"u_max": max(s["u_max"] for s in tr), "rate_p99": max(s["rate_p99"] for s in tr),
            "f95": max(s["f95"] for s in tr), "hold_s": max(s["hold_s"] for s in tr),
            "duration_s": max(s["duration_s"] for s in tr)}
    umin = min(s["u_min"] for s in tr)
    for r in validate:
        s = stats(r)
        for k, lim in lims.items():
            # holds shorter than 50 ms are turning points, not holds
            if s[k] > 1.1 * lim + 1e-12 and (k != "hold_s" or s[k] > 0.05):
                flags.append({"condition": k, "train": lim, "validate": s[k], "record": str(r.path)})
        span = max(lims["u_max"] - umin, 1e-9)
        if s["u_min"] < umin - 0.1 * span:
            flags.append({"condition": "u_min", "train": umin, "validate": s["u_min"], "record": str(r.path)})
    return flags


def decimate(records, q):
    """Every q-th sample of each record (the global search runs on these; the
    inputs of the paper's experiments are far below the new Nyquist frequency)."""
    if q <= 1:
        return list(records)
    return [Record.from_arrays(u=r.u[::q], y=r.y[::q], dt=r.dt * q, path=r.path) for r in records]


def _mse(records, preds):
    n = sum(len(r.y) for r in records)
    return float(sum(np.sum((r.y - p) ** 2) for r, p in zip(records, preds)) / n)


def _bootstrap(records, p0, p1, sigma2, seed, B=400, seg=0.2):
    """Bayesian block bootstrap over validation segments of `seg` s.

    Every resample weighs the segments by Dirichlet(1, …, 1) weights (Rubin's
    Bayesian bootstrap) and returns quantiles of

        gap_closed_b = Σ w_j (SSE0_j − SSE1_j) / Σ w_j n_j / (MSE0 − σ²),

    the improvement of the resample over the excess of the whole validation
    set (a resample's own excess can be near zero, which would make a ratio
    unstable). Why not the multinomial bootstrap: an effect seen only at the
    few step edges of the validation records (a lag, a resonance) lives in
    two or three segments, and a multinomial resample drops all k of them
    with probability ≈ e^−k — 13 % for two edges — so its 10th percentile
    is the effect-free value whatever the effect. Continuous weights never
    drop a segment; an improvement carried by one segment against losses
    elsewhere still fails, because that segment's weight falls below a
    tenth of its mean in one resample out of ten.
    """
    e0, e1, lens = [], [], []
    for r, a, b in zip(records, p0, p1):
        L = max(8, int(round(seg / r.dt)))
        for k in range(0, len(r.y), L):
            e0.append(float(np.sum((r.y[k:k + L] - a[k:k + L]) ** 2)))
            e1.append(float(np.sum((r.y[k:k + L] - b[k:k + L]) ** 2)))
            lens.append(min(L, len(r.y) - k))
    e0, e1, lens = np.array(e0), np.array(e1), np.array(lens, dtype=float)
    excess = e0.sum() / lens.sum() - sigma2
    if not excess > 0:
        return {"p05": 0.0, "p10": 0.0, "p50": 0.0}
    rng = np.random.default_rng(seed)
    w = rng.dirichlet(np.ones(len(e0)), size=B)
    g = (w @ (e0 - e1)) / (w @ lens) / excess
    g = g[np.isfinite(g)]
    if g.size == 0:
        return {"p05": 0.0, "p10": 0.0, "p50": 0.0}
    return {"p05": float(np.quantile(g, 0.05)), "p10": float(np.quantile(g, 0.1)),
            "p50": float(np.quantile(g, 0.5))}


def _loro(fitter, fit_base, fit_eff, eff_base, eff_new, yrefs):
    """Leave one training record out: does the effect still help the held-out record?

    The linear parameters (ku, kh and the effects' gains) are refit on the
    other records; the nonlinear ones are kept. The held-out record is
    scored over the time and the displacements the other records span (a
    record may be the only one to reach a stroke limit: agreement cannot be
    judged there). Returns the held-out MSE ratios effect/base per record
    and pooled over the records (< 1: the effect helps), or None with one
    record.
    """
    recs = fitter.records
    if len(recs) < 2:
        return None
    A0 = fitter.design(recs, fit_base["x"][None, :], eff_base, [t[None, :] for t in fit_base["th"]], yrefs)[0]
    A1 = fitter.design(recs, fit_eff["x"][None, :], eff_new, [t[None, :] for t in fit_eff["th"]], yrefs)[0]
    o0 = fitter.outer(eff_base, [t[None, :] for t in fit_base["th"]], 0)
    o1 = fitter.outer(eff_new, [t[None, :] for t in fit_eff["th"]], 0)
    lens = [len(r.y) for r in recs]
    bounds = np.cumsum([0] + lens)
    ratios, tot = [], [0.0, 0.0]
    for i in range(len(recs)):
        m = np.ones(bounds[-1], dtype=bool)
        m[bounds[i]:bounds[i + 1]] = False
        # the held-out record is scored only over the time the other records
        # span: agreement of the parameters, not extrapolation in time (a
        # drift fitted on 3 s says little about second 8)
        k = min(lens[i], max(lens[j] for j in range(len(recs)) if j != i))
        held = np.arange(bounds[i], bounds[i] + k)
        # ... and over the displacements they span: a stroke limit that only
        # one record reaches cannot be checked for agreement by the others
        yo = fitter.y[m]
        held = held[(fitter.y[held] >= yo.min()) & (fitter.y[held] <= yo.max())]
        if held.size == 0:
            continue
        out = []
        for A, o in ((A0, o0), (A1, o1)):
            b, _ = fitter.fit_linear(A[m], fitter.y[m], o)
            r = fitter.y[held] - fitter.output(A[held], b, o)
            out.append(float(np.mean(r * r)))
        ratios.append(out[1] / out[0] if out[0] > 0 else 1.0)
        tot[0] += out[0] * held.size
        tot[1] += out[1] * held.size
    # the pooled held-out error decides; per-record ratios are reported
    return {"ratios": ratios, "pooled_ratio": tot[1] / tot[0] if tot[0] > 0 else 1.0}


def _as_records(recs, what):
    if recs is None:
        raise ValueError(f"diagnose: need at least one {what} record")
    if isinstance(recs, Record):
        recs = [recs]
    recs = list(recs)
    if not recs:
        raise ValueError(f"diagnose: need at least one {what} record")
    for r in recs:
        if r.u is None or r.y is None:
            raise ValueError(f"diagnose: {what} record {r.path} needs columns u and y")
        if len(r.u) < 64:
            raise ValueError(f"diagnose: {what} record {r.path} has {len(r.u)} samples; need at least 64")
    return recs


def diagnose(train_records, validate_records, model=None, seed=0, progress=False, budget=1000,
             refit_evals=90, global_evals=None, coarse_rate=1000.0, effects=fx.EFFECTS, max_effects=3,
             min_gap_closed=0.2, floor_tol=0.2, tie_margin=0.05, N=3, memory="fast"):
    """Diagnose the gap between the nominal FONBW model and measured records.

    Parameters
    ----------
    train_records, validate_records : list of Record
        Measured records (u [V], y [µm]) with one sampling period.
    model : FONBW or NBW, optional
        Nominal model; identified on the training records if None.
    seed : int
        Seed of every random choice (identification, refits, bootstrap).
    progress : bool
        Print one line per step to stderr.
    budget : int
        Evaluations of the nominal identification (each simulates every
        training record once, decimated to `coarse_rate`).
    refit_evals : int
        Evaluations of the local joint refit at the full rate, per candidate.
    global_evals : int, optional
        Evaluations of the global joint search (jDE over the full bounds)
        per candidate, on the records decimated to `coarse_rate`: an effect
        the nominal fit has absorbed can leave the hysteresis parameters far
        from where they belong, out of reach of a local refit (a 3 ms delay
        fitted as λ2 = 0.05 against a true 0.6). Default: `budget`, so a
        candidate gets the search the nominal model got.
    coarse_rate : float
        Sampling rate [Hz] of the global searches (records are decimated to
        it when sampled faster).
    effects : sequence of str
        Candidate blocks (:data:`fonbw.gap.effects.EFFECTS`).
    max_effects : int
        Greedy steps.
    min_gap_closed : float
        Part of the excess gap an effect must close to be material.
    floor_tol : float
        The gap is at the noise floor when MSE0 ≤ (1 + floor_tol) σ².
    tie_margin : float
        Passing effects that close at least the best one's gap_closed minus
        this margin are tied; the lowest training BIC among them wins.
    N : int
        Order of g(u) of the nominal model.
    memory : str
        GL memory engine.

    Returns
    -------
    dict
        The JSON contract: ``nominal`` {model, rms_validate, noise_floor (σ
        [µm]), rms_train}, ``localization``, ``candidates`` [{effect,
        gap_closed, accepted, params, checks}], ``verdict`` {effects,
        gap_closed, unexplained, at_noise_floor, steps, coverage}, ``timing``.
    """
    import sys

    from ..identify import identify, search_space  # the module, not fonbw.identify (the function)

    t_start = time.perf_counter()
    global_evals = int(budget if global_evals is None else global_evals)
    train = _as_records(train_records, "training")
    val = _as_records(validate_records, "validation")
    dt = train[0].dt
    for r in train + val:
        if not math.isclose(r.dt, dt, rel_tol=1e-6):
            raise ValueError(f"diagnose: record {r.path} has dt = {r.dt} s, the first training record {dt} s; "
                             "all records need one sampling period")
    say = (lambda *a: print("[diagnose]", *a, file=sys.stderr, flush=True)) if progress else (lambda *a: None)
    space = search_space(KIND, train, N=N)
    fitter = Fitter(train, space, N=N, memory=memory)
    q = max(1, int(round(1.0 / (coarse_rate * dt))))
    coarse = decimate(train, q)
    fitter_c = Fitter(coarse, space, N=N, memory=memory)
    U = max(float(np.max(np.abs(r.u))) for r in train)
    t_max = max(len(r.u) * dt for r in train + val)
    ys = np.concatenate([r.y for r in train])
    # the top is the largest displacement, not a quantile: a stroke limit may
    # bind only at brief peaks (FONBW's spikes at step edges), fewer than
    # 0.1 % of the training samples
    lib = fx.library(dt, U, t_max, effects, y_range=(float(np.quantile(ys, 0.001)), float(np.max(ys))))
    timing = {}

    # 1. nominal
    t0 = time.perf_counter()
    given = None
    if model is None:
        res = identify(coarse, KIND, seed=seed, max_evals=int(budget), N=N, memory=memory)
        x0 = np.asarray(res.search["x"], dtype=float)
    else:
        if getattr(model, "kind", None) not in ("fonbw", "nbw"):
            raise ValueError(f"diagnose: the nominal model must be FONBW or NBW, got {getattr(model, 'kind', model)!r}")
        x0 = _x_from_model(model, space)
        given = model
    # the creep block is driven by the nominal output: a first pass without it
    zero_ref = [np.zeros(len(r.u)) for r in train]
    base = fitter.refit([], x0, [], zero_ref, evals=refit_evals, seed=seed)
    nominal = fitter.model(base)
    yref_tr = fitter.predict(train, base, [], zero_ref)
    yref_c = [y[::q] for y in yref_tr]
    yref_va = [nominal.simulate(r.u, dt) for r in val]
    p0_va = fitter.predict(val, base, [], [np.zeros(len(r.u)) for r in val])
    timing["nominal_s"] = time.perf_counter() - t0
    say(f"nominal fitted in {timing['nominal_s']:.1f} s, train rms {base['rms']:.4g} µm")

    # 2. noise floor and localization
    res_all = [r.y - p for r, p in zip(train, yref_tr)] + [r.y - p for r, p in zip(val, p0_va)]
    sigma2 = noise_floor(res_all, dt)
    loc = localize(val, p0_va, dt, sigma2)
    mse0 = _mse(val, p0_va)
    mse0_tr = base["rms"] ** 2
    excess0 = mse0 - sigma2
    at_floor = mse0 <= (1.0 + floor_tol) * sigma2
    ntr = len(fitter.y)
    cov = coverage(train, val, dt)
    say(f"noise floor σ = {math.sqrt(sigma2):.4g} µm, validation rms {math.sqrt(mse0):.4g} µm"
        + (" (at the floor)" if at_floor else ""))

    def evaluate(active, new_idx, start):
        """Refit `active` effects (the last is new) from `start` and score it."""
        eff = [lib[i] for i in active]
        th0 = [start["th"][j] if j < len(start["th"]) else (e.grid[0] if len(e.names) else np.zeros(0))
               for j, e in enumerate(eff)]
        fc = fitter_c.refit(eff, start["x"], th0, yref_c, evals=global_evals, seed=seed,
                            new=len(eff) - 1, local=False, popsize=16)
        # the coarse optimum can sit worse at the full rate than the start
        # itself (the GL sums depend on the step): polish the better of the
        # two, the start with the new block's grid tried at the full rate
        new_i = len(eff) - 1
        th_s = list(th0)
        if len(eff[new_i].names):
            G = eff[new_i].grid
            X = np.repeat(np.asarray(start["x"])[None, :], len(G), axis=0)
            TH = [np.repeat(np.asarray(t, dtype=float)[None, :], len(G), axis=0) for t in th_s]
            TH[new_i] = G
            c = fitter.cost(X, eff, TH, yref_tr)
            th_s[new_i] = G[int(np.argmin(c))]
            c_s = float(np.min(c))
        else:
            c_s = float(fitter.cost(np.asarray(start["x"])[None, :], eff,
                                    [np.asarray(t, dtype=float)[None, :] for t in th_s], yref_tr)[0])
        c_c = float(fitter.cost(fc["x"][None, :], eff, [t[None, :] for t in fc["th"]], yref_tr)[0])
        x1, th1 = (fc["x"], fc["th"]) if c_c <= c_s else (np.asarray(start["x"]), th_s)
        fit = fitter.refit(eff, x1, th1, yref_tr, evals=refit_evals, seed=seed)
        pv = fitter.predict(val, fit, eff, yref_va)
        return fit, pv, _mse(val, pv)

    t0 = time.perf_counter()
    current = {"fit": base, "eff": [], "idx": [], "mse": mse0, "mse_tr": mse0_tr, "pred": p0_va}
    candidates = []
    accepted = []
    steps = [{"label": "nominal", "rms_validate": math.sqrt(mse0)}]
    pool = list(range(len(lib)))
    for step in range(max_effects):
        if current["mse"] <= (1.0 + floor_tol) * sigma2 or not pool:
            break
        results = []
        for i in pool:
            fit, pv, mse = evaluate(current["idx"] + [i], len(current["idx"]), current["fit"])
            eff = current["eff"] + [lib[i]]
            gc = (current["mse"] - mse) / excess0 if excess0 > 0 else 0.0
            if not math.isfinite(gc):
                gc = -math.inf  # diverged on the validation inputs
            k = len(lib[i].names) + len(lib[i].lin_names)
            dbic = ntr * math.log(max(fit["rms"] ** 2, 1e-300) / current["mse_tr"]) + k * math.log(ntr)
            checks = {"gap_closed_step": gc if math.isfinite(gc) else None, "delta_bic": dbic,
                      "material": bool(gc >= min_gap_closed * (1.0 if step == 0 else 0.5)
                                       and current["mse"] - mse > 0.1 * sigma2)}
            if checks["material"] and dbic < 0:
                checks["bootstrap"] = _bootstrap(val, current["pred"], pv, sigma2, seed)
                checks["loro"] = _loro(fitter, current["fit"], fit, current["eff"], eff, yref_tr)
            passed = (checks["material"] and dbic < 0 and checks["bootstrap"]["p10"] > 0
                      and (checks["loro"] is None or checks["loro"]["pooled_ratio"] < 1.0))
            checks["passed"] = bool(passed)
            checks["identified"] = bool(lib[i].identified(fit["th"][-1]))
            results.append({"i": i, "fit": fit, "pv": pv, "mse": mse, "eff": eff, "checks": checks})
            say(f"step {step + 1}: +{lib[i].name}: gap closed {gc:.3f}, ΔBIC {dbic:.3g}, "
                f"{'passes' if passed else 'fails'} ({time.perf_counter() - t0:.0f} s)")
        if step == 0:
            for r in results:
                gcj = float(r["checks"]["gap_closed_step"])
                candidates.append({
                    "effect": lib[r["i"]].name,
                    "gap_closed": gcj if math.isfinite(gcj) else None,
                    "rms_validate": math.sqrt(r["mse"]) if math.isfinite(r["mse"]) else None,
                    "accepted": False,
                    "params": fitter.effect_params(r["fit"], r["eff"])[lib[r["i"]].name],
                    "checks": _jsonable(r["checks"]),
                })
        ok = [r for r in results if r["checks"]["passed"]]
        if not ok:
            break
        best = max(ok, key=lambda r: r["checks"]["gap_closed_step"])  # finite for passing ones
        # lags of a delay, an amplifier and a resonance close nearly the same
        # part of the validation gap (the sines at 1-25 Hz cannot tell them
        # apart); among those the training records' information criterion
        # decides, which weighs the step edges and charges every parameter
        tied = [r for r in ok if r["checks"]["gap_closed_step"] >= best["checks"]["gap_closed_step"] - tie_margin]
        # a block whose fit degenerates into another effect (a "resonance"
        # above the Nyquist frequency is a lag) yields to a tied one that is
        # identified
        best = min(tied, key=lambda r: (not r["checks"]["identified"], r["checks"]["delta_bic"]))
        # ... and, untied, to an identified passing block that fits the
        # training records better: a lag the resonance block imitates is
        # no evidence of a resonance, while the step edges of the training
        # records (not the validation sines) separate the lags
        if not best["checks"]["identified"]:
            alt = [r for r in ok if r["checks"]["identified"]
                   and r["checks"]["delta_bic"] < best["checks"]["delta_bic"]]
            if alt:
                best = max(alt, key=lambda r: r["checks"]["gap_closed_step"])
        accepted.append(lib[best["i"]].name)
        current = {"fit": best["fit"], "eff": best["eff"], "idx": current["idx"] + [best["i"]],
                   "mse": best["mse"], "mse_tr": best["fit"]["rms"] ** 2, "pred": best["pv"]}
        steps.append({"label": "+" + lib[best["i"]].name, "rms_validate": math.sqrt(best["mse"])})
        # later steps only retry effects that helped on their own
        # (the three best of them: each retry costs a joint refit)
        helped = [c["effect"] for c in sorted(candidates, key=lambda c: -(c["gap_closed"] or -1.0))
                  if (c["gap_closed"] or 0.0) > 0.02 and c["effect"] not in accepted][:3]
        pool = [i for i in pool if i != best["i"] and lib[i].name in helped]
    timing["attribute_s"] = time.perf_counter() - t0
    for c in candidates:
        c["accepted"] = c["effect"] in accepted
    candidates.sort(key=lambda c: -(c["gap_closed"] if c["gap_closed"] is not None else -math.inf))
    steps.append({"label": "noise floor", "rms_validate": math.sqrt(sigma2)})
    total = (mse0 - current["mse"]) / excess0 if excess0 > 0 and not at_floor else 0.0
    # strongest first: by what each accepted effect closes on its own
    alone = {c["effect"]: (c["gap_closed"] if c["gap_closed"] is not None else -math.inf) for c in candidates}
    accepted = sorted(accepted, key=lambda e: -alone.get(e, -math.inf))
    verdict = {
        "effects": [] if at_floor else accepted,
        "gap_closed": float(total),
        "unexplained": bool(not at_floor and total < 0.5),
        "at_noise_floor": bool(at_floor),
        "steps": steps,
        "coverage": cov,
        "params": fitter.effect_params(current["fit"], current["eff"]),
    }
    if at_floor:
        verdict["message"] = "the nominal model's gap is at the noise floor: no effect is named"
    elif not accepted:
        verdict["message"] = "unexplained: no candidate effect closes the gap"
    elif verdict["unexplained"]:
        verdict["message"] = f"partly explained by {', '.join(accepted)}; most of the gap is unexplained"
    else:
        verdict["message"] = f"explained by {', '.join(accepted)}"
    timing["total_s"] = time.perf_counter() - t_start
    out = {
        "nominal": {
            "model": nominal.to_dict(),
            "rms_validate": math.sqrt(mse0),
            "rms_train": base["rms"],
            "noise_floor": math.sqrt(sigma2),
            "given_model_rms_validate": (math.sqrt(_mse(val, [given.simulate(r.u, dt) for r in val]))
                                         if given is not None else None),
        },
        "localization": loc,
        "candidates": candidates,
        "verdict": verdict,
        "timing": timing,
        "records": {"train": [str(r.path) for r in train], "validate": [str(r.path) for r in val]},
    }
    say(verdict["message"])
    return out


def _jsonable(d):
    if isinstance(d, dict):
        return {k: _jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_jsonable(v) for v in d]
    if isinstance(d, (np.floating, float)):
        return float(d)
    if isinstance(d, (np.bool_, bool)):
        return bool(d)
    if isinstance(d, np.integer):
        return int(d)
    return d
