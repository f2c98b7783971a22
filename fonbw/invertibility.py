"""Invertibility of a discrete hysteresis model: the one-step slope u_k ↦ H_k.

The causal compensator (:mod:`fonbw.compensate`) solves H(u_k; history) = H_d,k
for u_k at every step. That inverse exists, is unique and stays bounded when
the step map u_k ↦ H_k is increasing with some margin at every state the
trajectory visits. For FONBW (eqs. 9–11, GL discretization) the slope is

    ∂H_k/∂u_k = g'(u_k) + k_h ∂ħ_k/∂u_k ,
    ∂ħ_k/∂u_k = a1 ρ φ / (a2 + ρ n |ħ|^(n−1) (σ|D1| − (σ−1) D1 sgn ħ)) ,

with a_i the GL engine's weight of the current sample (dt^(−λi)), D1 = D^λ1 u
at step k and φ = 1 − |ħ|^n on a loading branch (D1 ħ > 0), 1 + (2σ−1)|ħ|^n
on an unloading one. For small ħ it is k_u1 + k_h ρ dt^(λ2−λ1): with
k_h ρ < 0 and λ1 > λ2, the usual outcome of an unconstrained fit, it turns
negative at fine steps, and the small-signal response k_u1 + k_h ρ s^(λ1−λ2)
has a zero on the positive real axis (non-minimum phase).

What this module offers
-----------------------
:func:`one_step_slope`
    the slope at the states a given input visits, on the branch the input is
    on and on the opposite branch (which the compensator reaches at every
    reversal).
:func:`check_invertible`
    ``(ok, slope_min, message)`` for a model at a step.
:class:`ConstrainedProjection`
    identification under the constraint (``identify(..., for_compensation=DT)``):
    given the nonlinear parameters the slope is *linear* in the linear ones
    (k_u1 … k_uN, k_h), so the least-squares solve of the variable projection
    becomes an inequality-constrained least-squares problem, solved exactly
    (unconstrained solution if feasible, else its projection onto the
    feasible polyhedron in the metric of the normal equations).

The margin is relative to the data's quasi-static gain ``gain_ref`` (least-
squares slope of y on u over the training records [µm/V]): the constraint is
slope ≥ margin · gain_ref at every visited state, both branches.

Units: u [V], H [µm], dt [s], slopes [µm/V].
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["DEFAULT_MARGIN", "one_step_slope", "check_invertible", "invertibility_report",
           "ConstrainedProjection", "annotate_result", "default_states", "model_u_range"]

#: Default margin: one-step slope ≥ 0.3 × the data's quasi-static gain.
DEFAULT_MARGIN = 0.3


# ---------------------------------------------------------------------------
# model metadata

def model_u_range(model, default=None):
    """The training input range (u_min, u_max) [V] stored with the model, else ``default``."""
    meta = getattr(model, "meta", None) or {}
    r = meta.get("u_range")
    if r is None:
        return default
    lo, hi = (float(v) for v in r)
    return (lo, hi) if lo < hi else default


def default_states(model, dt, T=2.0):
    """Input [V] whose visited states :func:`check_invertible` examines by default.

    A decaying sweep over the model's training range (``meta["u_range"]``,
    else the paper's 0–120 V) at 1, 5 and 20 Hz, so that major and minor
    loops, slow and fast reversals are visited. At most 40000 samples.
    """
    from .paper import U_RANGE

    lo, hi = model_u_range(model, U_RANGE)
    n = int(min(max(round(T / dt), 64), 40000))
    t = np.arange(n) * dt
    T = n * dt
    env = np.exp(-1.5 * t / T)
    x = env * (0.6 * np.sin(2 * np.pi * 1.0 * t) + 0.25 * np.sin(2 * np.pi * 5.0 * t)
               + 0.15 * np.sin(2 * np.pi * 20.0 * t))
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    u = mid + half * x
    # start at rest at the end of the range nearest to 0 V, ramp in (no jump)
    u0 = min(max(0.0, lo), hi)
    ramp = np.minimum(t / (0.1 * T), 1.0)
    return u0 + ramp * (u - u0)


# ---------------------------------------------------------------------------
# the slope

def _lead(lam, dt, memory):
    """Weight of the current sample in the engine's D^λ (dt^(−λ) for every GL engine)."""
    if lam == 1.0 or memory != "oustaloup":
        return dt ** (-lam)
    from .fractional import make_op
    return float(make_op(lam, dt, memory).a)


