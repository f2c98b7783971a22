"""Bouc-Wen hysteresis models of a piezoelectric actuator, fixed step.

Units everywhere: input voltage u [V], displacement [µm], time [s].

Models (equation numbers of the paper):

* :class:`CBW` — classical Bouc-Wen, eqs. (1)–(2), with the exact
  normalization :meth:`CBW.to_nbw` of eqs. (7)–(8).
* :class:`NBW` — normalized Bouc-Wen, eqs. (7)–(8); with a list ``ku`` it is
  the asymmetric NBW of eqs. (9)–(10) with the polynomial g(u) of any order N.
* :class:`FONBW` — eqs. (9)–(11), two Grünwald–Letnikov derivatives of orders
  0 < λ1, λ2 ≤ 1 (:mod:`fonbw.fractional`).
* :class:`Zhu2016` — the rate-dependent baseline of eq. (20) as written.

Discretization (the same for batch and per-step use):

* Fixed step dt, zero-order-hold input, everything at rest before t = 0: the
  input is taken to have been at its first value u_0 forever, so the
  fractional derivative acts on u − u_0 (for λ1 = 1 this is the plain
  backward difference with Δu_0 = 0).
* The Bouc-Wen state is advanced implicitly. For FONBW, eq. (11) with the GL
  sums becomes, for the unknown x = ħ_k, the scalar equation

      F(x) = x − b + c1 |x|^(n−1) x + c2 |x|^n = 0,
      b  = (ρ D1 − h2)/a2,  c1 = ρσ|D1|/a2,  c2 = ρ(1−σ) D1/a2,

  where D^λ1 u_k = D1 and D^λ2 ħ_k = a2 ħ_k + h2 (h2 from the history). It is
  solved by a safeguarded Newton iteration (bracket + bisection fallback) for
  any real n ≥ 1. For σ ≥ 1/2 the root is unique and lies between 0 and b.
  λ1 = λ2 = 1 gives exactly backward-Euler NBW; CBW and Zhu use backward
  Euler on their own state h with the same solver.

Every model has ``simulate(u, dt)`` (batch, compiled) and ``stepper(dt)``
(one sample at a time for FMUs and closed loops); both run the same compiled
step function and give bit-identical results.

Modules: :mod:`~fonbw.hysteresis.kernels` (compiled step and batch kernels),
:mod:`~fonbw.hysteresis.models` (the model classes), :mod:`~fonbw.hysteresis.stepper`
(per-sample steppers), :mod:`~fonbw.hysteresis.serialize` (JSON) and
:mod:`~fonbw.hysteresis.population` (parameter vectors, population runs).
This package re-exports the names other modules use, so
``fonbw.hysteresis.X`` works for each of them.
"""
from __future__ import annotations

from .kernels import (  # noqa: F401
    BRACKET_SNAP,
    CODE_CBW,
    CODE_FONBW,
    CODE_ZHU,
    FONBW_S0,
    NEWTON_RTOL,
    POW_REFRESH,
    POW_SERIES_D,
    cbw_core,
    cbw_step,
    fonbw_advance,
    fonbw_core,
    fonbw_exact_leaf,
    fonbw_output,
    fonbw_predict,
    fonbw_solve,
    fonbw_step,
    fonbw_views,
    plain_views,
    run_kernel,
    run_population,
    solve_bw,
    solve_bw_full,
    solve_bw_p,
    step_code,
    zhu_core,
    zhu_step,
)
from .models import (  # noqa: F401
    CBW,
    EXACT_BLOCKED_MIN,
    FONBW,
    KINDS,
    NBW,
    Zhu2016,
    _dt,
    _input,
    _simulate,
    _simulate_exact_blocked,
)
from .population import model_from_vector, param_names, simulate_population  # noqa: F401
from .serialize import load_model, model_from_dict  # noqa: F401
from .stepper import Stepper  # noqa: F401

__all__ = [
    "CBW",
    "NBW",
    "FONBW",
    "Zhu2016",
    "Stepper",
    "load_model",
    "model_from_dict",
    "param_names",
    "model_from_vector",
    "simulate_population",
    "KINDS",
]
