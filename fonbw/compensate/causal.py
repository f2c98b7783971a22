"""Feedforward hysteresis compensation by the inverse multiplicative structure.

The paper's compensator (eqs. 16–17) gets the voltage from the desired
displacement H_d without inverting the model:

    u(t) = (H_d(t) − G(u, t)) / k_u1,
    G(u, t) = k_h ħ(t) + k_u2 u² + … + k_uN u^N .

G depends on the *current* u (through the polynomial and through ħ, which
eq. (11) ties to D^λ1 u at the same instant), so eq. (16) is implicit at every
step. With the model discretized as in :mod:`fonbw.hysteresis` it is exactly

    find u_k in [u_min, u_max] with H(u_k; history up to k−1) = H_d,k ,

a scalar root find on the model's own step function. Each step here evaluates
the model's compiled step with ``commit=False`` inside a safeguarded root
finder (secant from the previous voltage with the previous local slope;
Brent's method as soon as a sign change brackets the root; a bracket over the
whole voltage range as the fallback), then commits one step with the root.
Model and compensator therefore share their numerics (memory engine
included), and the model driven by the compensator's voltage reproduces H_d
to the solver tolerance.

The same per-step inversion serves CBW (eq. 21: u = (H_d − k_b D ĥ)/k_a,
implicit in ĥ for the same reason) and the model of Zhu et al. (eq. 22).

Zhu et al., eq. (22)
    As written, eq. (22) divides by (k1/τ) e^(−t/τ): the direct input term of
    eq. (20) decays with absolute time (τ ≈ 2e-5 s in Table 1), so after a
    few τ the division is by a number that underflows to zero and eq. (22)
    gives u → ∞. What actually carries u into the output after that is the
    Bouc-Wen state h (through A u̇ and δ u sgn u̇). Two honest readings:

    ``form="discrete"`` (default)
        the per-step inversion of the discrete model, x_k as a function of
        u_k with the mechanics included, as for every other kind: model ∘
        compensator = identity. Its one-step authority is small (the force
        reaches x_k through the mechanics' Γ, about dt²/(2 m0) for light
        damping), and it is greedy: one out-of-reach sample (an x0 offset at
        t = 0, say) can park u on a limit where the rate-independent h no
        longer moves. On the Zhu model identified from the virtual bench it
        does exactly that.
    ``form="eq22"``
        eq. (22) made implicit: the mechanics are inverted on H_d (backward
        differences for Ḣd, Ḧd) and the force balance
        (k1/τ)e^(−t_k/τ) u_k + ĥ_k(u_k) = m0 Ḧd + c0 Ḣd + k0 (H_d − x0)
        is solved per step for u_k. That is the compensator Table 4 compares.

Invertibility
    The per-step inverse exists and is stable when the model's step map
    u_k ↦ H_k has the sign of its quasi-static gain. For FONBW with k_h ρ < 0
    and λ1 > λ2 — the paper's Table 1 set, and what identification finds on
    the virtual bench — the one-step slope k_u1 + k_h ρ dt^(λ2−λ1) (small ħ)
    is negative at 10 kHz: a step in u first moves H the wrong way, the
    linearization has a right-half-plane zero, and the exact inverse is
    unstable. The solver then does what it can (chatters, saturates, or
    reports samples without a root) and says so in the status; it does not
    hide it. With the paper's Table 1 set the 5-Hz trajectory saturates at
    0 V from the second sample on.

Explicit (one-step-delayed) variant
    ``explicit=True`` evaluates G with the previous voltage and the previous
    hysteretic state, u_k = (H_d,k − k_h ħ_(k−1) − Σ_(i≥2) k_ui u_(k−1)^i)/k_u1
    (CBW: u_k = (H_d,k − k_b D h_(k−1))/k_a), which is how a block diagram
    with a unit delay in the loop of Fig. 5 would run. It tracks less well;
    offered for comparison only. Not defined for Zhu2016 (see above).

Voltage limits default to the paper's amplifier range 0–120 V. A sample
whose H_d cannot be reached within the limits gets the limit nearer to the
solution and is reported as saturated; a sample whose equation has no root
the solver can find (a jump of the model's step map, e.g. the δ u sgn u̇ term
of eq. 20 at u̇ = 0) gets the voltage of smallest residual and is reported as
not converged.

Units: u [V], H_d and outputs [µm], dt and t [s].
"""
from __future__ import annotations

