"""Models as flat parameter vectors, and many of them simulated at once.

The identification searches over vectors in the order of
:func:`param_names`; :func:`simulate_population` runs a whole population of
them in one compiled, parallel call (:func:`fonbw.hysteresis.kernels.run_population`).
"""
from __future__ import annotations

import numpy as np

from .kernels import run_population
from .models import CBW, FONBW, KINDS, NBW, Zhu2016, _dt, _input


def param_names(kind: str, N: int = 3) -> list[str]:
    """Order of the parameter vector of :func:`simulate_population` for a kind."""
    ku = [f"ku{i}" for i in range(1, N + 1)]
    if kind == "fonbw":
        return ku + ["kh", "rho", "sigma", "n", "lam1", "lam2"]
    if kind == "nbw":
        return ku + ["kh", "rho", "sigma", "n"]
    if kind == "cbw":
        return ["ka", "kb", "D", "A", "beta", "gamma", "n"]
    if kind == "zhu":
        return list(Zhu2016.names)
    raise ValueError(f"unknown model kind {kind!r}; choose one of {', '.join(KINDS)}")


def model_from_vector(kind: str, theta, N: int = 3, memory: str = "fast"):
    """Model of `kind` from a parameter vector in the order of :func:`param_names`."""
    th = [float(v) for v in theta]
    if len(th) != len(param_names(kind, N)):
        raise ValueError(f"{kind} with N={N} takes {len(param_names(kind, N))} parameters, got {len(th)}")
    if kind == "fonbw":
        return FONBW(th[:N], *th[N:], memory=memory)
    if kind == "nbw":
        return NBW(th[:N], *th[N:])
    if kind == "cbw":
        return CBW(ka=th[0], kb=th[1], D=th[2], A=th[3], beta=th[4], gamma=th[5], n=th[6])
    return Zhu2016(*th)


def simulate_population(kind: str, theta, u, dt, memory: str = "fast", N: int = 3) -> np.ndarray:
    """Simulate many parameter sets in one compiled, parallel call.

    Parameters
    ----------
    kind : {"fonbw", "nbw", "cbw", "zhu"}
    theta : array_like, shape (P, d)
        Parameter vectors in the order of :func:`param_names`.
    u : array_like, shape (n,) or (P, n)
        Input [V]: one input for all candidates, or one row per candidate
        (e.g. when an input-side effect block filters the voltage differently
        for each candidate).
    dt : float
        Step [s].
    memory : str
        GL engine (fonbw). ``oustaloup`` runs the rows one after the other.
    N : int
        Polynomial order (fonbw, nbw).

    Returns
    -------
    ndarray, shape (P, n)
        Outputs [µm]; a row is NaN from the step where its candidate diverged
        (and whole-NaN for an invalid parameter vector).
    """
    th = np.atleast_2d(np.asarray(theta, dtype=float))
    U = np.ascontiguousarray(u, dtype=float)
    if U.ndim == 1:
        U = _input(U)[None, :]
    elif U.ndim != 2 or U.shape[0] != th.shape[0]:
        raise ValueError(f"u must be 1-D or have one row per parameter vector ({th.shape[0]}), got shape {U.shape}")
    elif not np.all(np.isfinite(U)):
        raise ValueError("input u contains NaN or infinite values")
    dt = _dt(dt)
    P = th.shape[0]
    n = U.shape[1]
    d = len(param_names(kind, N))
    if th.shape[1] != d:
        raise ValueError(f"theta must have {d} columns for {kind} with N={N}, got {th.shape[1]}")
    out = np.full((P, n), np.nan)
    models = []
    for p in range(P):
        try:
            models.append((p, model_from_vector(kind, th[p], N, memory)))
        except ValueError:
            pass  # invalid candidate: its row stays NaN
    if not models:
        return out
    if memory == "oustaloup" and kind == "fonbw":
        for p, m in models:
            out[p] = m.simulate(U[0] if U.shape[0] == 1 else U[p], dt)
        return out
    rows = [p for p, _ in models]
    packs = [m._pack(dt, n_steps=n) for _, m in models]
    width = max(len(pk[0]) for pk in packs)
    Pm = np.zeros((len(packs), width))
    for i, (pk, _) in enumerate(packs):
        Pm[i, :len(pk)] = pk
    ss = np.array([pk[1] for pk in packs], dtype=np.int64)
    sub = np.empty((len(packs), n))
    run_population(models[0][1]._code, U if U.shape[0] == 1 else U[rows], Pm, ss, sub)
    out[rows] = sub
    return out