def sensitivity(rho, sigma, n, hb, D1, a1, a2):
    """∂ħ_k/∂u_k of the discrete eq. (11) at state ħ_k = hb and D1 = D^λ1 u_k.

    Arrays broadcast. ``D1`` = ±0.0 selects a branch at a reversal (its sign
    bit decides: +0.0 a rising input, −0.0 a falling one). Units [1/V].
    """
    ah = np.abs(hb)
    p = np.where(ah > 0.0, ah ** (n - 1.0), 1.0 if n == 1.0 else 0.0)
    s = np.where(np.signbit(D1), -1.0, 1.0)
    sh = np.sign(hb)
    # ∂F/∂D1 = −ρφ with φ = 1 − σ s |ħ|^(n−1) ħ + (σ − 1)|ħ|^n
    phi = 1.0 - sigma * s * p * hb + (sigma - 1.0) * p * ah
    den = a2 + rho * n * p * (sigma * np.abs(D1) - (sigma - 1.0) * D1 * sh)
    return a1 * rho * phi / den


def _bw_params(model):
    """(ku, kh, rho, sigma, n, lam1, lam2, memory) of a FONBW/NBW, or of a CBW as the
    backward-Euler NBW it equals (h with A = 1 … ; H = ka u + kb D h)."""
    from . import hysteresis as hy

    if isinstance(model, hy.FONBW):
        m = model
        return (np.asarray(m.ku, float), float(m.kh), m.rho, m.sigma, m.n,
                getattr(m, "lam1", 1.0), getattr(m, "lam2", 1.0), m.memory)
    if isinstance(model, hy.CBW):
        # D ḣ = A u̇ − β|u̇||h|^(n−1)h − γ u̇|h|^n is eq. (11) for h/A... with
        # ħ = h, ρ = A/D, σ = β/A, provided β + γ = A (the normalized class);
        # otherwise use method="fd".
        m = model
        if not math.isclose(m.beta + m.gamma, m.A, rel_tol=1e-12):
            return None
        return (np.array([m.ka]), m.kb * m.D, m.A / m.D, m.beta / m.A, m.n, 1.0, 1.0, "exact")
    return None


def _slopes_analytic(model, u, dt_states, dt, bw):
    from .fractional import gl_derivative

    ku, kh, rho, sigma, n, lam1, lam2, memory = bw
    # ħ (or the CBW's h, which is ħ when β + γ = A) at every visited state
    _, hb = model.simulate(u, dt_states, return_state=True)
    # D^λ1 u of the visited states (exact GL; the fast engine differs by ~1e-7)
    D1 = gl_derivative(u - u[0], dt_states, lam1)
    a1, a2 = _lead(lam1, dt, memory), _lead(lam2, dt, memory)
    gp = sum((i + 1) * ku[i] * u ** i for i in range(len(ku)))
    cur = gp + kh * sensitivity(rho, sigma, n, hb, D1, a1, a2)
    opp = gp + kh * sensitivity(rho, sigma, n, hb, np.where(D1 >= 0.0, -0.0, 0.0), a1, a2)
    return np.column_stack([cur, opp])


def _slopes_fd(model, u, dt, rel=1e-6):
    """Central differences of the compiled step (trial, not committed) along u."""
    from .hysteresis.kernels import step_code

    P, ss = model._pack(dt, n_steps=len(u))
    S = np.zeros(ss)
    h = rel * max(1.0, float(np.max(np.abs(u))))
    out = np.empty((len(u), 2))
    for k, uk in enumerate(u):
        f0 = step_code(model._code, uk, False, P, S)
        fp = step_code(model._code, uk + h, False, P, S)
        fm = step_code(model._code, uk - h, False, P, S)
        out[k] = ((fp - f0) / h, (f0 - fm) / h)
        step_code(model._code, uk, True, P, S)
    return out