import dataclasses
import math

import numba as nb
import numpy as np

from . import hysteresis as _hy
from .paper import U_RANGE

__all__ = [
    "compensate",
    "compensator",
    "Compensator",
    "CompensationResult",
    "compensate_file",
    "OK",
    "SAT_LOW",
    "SAT_HIGH",
    "NOT_CONVERGED",
]

#: Per-sample status codes of a compensation.
OK, SAT_LOW, SAT_HIGH, NOT_CONVERGED = 0, 1, 2, 3
_STATUS_NAMES = {OK: "ok", SAT_LOW: "saturated at u_min", SAT_HIGH: "saturated at u_max",
                 NOT_CONVERGED: "not converged"}

#: The paper's amplifier range [V] (Sec. IV-A: 0–120 V).
DEFAULT_LIMITS = U_RANGE
#: Default tolerance on |H(u_k) − H_d,k| [µm] (0.1 pm).
DEFAULT_TOL = 1e-10
_MAX_ITER = 100
_EPS = 2.220446049250313e-16


# ---------------------------------------------------------------------------
# compiled per-step solver

@nb.njit(cache=True)
def _same_sign(a, b):
    return (a > 0.0) == (b > 0.0)


@nb.njit(cache=True)
def _brent(core, V, hd, a, fa, b, fb, tol, maxit):
    """Brent's zeroin on a bracket (fa, fb of opposite signs).

    Stops when |f| ≤ tol or the bracket has shrunk to a few ulps. Returns
    (x, f(x), contrapoint, f(contrapoint), evaluations).
    """
    c, fc = a, fa
    d = b - a
    e = d
    n = 0
    for _ in range(maxit):
        if _same_sign(fb, fc):
            c, fc = a, fa
            d = b - a
            e = d
        if abs(fc) < abs(fb):
            a, fa = b, fb
            b, fb = c, fc
            c, fc = a, fa
        tol1 = 2.0 * _EPS * abs(b) + 1e-300
        xm = 0.5 * (c - b)
        if abs(fb) <= tol or abs(xm) <= tol1:
            break
        if abs(e) >= tol1 and abs(fa) > abs(fb):
            s = fb / fa
            if a == c:
                p = 2.0 * xm * s
                q = 1.0 - s
            else:
                q = fa / fc
                r = fb / fc
                p = s * (2.0 * xm * q * (q - r) - (b - a) * (r - 1.0))
                q = (q - 1.0) * (r - 1.0) * (s - 1.0)
            if p > 0.0:
                q = -q
            p = abs(p)
            if 2.0 * p < min(3.0 * xm * q - abs(tol1 * q), abs(e * q)):
                e = d
                d = p / q
            else:
                d = xm
                e = d
        else:
            d = xm
            e = d
        a, fa = b, fb
        if abs(d) > tol1:
            b = b + d
        else:
            b = b + (tol1 if xm > 0.0 else -tol1)
        fb = core(b, False, V) - hd
        n += 1
        if not math.isfinite(fb):
            break
    return b, fb, c, fc, n


@nb.njit(cache=True)
def _bracketed(core, V, hd, a, fa, b, fb, tol, maxit, n, bx, bf, slope):
    """Brent on a sign-change bracket; the best point so far if it does not converge."""
    x, fx, c, fc, m = _brent(core, V, hd, a, fa, b, fb, tol, maxit)
    n += m
    if abs(fx) <= tol:
        return x, fx, OK, n, ((fx - fc) / (x - c) if x != c else slope)
    if abs(fx) < abs(bf):
        bx, bf = x, fx
    return bx, bf, NOT_CONVERGED, n, slope


