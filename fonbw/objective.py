"""The objective of identification, eq. (18), plain and with the linear
parameters solved (variable projection); see :mod:`fonbw.identify`.

Candidates whose hysteretic basis signal is almost a polynomial of the input
are refused (:data:`MIN_OWN_SHARE`): their gains would cancel.

Records that do not start at rest are simulated after a smooth lead-in from
0 V to their first input (:func:`lead_in`) and count only after their burn-in,
each with its own constant sensor offset among the linear parameters. Once a
model exists, :func:`score` (validation, and identify's reports and plots)
runs such a record after the history that best explains its burn-in instead.
"""
from __future__ import annotations

import numpy as np

__all__ = ["stage_rest", "rms_cost", "Projected", "lead_in", "as_records", "simulate_record", "score",
           "DivergedError"]


class DivergedError(RuntimeError):
    """Every candidate model diverged on the records: the data or the bounds,
    not the code, are at fault (the command line reports it as bad input)."""


#: Smallest share (in RMS) of a candidate's basis signal that is not a linear
#: combination of the fixed regressors (powers of u, offsets). Below it the
#: hysteretic term is a tiny correction to a polynomial of u carried by a huge
#: gain that the polynomial cancels (CBW k_a = −k_b = 7e10, NBW σ = 1e16 on a
#: bipolar record): the data no longer fix the parameters, so such candidates
#: are refused. Well-posed fits have shares of 0.3 to 0.8, the paper's Table 1
#: FONBW 0.55.
MIN_OWN_SHARE = 0.05

#: Longest lead-in [s].
LEAD_IN_MAX = 1.0


def lead_in(u, dt) -> np.ndarray:
    """Input [V] that brings a model from rest to a record's first input `u[0]`.

    A raised-cosine ramp from 0 V to u[0], as long as the record's input takes
    to move by |u[0]| at its median rate (at least 10 samples, at most
    ``LEAD_IN_MAX``). Started with a jump instead, a fractional model's memory
    would hold that jump for a long time (the GL weights decay as a power of
    time), well after the hysteresis state has forgotten the start.

    Parameters
    ----------
    u : ndarray
        The record's input [V].
    dt : float
        Sampling step [s].

    Returns
    -------
    ndarray
        The lead-in samples (none when u[0] = 0).
    """
    u0 = float(u[0])
    if u0 == 0.0:
        return np.zeros(0)
    rate = float(np.median(np.abs(np.diff(u)))) / dt
    T = abs(u0) / rate if rate > 0 else LEAD_IN_MAX
    L = int(np.clip(round(T / dt), 10, max(10, round(LEAD_IN_MAX / dt))))
    return u0 * 0.5 * (1.0 - np.cos(np.pi * np.arange(L) / L))


def simulate_record(model, u, dt, burn_in=0) -> np.ndarray:
    """A model's output [µm] over a record's input `u` [V]: from the model's
    recorded start (from rest, or after the rest cycle it was identified
    behind, counted from the end of it: :mod:`fonbw.compensate.rest`), after
    :func:`lead_in` instead when the record has a burn-in (it does not start
    at rest)."""
    if burn_in <= 0:
        from .compensate.rest import start_history

        pre = start_history(model, dt)
        if pre.size:
            y = model.simulate(np.concatenate([pre, u]), dt)
            return y[pre.size:] - y[pre.size - 1]
        return model.simulate(u, dt)
    pre = lead_in(u, dt)
    return model.simulate(np.concatenate([pre, u]), dt)[pre.size:]

# --------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------

