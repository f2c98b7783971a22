"""Tests of fonbw.de.jde_minimize (jDE, Brest et al. 2006)."""
import numpy as np
import pytest
from scipy.optimize import differential_evolution, rosen

from fonbw.de import DEResult, jde_minimize


def sphere_pop(X):
    return np.sum((X - 0.3) ** 2, axis=1)


def rosen_pop(X):
    return np.sum(100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2,
                  axis=1)


def rastrigin_pop(X):
    return 10.0 * X.shape[1] + np.sum(X ** 2 - 10.0 * np.cos(2 * np.pi * X), axis=1)


def test_sphere_minimum_and_result_fields():
    r = jde_minimize(sphere_pop, [(-5, 5)] * 4, max_evals=4000, seed=0)
    assert isinstance(r, DEResult)
    np.testing.assert_allclose(r.x, 0.3, atol=1e-6)
    assert r.fun < 1e-12
    assert r.nfev <= 4000
    # history: one entry per generation plus the initial population, non-increasing
    assert len(r.history) == r.nit + 1
    assert np.all(np.diff(r.history) <= 0)
    assert r.fun <= r.history[-1]


def test_rosenbrock_5d_reaches_global_minimum():
    r = jde_minimize(rosen_pop, [(-5, 5)] * 5, max_evals=20000, seed=1)
    np.testing.assert_allclose(r.x, np.ones(5), atol=1e-4)
    assert r.fun < 1e-8
    assert r.nfev <= 20000


def test_rastrigin_5d_global_not_local():
    # Rastrigin has ~10^5 local minima in this box; the global one is 0 at 0.
    r = jde_minimize(rastrigin_pop, [(-5.12, 5.12)] * 5, max_evals=25000, seed=2)
    assert r.fun < 1e-8
    np.testing.assert_allclose(r.x, 0.0, atol=1e-5)


def test_reproducible_for_fixed_seed_and_differs_across_seeds():
    kw = dict(max_evals=3000, polish=False)
    a = jde_minimize(rastrigin_pop, [(-5.12, 5.12)] * 3, seed=123, **kw)
    b = jde_minimize(rastrigin_pop, [(-5.12, 5.12)] * 3, seed=123, **kw)
    c = jde_minimize(rastrigin_pop, [(-5.12, 5.12)] * 3, seed=124, **kw)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.history, b.history)
    assert a.nfev == b.nfev
    assert not np.array_equal(a.history, c.history)
    # A numpy Generator is accepted as seed as well.
    g1 = jde_minimize(sphere_pop, [(-1, 1)] * 2, seed=np.random.default_rng(5), **kw)
    g2 = jde_minimize(sphere_pop, [(-1, 1)] * 2, seed=np.random.default_rng(5), **kw)
    np.testing.assert_array_equal(g1.history, g2.history)


def test_nan_and_inf_regions_are_survived():
    # Half of the box "diverges" (NaN), a quarter returns inf; minimum at (0.5, 0.5).
    calls = []

    def f(X):
        calls.append(X.shape)
        c = np.sum((X - 0.5) ** 2, axis=1)
        c[X[:, 0] < 0.0] = np.nan
        c[(X[:, 0] >= 0.0) & (X[:, 1] < -1.0)] = np.inf
        return c

    r = jde_minimize(f, [(-2, 2), (-2, 2)], max_evals=3000, seed=3)
    np.testing.assert_allclose(r.x, [0.5, 0.5], atol=1e-6)
    assert np.isfinite(r.fun)
    assert all(s[1] == 2 for s in calls)


def test_all_nan_objective_returns_failure_not_exception():
    r = jde_minimize(lambda X: np.full(X.shape[0], np.nan), [(0, 1)] * 2,
                     max_evals=200, seed=0)
    assert not r.success
    assert r.fun == np.inf
    assert "no finite cost" in r.message


def test_log_scale_finds_minimum_at_3p7e_minus_6():
    # Cost in natural units: a narrow basin at 3.7e-6 in a box spanning 5 decades.
    # Linear search of [1e-8, 1e-3] would put only 0.4 % of samples below 4e-6.
    x_true = 3.7e-6

    def f(X):
        return ((X[:, 0] - x_true) / x_true) ** 2 + (X[:, 1] - 2.0) ** 2

    r = jde_minimize(f, [(1e-8, 1e-3), (-5, 5)], log_scale=[True, False],
                     max_evals=3000, seed=4)
    assert abs(r.x[0] - x_true) / x_true < 1e-3
    assert abs(r.x[1] - 2.0) < 1e-3


def test_log_scale_negative_only_range():
    x_true = -3.3e4

    def f(X):
        return np.log10(X[:, 0] / x_true) ** 2

    r = jde_minimize(f, [(-1e5, -1e2)], log_scale=[True], max_evals=1000, seed=5)
    assert r.x[0] < 0
    assert abs(r.x[0] / x_true - 1.0) < 1e-4