def one_step_slope(model, dt, states=None, *, dt_states=None, method="auto"):
    """One-step slope ∂H_k/∂u_k [µm/V] of the model's discrete step at step dt.

    Parameters
    ----------
    model : FONBW, NBW, CBW or Zhu2016
    dt : float
        The step the model is used with (the compensator's) [s].
    states : array_like, optional
        Input u [V] (from rest) whose visited states are examined; default
        :func:`default_states`.
    dt_states : float, optional
        Sampling step of ``states`` [s]; default ``dt``. The states (ħ, D^λ1 u)
        are physical quantities, so training records at their own rate can
        be examined at another dt (``method="analytic"`` only).
    method : {"auto", "analytic", "fd"}
        "analytic" (FONBW, NBW, CBW with β + γ = A): the formula of the
        module docstring on both branches. "fd": central differences of the
        compiled step along the trajectory (any kind; the current branch
        only, both sides). "auto": analytic where defined.

    Returns
    -------
    ndarray, shape (len(states), 2)
        Analytic: column 0 the branch the input is on, column 1 the opposite
        branch at a reversal. fd: right and left difference quotients.
    """
    from .hysteresis.models import _dt

    dt = _dt(dt)
    u = default_states(model, dt) if states is None else np.ascontiguousarray(states, dtype=float)
    dts = dt if dt_states is None else _dt(dt_states)
    bw = _bw_params(model)
    if method not in ("auto", "analytic", "fd"):
        raise ValueError(f"method must be 'auto', 'analytic' or 'fd', got {method!r}")
    if method == "analytic" and bw is None:
        raise ValueError(f"no analytic slope for {type(model).__name__}; use method='fd'")
    if method == "fd" or bw is None:
        if dts != dt:
            raise ValueError("method='fd' evaluates the step at the states' own dt; "
                             "pass dt_states=None")
        return _slopes_fd(model, u, dt)
    return _slopes_analytic(model, u, dts, dt, bw)


def check_invertible(model, dt, states=None, *, margin=0.0, dt_states=None):
    """Whether the causal compensator can invert ``model`` at step ``dt``.

    Parameters
    ----------
    model, dt, states, dt_states
        As for :func:`one_step_slope`.
    margin : float
        Required slope [µm/V] (0: strictly positive).

    Returns
    -------
    (ok, slope_min, message) : (bool, float, str)
        ``slope_min`` [µm/V] over the visited states and both branches.
    """
    s = one_step_slope(model, dt, states, dt_states=dt_states)
    finite = s[np.isfinite(s)]
    smin = float(finite.min()) if finite.size else math.nan
    ok = bool(finite.size == s.size and smin > margin)
    frac = float(np.mean(np.min(s, axis=1) <= margin)) if s.size else 0.0
    if ok:
        msg = (f"invertible at dt = {dt:g} s: one-step slope ≥ {smin:.4g} µm/V at every "
               f"visited state")
    else:
        msg = (f"not invertible at dt = {dt:g} s: the one-step slope u_k → H_k falls to "
               f"{smin:.4g} µm/V (≤ {margin:g} at {100 * frac:.1f} % of the visited states); "
               "the causal inverse then has no root or chatters. Identify with "
               "for_compensation=dt (fonbw identify --for-compensation DT), or use compensate(..., "
               "preview=True) (fonbw compensate --preview) for a known trajectory")
    return ok, smin, msg


def invertibility_report(model, dt, states=None, *, dt_states=None, gain_ref=None):
    """``{"dt", "slope_min", "margin"}`` for the model JSON (margin = slope_min / gain_ref)."""
    _, smin, _ = check_invertible(model, dt, states, dt_states=dt_states)
    d = {"dt": float(dt), "slope_min": smin}
    if gain_ref:
        d["gain_ref"] = float(gain_ref)
        d["margin"] = smin / float(gain_ref)
    return d

# ---------------------------------------------------------------------------
# identification under the constraint