@nb.njit(cache=True)
def _solve(core, V, hd, lo, hi, x0, slope, tol, maxit):
    """Root u of H(u; history) = hd in [lo, hi] by trial steps (commit=False).

    Returns (u, residual H(u) − hd, status, evaluations, new slope estimate).
    """
    x0 = min(max(x0, lo), hi)
    f0 = core(x0, False, V) - hd
    n = 1
    if abs(f0) <= tol:
        return x0, f0, OK, n, slope
    bx = x0
    bf = f0 if math.isfinite(f0) else math.inf
    if not (math.isfinite(slope) and slope != 0.0):
        # first step or lost estimate: one-sided difference into the range
        h = 1e-3 * (hi - lo)
        xb = x0 + h if x0 + h <= hi else x0 - h
        fb = core(xb, False, V) - hd
        n += 1
        slope = (fb - f0) / (xb - x0)
    # local secant search from the previous voltage (keeps the solution on
    # the branch the trajectory is on when the step map is not monotone)
    a, fa = x0, f0
    if math.isfinite(f0) and math.isfinite(slope) and slope != 0.0:
        dx = -f0 / slope
        for _ in range(12):
            b = min(max(a + dx, lo), hi)
            if b == a:
                break  # pushing against a limit: decided by the fallback
            fb = core(b, False, V) - hd
            n += 1
            if not math.isfinite(fb):
                break
            if abs(fb) < abs(bf):
                bx, bf = b, fb
            if abs(fb) <= tol:
                return b, fb, OK, n, (fb - fa) / (b - a)
            if not _same_sign(fa, fb):
                return _bracketed(core, V, hd, a, fa, b, fb, tol, maxit, n, bx, bf, slope)
            if abs(fb) >= abs(fa):
                break  # no progress: the fallback brackets the whole range
            dx = -fb * (b - a) / (fb - fa)
            slope = (fb - fa) / (b - a)
            a, fa = b, fb
    # fallback: the whole voltage range
    flo = core(lo, False, V) - hd
    fhi = core(hi, False, V) - hd
    n += 2
    if math.isfinite(flo) and math.isfinite(fhi) and not _same_sign(flo, fhi):
        if math.isfinite(f0) and lo < x0 < hi:
            if _same_sign(f0, flo):
                a, fa, b, fb = x0, f0, hi, fhi
            else:
                a, fa, b, fb = lo, flo, x0, f0
        else:
            a, fa, b, fb = lo, flo, hi, fhi
        return _bracketed(core, V, hd, a, fa, b, fb, tol, maxit, n, bx, bf, slope)
    # no sign change over [lo, hi]: the target is out of reach
    alo = abs(flo) if math.isfinite(flo) else math.inf
    ahi = abs(fhi) if math.isfinite(fhi) else math.inf
    if alo <= ahi and alo <= abs(bf):
        return lo, flo, SAT_LOW, n, slope
    if ahi < alo and ahi <= abs(bf):
        return hi, fhi, SAT_HIGH, n, slope
    return bx, bf, NOT_CONVERGED, n, slope


@nb.njit(cache=True)
def _explicit(S, hd, lo, hi, uprev, ku, kh):
    """Eq. (16)/(21) with G from the previous step (state S[2] = ħ_(k−1) or h_(k−1))."""
    g = 0.0
    for i in range(ku.shape[0] - 1, 0, -1):
        g = (g + ku[i]) * uprev
    g *= uprev  # Σ_{i≥2} ku_i u^i
    u = (hd - kh * S[2] - g) / ku[0]
    if not math.isfinite(u):
        return uprev, NOT_CONVERGED
    if u < lo:
        return lo, SAT_LOW
    if u > hi:
        return hi, SAT_HIGH
    return u, OK


@nb.njit(cache=True)
def _one(core, V, S, hd, lo, hi, tol, maxit, explicit, ku, kh, ctl):
    """Voltage for one sample (not committed). ctl = [u_(k−1), slope]."""
    if explicit:
        u, st = _explicit(S, hd, lo, hi, ctl[0], ku, kh)
        return u, st, 0
    u, f, st, n, s = _solve(core, V, hd, lo, hi, ctl[0], ctl[1], tol, maxit)
    ctl[1] = s
    return u, st, n