def test_candidates_stay_inside_bounds_and_fixed_parameter():
    seen = []

    def f(X):
        seen.append(X.copy())
        return np.sum(X ** 2, axis=1)

    bounds = [(1e-3, 1e2), (-3, -1), (0.7, 0.7)]
    jde_minimize(f, bounds, log_scale=[True, False, False], max_evals=2000, seed=6)
    allx = np.vstack(seen)
    lo = np.array([b[0] for b in bounds])
    hi = np.array([b[1] for b in bounds])
    assert np.all(allx >= lo) and np.all(allx <= hi)
    assert np.all(allx[:, 2] == 0.7)
    # Minimum at the lower corner (1e-3, -1): the bounce-back must reach it.
    assert allx[:, 0].min() < 1.01e-3


def test_x0_is_in_initial_population():
    first = []

    def f(X):
        if not first:
            first.append(X.copy())
        return np.sum(X ** 2, axis=1)

    jde_minimize(f, [(-1, 1)] * 3, x0=[0.25, -0.5, 0.125], max_evals=200, seed=0,
                 polish=False)
    np.testing.assert_allclose(first[0][0], [0.25, -0.5, 0.125], rtol=1e-14)


def test_budget_is_a_hard_cap_including_polish():
    n = [0]

    def f(X):
        n[0] += X.shape[0]
        return rosen_pop(X)

    r = jde_minimize(f, [(-5, 5)] * 4, max_evals=1234, seed=7, popsize=30)
    assert r.nfev == n[0]
    assert r.nfev <= 1234
    assert r.nfev >= 1234 - 2 * (2 * 4 + 1)  # budget used (polish stops on budget)


def test_stagnation_stop_is_early_and_successful():
    # Constant cost: no improvement at all, must stop after `patience` generations.
    r = jde_minimize(lambda X: np.ones(X.shape[0]), [(0, 1)] * 2, popsize=10,
                     patience=7, max_evals=10000, seed=0, polish=False)
    assert r.success
    assert r.nit == 7
    assert r.nfev == 10 * 8
    assert "stagnation" in r.message


def test_keyboard_interrupt_returns_best_so_far():
    count = [0]

    def f(X):
        count[0] += 1
        if count[0] == 5:
            raise KeyboardInterrupt
        return sphere_pop(X)

    r = jde_minimize(f, [(-5, 5)] * 3, popsize=20, max_evals=10000, seed=0)
    assert not r.success
    assert r.message == "interrupted"
    assert r.nfev == 4 * 20
    assert np.isfinite(r.fun)
    assert r.fun == r.history[-1]
    np.testing.assert_allclose(sphere_pop(r.x[None, :])[0], r.fun, rtol=1e-12)


def test_callback_can_stop():
    seen = []

    def cb(x, fun, nit):
        seen.append((fun, nit))
        return nit >= 3

    r = jde_minimize(sphere_pop, [(-5, 5)] * 2, popsize=10, callback=cb,
                     max_evals=5000, seed=0, polish=False)
    assert r.nit == 3 and not r.success
    assert r.message == "stopped by callback"
    assert [s[1] for s in seen] == [1, 2, 3]


def test_nelder_mead_polish_improves_over_no_polish():
    kw = dict(max_evals=1500, seed=8)
    raw = jde_minimize(rosen_pop, [(-2, 2)] * 3, polish=False, **kw)
    nm = jde_minimize(rosen_pop, [(-2, 2)] * 3, polish="Nelder-Mead", **kw)
    lb = jde_minimize(rosen_pop, [(-2, 2)] * 3, polish=True, **kw)
    assert nm.fun < raw.fun and lb.fun < raw.fun
    assert nm.nfev <= 1500 and lb.nfev <= 1500


@pytest.mark.parametrize("bad, match", [
    (dict(bounds=[(1, 0)]), "lower bound exceeds"),
    (dict(bounds=[(-1, 1)], log_scale=[True]), "contains or touches zero"),
    (dict(bounds=[(0, 1)], log_scale=[True, False]), "log_scale has 2"),
    (dict(bounds=[(0, 1)], popsize=3), "popsize"),
    (dict(bounds=[(0, 1)], max_evals=10, popsize=20), "at least one population"),
    (dict(bounds=[(0, np.inf)]), "finite"),
    (dict(bounds=[(0, 1)], x0=[0.1, 0.2]), "x0"),
    (dict(bounds=[(0, 1)], polish="BFGS"), "polish"),
    (dict(bounds=[(0, 1)], polish_rtol=0.0), "polish_rtol"),
    (dict(bounds=[(0, 1)], polish="Nelder-Mead", polish_rtol=1e-9), "L-BFGS-B polish only"),
])
def test_validation_errors(bad, match):
    kw = dict(bad)
    b = kw.pop("bounds")
    with pytest.raises(ValueError, match=match):
        jde_minimize(sphere_pop, b, **kw)


