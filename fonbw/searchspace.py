"""Search spaces of model identification: the variables jDE searches and their ranges.

:func:`search_space` gives, for each model kind, the nonlinear variables
:func:`fonbw.identify.identify` searches (the linear ones are solved, see
:mod:`fonbw.identify`), their default ranges and the maps back to the
model's natural parameters.

Search variables (reparametrization)
------------------------------------
The paper's Table 1 FONBW values are extreme (ρ = 6.5e-7, σ = 1.3e5,
k_h = −3.3e4): the data do not fix ρ, σ and k_h separately there. With
z = ħ/ρ eq. (11) reads

    D^λ2 z = D^λ1 u − σρ^n |D^λ1 u| |z|^(n−1) z + (σ − 1)ρ^n D^λ1 u |z|^n ,
    H = g(u) + (k_h ρ) z ,

so what the output fixes for small ħ is k_h ρ (solved linearly) and σρ^n,
while ρ alone only sets where ħ would saturate, a nearly flat direction of J
when σ ≫ 1. FONBW/NBW/CBW therefore search (default ``reparametrize=True``)

=============  ===========================  ==================================
name           meaning                      default range (U = max|u| [V])
=============  ===========================  ==================================
``rho``        ρ                            log, [1e-7, 1e4]/U
``sigma_rho``  σ^(1/n) ρ                    log, [1e-3, 1e4]/U
``n``          n                            linear, [1, 4]
``lam1/lam2``  λ1, λ2 (FONBW only)          linear, [λ_lo, 1] (below)
=============  ===========================  ==================================

and σ = (sigma_rho/ρ)^n. The map is a bijection, linear in log coordinates:
when ħ saturates, ρ and σ stay identifiable; when σ ≫ 1 the flat direction is
along the ``rho`` axis alone, which DE copes with far better than with the
diagonal ridge it makes in (log ρ, log σ). The wide ρ range allows for the
factor ω^(λ1−λ2) by which the fractional orders rescale ρ.
In that regime (ħ ≪ 1, eq. (11) nearly linear) even λ1 and λ2 are not
identifiable one by one: the GL weights of orders λ1 and −λ2 compose exactly
into those of λ1 − λ2, so the data fix the difference λ1 − λ2 (checked in
tests/test_identify.py on Table 1's values: λ1 − λ2 is recovered to 1e-3,
λ1 and λ2 themselves are not). The fitted model still predicts as well.
``reparametrize=False`` searches ``rho`` and ``sigma`` (log, [1e-2, 1e8])
directly. CBW (eqs. 1-2, redundant, Sec. II-B) is searched in its normalized
form and mapped back with A = 1, β + γ = 1 (so h0 = 1): β = σ, γ = 1 − σ,
D = 1/ρ, and the paper's ka = αk = ku1, kb = (1 − α)k = k_h ρ. The Zhu model
is searched with k0 = 1 (its force balance has the same overall-scale
redundancy): ``wn`` = sqrt(k0/m0) [rad/s] log [2π, 2π·5e3], ``zeta`` =
c0/(2 sqrt(k0 m0)) log [0.05, 20], ``k1_rel`` = k1/(τA) linear [−2, 2],
``tau`` [s] log [1e-6, 1], ``beta_hat`` = β' U^n log [1e-3, 1e3],
``gamma_rel`` = γ/β linear [−1, 1] (β > 0, |γ| ≤ β: the bounded-h class of the
BW equation; outside it most candidates diverge), ``delta_rel`` = δ/A [1/s]
linear [−20, 20], ``n``.
Override any range with ``bounds={"rho": (lo, hi), ...}``.

Ranges the records can identify
-------------------------------
Two default ranges follow the data (:mod:`fonbw.identifiable`), so that a
fit cannot run off along directions the records do not see:

* λ1, λ2 ∈ [λ_lo, 1] with λ_lo from the records' *rate span* R: the input is
  cut into monotone swings between reversals (a reversal counts once the
  input came back by 2 % of its range), a swing of duration T has the
  frequency 1/(2T), and R is the ratio of the 90th to the 10th percentile of
  those frequencies, each swing weighted by its stroke (the first and last
  swing of a record, cut by its ends, left out). Then

      λ_lo = clip(0.5 − 0.45 log10(R), 0.05, 0.5):

  0.5 for records of a single rate (R = 1: a bipolar 1 Hz drive), the full
  0.05 from a decade of rates on. The gain (2πf)^λ of the GL derivatives is
  what tells λ from ρ; with one rate it is a constant that ρ and the gains
  absorb, and the search ran to the corner λ → 0 (an operator near the
  identity). Examples: eq. (19) over 10 s, R = 3.3, λ_lo = 0.27; over 30 s,
  R = 6.3, λ_lo = 0.14; a triangle wave of 3 periods at 1 Hz then 12 at 4 Hz,
  R = 4, λ_lo = 0.229.
* σ ≤ 1e3 (FONBW/NBW/CBW): a candidate with (sigma_rho/ρ)^n > 1e3 is
  evaluated with ρ raised to sigma_rho·1e3^(−1/n) (``SearchSpace.project``;
  ``search["x"]`` holds the projected point). At fixed σ^(1/n)ρ, σ changes
  the loop only through 1 − 1/σ and the saturation of ħ that a small ρ puts
  out of reach, by less than 0.1 % of the hysteretic term past 1e3; the
  search used to drift there (σ = 1e7 to 1e15 on bipolar records), with
  parameters that meant nothing. The paper's Table 1 (σ = 1.3e5, ħ ≪ 1) is
  matched at σ = 1e3 to the noise floor (tests/test_identify.py).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from fonbw.identifiable import LAM_MIN, SIGMA_MAX, lambda_floor, rate_span
from fonbw.objective import as_records as _as_records

__all__ = ["KINDS", "SearchSpace", "search_space", "search_vector"]

#: Model kinds :func:`fonbw.identify.identify` fits.
KINDS = ("fonbw", "nbw", "cbw", "zhu")


@dataclass
class SearchSpace:
    """Nonlinear search variables of one model kind and the linear part.

    Attributes
    ----------
    names, bounds, log_scale : list
        Search variables handed to :func:`fonbw.de.jde_minimize`.
    basis_params : callable
        ``basis_params(X) -> dict`` of natural parameter arrays (P,) that make
        the simulator return the *basis signal* s (ħ, h or x̃) of each
        candidate row of X.
    fixed_columns : callable
        ``fixed_columns(u) -> (len(u), q)`` array F of the regressors that do
        not depend on the candidate (u^i/U^i, or a constant).
    final_params : callable
        ``final_params(x, c, G) -> dict`` of natural parameters from one search
        vector x, the coefficients c of F and the gain G of s.
    project : callable, optional
        ``project(X) -> X`` onto the search vectors the maps actually use
        (σ ≤ :data:`fonbw.identifiable.SIGMA_MAX` by raising ρ, σ at or above
        its floor, if any, by lowering it); identity if None.
    """

    kind: str
    names: list
    bounds: list
    log_scale: list
    basis_params: Callable = field(repr=False)
    fixed_columns: Callable = field(repr=False)
    final_params: Callable = field(repr=False)
    project: Callable | None = field(default=None, repr=False)


def search_space(kind: str, records, *, N: int = 3, bounds: Mapping | None = None,
                 reparametrize: bool = True, sigma_min: float | None = None) -> SearchSpace:
    """Search variables, default bounds and the maps to natural parameters.

    Parameters
    ----------
    kind : {"fonbw", "nbw", "cbw", "zhu"}
    records : record or list of records
        Their max|u| scales the default bounds (module docstring).
    N : int
        Order of g(u), eq. (10) (FONBW and NBW; CBW has N = 1).
    bounds : mapping, optional
        ``{search_variable_name: (lo, hi)}`` overriding defaults.
    reparametrize : bool
        FONBW/NBW/CBW: search σ^(1/n)ρ (default) or σ.
    sigma_min : float, optional
        FONBW/NBW/CBW: smallest σ the maps use (ρ is lowered to hold it, as
        it is raised to hold :data:`~fonbw.identifiable.SIGMA_MAX`); e.g.
        :data:`~fonbw.identifiable.SIGMA_BOUNDED` for a model that must stay
        bounded on inputs it was not fitted on. Default: no floor.

    Returns
    -------
    SearchSpace
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    if isinstance(N, bool) or int(N) != N or N < 1:
        raise ValueError(f"N must be a positive integer, got {N!r}")
    recs = _as_records(records)
    U = max(float(np.max(np.abs(u))) for u, _, _ in recs)
    if kind in ("fonbw", "nbw", "cbw"):
        lam_lo = lambda_floor(rate_span(recs)) if kind == "fonbw" else LAM_MIN
        space = _bw_space(kind, U, int(N) if kind != "cbw" else 1, reparametrize, lam_lo, sigma_min)
    else:
        space = _zhu_space(U)
    if bounds is not None:
        _override_bounds(space, bounds)
    return space


