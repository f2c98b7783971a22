"""Tests of fonbw.identify (eq. 18 minimized by jDE, variable projection).

Reference data come from the public model classes (fonbw.FONBW, NBW, CBW),
not from the population kernel the identification uses.
"""
import os
import subprocess
import sys

import numpy as np
import pytest

import fonbw.hysteresis as hyst
from fonbw.hysteresis import CBW, FONBW, NBW
from fonbw.identify import (IdentifyResult, _as_records, _Projected, identify,
                            rms_cost, search_space)
from fonbw.io import Record
from fonbw.paper import TABLE1_FONBW
from fonbw.signals import eq19_input

NOISE = 0.02   # µm, white measurement noise of the synthetic records
DT = 5e-3      # s; 200 Hz keeps the test short (the paper samples at 10 kHz)
TRUE = dict(ku=[0.18, -1.4e-4, -7.7e-8], kh=-2.0, rho=0.02, sigma=0.8, n=1.5,
            lam1=0.95, lam2=0.85)


def eq19(T=10.0, dt=DT):
    """Identification input, eq. (19) [V]."""
    return eq19_input(1.0 / dt, T)[1]


def sine(f, periods=3, dt=DT):
    """Validation input 60 − 60 cos(2πft) [V]."""
    t = np.arange(0.0, periods / f, dt)
    return 60.0 - 60.0 * np.cos(2 * np.pi * f * t)


def noisy_record(model, u, seed, dt=DT):
    y = model.simulate(u, dt)
    y = y + NOISE * np.random.default_rng(seed).standard_normal(y.size)
    return Record.from_arrays(u=u, y=y, dt=dt)


@pytest.fixture(scope="module")
def truth():
    return FONBW(**TRUE, memory="fast")


@pytest.fixture(scope="module")
def fonbw_fit(truth):
    rec = noisy_record(truth, eq19(), seed=0)
    return rec, identify(rec, "fonbw", seed=1, max_evals=3000)


def test_fonbw_identification_validates_on_sines(truth, fonbw_fit):
    rec, res = fonbw_fit
    assert isinstance(res, IdentifyResult)
    assert res.kind == "fonbw" and res.nfev <= 3000
    # Training RMS at the noise floor: below the truth's own RMS on this noisy
    # record plus a hair (the fit may absorb a little noise), not far below it.
    rms_truth = np.sqrt(np.mean((truth.simulate(rec.u, DT) - rec.y) ** 2))
    assert 0.9 * NOISE < res.rms <= rms_truth * 1.001
    # The returned model reproduces the reported RMS (independent simulation).
    rms_model = np.sqrt(np.mean((res.model.simulate(rec.u, DT) - rec.y) ** 2))
    assert abs(rms_model - res.rms) < 1e-9
    # Validation on sines the identification never saw.
    for i, f in enumerate([0.5, 1.0, 2.0, 5.0]):
        val = noisy_record(truth, sine(f), seed=100 + i)
        rms_val = np.sqrt(np.mean((res.model.simulate(val.u, DT) - val.y) ** 2))
        assert rms_val < 2 * NOISE, (f, rms_val)
        # ... and against the noiseless truth, the model error itself is small.
        err = np.sqrt(np.mean((res.model.simulate(val.u, DT) - truth.simulate(val.u, DT)) ** 2))
        assert err < 0.5 * NOISE, (f, err)


def test_fonbw_identification_recovers_parameters(fonbw_fit):
    _, res = fonbw_fit
    p = res.params
    assert abs(p["ku1"] - 0.18) < 0.01
    assert abs(p["kh"] - (-2.0)) < 0.1
    assert abs(p["rho"] - 0.02) / 0.02 < 0.05
    assert abs(p["lam1"] - 0.95) < 0.02 and abs(p["lam2"] - 0.85) < 0.02
    assert abs(p["n"] - 1.5) < 0.1


def test_history_is_rms_and_non_increasing(fonbw_fit):
    _, res = fonbw_fit
    h = res.history
    assert np.all(np.diff(h) <= 0)
    assert h[-1] >= res.rms * (1 - 1e-7)   # polish can only improve on DE's best
    assert h[0] > 2 * res.rms              # the initial population is far off


