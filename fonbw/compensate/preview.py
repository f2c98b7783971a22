"""Stable inversion for a known trajectory: the preview compensator.

When the whole desired path H_d is known in advance (a scan, a repeated
trajectory, an offline test), the voltage need not be computed causally.
:func:`compensate_preview` solves H(u) = H_d for the whole sequence u with the
model's own batch simulation, by a model-based iterative inversion (iterative
learning control run on the model, not on the stage):

    e_j = H_d − H(u_j) ,   u_(j+1) = clip(u_j + γ_j L e_j) ,

where L is the *non-causal* regularized inverse of the model's small-signal
response on the discrete grid (an FFT filter, so zero-phase in the sense
that it carries no delay),

    P(ω) = g'(ū) + k_h ρ Δ(ω)^λ1 / Δ(ω)^λ2 ,  Δ(ω) = (1 − e^(−jω dt))/dt ,
    L(ω) = P(ω)* / (|P(ω)|² + μ) ,

and γ_j a step halved whenever the error would grow. P has a zero on the
positive real axis when k_h ρ < 0 and λ1 > λ2 (non-minimum phase), but not
on the imaginary axis, so its non-causal inverse is bounded (the stable
inversion of Devasia, Chen and Paden, 1996): the voltage leads the
trajectory by the zero's time constant instead of blowing up. The nonlinear
iteration only needs P's phase to be within ±90° of the true local response;
the model's hysteresis, polynomial and saturation are handled by iterating.

Which compensator to use
------------------------
* Causal (:func:`fonbw.compensate.compensate`, :class:`Compensator`, the FMU):
  online, one sample at a time, H_d unknown ahead. Exact only when the model
  is invertible at that step (:func:`fonbw.invertibility.check_invertible`;
  identify with ``for_compensation=dt``).
* Preview (this module): H_d known ahead. Works for any identified model,
  invertible or not; gives a bounded, smooth voltage and tracks the model to
  ``tol`` where the limits allow.

Units: u [V], H_d [µm], dt [s].
"""
from __future__ import annotations

import math

import numpy as np

from .. import hysteresis as _hy
from .kernels import NOT_CONVERGED, OK, SAT_HIGH, SAT_LOW

__all__ = ["compensate_preview", "small_signal_response", "default_lead", "rhp_zero"]


def _lin_params(model):
    """(g'(u) as a function, kh ρ, λ1, λ2) of the model's small-signal response."""
    if isinstance(model, _hy.FONBW):
        ku = np.asarray(model.ku, float)
        khr = model.kh * model.rho
        lam1, lam2 = getattr(model, "lam1", 1.0), getattr(model, "lam2", 1.0)
    elif isinstance(model, _hy.CBW):
        ku = np.array([model.ka])
        khr = model.kb * model.A  # kb D · (A/D): the NBW it equals
        lam1 = lam2 = 1.0
    else:
        raise ValueError(f"compensate_preview needs a FONBW, NBW or CBW, not a {type(model).__name__}")

    def gprime(u):
        return sum((i + 1) * ku[i] * u ** i for i in range(len(ku)))
    return gprime, khr, lam1, lam2


def small_signal_response(model, dt, n, u_bar=0.0):
    """P(ω_k) [µm/V] of the model linearized at u_bar, ħ = 0, on an rfft grid of n points."""
    gprime, khr, lam1, lam2 = _lin_params(model)
    w = 2.0 * np.pi * np.fft.rfftfreq(n, dt)
    delta = (1.0 - np.exp(-1j * w * dt)) / dt
    delta[0] = 1e-300  # DC: the limit of Δ^λ1/Δ^λ2 (0, 1 or ∞ by the orders)
    ratio = delta ** lam1 / delta ** lam2
    if lam1 == lam2:
        ratio[0] = 1.0
    elif lam1 < lam2:
        ratio[0] = ratio[1] if n > 2 else 1.0  # integrating ħ: bounded by saturation
    return gprime(u_bar) + khr * ratio


