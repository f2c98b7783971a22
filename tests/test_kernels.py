"""Memory kernels against independent references: the blocked-FFT exact run
against the direct GL sum and a triangular Toeplitz solve, the SIMD sums
against numpy, the Newton solver against brentq, the series power against
pow, the fast engine against the exact one over the range of orders, and the
per-step state (predictor, counters) against the batch run bit for bit; the
compiled-code cache key against edits of compiled and other sources."""
import math
from pathlib import Path

import numba as nb
import numpy as np
import pytest
from scipy import linalg, optimize

import fonbw
from fonbw import fractional as fr
from fonbw import hysteresis as H
from fonbw.paper import TABLE1_FONBW
from fonbw.signals import eq19_input

DT = 1e-4
TABLE1 = TABLE1_FONBW


def eq19(n):
    return eq19_input(1.0 / DT, n * DT)[1]


def rel(a, ref):
    return np.max(np.abs(a - ref)) / np.max(np.abs(ref))


@pytest.mark.parametrize("lams", [(0.9557, 0.622), (0.3, 0.9), (1.0, 0.5), (0.7, 1.0)])
def test_blocked_exact_equals_direct_sum(lams):
    u = eq19(20_000)
    assert len(u) >= H.EXACT_BLOCKED_MIN
    m = fonbw.FONBW(**{**TABLE1, "lam1": lams[0], "lam2": lams[1]}, memory="exact")
    yb, hb = m.simulate(u, DT, return_state=True)          # blocked FFT history sums
    yd, hd = H._simulate(m, u, DT, return_state=True)      # direct full sums
    assert not np.array_equal(yb, yd)  # really two different summations
    assert rel(yb, yd) <= 1e-12
    assert rel(hb, hd) <= 5e-12


def test_short_exact_runs_keep_the_direct_sum_bit_for_bit():
    u = eq19(H.EXACT_BLOCKED_MIN - 1)
    m = fonbw.FONBW(**TABLE1, memory="exact")
    assert np.array_equal(m.simulate(u, DT), H._simulate(m, u, DT, False))


def _toeplitz_leaf(w, f, x):
    def leaf(lo, hi, hist):
        for k in range(lo, hi):
            x[k] = f[k] - hist[k] - np.dot(w[k - lo:0:-1][: k - lo], x[lo:k])
        return hi
    return leaf


@pytest.mark.parametrize("leaf_size", [1, 16, 64])
def test_blocked_solve_equals_triangular_toeplitz_solve(leaf_size):
    # x_k + Σ_{j=1..k} w_j x_{k-j} = f_k: a lower-triangular Toeplitz system
    n = 1000
    w = fr.gl_weights(0.6, n)
    f = np.sin(np.arange(n) * 0.01) + np.random.default_rng(1).normal(0, 0.1, n)
    ref = linalg.solve_triangular(linalg.toeplitz(w, np.zeros(n)), f, lower=True)
    x = np.zeros(n)
    assert fr.blocked_solve(w, x, _toeplitz_leaf(w, f, x), leaf_size=leaf_size) == n
    np.testing.assert_allclose(x, ref, rtol=1e-12, atol=1e-12 * np.max(np.abs(ref)))


def test_blocked_solve_stops_where_a_leaf_stops():
    n = 600
    w = fr.gl_weights(0.5, n)
    x = np.zeros(n)
    inner = _toeplitz_leaf(w, np.ones(n), x)

    def leaf(lo, hi, hist):
        done = inner(lo, hi, hist)
        return min(done, 300) if hi > 300 else done

    assert fr.blocked_solve(w, x, leaf, leaf_size=32) == 300