def as_records(records):
    """List of checked (u, y, dt) tuples from a record or a list of records."""
    if records is None:
        raise ValueError("records: need at least one record with u and y")
    if hasattr(records, "u") and hasattr(records, "y"):
        records = [records]
    records = list(records)
    if not records:
        raise ValueError("records: need at least one record with u and y")
    out = []
    for i, r in enumerate(records):
        name = getattr(r, "path", None) or f"record {i}"
        for attr in ("u", "y", "dt"):
            if getattr(r, attr, None) is None:
                raise ValueError(f"{name}: record has no {attr!r}")
        u = np.ascontiguousarray(r.u, dtype=float).reshape(-1)
        y = np.ascontiguousarray(r.y, dtype=float).reshape(-1)
        dt = float(r.dt)
        if u.shape != y.shape:
            raise ValueError(f"{name}: u has {u.size} samples but y has {y.size}")
        if u.size < 8:
            raise ValueError(f"{name}: only {u.size} samples, need at least 8")
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
            raise ValueError(f"{name}: u and y must be finite")
        if not (dt > 0.0 and np.isfinite(dt)):
            raise ValueError(f"{name}: sampling period dt must be > 0, got {dt}")
        out.append((u, y, dt))
    names = ", ".join(str(getattr(r, "path", None) or f"record {i}") for i, r in enumerate(records))
    U = max(float(np.max(np.abs(u))) for u, _, _ in out)
    if U == 0.0:
        raise ValueError(f"{names}: the input u is identically zero; nothing to identify")
    if max(float(np.ptp(u)) for u, _, _ in out) == 0.0:
        # every candidate then diverges or ties: a held voltage traces no loop
        held = ", ".join(f"{u[0]:.6g}" for u, _, _ in out)
        raise ValueError(f"{names}: the input u is constant ({held} V) in every record; a drive that never "
                         "moves shows no hysteresis, nothing to identify")
    if max(float(np.ptp(y)) for _, y, _ in out) == 0.0:
        raise ValueError(f"{names}: the output y is constant; nothing to identify")
    return out


# --------------------------------------------------------------------------
# Objective
# --------------------------------------------------------------------------

def rms_cost(kind, theta, records, *, memory="fast", N=3):
    """Eq. (18) of each row of ``theta`` over all records pooled [µm].

    Each record is simulated from rest separately; divergent candidates
    (NaN rows from the simulator) cost +inf. This is the plain objective, with
    every parameter given (no linear solve).

    Parameters
    ----------
    kind : str
    theta : ndarray, shape (P, d)
        Natural parameters in the order of ``fonbw.hysteresis.param_names``.
    records : record or list of records

    Returns
    -------
    ndarray, shape (P,)
    """
    from fonbw import hysteresis as hyst

    recs = as_records(records)
    theta = np.ascontiguousarray(np.atleast_2d(theta), dtype=float)
    sse = np.zeros(theta.shape[0])
    M = 0
    with np.errstate(over="ignore", invalid="ignore"):
        for u, y, dt in recs:
            Y = hyst.simulate_population(kind, theta, u, dt, memory=memory, N=N)
            sse += np.sum((Y - y) ** 2, axis=1)
            M += y.size
        J = np.sqrt(sse / M)
    return np.where(np.isfinite(J), J, np.inf)