def _status(u, e, lo, hi, tol):
    st = np.where(np.abs(e) <= tol, OK, NOT_CONVERGED).astype(np.int8)
    st[(st != OK) & (u <= lo)] = SAT_LOW
    st[(st != OK) & (u >= hi)] = SAT_HIGH
    return st


def _newton_krylov(sim, Hd, w, u, apply_L, lo, hi, tol, max_iter, inner=30):
    """Newton's method on W(H_d − H(u)) = 0 for the whole sequence, each step by
    GMRES on the right-preconditioned system W J L z = W e (J v by a finite
    difference of the model's batch simulation `sim`, L the stable inverse),
    then δ = L z with a backtracking step. Returns (u, H(u), W e, iterations)."""
    from scipy.sparse.linalg import LinearOperator, gmres

    n = len(u)
    y = sim(u)
    e = (Hd - y) * w
    err = float(np.sqrt(np.mean(e * e)))
    it = 0
    while it < max_iter and np.max(np.abs(e)) > tol:
        it += 1
        scale = max(1e-6, 1e-7 * float(np.max(np.abs(u))))

        def jl(z, u=u, y=y):
            v = apply_L(z * w)
            nv = float(np.max(np.abs(v)))
            if nv == 0.0:
                return np.zeros(n)
            eps = scale / nv
            return (sim(u + eps * v) - y) / eps * w + z * (1.0 - w)

        A = LinearOperator((n, n), matvec=jl, dtype=float)
        z, _ = gmres(A, e, restart=inner, maxiter=2, rtol=1e-4, atol=0.0)
        du = apply_L(z * w)
        gamma = 1.0
        for _ in range(30):
            ut = np.clip(u + gamma * du, lo, hi)
            yt = sim(ut)
            et = (Hd - yt) * w
            errt = float(np.sqrt(np.mean(et * et)))
            if np.isfinite(errt) and errt < err:
                break
            gamma *= 0.5
        else:
            break  # no descent: stalled on the limits or at round-off
        u, y, e, err = ut, yt, et, errt
    return u, y, e, it


def default_lead(model, dt, n=None):
    """Pre-actuation [samples] the preview needs before t = 0.

    The stable inverse of a model with a zero at s0 > 0 (module docstring)
    acts ahead of the trajectory, decaying backwards by 1 − s0·dt per sample
    (the zero of P(z) at z = 1/(1 − s0 dt)); 20 e-folds leave 2e-9 of it.
    A minimum-phase model needs none beyond a few samples.
    """
    s0 = rhp_zero(model)
    if s0 is None or s0 * dt >= 1.0:
        L = 16
    else:
        L = int(math.ceil(20.0 / -math.log1p(-s0 * dt)))
    L = max(L, 16)
    return L if n is None else min(L, max(16, 4 * int(n)))


def rhp_zero(model):
    """The positive real zero s0 [rad/s] of the small-signal response
    k_u1 + k_h ρ s^(λ1−λ2) at ħ = 0, u = 0, or None (minimum phase)."""
    gprime, khr, lam1, lam2 = _lin_params(model)
    a = float(gprime(0.0))
    if not (khr < 0.0 and a > 0.0) or lam1 == lam2:
        return None
    return (a / -khr) ** (1.0 / (lam1 - lam2))