def test_blocked_exact_divergence_is_nan_from_the_same_step():
    # σ < 1/2 with a large ρ: the implicit step loses its bracket
    u = np.concatenate([np.zeros(10), 60 - 60 * np.cos(2 * np.pi * 5 * np.arange(H.EXACT_BLOCKED_MIN) * DT)])
    m = fonbw.FONBW(ku=[0.1], kh=1.0, rho=50.0, sigma=-40.0, n=2.0, lam1=0.8, lam2=0.7, memory="exact")
    yb = m.simulate(u, DT)
    yd = H._simulate(m, u, DT, False)
    assert np.isnan(yd).any()
    k = np.argmax(np.isnan(yd))
    assert np.array_equal(np.isnan(yb), np.isnan(yd))
    assert rel(yb[:k], yd[:k]) <= 1e-12


@nb.njit
def _dot_off(a, ao, b, bo, n):
    return fr._dot_off(a, nb.uint64(ao), b, nb.uint64(bo), nb.uint64(n))


@nb.njit
def _modes(P, oc, orr, S, qz, M, old):
    return fr._modes_push(P, nb.uint64(oc), nb.uint64(orr), S, nb.uint64(qz), nb.uint64(M), old)


def test_simd_sums_equal_numpy():
    rng = np.random.default_rng(2)
    a = rng.normal(size=200)
    b = rng.normal(size=200)
    for n in range(0, 41):
        ao, bo = rng.integers(0, 100, 2)
        ref = np.dot(a[ao:ao + n], b[bo:bo + n])
        assert _dot_off(a, ao, b, bo, n) == pytest.approx(ref, rel=1e-13, abs=1e-13)
    for M in (0, 1, 7, 8, 9, 56, 61):
        P = rng.uniform(0, 1, 300)
        S = rng.normal(size=200)
        S0 = S.copy()
        z = P[150:150 + M] * (S0[20:20 + M] + 0.3)
        got = _modes(P, 10, 150, S, 20, M, 0.3)
        np.testing.assert_array_equal(S[20:20 + M], z)  # elementwise: exactly the same operations
        assert got == pytest.approx(np.dot(P[10:10 + M], z), rel=1e-13, abs=1e-13)
        assert np.array_equal(np.delete(S, np.s_[20:20 + M]), np.delete(S0, np.s_[20:20 + M]))


def _bw_root(b, c1, c2, n):
    b, c1, c2, n = float(b), float(c1), float(c2), float(n)
    F = lambda x: x - b + c1 * abs(x) ** (n - 1) * x + c2 * abs(x) ** n
    lo, hi = min(0.0, b), max(0.0, b)
    for _ in range(60):  # widen as the solver does; no bracket → no root to compare
        if F(lo) <= 0:
            break
        lo = 2 * lo - 1
    for _ in range(60):
        if F(hi) >= 0:
            break
        hi = 2 * hi + 1
    return optimize.brentq(F, lo, hi, xtol=1e-300, rtol=8.9e-16, maxiter=500)


@pytest.mark.parametrize("n", [1.0, 1.5, 2.0, 2.0006, 3.4])
def test_newton_solver_equals_brentq(n):
    rng = np.random.default_rng(int(n * 1000))
    checked = 0
    for _ in range(300):
        b = rng.choice([-1, 1]) * 10 ** rng.uniform(-8, 1)
        c1 = 10 ** rng.uniform(-4, 1)
        c2 = rng.uniform(-1.5, 1.5) * c1  # includes c1 < |c2|
        try:
            ref = _bw_root(b, c1, c2, n)
        except (ValueError, OverflowError):
            continue
        dF = abs(1 + n * abs(ref) ** (n - 1) * (c1 + (c2 if ref >= 0 else -c2)))
        for x0 in (ref * (1 + 1e-7), ref * (1 - 3e-4), -ref, 2 * b, 0.0):
            # round-off bound: a few ulps of the terms of F where the last
            # Newton step started (at most max(|x0|, |b|, |root|) away) over |F'|
            xm = max(abs(ref), abs(x0), abs(b))
            tol = 8 * 2.2e-16 * (xm * (1 + (c1 + abs(c2)) * xm ** (n - 1)) + abs(b)) / dF
            for p0 in (abs(x0) ** (n - 1), -1.0):
                x = H.solve_bw_p(b, c1, c2, n, x0, p0)
                assert abs(x - ref) <= tol, (b, c1, c2, n, x0, p0)
                checked += 1
    assert checked >= 2000
    assert H.solve_bw(0.0, 1.0, 0.5, n, 0.3) == 0.0
    assert math.isnan(H.solve_bw(math.nan, 1.0, 0.5, n, 0.3))