def _gain_ref(recs, burn_in=None):
    """Least-squares slope of y on (1, u) over the records' scored samples
    (after each burn-in, whose outputs are not data) [µm/V]."""
    b = list(burn_in or [0] * len(recs))
    u = np.concatenate([r[0][k:] for r, k in zip(recs, b)])
    y = np.concatenate([r[1][k:] for r, k in zip(recs, b)])
    A = np.column_stack([np.ones_like(u), u])
    return float(np.linalg.lstsq(A, y, rcond=None)[0][1])


def _project(phi0, B, d, tol, maxit=60):
    """Nearest point to phi0 of {φ : Bφ ≥ d} (rows of B unit length), by a dual
    active set: add the most violated row, solve on the active rows, drop rows
    whose multiplier turns negative. Returns (φ, feasible)."""
    W = []
    phi = phi0
    for _ in range(maxit):
        v = d - B @ phi
        j = int(np.argmax(v))
        if v[j] <= tol:
            return phi, True
        if j in W:
            break  # no progress at round-off: give up on this candidate
        W.append(j)
        while True:
            Bw = B[W]
            lam = np.linalg.lstsq(Bw @ Bw.T, d[W] - Bw @ phi0, rcond=None)[0]
            if np.all(lam >= 0.0) or len(W) == 1:
                break
            W.pop(int(np.argmin(lam)))
        phi = phi0 + Bw.T @ np.maximum(lam, 0.0)
    return phi, bool(np.max(d - B @ phi) <= tol)