def compensate_preview(model, Hd, dt, *, limits=None, tol=1e-9, max_iter=100, mu=None,
                       u0=None, tail=None, lead=None, history=None):
    """Feedforward voltage for a known trajectory, non-causally (stable inversion).

    Parameters
    ----------
    model : FONBW, NBW or CBW
        The identified model (invertible at dt or not).
    Hd : array_like
        Desired displacement H_d [µm] at step dt, from rest.
    dt : float
        Step [s].
    limits : (float, float), optional
        Voltage range [V]; default the model's training range
        (``model.meta["u_range"]``), else the paper's 0–120 V.
    tol : float
        Target of max |H(u) − H_d| [µm] over the trajectory; iteration stops there.
    max_iter : int
        Newton iterations (each a few tens of batch simulations of the model).
    mu : float, optional
        Regularization of the inverse filter [(µm/V)²]; default
        (1e-3 g'(ū))², which only matters where |P| is that small.
    u0 : array_like, optional
        Starting voltage over lead + trajectory + tail [V]; default the
        linear inverse of H_d.
    tail : int, optional
        Samples appended after the end, H_d held at its last value, where
        the error does not count (default: a quarter of the length, at
        least 64).
    lead : int, optional
        Samples of pre-actuation before t = 0, where the voltage may move
        and the output is not scored (default :func:`default_lead`). With a
        zero of the small-signal response in the right half-plane, exact
        tracking from t = 0 on needs the voltage to start ahead: over the
        trajectory alone the discrete equations are triangular, and their
        only solution is the unstable causal inverse.
    history : array_like, optional
        Voltage [V] run before everything else, output counted from its
        end (default: the model's own start, as :func:`fonbw.compensate`).

    Returns
    -------
    CompensationResult
        ``u`` over the trajectory, ``u_lead`` the pre-actuation (drive the
        actuator with ``u_full``); ``nfev`` holds the iteration count in
        every entry; ``status`` is OK where |H(u) − H_d| ≤ tol, SAT_LOW /
        SAT_HIGH where u sits on a limit with the error above tol,
        NOT_CONVERGED elsewhere.
    """
    from .causal import CompensationResult, _hd, _history, _limits, default_limits

    Hd0 = _hd(Hd)
    dt = _hy._dt(dt)
    lo, hi = _limits(default_limits(model) if limits is None else limits)
    pre = _history(model, dt, history)
    n0 = len(Hd0)
    tail = max(64, n0 // 4) if tail is None else int(tail)
    lead = default_lead(model, dt, n0) if lead is None else int(lead)
    if tail < 0 or lead < 0:
        raise ValueError(f"lead and tail must be ≥ 0 samples, got {lead!r}, {tail!r}")
    h0, h1 = (Hd0[0], Hd0[-1]) if n0 else (0.0, 0.0)
    Hd = np.concatenate([np.full(lead, h0), Hd0, np.full(tail, h1)])
    # only the trajectory's errors count
    w = np.concatenate([np.zeros(lead), np.ones(n0), np.zeros(tail)])
    n = len(Hd)
    y_rest = float(model.simulate(pre, dt)[-1]) if pre.size else 0.0

    def sim(u):
        if not pre.size:
            return model.simulate(u, dt)
        return model.simulate(np.concatenate([pre, u]), dt)[pre.size:] - y_rest

    nfft = int(2 ** math.ceil(math.log2(max(2 * n, 16))))
    gprime, *_ = _lin_params(model)
    u_bar = 0.5 * (lo + hi)
    P = small_signal_response(model, dt, nfft, u_bar)
    g0 = abs(gprime(u_bar)) or float(np.max(np.abs(P)))
    mu = (1e-3 * g0) ** 2 if mu is None else float(mu)
    L = np.conj(P) / (np.abs(P) ** 2 + mu)

    def apply_L(e):
        return np.fft.irfft(L * np.fft.rfft(e, nfft), nfft)[:n]

    u_rest = pre[-1] if pre.size else min(max(0.0, lo), hi)
    if u0 is None:
        u = np.clip(u_rest + apply_L((Hd - h0) * w), lo, hi)
    else:
        u = np.clip(np.asarray(u0, float).copy(), lo, hi)
        if u.shape != (n,):
            raise ValueError(f"u0 must have lead + len(Hd) + tail = {n} samples")
    u, y, e, it = _newton_krylov(sim, Hd, w, u, apply_L, lo, hi, tol, max_iter)
    sl = slice(lead, lead + n0)
    u_t, y_t, e_t = u[sl], y[sl], e[sl]
    return CompensationResult(u=u_t, y_model=y_t, Hd=Hd0, dt=dt, status=_status(u_t, e_t, lo, hi, tol),
                              nfev=np.full(n0, it, dtype=np.int64), limits=(lo, hi), tol=tol,
                              preview=True, history=pre, u_lead=u[:lead].copy())