@nb.njit(cache=True, inline="always")
def _run_on(views, core, hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh, u, y, status, nfev):
    """Batch compensation from rest (the model's state starts at rest)."""
    S = np.zeros(ssize)
    V = views(P, S)
    ctl = np.array([min(max(0.0, lo), hi), math.nan])
    for k in range(hd.shape[0]):
        uk, st, n = _one(core, V, S, hd[k], lo, hi, tol, maxit, explicit, ku, kh, ctl)
        y[k] = core(uk, True, V)
        u[k] = uk
        status[k] = st
        nfev[k] = n
        ctl[0] = uk


@nb.njit(cache=True, inline="always")
def _step_on(views, core, hd, P, S, lo, hi, tol, maxit, explicit, ku, kh, ctl, out, commit):
    """Per-step body on the blocks of a model stepper: out = [u, status, nfev, y]."""
    V = views(P, S)
    uk, st, n = _one(core, V, S, hd, lo, hi, tol, maxit, explicit, ku, kh, ctl)
    out[0] = uk
    out[1] = st
    out[2] = n
    if commit:
        out[3] = core(uk, True, V)
        ctl[0] = uk


# One entry point per kernel pair, batch and per step: the kernels are
# referenced as globals, not passed from Python (numba would type two
# dispatcher objects on every per-step call, ~60 µs, and its cache index
# cannot always pickle dispatcher types).
#
# Caveat of numba's cache=True: the cache of these functions is keyed on this
# file only; after an edit of hysteresis.py or fractional.py delete
# fonbw/__pycache__/compensate.* (or touch this file) or stale kernels run.
@nb.njit(cache=True)
def _run_fonbw(hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh, u, y, status, nfev):
    _run_on(_hy.fonbw_views, _hy.fonbw_core, hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh,
            u, y, status, nfev)


@nb.njit(cache=True)
def _run_cbw(hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh, u, y, status, nfev):
    _run_on(_hy.plain_views, _hy.cbw_core, hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh,
            u, y, status, nfev)


@nb.njit(cache=True)
def _run_zhu(hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh, u, y, status, nfev):
    _run_on(_hy.plain_views, _hy.zhu_core, hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh,
            u, y, status, nfev)


@nb.njit(cache=True)
def _step_fonbw(hd, P, S, lo, hi, tol, maxit, explicit, ku, kh, ctl, out, commit):
    _step_on(_hy.fonbw_views, _hy.fonbw_core, hd, P, S, lo, hi, tol, maxit, explicit, ku, kh,
             ctl, out, commit)


@nb.njit(cache=True)
def _step_cbw(hd, P, S, lo, hi, tol, maxit, explicit, ku, kh, ctl, out, commit):
    _step_on(_hy.plain_views, _hy.cbw_core, hd, P, S, lo, hi, tol, maxit, explicit, ku, kh,
             ctl, out, commit)


@nb.njit(cache=True)
def _step_zhu(hd, P, S, lo, hi, tol, maxit, explicit, ku, kh, ctl, out, commit):
    _step_on(_hy.plain_views, _hy.zhu_core, hd, P, S, lo, hi, tol, maxit, explicit, ku, kh,
             ctl, out, commit)


# Eq. (22) form for Zhu2016: the mechanics are inverted on H_d's derivatives and
# only the force balance is solved per step, for u in
#     (k1/τ) e^(−t_k/τ) u_k + ĥ_k(u_k) = m0 Ḧd_k + c0 Ḣd_k + k0 (H_d,k − x0).
@nb.njit(cache=True)
def _zhu_force_core(u, commit, V):
    """Trial: the force of eq. (20) for u_k (model units). Commit: advance the
    model with u_k and return x_k [µm] (the model output)."""
    if commit:
        return _hy.zhu_core(u, True, V)
    P, S = V
    direct = P[1] / P[2] * math.exp(-S[6] * P[0] / P[2]) * u  # before the trial step, as zhu_step
    _hy.zhu_core(u, False, V)
    return direct + S[3]