@pytest.mark.parametrize("n", [1.5, 2.0006, 3.4])
def test_predictor_power_stays_within_ulps_of_pow(n):
    # the series updates of |x0|^(n-1) against pow at every step, a bipolar input
    m = fonbw.FONBW(**{**TABLE1, "n": n, "rho": 0.05, "sigma": 0.8, "kh": -2.0})
    s = m.stepper(DT)
    u = 60 * np.sin(2 * np.pi * 7 * np.arange(6000) * DT)
    series = 0
    for v in u:
        s.step(v)
        x0, p0, c = s.S[5], s.S[6], s.S[7]
        series += c > 0
        assert p0 == pytest.approx(abs(x0) ** (n - 1), rel=2e-14, abs=1e-300)
    assert series > 0.5 * len(u)  # the series is the common case


@pytest.mark.parametrize("params", [TABLE1, {**TABLE1, "n": 1.5, "rho": 0.05, "sigma": 0.8, "kh": -2.0}])
def test_stepper_with_peeks_equals_simulate_bit_for_bit(params):
    u = np.concatenate([eq19(3000), 60 * np.sin(2 * np.pi * 9 * np.arange(3000) * DT)])
    m = fonbw.FONBW(**params)
    y = m.simulate(u, DT)
    s = m.stepper(DT)
    ys = []
    for k, v in enumerate(u):
        if k % 3 == 0:
            s.peek(v + 1.0)  # trial evaluations must not touch the predictor state
        ys.append(s.step(v))
    assert np.array_equal(np.array(ys), y)


@pytest.mark.parametrize("lams", [(0.3, 0.9), (0.3, 0.3), (0.9557, 0.622), (1.0, 0.3), (0.99, 0.99), (0.5, 1.0)])
def test_fast_engine_within_1e7_of_exact_over_the_orders(lams):
    u = eq19(100_000)
    p = {**TABLE1, "lam1": lams[0], "lam2": lams[1]}
    ye = fonbw.FONBW(**p, memory="exact").simulate(u, DT)
    yf = fonbw.FONBW(**p).simulate(u, DT)
    assert rel(yf, ye) <= 1e-7


def test_lowest_mode_carries_the_truncated_tail():
    # without the lumped nodes below s_lo, E1 at λ = 0.3 plateaus near 3e-8 for any M
    assert fr.tail_error(0.3, fr.FAST_K, 64, horizon=100_000) < 1e-11
    assert fr.tail_error(0.3, fr.FAST_K, fr.FAST_M, horizon=1_000_000) < 1e-9


def test_numba_cache_key_follows_the_compiled_sources_only(tmp_path):
    import shutil

    import fonbw

    pkg = tmp_path / "fonbw"
    shutil.copytree(Path(fonbw.__file__).parent, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    key = fonbw._kernel_sources_digest(str(pkg), "0.68.1")
    assert key == fonbw._kernel_sources_digest(str(pkg), "0.68.1") and len(key) == 16
    assert fonbw._kernel_sources_digest(str(pkg), "0.69.0") != key     # a numba upgrade
    for rel in ("cli/main.py", "loop/run.py", "gap/attribute.py"):   # no compiled code there
        (pkg / rel).write_text((pkg / rel).read_text() + "\n# edited\n")
    assert fonbw._kernel_sources_digest(str(pkg), "0.68.1") == key
    for rel in ("fractional/weights.py", "hysteresis/models.py", "plant.py", "gap/plays.py"):
        src = (pkg / rel).read_text()
        (pkg / rel).write_text(src + "\n# edited\n")
        assert fonbw._kernel_sources_digest(str(pkg), "0.68.1") != key, rel
        (pkg / rel).write_text(src)
    assert fonbw._kernel_sources_digest(str(pkg), "0.68.1") == key