def _bw_space(kind, U, Np, reparametrize, lam_lo=LAM_MIN, sigma_min=None):
    """FONBW, NBW or CBW search space (module docstring) for max|u| = U [V],
    the lower bound `lam_lo` of the fractional orders and the floor
    `sigma_min` of σ (None: none)."""
    names = ["rho", "sigma_rho" if reparametrize else "sigma", "n"]
    bnds = [(1e-7 / U, 1e4 / U),
            (1e-3 / U, 1e4 / U) if reparametrize else (max(1e-2, sigma_min or 0.0), SIGMA_MAX),
            (1.0, 4.0)]
    logs = [True, True, False]
    if kind == "fonbw":
        names += ["lam1", "lam2"]
        bnds += [(lam_lo, 1.0), (lam_lo, 1.0)]
        logs += [False, False]

    def project(X):
        # σ = (sigma_rho/ρ)^n ≤ SIGMA_MAX: ρ is raised to its floor at that σ
        # (beyond it ρ only moves along a flat direction, fonbw.identifiable).
        X = np.array(X, dtype=float, ndmin=2)
        if reparametrize:
            X[:, 0] = np.maximum(X[:, 0], X[:, 1] * SIGMA_MAX ** (-1.0 / X[:, 2]))
            if sigma_min is not None:
                X[:, 0] = np.minimum(X[:, 0], X[:, 1] * sigma_min ** (-1.0 / X[:, 2]))
        return X

    def rho_sigma_n(X):
        X = project(X)
        rho, n = X[:, 0], X[:, 2]
        sigma = (X[:, 1] / rho) ** n if reparametrize else X[:, 1]
        return rho, sigma, n

    def fixed_columns(u):
        # Scaled powers keep the least-squares problem well conditioned.
        return np.column_stack([(u / U) ** (i + 1) for i in range(Np)])

    if kind == "cbw":
        def basis_params(X):
            rho, sigma, n = rho_sigma_n(X)
            # ka = 0 and kb D = 1 make the output h itself (h0 = 1).
            return {"ka": np.zeros_like(rho), "kb": rho, "D": 1.0 / rho,
                    "A": np.ones_like(rho), "beta": sigma, "gamma": 1.0 - sigma,
                    "n": n}

        def final_params(x, c, G):
            rho, sigma, n = (float(v[0]) for v in rho_sigma_n(x[None, :]))
            return {"ka": float(c[0]) / U, "kb": G * rho, "D": 1.0 / rho, "A": 1.0,
                    "beta": sigma, "gamma": 1.0 - sigma, "n": n}
    else:
        def basis_params(X):
            rho, sigma, n = rho_sigma_n(X)
            p = {f"ku{i + 1}": np.zeros_like(rho) for i in range(Np)}
            p.update(kh=np.ones_like(rho), rho=rho, sigma=sigma, n=n)
            if kind == "fonbw":
                p.update(lam1=X[:, 3], lam2=X[:, 4])
            return p

        def final_params(x, c, G):
            p = {k: float(v[0]) for k, v in basis_params(x[None, :]).items()}
            for i in range(Np):
                p[f"ku{i + 1}"] = float(c[i]) / U ** (i + 1)
            p["kh"] = G
            return p
    return SearchSpace(kind=kind, names=names, bounds=bnds, log_scale=logs,
                       basis_params=basis_params, fixed_columns=fixed_columns,
                       final_params=final_params, project=project)