# not cached: numba refuses to cache a function that passes another function
# of this module as a value ("dynamic globals"); compiled on first use.
@nb.njit(cache=False)
def _run_zhu22(hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh, u, y, status, nfev):
    _run_on(_hy.plain_views, _zhu_force_core, hd, P, ssize, lo, hi, tol, maxit, explicit, ku, kh,
            u, y, status, nfev)


@nb.njit(cache=False)
def _step_zhu22(hd, P, S, lo, hi, tol, maxit, explicit, ku, kh, ctl, out, commit):
    _step_on(_hy.plain_views, _zhu_force_core, hd, P, S, lo, hi, tol, maxit, explicit, ku, kh,
             ctl, out, commit)


def _force_target(m, h, h1, h2, dt):
    """Right side of eq. (22), m0 Ḧd + c0 Ḣd + k0 (H_d − x0), with backward
    differences (h1, h2: H_d one and two samples back). Same arithmetic for
    arrays (batch) and floats (per step), so both give the same bits."""
    return m.m0 * ((h - 2.0 * h1) + h2) / (dt * dt) + m.c0 * (h - h1) / dt + m.k0 * (h - m.x0)


def _form(model, form):
    if form not in ("discrete", "eq22"):
        raise ValueError(f"form must be 'discrete' or 'eq22', got {form!r}")
    if form == "eq22" and not isinstance(model, _hy.Zhu2016):
        raise ValueError(f"form='eq22' is the Zhu2016 compensator of eq. (22); "
                         f"a {type(model).__name__} has no such form")
    return form


def _entries(model, form="discrete"):
    """(batch, per-step) compiled entry points for the model's kernels."""
    if form == "eq22":
        return _run_zhu22, _step_zhu22
    if isinstance(model, _hy.FONBW):
        return _run_fonbw, _step_fonbw
    if isinstance(model, _hy.CBW):
        return _run_cbw, _step_cbw
    return _run_zhu, _step_zhu


# ---------------------------------------------------------------------------
# validation

def _check_model(model):
    if not isinstance(model, (_hy.FONBW, _hy.CBW, _hy.Zhu2016)):
        raise ValueError(f"cannot compensate a {type(model).__name__}: expected a fonbw model "
                         "(FONBW, NBW, CBW or Zhu2016)")


