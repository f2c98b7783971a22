"""One-step slope, invertibility warnings, model-derived voltage limits, the
rest-cycle start and the preview inverse.

References: finite differences of the compiled step (slope), the closed-form
zero (k_u1/|k_h ρ|)^(1/(λ1−λ2)) and one-step slope k_u1 + k_h ρ dt^(λ2−λ1),
the model's own stepper and batch simulation driven by the compensators'
voltage, and a noisy record of a known invertible truth (identification)."""
import warnings

import numpy as np
import pytest

from fonbw.compensate import compensate, default_limits
from fonbw.hysteresis import FONBW
from fonbw.invertibility import check_invertible, one_step_slope

DT = 2e-4
T = np.arange(2500) * DT  # 0.5 s


def _minimum_phase():
    # k_h ρ > 0 with λ1 > λ2: the hysteresis adds to the one-step slope
    return FONBW(ku=[0.1, 2e-4], kh=2.0, rho=0.02, sigma=0.8, n=1.5, lam1=0.9, lam2=0.7)


def _non_minimum_phase():
    # k_h ρ < 0, λ1 > λ2: slope k_u1 + k_h ρ dt^(λ2−λ1) < 0 at this step
    return FONBW(ku=[0.15], kh=-10.0, rho=0.01, sigma=0.8, n=1.5, lam1=0.95, lam2=0.6)


def test_analytic_slope_matches_finite_differences():
    m = _minimum_phase()
    u = 60 - 60 * np.cos(2 * np.pi * 5 * T)
    an = one_step_slope(m, DT, u)
    fd = one_step_slope(m, DT, u, method="fd")
    # sample 0 is the rest reference (ħ does not move); elsewhere the branch the input is on
    assert np.allclose(an[1:, 0], fd[1:, 0], rtol=1e-5, atol=1e-8)


def test_minimum_phase_causal_inverse_is_exact():
    m = _minimum_phase()
    ok, smin, _ = check_invertible(m, DT)
    assert ok and smin > 0
    Hd = 5 - 5 * np.cos(2 * np.pi * 5 * T)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        res = compensate(m, Hd, DT, limits=(-50, 200))
    assert res.ok and res.tracking_impossible is None
    assert np.max(np.abs(m.simulate(res.u, DT) - Hd)) <= 1e-10


def test_non_minimum_phase_model_warns():
    m = _non_minimum_phase()
    ok, smin, msg = check_invertible(m, DT)
    assert not ok and smin < 0 and "not invertible" in msg
    with pytest.warns(RuntimeWarning, match="not invertible"):
        compensate(m, 5 - 5 * np.cos(2 * np.pi * 5 * T[:200]), DT)


def test_limits_come_from_the_training_range():
    # a bipolar stage: odd g(u), 0.2 µm/V, identified on ±150 V
    m = FONBW(ku=[0.2], kh=2.0, rho=0.02, sigma=0.8, n=1.5, lam1=0.9, lam2=0.7)
    m.meta = {"u_range": [-150.0, 150.0]}
    assert default_limits(m) == (-150.0, 150.0)
    Hd = 15 * np.sin(2 * np.pi * 2 * T)
    res = compensate(m, Hd, DT)
    assert res.counts["saturated_low"] == 0 and res.counts["saturated_high"] == 0
    assert np.max(np.abs(res.residual)) <= 1e-10
    assert default_limits(_minimum_phase()) == (0.0, 120.0)
    m.meta = {}
    clipped = compensate(m, Hd, DT)
    assert clipped.tracking_impossible and "clipped at u_min" in clipped.tracking_impossible


def test_meta_round_trips_through_json(tmp_path):
    from fonbw.hysteresis import load_model
    m = _minimum_phase()
    m.meta = {"u_range": [-150.0, 150.0], "invertibility": {"dt": DT, "slope_min": 0.1, "margin": 0.5}}
    m.save(tmp_path / "m.json")
    m2 = load_model(tmp_path / "m.json")
    assert m2.meta == m.meta and m2 == m


def test_preview_tracks_a_non_minimum_phase_model():
    from fonbw.compensate.preview import default_lead, rhp_zero
    from fonbw.paper import TABLE1_FONBW

    # the paper's Table 1 set: k_h ρ < 0, λ1 > λ2; one-step slope < 0 at 10 kHz
    m = FONBW(**TABLE1_FONBW)
    dt = 1e-4
    kr = TABLE1_FONBW["kh"] * TABLE1_FONBW["rho"]
    alpha = TABLE1_FONBW["lam1"] - TABLE1_FONBW["lam2"]
    s0 = rhp_zero(m)
    # the zero of k_u1 + k_h ρ s^(λ1−λ2) in closed form, and the one-step slope
    assert s0 == pytest.approx((TABLE1_FONBW["ku"][0] / -kr) ** (1 / alpha), rel=1e-12)
    assert TABLE1_FONBW["ku"][0] + kr * dt ** -alpha < 0.0
    Hd = 5 - 5 * np.cos(2 * np.pi * 5 * np.arange(2000) * dt)
    span = float(np.ptp(Hd))
    lim = (-100.0, 200.0)  # pure simulation: from the virgin state the bottom needs u < 0
    with pytest.warns(RuntimeWarning, match="not invertible"):
        causal = compensate(m, Hd, dt, limits=lim)
    assert not causal.ok  # no root or a limit on most samples
    res = compensate(m, Hd, dt, limits=lim, preview=True, tol=1e-7 * span)
    assert res.ok and res.u_lead.size == default_lead(m, dt, len(Hd))
    # pre-actuation of about 20 time constants of the zero
    assert res.u_lead.size == pytest.approx(20 / (s0 * dt), rel=0.05)
    # independent path: the model's stepper, one sample at a time, over lead + trajectory
    st = m.stepper(dt)
    y = np.array([st.step(v) for v in res.u_full])[res.u_lead.size:]
    assert np.max(np.abs(y - Hd)) <= 1e-6 * span
    # bounded and smooth
    assert np.all(np.abs(res.u_full) < 100.0)
    assert np.sqrt(np.mean(np.diff(res.u_full) ** 2)) < 0.5