class Projected:
    """Eq. (18) minimized over the linear parameters, for a population.

    With F the fixed regressors (thin QR: F = QR) and s the candidate's basis
    signal, all records stacked: r_y = y − QQᵀy, r_s = s − QQᵀs,
    G = r_s·r_y / r_s·r_s, residual r_y − G r_s, c = R⁻¹Qᵀ(y − G s).
    """

    def __init__(self, space, recs, pnames, kind, memory, N, burn_in=None):
        self.space, self.recs, self.pnames = space, recs, pnames
        self.kind, self.memory, self.N = kind, memory, N
        self.burn_in = list(burn_in) if burn_in is not None else [0] * len(recs)
        F = np.vstack([space.fixed_columns(u)[b:] for (u, _, _), b in zip(recs, self.burn_in)])
        self.q = F.shape[1]
        # A record that does not start at rest has an unknown sensor offset: one
        # constant regressor on its samples (the Zhu model's x0 is a constant
        # already, so it needs one fewer when every record has one).
        self.offset_records = [i for i, b in enumerate(self.burn_in) if b > 0]
        if kind == "zhu" and len(self.offset_records) == len(recs):
            self.offset_records = self.offset_records[1:]
        if self.offset_records:
            sizes = [y.size - b for (_, y, _), b in zip(recs, self.burn_in)]
            ends = np.cumsum(sizes)
            ind = np.zeros((F.shape[0], len(self.offset_records)))
            for j, i in enumerate(self.offset_records):
                ind[ends[i] - sizes[i]:ends[i], j] = 1.0
            F = np.hstack([F, ind])
        self.y = np.concatenate([y[b:] for (_, y, _), b in zip(recs, self.burn_in)])
        self.Q, self.R = np.linalg.qr(F)
        self.ry = self.y - self.Q @ (self.Q.T @ self.y)
        self.M = self.y.size

    def basis(self, X):
        from fonbw import hysteresis as hyst

        p = self.space.basis_params(np.atleast_2d(X))
        theta = np.column_stack([np.asarray(p[k], dtype=float) for k in self.pnames])
        out = []
        for (u, _, dt), b in zip(self.recs, self.burn_in):
            pre = lead_in(u, dt) if b > 0 else np.zeros(0)
            S = hyst.simulate_population(self.kind, theta, np.concatenate([pre, u]), dt,
                                         memory=self.memory, N=self.N)
            out.append(S[:, pre.size + b:])
        return np.hstack(out)

    def solve(self, X):
        """(rms (P,), G (P,), c (P, q)) for search vectors X (P, d)."""
        S = self.basis(X)
        P = S.shape[0]
        ok = np.all(np.isfinite(S), axis=1)
        rms = np.full(P, np.inf)
        G = np.zeros(P)
        c = np.zeros((P, self.Q.shape[1]))
        Qty = self.Q.T @ self.y
        # Blocks of candidates bound the temporaries to a few (8, M) arrays.
        for i0 in range(0, P, 8):
            rows = np.arange(i0, min(i0 + 8, P))
            rows = rows[ok[rows]]
            if rows.size == 0:
                continue
            Sb = S[rows]
            with np.errstate(over="ignore", invalid="ignore"):
                QtS = Sb @ self.Q                      # (b, q)
                rS = Sb - QtS @ self.Q.T
                ss = np.einsum("ij,ij->i", rS, rS)
                # A basis signal that is almost a polynomial of u needs a gain
                # that its polynomial part cancels: not identifiable (module docstring).
                ss = np.where(ss >= MIN_OWN_SHARE ** 2 * np.einsum("ij,ij->i", Sb, Sb), ss, 0.0)
                g = np.where(ss > 0.0, (rS @ self.ry) / np.where(ss > 0.0, ss, 1.0), 0.0)
                rS *= -g[:, None]
                rS += self.ry[None, :]                 # residual ry − g rS
                J = np.sqrt(np.einsum("ij,ij->i", rS, rS) / self.M)
                cc = np.linalg.solve(self.R, Qty[:, None] - QtS.T * g).T
            good = np.isfinite(J) & np.all(np.isfinite(cc), axis=1) & (ss > 0.0)
            rms[rows] = np.where(good, J, np.inf)
            G[rows] = np.where(good, g, 0.0)
            c[rows] = np.where(good[:, None], cc, 0.0)
        return rms, G, c

    def __call__(self, X):
        return self.solve(X)[0]

    def residuals(self, X) -> np.ndarray:
        """Residual vectors (P, M) [µm] of search vectors X (P, d), the linear
        parameters solved (the collinearity guard of :meth:`solve` left out:
        this is for the curvature at an accepted optimum)."""
        S = self.basis(X)
        with np.errstate(over="ignore", invalid="ignore"):
            rS = S - (S @ self.Q) @ self.Q.T
            ss = np.einsum("ij,ij->i", rS, rS)
            g = np.where(ss > 0.0, (rS @ self.ry) / np.where(ss > 0.0, ss, 1.0), 0.0)
            return self.ry[None, :] - g[:, None] * rS