def _limits(limits):
    try:
        lo, hi = (float(v) for v in limits)
    except (TypeError, ValueError):
        raise ValueError(f"limits must be a pair (u_min, u_max) of volts, got {limits!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"limits must be finite with u_min < u_max [V], got {limits!r}")
    return lo, hi


def _tol(tol):
    tol = float(tol)
    if not (math.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a positive number of µm, got {tol!r}")
    return tol


def _max_iter(n):
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise ValueError(f"max_iter must be a positive integer, got {n!r}")
    return int(n)


def _explicit_coeffs(model, explicit):
    """(ku, kh) of the explicit form u = (H_d − kh·x_(k−1) − Σ_(i≥2) ku_i u^i)/ku_1."""
    if isinstance(model, _hy.FONBW):
        ku, kh = np.asarray(model.ku, dtype=float), float(model.kh)
    elif isinstance(model, _hy.CBW):
        ku, kh = np.array([model.ka]), float(model.kb * model.D)
    else:
        if explicit:
            raise ValueError("explicit=True is not defined for Zhu2016: eq. (22) divides by "
                             "(k1/τ)e^(−t/τ), which vanishes after a few τ; use the implicit "
                             "per-step inversion (explicit=False)")
        return np.ones(1), 0.0
    if explicit and ku[0] == 0.0:
        raise ValueError("explicit=True needs k_u1 ≠ 0 (eq. 16 divides by it)")
    return np.ascontiguousarray(ku), kh


def _hd(Hd):
    Hd = np.ascontiguousarray(Hd, dtype=float)
    if Hd.ndim != 1:
        raise ValueError(f"desired displacement Hd must be a 1-D array, got shape {Hd.shape}")
    if not np.all(np.isfinite(Hd)):
        k = int(np.flatnonzero(~np.isfinite(Hd))[0])
        raise ValueError(f"desired displacement Hd is not finite at sample {k}")
    return Hd


# ---------------------------------------------------------------------------
# public API

@dataclasses.dataclass
class CompensationResult:
    """Outcome of :func:`compensate`. ``np.asarray(result)`` is the voltage u.

    Attributes
    ----------
    u : ndarray
        Compensating voltage [V], one per sample of H_d.
    y_model : ndarray
        The model's output for u [µm] (what the compensator expects the
        actuator to do); equals H_d to ``tol`` where ``status == OK``.
    Hd : ndarray
        Desired displacement [µm].
    dt : float
        Step [s].
    status : ndarray of int8
        Per sample: ``OK`` (0), ``SAT_LOW`` (1, u = u_min), ``SAT_HIGH``
        (2, u = u_max), ``NOT_CONVERGED`` (3).
    nfev : ndarray of int
        Model step evaluations per sample (0 for the explicit variant).
    limits : tuple
        (u_min, u_max) [V].
    tol : float
        Solver tolerance on |y_model − H_d| [µm].
    explicit : bool
        Whether the one-step-delayed variant was used.
    form : str
        "discrete" or "eq22" (see :func:`compensate`).
    """

    u: np.ndarray
    y_model: np.ndarray
    Hd: np.ndarray
    dt: float
    status: np.ndarray
    nfev: np.ndarray
    limits: tuple
    tol: float
    explicit: bool = False
    form: str = "discrete"

    def __array__(self, dtype=None, copy=None):
        return self.u if dtype is None else self.u.astype(dtype)

    def __len__(self):
        return len(self.u)

    @property
    def converged(self) -> np.ndarray:
        """True where the implicit equation was solved to ``tol`` (no saturation)."""
        return self.status == OK

    @property
    def saturated(self) -> np.ndarray:
        """True where u sits on a limit because H_d was out of reach."""
        return (self.status == SAT_LOW) | (self.status == SAT_HIGH)

    @property
    def saturated_samples(self) -> np.ndarray:
        """Indices of the saturated samples."""
        return np.flatnonzero(self.saturated)

    @property
    def unconverged_samples(self) -> np.ndarray:
        """Indices of the samples where no root was found (not saturation)."""
        return np.flatnonzero(self.status == NOT_CONVERGED)

    @property
    def residual(self) -> np.ndarray:
        """y_model − H_d [µm]."""
        return self.y_model - self.Hd

    @property
    def ok(self) -> bool:
        """Every sample solved, none saturated."""
        return bool(np.all(self.status == OK))

    def summary(self) -> str:
        """One line: samples, saturation (with the first sample and time), failures."""
        n = len(self.u)
        parts = [f"{n} samples"]
        for code in (SAT_LOW, SAT_HIGH, NOT_CONVERGED):
            idx = np.flatnonzero(self.status == code)
            if idx.size:
                parts.append(f"{idx.size} {_STATUS_NAMES[code]} (first at sample {idx[0]}, "
                             f"t = {idx[0] * self.dt:.6g} s)")
        if len(parts) == 1:
            parts.append("all solved" if not self.explicit else "none saturated")
        res = np.abs(self.residual)
        parts.append(f"max |model − Hd| = {res.max() if n else 0.0:.3g} µm")
        return "; ".join(parts)


def compensate(model, Hd, dt, *, limits=DEFAULT_LIMITS, explicit=False, tol=DEFAULT_TOL,
               max_iter=_MAX_ITER, form="discrete") -> CompensationResult:
    """Feedforward voltage for a desired displacement, from rest (eqs. 16–17, 21, 22).

    Parameters
    ----------
    model : FONBW, NBW, CBW or Zhu2016
        The identified model; its memory engine is used as is.
    Hd : array_like
        Desired displacement H_d [µm], sampled at dt.
    dt : float
        Step [s].
    limits : (float, float)
        Voltage range (u_min, u_max) [V]; default the paper's 0–120 V.
    explicit : bool
        One-step-delayed variant (G from the previous step) instead of the
        per-step implicit solve (module docstring).
    tol : float
        Tolerance on |H(u_k) − H_d,k| [µm] of the implicit solve.
    max_iter : int
        Iteration cap of each bracketed solve.
    form : {"discrete", "eq22"}
        "discrete" (default, every kind): per-step inversion of the discrete
        model, H(u_k) = H_d,k. "eq22" (Zhu2016 only): eq. (22) made implicit,
        the mechanics inverted on H_d with backward differences and the force
        balance (k1/τ)e^(−t/τ)u + ĥ(u) = m0 Ḧd + c0 Ḣd + k0 (H_d − x0)
        solved per step; status and ``tol`` then refer to that force
        balance, and the model output differs from H_d by the mechanics'
        discretization.

    Returns
    -------
    CompensationResult
        u [V], the model output, and per-sample status (saturation and
        convergence).
    """
    _check_model(model)
    Hd = _hd(Hd)
    dt = _hy._dt(dt)
    lo, hi = _limits(limits)
    tol = _tol(tol)
    max_iter = _max_iter(max_iter)
    ku, kh = _explicit_coeffs(model, explicit)
    form = _form(model, form)
    n = len(Hd)
    target = Hd
    if form == "eq22" and n:
        h1 = np.concatenate([Hd[:1], Hd[:-1]])
        h2 = np.concatenate([Hd[:1], Hd[:1], Hd[:-2]])[:n]
        target = np.ascontiguousarray(_force_target(model, Hd, h1, h2, dt))
    P, ss = model._pack(dt, n_steps=max(n, 1))
    u = np.empty(n)
    y = np.empty(n)
    status = np.empty(n, dtype=np.int8)
    nfev = np.empty(n, dtype=np.int64)
    if n:
        _entries(model, form)[0](target, P, ss, lo, hi, tol, int(max_iter), bool(explicit), ku, kh,
             u, y, status, nfev)
    return CompensationResult(u=u, y_model=y, Hd=Hd, dt=dt, status=status, nfev=nfev,
                              limits=(lo, hi), tol=tol, explicit=bool(explicit), form=form)


class Compensator:
    """The compensator one sample at a time: ``u_k = c.step(Hd_k)``.

    Gives the numbers of :func:`compensate` bit for bit (same compiled solver
    on the blocks of the model's own stepper). ``get_state``/``set_state``
    copy everything (model memory, previous voltage, slope estimate,
    counters) as one float64 array, for FMU rollback.

    Parameters
    ----------
    model, dt, limits, explicit, tol, max_iter, form
        As for :func:`compensate`.

    Attributes
    ----------
    status : int
        Status of the last step (``OK``, ``SAT_LOW``, ``SAT_HIGH``,
        ``NOT_CONVERGED``).
    y_model : float
        Model output for the last voltage [µm].
    n_saturated, n_not_converged, steps : int
        Counts since the last reset.
    """

    _NCTL = 9  # steps, u_prev, slope, n_sat, n_fail, status, y_model, H_d(k-1), H_d(k-2)

    def __init__(self, model, dt, *, limits=DEFAULT_LIMITS, explicit=False, tol=DEFAULT_TOL,
                 max_iter=_MAX_ITER, form="discrete"):
        _check_model(model)
        self.model = model
        self.dt = _hy._dt(dt)
        self.limits = _limits(limits)
        self.tol = _tol(tol)
        self.max_iter = _max_iter(max_iter)
        self.explicit = bool(explicit)
        self._ku, self._kh = _explicit_coeffs(model, explicit)
        self.form = _form(model, form)
        self._entry = _entries(model, self.form)[1]
        self._out = np.zeros(4)
        self.reset()

    def reset(self) -> None:
        """Back to rest at t = 0."""
        # The model's own stepper holds the packed blocks P, S (and grows the
        # exact engine's window); the compiled step solves on them.
        self._st = self.model.stepper(self.dt)
        self._growable = any(op.growable for op in getattr(self._st, "ops", ()))
        self._ctl = np.array([min(max(0.0, self.limits[0]), self.limits[1]), math.nan])
        self.steps = 0
        self.n_saturated = 0
        self.n_not_converged = 0
        self.status = OK
        self.y_model = 0.0
        self._hd1 = self._hd2 = 0.0

    def step(self, y_ref: float) -> float:
        """Voltage u_k [V] for the desired displacement y_ref = H_d,k [µm]."""
        hd = float(y_ref)
        if not math.isfinite(hd):
            raise ValueError(f"desired displacement at step {self.steps} is not finite: {y_ref!r}")
        st, out = self._st, self._out
        lo, hi = self.limits
        if self.form == "eq22":
            if self.steps == 0:
                self._hd1 = self._hd2 = hd  # at rest before t = 0
            target = _force_target(self.model, hd, self._hd1, self._hd2, self.dt)
            self._hd2, self._hd1 = self._hd1, hd
            hd = target
        # solve and commit in one compiled call, except when the exact
        # engine's window may have to grow first: the model stepper commits then
        self._entry(hd, st.P, st.S, lo, hi, self.tol, self.max_iter, self.explicit, self._ku,
                    self._kh, self._ctl, out, not self._growable)
        u = float(out[0])
        if self._growable:
            self.y_model = st.step(u)
            self._ctl[0] = u
        else:
            self.y_model = float(out[3])
            st._steps += 1  # keep the stepper's own count true (its state is ours)
        self.status = int(out[1])
        self.steps += 1
        if self.status in (SAT_LOW, SAT_HIGH):
            self.n_saturated += 1
        elif self.status == NOT_CONVERGED:
            self.n_not_converged += 1
        return u

    def get_state(self) -> np.ndarray:
        head = [float(self.steps), self._ctl[0], self._ctl[1], float(self.n_saturated),
                float(self.n_not_converged), float(self.status), float(self.y_model),
                self._hd1, self._hd2]
        return np.concatenate([head, self._st.get_state()])

    def set_state(self, state) -> None:
        s = np.asarray(state, dtype=float)
        if s.ndim != 1 or len(s) <= self._NCTL:
            raise ValueError("state must be a 1-D array from Compensator.get_state()")
        self._st.set_state(s[self._NCTL:])
        self.steps = int(s[0])
        self._ctl = np.array([s[1], s[2]])
        self.n_saturated, self.n_not_converged, self.status = int(s[3]), int(s[4]), int(s[5])
        self.y_model = float(s[6])
        self._hd1, self._hd2 = float(s[7]), float(s[8])


def compensator(model, dt, *, limits=DEFAULT_LIMITS, explicit=False, tol=DEFAULT_TOL,
                max_iter=_MAX_ITER, form="discrete") -> Compensator:
    """Per-sample compensator (for FMUs and loops); see :class:`Compensator`."""
    return Compensator(model, dt, limits=limits, explicit=explicit, tol=tol, max_iter=max_iter,
                       form=form)


def compensate_file(model_path, traj_path, out_path, *, limits=DEFAULT_LIMITS, explicit=False,
                    tol=DEFAULT_TOL, form="discrete") -> CompensationResult:
    """``fonbw compensate``: model JSON + trajectory CSV (t, Hd) -> CSV (t, u, Hd, y_model, status).

    Errors in the inputs raise ValueError (``fonbw.io.DataError`` for the
    CSV) naming the file.
    """
    from .io import read_record, write_csv

    model = _hy.load_model(model_path)
    rec = read_record(traj_path, need=("Hd",))
    res = compensate(model, rec.hd, rec.dt, limits=limits, explicit=explicit, tol=tol, form=form)
    write_csv(out_path, {"t": rec.t, "u": res.u, "Hd": res.Hd, "y_model": res.y_model,
                         "status": res.status.astype(float)})
    return res