def test_wrong_cost_shape_is_refused():
    with pytest.raises(ValueError, match="returned 1 costs"):
        jde_minimize(lambda X: np.zeros(1), [(0, 1)] * 2, max_evals=100)


def test_against_scipy_differential_evolution_same_budget(capsys):
    """Print jDE vs scipy DE final costs on the same evaluation budget.

    Not a race (nothing timed); asserted only that jDE is not worse than
    10x scipy's result on Rosenbrock-5 and finds Rastrigin's global minimum.
    """
    budget = 15000
    rows = []
    for name, fpop, fone, box in [
        ("rosenbrock-5", rosen_pop, rosen, [(-5, 5)] * 5),
        ("rastrigin-5", rastrigin_pop, lambda x: rastrigin_pop(x[None, :])[0],
         [(-5.12, 5.12)] * 5),
    ]:
        j = jde_minimize(fpop, box, max_evals=budget, seed=11)
        # scipy: popsize multiplier 15 -> 75 individuals; generations to fit budget
        # (scipy's polish runs on top of that, counted in its nfev).
        s = differential_evolution(fone, box, seed=11, popsize=15,
                                   maxiter=budget // 75 - 1, tol=0, polish=True)
        rows.append((name, j.fun, j.nfev, s.fun, s.nfev))
    with capsys.disabled():
        print("\n  problem        jDE fun    jDE nfev   scipy fun  scipy nfev")
        for r in rows:
            print(f"  {r[0]:<13s} {r[1]:10.3g} {r[2]:9d} {r[3]:10.3g} {r[4]:10d}")
    ros, ras = rows
    assert ros[1] <= max(10 * ros[3], 1e-10)
    assert ras[1] < 1e-8


def test_progress_bar_counts_evaluations(capsys):
    r = jde_minimize(sphere_pop, [(-1, 1)] * 2, popsize=10, max_evals=300, seed=0,
                     progress=True)
    err = capsys.readouterr().err
    assert "jDE" in err and f"{r.nfev}/300" in err


def test_callable_polish_is_counted_and_capped():
    calls = []

    def polish(z0, f0, budget):
        calls.append(budget)
        return np.full_like(z0, 0.5), 0.0, min(7, budget)   # the unit-cube centre, 7 evaluations

    rows = []

    def f(X):
        rows.append(X.shape[0])
        return np.sum((X - 0.3) ** 2, axis=1) + 1.0

    res = jde_minimize(f, [(-1.0, 2.0)] * 3, popsize=10, max_evals=200, seed=0, polish=polish,
                       polish_maxfev=40)
    # DE stops on its budget (160), the polish leaves 33 of 40, DE resumes with half
    # of them and the last polish gets the rest; every evaluation counted
    assert calls[0] == 40 and len(calls) >= 2
    assert res.nfev == sum(rows) + sum(min(7, b) for b in calls) <= 200
    assert sum(rows) > 160 and res.fun == 0.0
    np.testing.assert_allclose(res.x, 0.5)          # centre of (-1, 2)


def test_polish_rtol_ends_a_flat_polish_and_leaves_the_rest_unspent():
    # a shifted sphere: the minimum 1e-3 is reached in a few L-BFGS-B steps
    def f(X):
        return 1e-3 + np.sum((X - 0.3) ** 2, axis=1)

    kw = dict(popsize=4, max_evals=194, polish_maxfev=190, x0=[0.35] * 6, seed=0)
    full = jde_minimize(f, [(0.0, 1.0)] * 6, **kw)
    flat = jde_minimize(f, [(0.0, 1.0)] * 6, polish_rtol=1e-9, **kw)
    assert flat.fun - 1e-3 < 1e-12 and full.fun - 1e-3 < 1e-12
    # without the tolerance the evaluations left go back to DE and a second polish
    assert full.nfev > 150 and flat.nfev < 60


def test_polish_rtol_follows_the_same_path_until_it_stops():
    # an ill-conditioned ellipsoid is not flat within three gradient steps:
    # the run must be the one without the tolerance, bit for bit (a cost
    # rescaled to make ftol relative would not be: L-BFGS-B's first step
    # depends on the cost's scale)
    def ell(X):
        return 1e-3 + 1e-2 * np.sum(np.logspace(0, 3, X.shape[1]) * (X - 0.3) ** 2, axis=1)

    kw = dict(popsize=4, max_evals=43, polish_maxfev=39, x0=[0.35] * 6, seed=3)
    a = jde_minimize(ell, [(0.0, 1.0)] * 6, **kw)
    b = jde_minimize(ell, [(0.0, 1.0)] * 6, polish_rtol=1e-9, **kw)
    assert a.fun < ell(np.array([[0.35] * 6]))[0]
    assert a.x.tobytes() == b.x.tobytes() and a.fun == b.fun and a.nfev == b.nfev
