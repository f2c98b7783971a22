"""The joint refit's design matrices and least squares (fonbw.gap.fitter):
checked against matrices built here from the model's own simulation, and
against themselves once the simulations come from the fitter's cache."""
import numpy as np
import pytest
import scipy.linalg
from scipy.signal import lfilter

from fonbw import hysteresis as hyst
from fonbw.gap import effects as fx
from fonbw.gap.blas import _libs, single_thread
from fonbw.gap.fitter import Fitter
from fonbw.identify import search_space
from fonbw.io import Record

DT = 2e-4


def _records():
    t = np.arange(2400) * DT
    u1 = 60.0 + 50.0 * np.sin(2 * np.pi * 3.0 * t)
    u2 = np.where(t < 0.1, 20.0, 90.0) + 5.0 * np.sin(2 * np.pi * 11.0 * t[: t.size])
    y1 = 0.2 * u1 + 0.01 * np.sin(2 * np.pi * 7.0 * t)
    y2 = 0.2 * u2 - 0.02 * np.cos(2 * np.pi * 5.0 * t)
    return [Record.from_arrays(u=u1, y=y1, dt=DT), Record.from_arrays(u=u2[:1800], y=y2[:1800], dt=DT)]


def _setup(**kw):
    recs = _records()
    space = search_space("fonbw", recs, N=3)
    x = np.array([np.sqrt(lo * hi) for lo, hi in space.bounds])
    x[3:] = [0.6, 0.3]
    return recs, space, x, Fitter(recs, space, N=3, **kw)