class ConstrainedProjection:
    """Eq. (18) minimized over the linear parameters under the one-step-slope
    constraint, for a population (drop-in for identify's projection).

    At every training sample k and on both branches b, the slope of the
    discrete step at the compensator's step ``dt`` is
    Σ_i c_i i u_k^(i−1)/U^i + G q_b,k ≥ margin · gain_ref, linear in the
    linear parameters (c, G) once the candidate's ħ_k and D^λ1 u_k are known
    (module docstring). The squared error is a quadratic form in (c, G) with
    the normal matrix A = [F s]ᵀ[F s], so the constrained minimum is the
    A-metric projection of the unconstrained one onto the feasible set.

    Parameters
    ----------
    proj : identify's projection object
        Its records, basis simulation and unconstrained solve are reused.
    dt : float
        Step the model will be inverted at [s].
    margin : float
        Required slope as a fraction of ``gain_ref``.
    """

    def __init__(self, proj, dt, margin=DEFAULT_MARGIN):
        if proj.kind not in ("fonbw", "nbw", "cbw"):
            raise ValueError(f"for_compensation is defined for fonbw, nbw and cbw, not {proj.kind!r}")
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"for_compensation must be the compensator's step dt > 0 [s], got {dt!r}")
        self.proj, self.dt, self.margin = proj, dt, float(margin)
        self.burn_in = list(getattr(proj, "burn_in", None) or [0] * len(proj.recs))
        self.gain_ref = _gain_ref(proj.recs, self.burn_in)
        if not self.gain_ref > 0.0:
            raise ValueError("for_compensation: the records' quasi-static gain y/u is not positive "
                             f"({self.gain_ref:.3g} µm/V); the constraint needs a rising stage")
        self.bound = self.margin * self.gain_ref
        U = max(float(np.max(np.abs(u))) for u, _, _ in proj.recs)
        # the samples that count (after each record's burn-in, as the basis)
        uu = np.concatenate([u[b:] for (u, _, _), b in zip(proj.recs, self.burn_in)])
        q = getattr(proj, "q", proj.Q.shape[1])
        # d/du of the fixed regressors (u/U)^i; per-record offsets have none
        self.dF = np.zeros((uu.size, proj.Q.shape[1]))
        for i in range(q):
            self.dF[:, i] = (i + 1) * uu ** i / U ** (i + 1)
        self.n_violating = 0

    def __getattr__(self, name):
        return getattr(self.proj, name)

    def _nonlinear(self, x):
        p = {k: float(np.asarray(v)[0]) for k, v in self.proj.space.basis_params(x[None, :]).items()}
        if self.proj.kind == "cbw":
            return 1.0 / p["D"], p["beta"], p["n"], 1.0, 1.0
        return p["rho"], p["sigma"], p["n"], p.get("lam1", 1.0), p.get("lam2", 1.0)

    def rows(self, x, s):
        """Constraint matrix C (2M, q+1) of candidate x with basis signal s (M,)."""
        from .fractional import gl_derivative

        rho, sigma, n, lam1, lam2 = self._nonlinear(x)
        D1 = np.concatenate([gl_derivative(u - u[0], dt, lam1)[b:]
                             for (u, _, dt), b in zip(self.proj.recs, self.burn_in)])
        a1 = _lead(lam1, self.dt, self.proj.memory)
        a2 = _lead(lam2, self.dt, self.proj.memory)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            qc = sensitivity(rho, sigma, n, s, D1, a1, a2)
            qo = sensitivity(rho, sigma, n, s, np.where(D1 >= 0.0, -0.0, 0.0), a1, a2)
        return np.vstack([np.column_stack([self.dF, qc]), np.column_stack([self.dF, qo])])

    def _one(self, x, s, G, c, rms):
        """Constrained (rms, G, c) of one candidate from its unconstrained solution."""
        C = self.rows(x, s)
        th0 = np.append(c, G)
        if not np.all(np.isfinite(C)):
            return np.inf, G, c
        if np.min(C @ th0) >= self.bound:
            return rms, G, c
        self.n_violating += 1
        p = self.proj
        QtS = p.Q.T @ s
        F_s = p.R.T @ QtS
        A = np.zeros((len(th0), len(th0)))
        A[:-1, :-1] = p.R.T @ p.R
        A[:-1, -1] = A[-1, :-1] = F_s
        A[-1, -1] = s @ s
        A += np.eye(len(th0)) * 1e-14 * np.trace(A)
        L = np.linalg.cholesky(A)
        from scipy.linalg import solve_triangular
        B = solve_triangular(L, C.T, lower=True).T          # C L^-T
        nb = np.linalg.norm(B, axis=1)
        nb[nb == 0.0] = 1.0
        phi0 = L.T @ th0
        phi, ok = _project(phi0, B / nb[:, None], self.bound / nb, 1e-12 * np.linalg.norm(phi0))
        if not ok:
            return np.inf, G, c
        th = solve_triangular(L.T, phi, lower=False)
        extra = float(np.sum((phi - phi0) ** 2))
        return math.sqrt(rms ** 2 + extra / p.M), float(th[-1]), th[:-1]

    def solve(self, X):
        """(rms (P,), G (P,), c (P, q)) under the constraint, for search vectors X (P, d)."""
        X = np.atleast_2d(X)
        S = self.proj.basis(X)
        # the unconstrained solve on the same basis signals (simulated once)
        self.proj.basis = lambda _X: S
        try:
            rms, G, c = self.proj.solve(X)
        finally:
            del self.proj.basis
        for i in range(X.shape[0]):
            if np.isfinite(rms[i]):
                rms[i], G[i], c[i] = self._one(X[i], S[i], G[i], c[i], rms[i])
        return rms, G, c

    def __call__(self, X):
        return self.solve(X)[0]


def annotate_result(result, recs, for_compensation=None, gain_ref=None):
    """Record the training input range on the identified model and, with
    ``for_compensation`` (the compensator's step [s]), the one-step slope over
    the training states (both branches) on the result and the model."""
    from .io import input_range

    model = result.model
    lo, hi = input_range([u for u, _, _ in recs])
    meta = dict(getattr(model, "meta", None) or {})
    meta["u_range"] = [lo, hi]
    if for_compensation is not None:
        gain_ref = _gain_ref(recs, getattr(result, "burn_in", None)) if gain_ref is None else gain_ref
        smin = min(float(np.min(one_step_slope(model, for_compensation, u, dt_states=dt)))
                   for u, _, dt in recs)
        inv = {"dt": float(for_compensation), "slope_min": smin, "gain_ref": gain_ref,
               "margin": smin / gain_ref}
        meta["invertibility"] = inv
        result.invertibility = inv
    model.meta = meta
    return result
