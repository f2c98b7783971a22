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

__all__ = ["compensate_preview", "small_signal_response"]


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


def _newton_krylov(model, dt, Hd, w, u, apply_L, lo, hi, tol, max_iter, inner=20):
    """Newton's method on W(H_d − H(u)) = 0 for the whole sequence, each step by
    GMRES on the right-preconditioned system W J L z = W e (J v by a finite
    difference of the model's batch simulation, L the stable inverse), then
    δ = L z with a backtracking step. Returns (u, H(u), W e, iterations)."""
    from scipy.sparse.linalg import LinearOperator, gmres

    n = len(u)
    y = model.simulate(u, dt)
    e = (Hd - y) * w
    err = float(np.sqrt(np.mean(e * e)))
    it = 0
    while it < max_iter and np.max(np.abs(e)) > tol:
        it += 1
        scale = max(1e-6, 1e-7 * float(np.max(np.abs(u))))

        def jl(z, u=u, y=y):
            v = apply_L(z)
            nv = float(np.max(np.abs(v)))
            if nv == 0.0:
                return np.zeros(n)
            eps = scale / nv
            return (model.simulate(u + eps * v, dt) - y) / eps * w

        A = LinearOperator((n, n), matvec=jl, dtype=float)
        z, _ = gmres(A, e, restart=inner, maxiter=1, rtol=1e-3, atol=0.0)
        du = apply_L(z)
        gamma = 1.0
        for _ in range(20):
            ut = np.clip(u + gamma * du, lo, hi)
            yt = model.simulate(ut, dt)
            et = (Hd - yt) * w
            errt = float(np.sqrt(np.mean(et * et)))
            if np.isfinite(errt) and errt < err:
                break
            gamma *= 0.5
        else:
            break  # no descent: stalled on the limits or at round-off
        u, y, e, err = ut, yt, et, errt
    return u, y, e, it


def compensate_preview(model, Hd, dt, *, limits=None, tol=1e-9, max_iter=300, mu=None,
                       u0=None, tail=None):
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
        Target of max |H(u) − H_d| [µm]; iteration stops there.
    max_iter : int
        Iterations (each one batch simulation of the model).
    mu : float, optional
        Regularization of the inverse filter [(µm/V)²]; default
        (1e-3 g'(ū))², which only matters where |P| is that small.
    u0 : array_like, optional
        Starting voltage [V]; default the linear inverse of H_d.
    tail : int, optional
        Samples appended after the end, H_d held at its last value, where
        the error does not count (default: a quarter of the length, at
        least 64). The stable inverse of a non-minimum-phase model acts
        ahead of the trajectory; without room after the end it would have
        to act with unbounded voltage in the last samples. The model is
        causal, so the extension does not change what it does before the
        end; only the first len(H_d) voltages are returned.

    Returns
    -------
    CompensationResult
        ``nfev`` holds the iteration count in every entry; ``status`` is OK
        where |H(u) − H_d| ≤ tol, SAT_LOW/SAT_HIGH where u sits on a limit
        with the error above tol, NOT_CONVERGED elsewhere.
    """
    from .causal import CompensationResult, _hd, _limits, default_limits

    Hd0 = _hd(Hd)
    dt = _hy._dt(dt)
    lo, hi = _limits(default_limits(model) if limits is None else limits)
    n0 = len(Hd0)
    tail = max(64, n0 // 4) if tail is None else int(tail)
    Hd = np.concatenate([Hd0, np.full(tail, Hd0[-1] if n0 else 0.0)])
    w = np.concatenate([np.ones(n0), np.zeros(tail)])  # errors after the end do not count
    n = len(Hd)
    nfft = int(2 ** math.ceil(math.log2(max(2 * n, 16))))
    gprime, *_ = _lin_params(model)
    u_bar = 0.5 * (lo + hi)
    P = small_signal_response(model, dt, nfft, u_bar)
    g0 = abs(gprime(u_bar)) or float(np.max(np.abs(P)))
    mu = (1e-3 * g0) ** 2 if mu is None else float(mu)
    L = np.conj(P) / (np.abs(P) ** 2 + mu)

    def apply_L(e):
        return np.fft.irfft(L * np.fft.rfft(e, nfft), nfft)[:n]

    u = np.clip(apply_L(Hd) if u0 is None else np.asarray(u0, float).copy(), lo, hi)
    u, y, e, it = _newton_krylov(model, dt, Hd, w, u, apply_L, lo, hi, tol, max_iter)
    u, y, e = u[:n0], y[:n0], e[:n0]
    return CompensationResult(u=u, y_model=y, Hd=Hd0, dt=dt, status=_status(u, e, lo, hi, tol),
                              nfev=np.full(n0, it, dtype=np.int64), limits=(lo, hi), tol=tol,
                              preview=True)