def test_nbw_recovers_parameters_on_nbw_data():
    truth = NBW(ku=[0.15, -2e-4], kh=-3.0, rho=0.03, sigma=0.7, n=1.3)
    rec = noisy_record(truth, eq19(T=8.0), seed=3)
    res = identify(rec, "nbw", N=2, seed=2, max_evals=1500)
    p = res.params
    np.testing.assert_allclose([p["ku1"], p["kh"], p["rho"], p["sigma"], p["n"]],
                               [0.15, -3.0, 0.03, 0.7, 1.3], rtol=0.05)
    assert res.rms < 1.01 * NOISE


def test_cbw_redundant_parameters_map_to_the_same_normalized_model():
    # Non-canonical CBW (D, A, β+γ all far from 1): the identified CBW differs
    # in its raw parameters but its exact NBW normalization (eqs. 7-8) matches.
    truth = CBW(alpha=0.6, k=0.3, D=2.5, A=0.8, beta=0.05, gamma=0.03, n=1.2)
    rec = noisy_record(truth, eq19(T=8.0), seed=4)
    res = identify(rec, "cbw", seed=3, max_evals=1200)
    a, b = truth.to_nbw(), res.model.to_nbw()
    np.testing.assert_allclose([b.ku[0], b.kh, b.rho, b.sigma, b.n],
                               [a.ku[0], a.kh, a.rho, a.sigma, a.n], rtol=0.05)
    val = sine(2.0)
    err = np.sqrt(np.mean((res.model.simulate(val, DT) - truth.simulate(val, DT)) ** 2))
    assert err < 0.5 * NOISE


@pytest.mark.parametrize("kind", ["fonbw", "nbw", "cbw", "zhu"])
def test_projection_and_back_maps_agree_with_direct_simulation(truth, kind):
    """The variable-projection RMS of a search point equals eq. (18) of the
    natural parameters it maps back to, simulated directly."""
    recs_in = [noisy_record(truth, eq19(T=3.0), seed=5),
               noisy_record(truth, sine(2.0, periods=2), seed=6)]
    space = search_space(kind, recs_in)
    N = 3 if kind in ("fonbw", "nbw") else 1
    pnames = hyst.param_names(kind, N)
    proj = _Projected(space, _as_records(recs_in), pnames, kind, "fast", N)
    rng = np.random.default_rng(7)
    lo = np.array([b[0] for b in space.bounds])
    hi = np.array([b[1] for b in space.bounds])
    Z = rng.random((6, len(lo)))
    X = np.where(space.log_scale, lo * (hi / np.where(space.log_scale, lo, 1.0)) ** Z,
                 lo + Z * (hi - lo))
    rms, G, c = proj.solve(X)
    checked = 0
    for i in range(X.shape[0]):
        if not np.isfinite(rms[i]):
            continue
        p = space.final_params(X[i], c[i], float(G[i]))
        theta = np.array([[p[k] for k in pnames]])
        direct = rms_cost(kind, theta, recs_in, N=N)[0]
        # pooled by hand from the two records
        m = hyst.model_from_vector(kind, theta[0], N=N)
        sse = sum(np.sum((m.simulate(r.u, r.dt) - r.y) ** 2) for r in recs_in)
        by_hand = np.sqrt(sse / sum(r.y.size for r in recs_in))
        np.testing.assert_allclose(direct, by_hand, rtol=1e-12)
        np.testing.assert_allclose(rms[i], direct, rtol=1e-7)
        checked += 1
    assert checked >= 3


def test_seed_reproducibility():
    truth = NBW(ku=0.2, kh=-1.5, rho=0.05, sigma=0.9, n=1.0)
    rec = noisy_record(truth, eq19(T=4.0), seed=8)
    a = identify(rec, "nbw", N=1, seed=42, max_evals=400)
    b = identify(rec, "nbw", N=1, seed=42, max_evals=400)
    c = identify(rec, "nbw", N=1, seed=43, max_evals=400, polish=False)
    d = identify(rec, "nbw", N=1, seed=42, max_evals=400, polish=False)
    assert a.params == b.params
    np.testing.assert_array_equal(a.history, b.history)
    assert not np.array_equal(c.history, d.history)


