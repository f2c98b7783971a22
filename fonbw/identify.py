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

Search variables and their default ranges
-----------------------------------------
:mod:`fonbw.searchspace`: the reparametrization (ρ, σ^(1/n) ρ, n, λ1, λ2
for FONBW), the search ranges, and the ranges the records can identify.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from fonbw.de import _Space, jde_minimize
from fonbw.fitcheck import parameter_check
from fonbw.gnpolish import gauss_newton_polish
from fonbw.identifiable import SIGMA_MAX
from fonbw.objective import (DivergedError, Projected as _Projected, as_records as _as_records, rms_cost,
                             simulate_record)
from fonbw.searchspace import KINDS, SearchSpace, search_space, search_vector

__all__ = ["KINDS", "IdentifyResult", "SearchSpace", "search_space", "search_vector", "identify",
           "rms_cost", "simulate_record"]


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
        Overrides of search-variable bounds by name (:mod:`fonbw.searchspace`).
    reparametrize : bool
        Search σ^(1/n)ρ instead of σ (:mod:`fonbw.searchspace`).
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
        raise DivergedError(f"identify({kind!r}): every candidate diverged "
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