def test_rest_cycle_start_is_exact_and_zeroed():
    from fonbw.compensate.rest import rest_cycle, rest_start_meta, start_history

    m = _minimum_phase()
    m.meta = {"u_range": [0.0, 120.0], "start": rest_start_meta((0.0, 120.0), T=0.2)}
    pre = start_history(m, DT)
    assert pre.size == 1000 and pre[-1] == 0.0 and pre.max() == pytest.approx(120.0, rel=1e-6)
    assert np.array_equal(pre, rest_cycle((0.0, 120.0), DT, T=0.2))
    Hd = 5 - 5 * np.cos(2 * np.pi * 5 * T)
    # the fractional memory of the cycle still relaxes after it: allow u < 0
    lim = (-50.0, 200.0)
    res = compensate(m, Hd, DT, limits=lim)
    assert res.ok and np.array_equal(res.history, pre)
    # reference: the model's batch simulation through history + u, zeroed at the end of the history
    y = m.simulate(np.concatenate([pre, res.u]), DT)
    assert np.max(np.abs((y[pre.size:] - y[pre.size - 1]) - Hd)) <= 1e-10
    # from its virgin state the same voltage misses by the offset the cycle leaves
    assert np.max(np.abs(m.simulate(res.u, DT) - Hd)) > 1e-3
    # the per-step compensator runs the same history
    from fonbw.compensate import compensator
    c = compensator(m, DT, limits=lim)
    assert np.array_equal([c.step(h) for h in Hd[:300]], res.u[:300])
    assert np.array_equal(compensate(m, Hd[:50], DT, history=()).history, np.zeros(0))


def test_constrained_identification_recovers_an_invertible_truth():
    from fonbw.hysteresis import NBW
    from fonbw.identify import identify
    from fonbw.io import Record
    from fonbw.signals import eq19_input

    # k_h ρ > 0: the truth's one-step slope never falls below g'(120 V) = 0.102 µm/V,
    # above the constraint's 0.3 × the data's gain, so the constraint must not bias the fit
    truth = NBW(ku=[0.15, -2e-4], kh=3.0, rho=0.03, sigma=0.7, n=1.3)
    dt, noise = 5e-3, 0.02
    u = eq19_input(1.0 / dt, 8.0)[1]
    y = truth.simulate(u, dt) + noise * np.random.default_rng(3).standard_normal(u.size)
    rec = Record.from_arrays(u=u, y=y, dt=dt)
    ok, smin, _ = check_invertible(truth, 1e-4, u, dt_states=dt, margin=0.3 * 0.2)
    assert ok
    res = identify(rec, "nbw", N=2, seed=2, max_evals=1500, for_compensation=1e-4)
    p = res.params
    np.testing.assert_allclose([p["ku1"], p["kh"], p["rho"], p["sigma"], p["n"]],
                               [0.15, 3.0, 0.03, 0.7, 1.3], rtol=0.05)
    assert res.rms < 1.01 * noise
    inv = res.model.meta["invertibility"]
    assert inv["dt"] == 1e-4 and inv["margin"] >= 0.3 - 1e-9


def test_started_stepper_is_the_batch_run_and_rolls_back():
    from fonbw.compensate.rest import REST_PARAMETERS, rest_start_meta, rest_values, start_from_values, started_stepper

    m = _minimum_phase()
    assert type(started_stepper(m, DT)) is type(m.stepper(DT))  # no start recorded: the plain stepper
    m.meta = {"u_range": [-10.0, 120.0], "start": rest_start_meta((-10.0, 120.0), T=0.1)}
    st = started_stepper(m, DT)
    u = 30 - 30 * np.cos(2 * np.pi * 7 * np.arange(400) * DT)
    got = np.array([st.step(v) for v in u[:200]])
    snap = st.get_state()
    tail = np.array([st.step(v) for v in u[200:]])
    st.set_state(snap)
    assert np.array_equal([st.step(v) for v in u[200:]], tail) and st.steps == 400
    pre = st.history
    y = m.simulate(np.concatenate([pre, u]), DT)
    assert np.max(np.abs(np.concatenate([got, tail]) - (y[pre.size:] - y[pre.size - 1]))) <= 1e-12
    # the FMU parameters carry the same start, and back
    vals = rest_values(m)
    assert [n for n, _, _ in REST_PARAMETERS] == ["rest_lo", "rest_hi", "rest_T"]
    assert vals == (-10.0, 120.0, 0.1) and start_from_values(*vals) == m.meta["start"]
    assert rest_values(_minimum_phase()) == (0.0, 0.0, 0.0) and start_from_values(0.0, 0.0, 0.0) is None