def test_design_equals_columns_built_from_the_model():
    recs, space, x, f = _setup()
    creep, drift = fx.Creep(DT, 1.0), fx.Drift()
    yrefs = [r.y.copy() for r in recs]
    X = np.vstack([x, x * [1.01, 1, 1, 1, 1]])
    A = f.design(recs, X, [creep, drift], [np.zeros((2, 0))] * 2, yrefs)
    U = max(float(np.max(np.abs(r.u))) for r in recs)
    theta = f.core.theta(X)
    for p in range(2):
        model = hyst.model_from_vector("fonbw", theta[p], 3, "fast")
        cols = []
        for r, yr in zip(recs, yrefs):
            h = model.simulate(r.u, DT)
            lp = [lfilter([1 - a], [1, -a], yr, zi=[a * yr[0]])[0] - yr
                  for a in np.exp(-DT / np.array(creep.taus))]
            law = sum(lfilter([1 - a], [1, -a], yr, zi=[a * yr[0]])[0] - yr
                      for a in np.exp(-DT / np.array(creep.log_taus))) / 2
            s = np.arange(len(r.u)) * DT / 10.0
            cols.append(np.column_stack([(r.u / U) ** 1, (r.u / U) ** 2, (r.u / U) ** 3, h] + lp + [law, s, s * s]))
        ref = np.vstack(cols)
        assert len(creep.log_taus) == 5 and creep.lin_names[-1] == "gamma"
        assert A[p].shape == ref.shape == (4200, 4 + len(creep.taus) + 1 + 2)
        np.testing.assert_allclose(A[p], ref, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("names", [("delay",), ("dynamics", "creep"), ("saturation",), ("amplifier", "drift")])
def test_cached_simulations_give_the_same_matrices_bit_for_bit(names):
    recs, space, x, f = _setup(skip=[40, 0])
    ys = np.concatenate([r.y for r in recs])
    lib = {e.name: e for e in fx.library(DT, 110.0, 0.5, fx.EFFECTS, y_range=(float(ys.min()), float(ys.max())))}
    eff = [lib[k] for k in names]
    TH = [np.repeat(e.grid[:1], 3, axis=0) if e.names else np.zeros((3, 0)) for e in eff]
    X = np.vstack([x, x, x * [1, 1.02, 1, 1, 1]])
    yrefs = [r.y.copy() for r in recs]
    first = f.design(recs, X, eff, TH, yrefs)
    assert f._sims  # the simulations are kept
    again = f.design(recs, X, eff, TH, yrefs)
    fresh = Fitter(recs, space, N=3, skip=[40, 0])
    fresh.cache_bytes = 0  # keeps only the rows of the running call
    cold = fresh.design(recs, X, eff, TH, yrefs)
    assert len(fresh._sims) <= 2  # two distinct rows (X and input-side parameters)
    for a, b, c in zip(first, again, cold):
        assert np.array_equal(a, b) and np.array_equal(a, c)
        # the memory order sets the order of the sums in the least squares
        assert a.flags.c_contiguous == b.flags.c_contiguous == c.flags.c_contiguous
    np.testing.assert_array_equal(f.cost(X, eff, TH, yrefs), fresh.cost(X, eff, TH, yrefs))


def test_solve_against_lstsq_and_non_finite_columns():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((3000, 5)) * [1.0, 10.0, 0.1, 3.0, 1e3]
    y = A @ [1.0, -2.0, 3.0, 0.5, 1e-3] + 0.01 * rng.standard_normal(3000)
    for M in (A, np.asfortranarray(A)):
        b, r = Fitter.solve(M, y)
        ref = np.linalg.lstsq(A, y, rcond=None)[0]
        np.testing.assert_allclose(b, ref, rtol=1e-9)
        # normal equations: the residual to ~1e-11 of |y| ~ 10 µm
        np.testing.assert_allclose(r, y - A @ ref, rtol=0, atol=1e-9)
    # a column the samples do not excite gets 0
    Z = np.column_stack([A, np.zeros(3000)])
    b, _ = Fitter.solve(Z, y)
    assert b[-1] == 0.0 and np.allclose(b[:-1], ref, rtol=1e-9)
    for bad in (np.nan, np.inf, -np.inf):
        B = A.copy()
        B[1234, 2] = bad
        assert Fitter.solve(B, y) == (None, None)
    # finite entries whose squares overflow are still finite columns
    H = A.copy()
    H[:, 4] *= 1e160
    b, _ = Fitter.solve(H, y)
    assert b is not None


def test_single_thread_keeps_the_numbers_and_restores_the_thread_counts():
    libs = _libs()
    if not libs:
        pytest.skip("no OpenBLAS found in this process")
    before = [get() for get, _ in libs]
    M = np.array([[0.0, 1.0, 0.0, 0.0], [-4e7, -2e3, 1.0, 0.0], [0, 0, 0, 1.0], [0, 0, 0, 0]]) * DT
    outside = scipy.linalg.expm(M)
    with single_thread():
        assert all(get() == 1 for get, _ in libs)
        inside = scipy.linalg.expm(M)
    assert [get() for get, _ in libs] == before
    assert np.array_equal(inside, outside)
    # the exponential of a nilpotent block, written out: exp([[0, a], [0, 0]]) = [[1, a], [0, 1]]
    N2 = np.array([[0.0, 3.0], [0.0, 0.0]])
    with single_thread():
        np.testing.assert_allclose(scipy.linalg.expm(N2), [[1.0, 3.0], [0.0, 1.0]], rtol=1e-14, atol=1e-15)


def test_a_fit_without_coefficients_predicts_nan_not_a_crash():
    # a refit whose training design was not finite has beta None and rms inf;
    # a blind-harness scenario (seed 49007) crashed in the form's check on it
    recs, space, x, f = _setup()
    creep = fx.Creep(DT, 1.0)
    fit = {"x": x, "th": [np.zeros(0)], "beta": None, "rms": float("inf")}
    out = f.predict(recs, fit, [creep], [r.y for r in recs])
    assert [len(o) for o in out] == [len(r.u) for r in recs]
    assert all(np.isnan(o).all() for o in out)
    # with coefficients the same call gives finite outputs
    good = f.refit([creep], x, [np.zeros(0)], [r.y for r in recs], evals=0)
    assert all(np.isfinite(o).all() for o in f.predict(recs, good, [creep], [r.y for r in recs]))