def test_nan_candidates_survive(monkeypatch, truth):
    """A simulator returning NaN rows for part of the population (divergence)
    must not stop or bias the identification."""
    real = hyst.simulate_population
    seen = {"nan_rows": 0}

    def flaky(kind, theta, u, dt, memory="fast", N=3):
        out = real(kind, theta, u, dt, memory=memory, N=N)
        # rows with λ2 < 0.5 "diverge" half-way through
        bad = theta[:, -1] < 0.5
        out[bad, u.size // 2:] = np.nan
        seen["nan_rows"] += int(bad.sum())
        return out

    monkeypatch.setattr(hyst, "simulate_population", flaky)
    rec = noisy_record(truth, eq19(T=6.0), seed=9)
    res = identify(rec, "fonbw", seed=4, max_evals=2500)
    # enough diverging candidates to matter (93 to a few hundred, by library versions)
    assert seen["nan_rows"] > 50
    assert np.isfinite(res.rms) and res.rms < 1.05 * NOISE
    assert res.params["lam2"] >= 0.5


def test_all_divergent_raises_clear_error(monkeypatch, truth):
    monkeypatch.setattr(hyst, "simulate_population",
                        lambda kind, theta, u, dt, memory="fast", N=3:
                        np.full((theta.shape[0], u.size), np.nan))
    rec = noisy_record(truth, eq19(T=1.0), seed=0)
    with pytest.raises(RuntimeError, match="every candidate diverged"):
        identify(rec, "nbw", seed=0, max_evals=200)


# TRUE and DT are prepended by the test
_WORKERS_CHECK = """
import numba, numpy as np
from fonbw.hysteresis import FONBW, param_names, simulate_population
from fonbw.identify import identify
from fonbw.io import Record
from fonbw.signals import eq19_input
truth = FONBW(**TRUE)
u = eq19_input(1.0 / DT, 2.0)[1]
rec = Record.from_arrays(u=u, y=truth.simulate(u, DT), dt=DT)
before = numba.get_num_threads()
used = []
identify(rec, "nbw", seed=0, max_evals=100, polish=False, workers=1,
         callback=lambda x, f, nit: used.append(numba.get_num_threads()))
# the parallel population kernel on two threads against each model run alone
vec = np.r_[TRUE["ku"], [TRUE[k] for k in param_names("fonbw")[3:]]]
th = vec * np.random.default_rng(0).uniform(0.9, 1.0, (16, vec.size))
pop = simulate_population("fonbw", th, u, DT)
alone = np.array([FONBW(t[:3], *t[3:]).simulate(u, DT) for t in th])
print(before, sorted(set(used)), numba.get_num_threads(), float(np.max(np.abs(pop - alone))))
"""


def test_workers_and_the_population_kernel_on_two_numba_threads():
    # two numba threads in a process of its own: the suite's workers run with one,
    # so this is also where the population kernel runs on more than one thread
    env = {**os.environ, "NUMBA_NUM_THREADS": "2"}
    code = f"TRUE = {TRUE!r}\nDT = {DT!r}\n" + _WORKERS_CHECK
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    before, used, after, diff = out.stdout.split()
    assert (before, used, after) == ("2", "[1]", "2")
    assert float(diff) == 0.0


def test_bounds_override_is_used(truth):
    rec = noisy_record(truth, eq19(T=2.0), seed=2)
    res = identify(rec, "fonbw", seed=0, max_evals=300, polish=False,
                   bounds={"lam1": (0.7, 0.7), "n": (2.0, 2.5)})
    assert res.params["lam1"] == pytest.approx(0.7, abs=1e-15)
    assert 2.0 <= res.params["n"] <= 2.5
    assert res.search["bounds"][res.search["names"].index("n")] == (2.0, 2.5)


def test_single_record_and_list_give_the_same_objective(truth):
    rec = noisy_record(truth, eq19(T=2.0), seed=3)
    theta = np.array([[0.18, -1.4e-4, -7.7e-8, -2.0, 0.02, 0.8, 1.5, 0.95, 0.85]])
    assert rms_cost("fonbw", theta, rec)[0] == rms_cost("fonbw", theta, [rec])[0]
    # the truth's RMS on its own noisy record is the noise level
    assert abs(rms_cost("fonbw", theta, rec)[0] - NOISE) < 0.1 * NOISE


@pytest.mark.parametrize("call, match", [
    (lambda r: identify(r, "prandtl"), "kind must be one of"),
    (lambda r: identify(r, "fonbw", bounds={"kh": (-1, 1)}), "unknown search variable"),
    (lambda r: identify(r, "fonbw", bounds={"rho": (0.0, 1.0)}), "log scale"),
    (lambda r: identify(r, "fonbw", bounds={"n": (3.0, 2.0)}), "lo <= hi"),
    (lambda r: identify(r, "fonbw", workers=0), "workers"),
    (lambda r: identify(r, "fonbw", N=0), "N must be"),
    (lambda r: identify(r, "fonbw", max_evals=0), "max_evals"),
    (lambda r: identify([], "fonbw"), "at least one record"),
    (lambda r: identify(Record.from_arrays(u=r.u, y=r.y[:-1], dt=DT), "nbw"),
     "samples but y has"),
    (lambda r: identify(Record.from_arrays(u=0 * r.u, y=r.y, dt=DT), "nbw"),
     "identically zero"),
    (lambda r: identify(Record.from_arrays(u=r.u, y=None, dt=DT), "nbw"), "no 'y'"),
])
def test_validation_errors(truth, call, match):
    rec = noisy_record(truth, eq19(T=1.0), seed=0)
    with pytest.raises(ValueError, match=match):
        call(rec)


def test_paper_table1_regime_is_identified():
    """Table 1's extreme FONBW values (ρ = 6.5e-7, σ = 1.3e5, k_h = −3.3e4).

    There ħ stays ≪ 1, so the output fixes k_h ρ, σ ρ^n and — since the GL
    weights of orders λ1 and −λ2 compose exactly to those of λ1 − λ2 — only
    the difference λ1 − λ2 of the orders, not ρ, σ, λ1, λ2 one by one. The
    fit must reach the noise floor and predict unseen sines anyway.
    """
    truth = FONBW(**TABLE1_FONBW)
    rec = noisy_record(truth, eq19(), seed=10)
    res = identify(rec, "fonbw", seed=1, max_evals=3000)
    rms_truth = np.sqrt(np.mean((truth.simulate(rec.u, DT) - rec.y) ** 2))
    assert res.rms <= rms_truth * 1.001
    p = res.params
    assert abs((p["lam1"] - p["lam2"]) - (0.9557 - 0.6220)) < 0.02
    assert abs(p["ku1"] - 0.1811) < 0.005
    # 5 Hz lies beyond the ≤ 1.5 Hz content of eq. (19): allow one noise std.
    for f in [0.5, 1.0, 2.0, 5.0]:
        u = sine(f)
        err = np.sqrt(np.mean((res.model.simulate(u, DT) - truth.simulate(u, DT)) ** 2))
        assert err < NOISE, (f, err)


def test_keyboard_interrupt_returns_best_model_so_far(truth):
    rec = noisy_record(truth, eq19(T=2.0), seed=11)

    def stop(x, f, nit):
        if nit == 2:
            raise KeyboardInterrupt

    res = identify(rec, "fonbw", seed=0, max_evals=2000, popsize=50, callback=stop)
    assert res.message == "interrupted" and not res.success
    assert res.nfev == 3 * 50          # initial population + 2 generations
    assert np.isfinite(res.rms)
    np.testing.assert_allclose(res.rms, res.history[-1], rtol=1e-7)


def test_unknown_memory_engine_is_refused(truth):
    rec = noisy_record(truth, eq19(T=1.0), seed=0)
    with pytest.raises(ValueError, match="memory must be one of"):
        identify(rec, "fonbw", memory="infinite")


def test_default_population_aims_at_forty_generations(truth):
    from fonbw.identify import _de_settings

    space = search_space("fonbw", noisy_record(truth, eq19(T=2.0), seed=12))
    # 1500 evaluations: 450 for the polish, 1050 for DE = 40 generations of 26
    assert _de_settings(space, 1500, True, None, None, None, 2) == (450, 26)
    # 3000: 2100 for DE, 52 capped at jDE's 10 d = 50; 500: 350 // 40 = 8, floored at 4 d = 20
    assert _de_settings(space, 3000, True, None, None, None, 2) == (900, 50)
    assert _de_settings(space, 500, True, None, None, None, 2) == (150, 20)


def test_small_budget_shrinks_population_and_respects_cap(truth):
    rec = noisy_record(truth, eq19(T=2.0), seed=12)
    res = identify(rec, "fonbw", seed=0, max_evals=60)
    assert res.nfev <= 60
    assert len(res.history) >= 4          # several generations, not one
    assert np.isfinite(res.rms)


# --------------------------------------------------------------------------
# Well-posed fits: no cancelling gains, parameters at bounds named, burn-in
# --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def bipolar_bench_record():
    """3 s of a ±150 V, 1 Hz drive on the bipolar bench (creep, drift, noise) at 1 kHz."""
    from fonbw.bench import Bench
    from fonbw.signals import bipolar_input

    b = Bench.bipolar_logger(seed=2, fs=1000.0)
    u = bipolar_input(fs=1000.0, T=3.0, f=1.0)[1]
    return Record.from_arrays(u=u, y=b.run(u), dt=1e-3)


@pytest.mark.parametrize("kind", ["cbw", "nbw"])
def test_no_cancelling_gains_on_a_bipolar_record(bipolar_bench_record, kind):
    # Unguarded, both fits ran off to a hysteretic term that is almost linear in u
    # with a huge gain its linear part cancels (CBW k_a = -k_b = 6e10, NBW σ = 1e16).
    res = identify(bipolar_bench_record, kind, seed=0, max_evals=600)
    p, rec = res.params, bipolar_bench_record
    U, span = np.max(np.abs(rec.u)), np.ptp(rec.y)
    # each term alone stays on the scale of the output: the linear one (|k_a| U or
    # |k_u1| U) and the hysteretic one (|k_b D| max|h|, h within ±1, or |k_h ρ| U)
    lin = abs(p["ka"]) * U if kind == "cbw" else abs(p["ku1"]) * U
    hyst_term = abs(p["kb"] * p["D"]) if kind == "cbw" else abs(p["kh"] * p["rho"]) * U
    assert lin < 2 * span and hyst_term < 2 * span, p
    if kind == "nbw":
        assert p["sigma"] < 1e6, p
    assert res.rms < 0.1 * span  # CBW is symmetric: a few % of range on this asymmetric bench


def test_parameter_at_a_bound_is_named_with_intervals(truth):
    rec = noisy_record(truth, eq19(T=4.0), seed=21)
    res = identify(rec, "fonbw", seed=0, max_evals=400, bounds={"lam1": (0.3, 0.6)})
    assert any(w.startswith("lam1 = 0.6 is at the upper bound of its search range [0.3, 0.6]")
               for w in res.warnings), res.warnings
    assert set(res.intervals) == {"rho", "sigma_rho", "n", "lam1", "lam2"}
    lo, hi = res.intervals["n"]
    assert lo <= res.params["n"] <= hi


def test_intervals_hold_the_truth_on_clean_data(truth, fonbw_fit):
    _, res = fonbw_fit
    lo, hi = res.intervals["rho"]
    assert lo <= TRUE["rho"] <= hi and hi / lo < 10
    lo, hi = res.intervals["n"]
    assert lo <= TRUE["n"] <= hi


def test_burn_in_leaves_the_start_out_and_fits_the_offset(truth):
    u = eq19(T=12.0)
    y = truth.simulate(u, DT) + 0.7          # a sensor offset
    k = 400                                   # cut mid-drive: the model's rest is wrong here
    rec = Record.from_arrays(u=u[k:], y=y[k:], dt=DT)
    res = identify(rec, "fonbw", seed=1, max_evals=1500, burn_in=[300])
    assert res.burn_in == [300]
    assert res.offsets[0] == pytest.approx(0.7, abs=0.2)  # shares a little with the polynomial of u
    assert res.rms < 0.05
    with pytest.raises(ValueError, match=r"burn_in\[0\] = -1: need an integer"):
        identify(rec, "fonbw", burn_in=[-1])


# --------------------------------------------------------------------------
# Ranges the records can identify: λ floor from the rate span, σ cap
# --------------------------------------------------------------------------

def _triangle(f, periods, dt=1e-3, A=100.0):
    """Triangle wave from −A [V], `periods` periods of frequency f [Hz]."""
    t = np.arange(int(round(periods / f / dt))) * dt
    phase = (t * f) % 1.0
    return A * (4.0 * np.abs(phase - 0.5) - 1.0) * -1.0


def test_rate_span_and_lambda_floor_by_hand():
    from fonbw.identifiable import lambda_floor, rate_span, swings

    u = np.concatenate([_triangle(1.0, 3), _triangle(4.0, 12)])
    f, stroke = swings(u, 1e-3)
    # 6 + 24 swings of 200 V; the first and last are cut by the record's ends
    assert f.size == 28 and np.allclose(stroke, 200.0)
    assert np.allclose(np.sort(f), [1.0] * 5 + [4.0] * 23)
    # 5 of 28 equal strokes at 1 Hz (18 %) put the 10th percentile there
    assert rate_span([(u, 1e-3)]) == pytest.approx(4.0)
    assert lambda_floor(4.0) == pytest.approx(0.5 - 0.45 * np.log10(4.0))  # 0.2291
    assert lambda_floor(1.0) == 0.5 and lambda_floor(10.0) == pytest.approx(0.05)
    assert lambda_floor(1e3) == pytest.approx(0.05)
    # one rate: the floor of a single-rate record
    assert rate_span([(_triangle(2.0, 5), 1e-3)]) == 1.0
    rec = Record.from_arrays(u=u + 100.0, y=np.sin(u / 30.0), dt=1e-3)
    space = search_space("fonbw", rec)
    assert space.bounds[3] == pytest.approx((0.5 - 0.45 * np.log10(4.0), 1.0))
    assert space.bounds[4] == space.bounds[3]
    # the user's bounds still win
    assert search_space("fonbw", rec, bounds={"lam1": (0.1, 0.9)}).bounds[3] == (0.1, 0.9)


def test_sigma_is_capped_by_raising_rho():
    from fonbw.identifiable import SIGMA_MAX

    rec = Record.from_arrays(u=eq19(T=4.0), y=np.sin(eq19(T=4.0) / 30.0), dt=DT)
    space = search_space("fonbw", rec)
    # sigma_rho / rho = 1e4 at n = 2 would be σ = 1e8: ρ rises to sigma_rho / sqrt(1e3)
    x = np.array([[1e-5, 0.1, 2.0, 0.9, 0.8], [0.02, 0.0172, 1.5, 0.9, 0.8]])
    p = space.basis_params(x)
    assert p["sigma"][0] == pytest.approx(SIGMA_MAX) and p["rho"][0] == pytest.approx(0.1 / np.sqrt(1e3))
    assert p["sigma"][1] == pytest.approx((0.0172 / 0.02) ** 1.5) and p["rho"][1] == 0.02  # inside: untouched
    assert search_space("nbw", rec, reparametrize=False).bounds[1] == (1e-2, SIGMA_MAX)


def test_a_sigma_floor_lowers_rho_and_keeps_the_state_bounded():
    from fonbw.identifiable import SIGMA_BOUNDED

    rec = Record.from_arrays(u=eq19(T=4.0), y=np.sin(eq19(T=4.0) / 30.0), dt=DT)
    free, floored = search_space("fonbw", rec), search_space("fonbw", rec, sigma_min=SIGMA_BOUNDED)
    # sigma_rho / rho = 0.01 at n = 2 is σ = 1e-4: ρ drops to 0.01 / sqrt(0.5), σ = 1/2
    x = np.array([[1.0, 0.01, 2.0, 0.9, 0.8], [0.02, 0.0172, 1.5, 0.9, 0.8]])
    p0, p1 = free.basis_params(x), floored.basis_params(x)
    assert p0["sigma"][0] == pytest.approx(1e-4) and p0["rho"][0] == 1.0
    assert p1["sigma"][0] == pytest.approx(0.5) and p1["rho"][0] == pytest.approx(0.01 / np.sqrt(0.5))
    assert p1["sigma"][1] == p0["sigma"][1] and p1["rho"][1] == 0.02  # σ = 0.8 inside: untouched
    assert search_space("nbw", rec, reparametrize=False, sigma_min=0.5).bounds[1][0] == 0.5
    # what the floor is for: on a bipolar sine, σ = 1e-4 runs away after the first
    # reversal while σ = 1/2 stays within ħ's saturation level 1
    u = 100.0 * np.sin(2 * np.pi * np.arange(0.0, 2.0, DT))
    h = {}
    for key, p in (("free", p0), ("floored", p1)):
        q = {k: float(p[k][0]) for k in ("rho", "sigma", "n", "lam1", "lam2")}
        with np.errstate(all="ignore"):
            h[key] = FONBW(ku=[0.0], kh=1.0, **q).simulate(u, DT)
    assert not np.all(np.isfinite(h["free"]))
    assert np.all(np.isfinite(h["floored"])) and np.max(np.abs(h["floored"])) <= 1.0


def test_bipolar_single_rate_record_stays_in_identifiable_ranges(bipolar_bench_record):
    # Unbounded, FONBW on one 1 Hz bipolar record ran to σ = 3.5e8 (ρ = 4e-9) or to the
    # λ corner; one rate cannot tell the fractional orders from ρ.
    res = identify(bipolar_bench_record, "fonbw", seed=1, max_evals=600)
    p, span = res.params, np.ptp(bipolar_bench_record.y)
    assert res.search["bounds"][3] == (0.5, 1.0) and res.search["bounds"][4] == (0.5, 1.0)
    assert p["lam1"] >= 0.5 and p["lam2"] >= 0.5, p
    assert p["sigma"] <= 1e3 * (1 + 1e-9), p
    # at the cap it is said so (this record pushes σ there)
    assert (p["sigma"] < 0.999e3) != any(w.startswith("sigma = 1000 is at its cap 1000") for w in res.warnings)
    assert res.rms < 0.05 * span


def test_gauss_newton_polish_reaches_the_noise_floor_from_nearby(truth):
    from fonbw.de import _Space
    from fonbw.gnpolish import gauss_newton_polish

    rec = noisy_record(truth, eq19(T=6.0), seed=31)
    space = search_space("fonbw", rec)
    proj = _Projected(space, _as_records(rec), hyst.param_names("fonbw", 3), "fonbw", "fast", 3)
    box = _Space(space.bounds, space.log_scale)
    x_true = np.array([0.02, 0.8 ** (1 / 1.5) * 0.02, 1.5, 0.95, 0.85])
    z0 = box.to_unit(x_true[None, :])[0] + np.array([0.02, -0.02, 0.03, -0.03, 0.02])
    f0 = float(proj(box.to_natural(z0[None, :]))[0])
    z, f, used = gauss_newton_polish(proj, box)(z0, f0, 150)
    rms_truth = np.sqrt(np.mean((truth.simulate(rec.u, DT) - rec.y) ** 2))
    assert f0 > 2 * rms_truth                # the start is well off the floor
    assert f <= rms_truth * 1.001 and used <= 150
    assert f == pytest.approx(float(proj(box.to_natural(z[None, :]))[0]), rel=1e-12)
    # no budget, no evaluation, the start returned
    zb, fb, ub = gauss_newton_polish(proj, box)(z0, f0, 0)
    assert ub == 0 and fb == f0 and np.array_equal(zb, z0)


def test_fonbw_warm_started_from_an_nbw_is_never_worse_than_it():
    # an NBW truth: the FONBW with λ1 = λ2 = 1 contains it exactly; from its
    # NBW start the FONBW search ends at or below the truth's RMS (the linear
    # parameters are solved, so the start alone already reaches it), while a
    # cold search with the same tiny budget does not get there
    nbw = NBW(ku=TRUE["ku"], kh=TRUE["kh"], rho=TRUE["rho"], sigma=TRUE["sigma"], n=TRUE["n"])
    rec = noisy_record(nbw, eq19(), seed=11)
    truth_rms = float(np.sqrt(np.mean((nbw.simulate(rec.u, rec.dt) - rec.y) ** 2)))
    warm = identify(rec, "fonbw", seed=0, max_evals=40, polish=False, x0=nbw)
    cold = identify(rec, "fonbw", seed=0, max_evals=40, polish=False)
    assert warm.rms <= truth_rms * (1 + 1e-9)
    assert cold.rms > 1.05 * truth_rms
    with pytest.raises(ValueError, match="reparametrized"):
        identify(rec, "fonbw", max_evals=40, reparametrize=False, x0=nbw)


def test_gauss_newton_polish_steps_around_a_divergent_region():
    # Residuals that diverge (NaN) just past the start along one axis: the
    # forward-difference Jacobian steps back instead, and the polish reaches
    # the least-squares minimum (0.3, 0.6) rather than failing inside trf.
    from fonbw.gnpolish import gauss_newton_polish

    class Box:
        def to_natural(self, Z):
            return np.asarray(Z, float)

    class Proj:
        M = 2000
        t = np.linspace(0.0, 1.0, M)

        def residuals(self, X):
            X = np.atleast_2d(X)
            R = (X[:, :1] - 0.3) * np.sin(7 * self.t) + (X[:, 1:2] - 0.6) ** 2 * self.t
            R[X[:, 0] > 0.45] = np.nan
            return R

        def __call__(self, X):
            return np.sqrt(np.mean(self.residuals(X) ** 2, axis=1))

    z0 = np.array([0.45 - 5e-7, 0.9])
    f0 = float(Proj()(z0[None])[0])
    z, f, used = gauss_newton_polish(Proj(), Box())(z0, f0, 200)
    assert f < 1e-8 * f0 and np.allclose(z, [0.3, 0.6], atol=1e-4) and used <= 200
