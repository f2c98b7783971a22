"""Model identification: minimize the RMS error of eq. (18) with jDE.

``identify(records, kind)`` fits a hysteresis model (FONBW, asymmetric NBW,
CBW or the model of Zhu et al., eq. (20)) to measured records by minimizing

    J(Θ) = sqrt( (1/M) Σ_i (H_i − H_i^model)^2 )                          (18)

over all M samples of all records (each record simulated from rest on its own,
the squared errors pooled), with the self-adaptive differential evolution of
:mod:`fonbw.de` (the paper's Sec. IV-B, Fig. 7). A whole DE generation is
simulated in one call of :func:`fonbw.hysteresis.simulate_population`, which is
compiled and parallel over candidates; ``workers`` sets its thread count.

How the budget is spent
-----------------------
``max_evals`` caps the evaluations (each simulates every record once). By
default 30 % is set aside for the polish and DE gets the rest, with a
population sized for about :data:`GENERATIONS` (40) generations (not fewer
than 4 d individuals, not more than jDE's 10 d). The polish is Gauss-Newton
on the projected residuals (:mod:`fonbw.gnpolish`): from DE's basin it reaches
the noise floor in a few tens of evaluations, and what it leaves goes back to
DE, then to a last polish (:meth:`fonbw.de.JDESolver.resume`). Measured on the
eq.-(19) FONBW record at 5 kHz over 30 s (1.5e5 samples, 1500 evaluations):
with 10 d = 50 individuals (21 generations) and an L-BFGS-B polish, DE settled
in wrong basins (RMS 0.053, 0.039 and 0.076 µm against the noise floor
0.020 µm; seed 1 with σ → 0 and n at its bound 4) on seeds 1-3. Now seeds 1-5
all end at the truth's RMS, and scipy's DE on the same objective and budget
at 0.022-0.030 µm (BENCHMARKS.md, Identification speed).

Linear parameters are solved, not searched (variable projection)
----------------------------------------------------------------
Every model here is *linear* in some of its parameters once the others are
fixed. FONBW/NBW: H = Σ ku_i u^i + k_h ħ(ρ, σ, n, λ1, λ2) (eqs. 9-10), and ħ
does not depend on ku_i or k_h. So DE searches only the nonlinear parameters;
for each candidate ħ is simulated once (k_h = 1, ku = 0) and (ku_1..ku_N, k_h)
follow from linear least squares on all records pooled. This is the exact
minimum of eq. (18) over the linear parameters (Golub & Pereyra's variable
projection), so the search dimension drops from 9 to 5 for FONBW and the
minimized value is still eq. (18). CBW: H = ka u + kb D h (ka, k_h = kb D
linear). Zhu (eq. 20): x = x0 + G·x̃ where x̃ is the output with k0 = 1,
A = 1, x0 = 0; G scales the state h (h = G w), which maps back to
A = G, k1 = G k1', δ = G δ', β = β'/|G|^(n−1), γ = γ' G/|G|^n.

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

import time
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from fonbw.de import _Space, jde_minimize
from fonbw.fitcheck import parameter_check
from fonbw.gnpolish import gauss_newton_polish
from fonbw.identifiable import LAM_MIN, SIGMA_MAX, lambda_floor, rate_span
from fonbw.objective import Projected as _Projected, as_records as _as_records, rms_cost, simulate_record

__all__ = ["KINDS", "IdentifyResult", "SearchSpace", "search_space", "search_vector", "identify",
           "rms_cost", "simulate_record"]

KINDS = ("fonbw", "nbw", "cbw", "zhu")

#: Generations the default population size aims DE's share of the budget at.
GENERATIONS = 40


@dataclass
class IdentifyResult:
    """Outcome of :func:`identify`.

    Attributes
    ----------
    model : object
        The identified model (``fonbw.hysteresis.model_from_vector``).
    kind : str
        Model kind.
    params : dict
        Natural model parameters by name (order of
        ``fonbw.hysteresis.param_names``).
    rms : float
        Eq. (18) of ``model`` over all records [µm], recomputed by simulating
        the returned parameters.
    nfev : int
        Candidate evaluations (each one simulates every record once).
    wall_time : float
        Wall-clock time of the optimization [s].
    history : ndarray
        Best RMS [µm] after the initial population and each DE generation.
    success, message
        From the optimizer (:class:`fonbw.de.DEResult`).
    search : dict
        Search variables: ``names``, ``bounds``, ``log_scale`` and ``x``
        (best point).
    burn_in : list of int
        Samples left out at the start of each record (0: it starts at rest).
    offsets : list of float
        Sensor offset fitted for each record with a burn-in [µm] (0 otherwise);
        the model's output plus it matches that record.
    warnings : list of str
        Search variables at a bound of the search or poorly determined.
    intervals : dict
        ``{search variable: (lo, hi)}``, approximate 95 % intervals from the
        Gauss-Newton curvature of eq. (18) at the optimum.
    """

    model: object
    kind: str
    params: dict
    rms: float
    nfev: int
    wall_time: float
    history: np.ndarray = field(repr=False)
    success: bool = True
    message: str = ""
    search: dict = field(default_factory=dict, repr=False)
    burn_in: list = field(default_factory=list, repr=False)
    offsets: list = field(default_factory=list, repr=False)
    warnings: list = field(default_factory=list, repr=False)
    invertibility: dict | None = None
    intervals: dict = field(default_factory=dict, repr=False)


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


# --------------------------------------------------------------------------
# Search spaces
# --------------------------------------------------------------------------

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
        # h = G w rescales the BW state: see the module docstring.
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


# --------------------------------------------------------------------------
# Driver
# --------------------------------------------------------------------------

def identify(records, kind: str = "fonbw", *, seed=None, max_evals: int = 5000,
             workers: int | None = None, progress: bool = False,
             memory: str = "fast", N: int = 3, bounds: Mapping | None = None,
             reparametrize: bool = True, popsize: int | None = None,
             polish: bool | str = True, polish_maxfev: int | None = None,
             callback=None, burn_in=None, for_compensation=None, x0=None) -> IdentifyResult:
    """Identify a hysteresis model by minimizing eq. (18) with jDE.

    Parameters
    ----------
    records : Record or list of Record
        Objects with ``u`` [V], ``y`` [µm] arrays and ``dt`` [s] (e.g. from
        :func:`fonbw.io.read_record`). Every record starts from rest.
    kind : {"fonbw", "nbw", "cbw", "zhu"}
        FONBW (eqs. 9-11), asymmetric NBW (eqs. 8-10, i.e. FONBW with
        λ1 = λ2 = 1), CBW (eqs. 1-2), Zhu et al. (eq. 20).
    seed : int, optional
        Seed of the optimizer; same seed and data give the same model.
    max_evals : int
        Candidate evaluations in all, polish included; each simulates every
        record once. Only nonlinear parameters are searched (module
        docstring), so a few thousand usually suffice.
    workers : int, optional
        Threads of the compiled population simulator (numba); default: numba's
        current setting. Restored afterwards.
    progress : bool
        Show a progress bar (evaluations).
    memory : str
        GL memory engine used during identification (see fonbw.fractional).
    N : int
        Order of g(u) (eq. 10) for "fonbw" and "nbw".
    bounds : mapping, optional
        Overrides of search-variable bounds by name (module docstring).
    reparametrize : bool
        Search σ^(1/n)ρ instead of σ (module docstring).
    burn_in : list of int, optional
        Leading samples of each record left out (weight 0): those of a record
        not at rest depend on its unknown initial state. Such a record is run
        through a lead-in from rest and gets its own sensor offset, solved
        with the linear parameters (``IdentifyResult.offsets``).
    for_compensation : float, optional
        Step dt [s] the model will be inverted at by the causal compensator:
        the linear parameters are then solved under the constraint that the
        one-step slope u_k ↦ H_k at that step stays ≥ 0.3 × the data's
        quasi-static gain at every training state, on both branches
        (:mod:`fonbw.invertibility`). ``IdentifyResult.invertibility`` and the
        model's saved JSON then record the slope reached.
    x0 : FONBW or NBW model, or array_like, optional
        A warm start, put into DE's initial population: a model of the kind
        (an NBW for ``kind="fonbw"`` is the FONBW with λ1 = λ2 = 1, so the
        result is never worse than it on these records) or a search vector
        (``IdentifyResult.search["names"]``). Clipped into the bounds.
    popsize, polish, polish_maxfev, callback
        Passed to :func:`fonbw.de.jde_minimize`; ``polish_maxfev`` defaults to
        30 % of ``max_evals`` (local refinement pays off here; what a polish
        that converges early leaves goes back to DE); ``popsize`` defaults to
        jDE's clip(10 d, 20, 100), reduced (not below 4 d) so that DE's share
        of the budget runs about :data:`GENERATIONS` generations, and for
        budgets too small for five generations of it.

    Returns
    -------
    IdentifyResult
    """
    import numba
    from fonbw import hysteresis as hyst
    from fonbw.fractional import ENGINES

    recs = _as_records(records)
    space = search_space(kind, records, N=N, bounds=bounds, reparametrize=reparametrize)
    if memory not in ENGINES:
        raise ValueError(f"memory must be one of {tuple(ENGINES)}, got {memory!r}")
    Nsim = int(N) if kind in ("fonbw", "nbw") else 1
    pnames = list(hyst.param_names(kind, Nsim))
    polish_maxfev, popsize = _de_settings(space, max_evals, polish, polish_maxfev, popsize,
                                          workers, numba.config.NUMBA_NUM_THREADS)
    proj = _Projected(space, recs, pnames, kind, memory, Nsim, _check_burn_in(burn_in, recs))
    if for_compensation is not None:
        from fonbw.invertibility import ConstrainedProjection
        proj = ConstrainedProjection(proj, for_compensation)

    if polish is True and type(proj) is _Projected:
        # Gauss-Newton on the residuals: a few Jacobians instead of tens of
        # quasi-Newton steps (fonbw.gnpolish); a constrained solve keeps L-BFGS-B.
        polish = gauss_newton_polish(proj, _Space(space.bounds, space.log_scale))
    if x0 is not None:
        x0 = search_vector(x0, space) if hasattr(x0, "params") else np.asarray(x0, dtype=float)
        x0 = np.clip(x0, [b[0] for b in space.bounds], [b[1] for b in space.bounds])
    res, wall = _search(proj, workers, popsize=popsize, max_evals=int(max_evals), seed=seed, polish=polish,
                        polish_maxfev=polish_maxfev, progress=progress, callback=callback, x0=x0)
    from fonbw.invertibility import annotate_result
    result = _identify_result(proj, res, wall, records, check=res.message != "interrupted")  # else no optimum
    return annotate_result(result, recs, for_compensation)


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


def _search(proj, workers, **options):
    """(DEResult, wall time [s]) of jDE on the projected objective, with numba's
    thread count set to `workers` for the run and restored after it."""
    import numba

    space = getattr(proj, "proj", proj).space
    old_threads = numba.get_num_threads()
    if workers is not None:
        numba.set_num_threads(int(workers))
    t0 = time.perf_counter()
    try:
        res = jde_minimize(proj, space.bounds, log_scale=space.log_scale, **options)
    finally:
        numba.set_num_threads(old_threads)
    return res, time.perf_counter() - t0


def _check_burn_in(burn_in, recs):
    """The per-record burn-ins as ints, checked against the record lengths."""
    if burn_in is None:
        return None
    b = list(burn_in)
    if len(b) != len(recs):
        raise ValueError(f"burn_in: {len(b)} values for {len(recs)} records")
    for i, (v, (u, _, _)) in enumerate(zip(b, recs)):
        if isinstance(v, bool) or int(v) != v or not 0 <= v <= u.size - 8:
            raise ValueError(f"burn_in[{i}] = {v!r}: need an integer in [0, {u.size - 8}] (samples)")
    return [int(v) for v in b]


def _de_settings(space, max_evals, polish, polish_maxfev, popsize, workers, max_threads):
    """Checked budget options and identify's defaults of (polish_maxfev, popsize)."""
    if int(max_evals) != max_evals or max_evals < 1:
        raise ValueError(f"max_evals must be a positive integer, got {max_evals!r}")
    if polish_maxfev is None and polish:
        # 30 %: on the eq.-(19) FONBW test problem the L-BFGS-B polish closes
        # the last decade of RMS far cheaper than DE.
        polish_maxfev = (3 * int(max_evals)) // 10
    if workers is not None and (isinstance(workers, bool) or int(workers) != workers
                                or not 1 <= workers <= max_threads):
        raise ValueError(f"workers must be an integer in [1, "
                         f"{max_threads}], got {workers!r}")
    if popsize is None:
        # jDE's default population, shrunk (to no fewer than 4 d) so that DE
        # runs about GENERATIONS generations: with 10 d individuals and ~1000
        # evaluations for DE it had 21 and settled in a wrong basin on 3 seeds
        # of 5 of the 5-kHz eq.-(19) record (BENCHMARKS.md). A tiny budget is a
        # user's explicit choice: about five generations at least.
        d = len(space.names)
        de_budget = int(max_evals) - (int(polish_maxfev) if polish else 0)
        full = int(np.clip(10 * d, 20, 100))
        popsize = int(min(full, max(4 * d, de_budget // GENERATIONS), max(4, de_budget // 5)))
    return polish_maxfev, popsize


def _identify_result(proj, res, wall, records, check=True):
    """The :class:`IdentifyResult` of the best search vector ``res.x`` (a
    :class:`fonbw.de.DEResult`): linear parameters solved once more, the model
    built and eq. (18) recomputed by simulating it."""
    from fonbw import hysteresis as hyst

    kind, space, memory, Nsim = proj.kind, proj.space, proj.memory, proj.N
    if not np.isfinite(res.fun) and (res.message or "").startswith("interrupted"):
        # Ctrl-C before any candidate was simulated (e.g. while compiling the
        # kernels): there is no best-so-far model, so the interrupt goes on.
        raise KeyboardInterrupt("interrupted before the search had a best candidate")
    if not np.isfinite(res.fun):
        raise RuntimeError(f"identify({kind!r}): every candidate diverged "
                           f"({res.nfev} evaluations); check the data and bounds")
    x = space.project(res.x)[0] if space.project is not None else res.x
    _, G, c = proj.solve(x[None, :])
    params = space.final_params(x, c[0], float(G[0]))
    theta = np.array([params[k] for k in proj.pnames], dtype=float)
    model = hyst.model_from_vector(kind, theta, N=Nsim, memory=memory)
    base = getattr(proj, "proj", proj)  # the plain projection under a constrained one
    offsets = [0.0] * len(base.recs)
    for j, i in enumerate(base.offset_records):
        offsets[i] = float(c[0][base.q + j])
    if any(base.burn_in):
        rms = _rms_after_burn_in(model, base, offsets)
    else:
        rms = float(rms_cost(kind, theta[None, :], records, memory=memory, N=Nsim)[0])
    intervals, warns = parameter_check(base, x) if check else ({}, [])
    if check and params.get("sigma", 0.0) >= SIGMA_MAX * (1 - 1e-9) and space.project is not None:
        warns.append(f"sigma = {params['sigma']:.4g} is at its cap {SIGMA_MAX:g}: the data push it "
                     "higher, where it no longer changes the loop measurably (rho was raised to keep it there)")
    return IdentifyResult(model=model, kind=kind, params=params, rms=rms,
                          nfev=res.nfev, wall_time=wall, history=res.history,
                          success=res.success, message=res.message,
                          search={"names": space.names, "bounds": space.bounds,
                                  "log_scale": space.log_scale, "x": x},
                          burn_in=list(base.burn_in), offsets=offsets, warnings=warns,
                          intervals=intervals)


def _rms_after_burn_in(model, proj, offsets) -> float:
    """Eq. (18) over the samples after each record's burn-in, each record's fitted
    offset [µm] added to the model output (simulated from rest on the whole record)."""
    sse, M = 0.0, 0
    for (u, y, dt), b, off in zip(proj.recs, proj.burn_in, offsets):
        e = (simulate_record(model, u, dt, b) + off - y)[b:]
        sse += float(e @ e)
        M += e.size
    return float(np.sqrt(sse / M))