def _zhu_space(U):
    """Search space of Zhu et al., eq. (20), for max|u| = U [V]; k0 = 1, A = 1 in
    the basis simulation."""
    names = ["wn", "zeta", "k1_rel", "tau", "beta_hat", "gamma_rel", "delta_rel", "n"]
    bnds = [(2 * np.pi, 2 * np.pi * 5e3), (0.05, 20.0), (-2.0, 2.0), (1e-6, 1.0),
            (1e-3, 1e3), (-1.0, 1.0), (-20.0, 20.0), (1.0, 4.0)]
    logs = [True, True, False, True, True, False, False, False]

    def basis_params(X):
        wn, zeta, k1r, tau, bh, gr, dr, n = X.T
        one = np.ones_like(wn)
        beta = bh / U ** n
        return {"m0": 1.0 / wn ** 2, "c0": 2.0 * zeta / wn, "k0": one,
                "k1": k1r * tau, "x0": np.zeros_like(wn), "tau": tau, "A": one,
                "beta": beta, "gamma": gr * beta, "delta": dr, "n": n}

    def fixed_columns(u):
        return np.ones((u.size, 1))

    def final_params(x, c, G):
        p = {k: float(v[0]) for k, v in basis_params(x[None, :]).items()}
        n = p["n"]
        # h = G w rescales the BW state: see fonbw.identify's docstring.
        p.update(x0=float(c[0]), A=G, k1=G * p["k1"], delta=G * p["delta"],
                 beta=p["beta"] / abs(G) ** (n - 1.0),
                 gamma=p["gamma"] * G / abs(G) ** n)
        return p

    return SearchSpace(kind="zhu", names=names, bounds=bnds, log_scale=logs,
                       basis_params=basis_params, fixed_columns=fixed_columns,
                       final_params=final_params)