def score(model, rec, burn_in=0, history=None, history_burn_in=0, rest=0.0) -> dict:
    """Errors of `model` on one record, scored after its burn-in.

    Parameters
    ----------
    model : hysteresis model
    rec : fonbw.io.Record
        With u [V] and y [µm].
    burn_in : int
        Samples left out at the start (a record not at rest, no history): the
        model runs first through the history that best explains the burn-in
        (:func:`fonbw.start.estimate_history`, or :func:`lead_in` when that
        explains it better) and the mean error after the burn-in, the unknown
        sensor offset, is removed.
    history : fonbw.io.Record, optional
        The record just before `rec`, run first in one simulation with it;
        then `rec` is scored whole, and the offset (when the history does not
        start at rest) is the mean error over the history after
        `history_burn_in` samples.
    history_burn_in : int
    rest : float
        The stage's input at rest [V] (:func:`fonbw.start.rest_level`), where
        the estimated histories start.

    Returns
    -------
    dict
        rms [µm], rms_percent [% of the scored range of y], max_abs [µm],
        range [µm], offset_um (fitted offset [µm] added to the model, None if
        none was fitted), start_history (what the model ran before a record
        with a burn-in, None otherwise), yhat (model output over `rec` [µm],
        offset included), yhat_history (its output over `history` [µm], no
        offset; None without one).
    """
    off, how, before = None, None, None
    if history is not None:
        full = simulate_record(model, np.concatenate([history.u, rec.u]), rec.dt, history_burn_in)
        yhat, burn_in, before = full[history.n:], 0, full[:history.n]
        if history_burn_in > 0:
            off = -float(np.mean((before - history.y)[history_burn_in:]))
    elif burn_in > 0:
        yhat, how = _after_estimated_history(model, rec, burn_in, rest)
        off = -float(np.mean((yhat - rec.y)[burn_in:]))
    else:
        yhat = simulate_record(model, rec.u, rec.dt, burn_in)
    if off is not None:
        yhat = yhat + off
    e = (yhat - rec.y)[burn_in:]
    rng = float(np.ptp(rec.y[burn_in:]))
    rms = float(np.sqrt(np.mean(e ** 2)))
    return {"rms": rms, "rms_percent": 100.0 * rms / rng if rng > 0 else float("inf"),
            "max_abs": float(np.max(np.abs(e))), "range": rng, "offset_um": off, "start_history": how,
            "yhat": yhat, "yhat_history": before}


def stage_rest(model, inputs) -> float:
    """The stage's input at rest [V] (:func:`fonbw.start.rest_level`) from the
    inputs [V] of the records at hand and, when the model recorded it, its
    training range: a validation record held at 40 V is then judged against
    the 0 V its training drives left from."""
    from .invertibility import model_u_range
    from .start import rest_level

    inputs = list(inputs)
    trained = model_u_range(model)
    if trained is not None:
        inputs.append(list(trained))
    return rest_level(inputs)


def _after_estimated_history(model, rec, burn_in, rest=0.0) -> tuple:
    """A model's output [µm] over `rec` after the input history [V] that best
    explains its burn-in up to a constant sensor offset, and what that history
    is: a drive cut mid-slope arrives moving, in a state its last extremes
    set, which a lead-in from rest straight to the first input does not give."""
    from .invertibility import model_u_range
    from .start import estimate_history

    def sim(v):
        return model.simulate(v, rec.dt)

    b = int(burn_in)
    pre, how, var = estimate_history(sim, rec.u, rec.y, b, offset=True, rest=rest, stage=model_u_range(model))
    lead = lead_in(rec.u, rec.dt)
    with np.errstate(all="ignore"):
        y_lead = sim(np.concatenate([lead, rec.u[:b]]))[lead.size:]
        var_lead = float(np.var(rec.y[:b] - y_lead))
    if np.isfinite(var_lead) and var_lead <= var:
        pre, how = lead, f"a lead-in from rest to {rec.u[0]:.4g} V"
    return sim(np.concatenate([pre, rec.u]))[pre.size:], how