def _override_bounds(space, bounds):
    """Replace default bounds of ``space`` by the user's ``{name: (lo, hi)}`` (checked)."""
    names, logs, kind = space.names, space.log_scale, space.kind
    for key, b in dict(bounds).items():
        if key not in names:
            raise ValueError(f"bounds: unknown search variable {key!r} for kind "
                             f"{kind!r}; valid names are {names}")
        try:
            lo, hi = (float(v) for v in b)
        except (TypeError, ValueError):
            raise ValueError(f"bounds[{key!r}] = {b!r}: need a pair (lo, hi)") from None
        j = names.index(key)
        if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
            raise ValueError(f"bounds[{key!r}] = {b!r}: need finite lo <= hi")
        if logs[j] and (lo <= 0.0 or hi <= 0.0):
            raise ValueError(f"bounds[{key!r}] = {b!r}: {key} is searched on a log "
                             "scale and must be > 0")
        space.bounds[j] = (lo, hi)


def search_vector(model, space) -> np.ndarray:
    """Search vector of a FONBW or NBW `model` in a FONBW/NBW `space`
    (reparametrized: ρ, σ^(1/n) ρ, n, and λ1, λ2 for FONBW; an NBW has λ = 1)."""
    p = model.params
    if space.kind not in ("fonbw", "nbw") or space.names[1] != "sigma_rho":
        raise ValueError(f"a model start needs the reparametrized fonbw or nbw search, not {space.kind!r}")
    rho, sigma, n = float(p["rho"]), float(p["sigma"]), float(p["n"])
    if sigma <= 0:
        raise ValueError("the start model's sigma must be > 0")
    x = [rho, sigma ** (1.0 / n) * rho, n]
    if len(space.names) == 5:
        x += [float(getattr(model, "lam1", 1.0)), float(getattr(model, "lam2", 1.0))]
    return np.array(x)
