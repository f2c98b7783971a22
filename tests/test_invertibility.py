"""One-step slope, invertibility warnings and model-derived voltage limits."""
import warnings

import numpy as np
import pytest

from fonbw.compensate import compensate, default_limits
from fonbw.hysteresis import FONBW
from fonbw.invertibility import check_invertible, one_step_slope

DT = 2e-4
T = np.arange(2500) * DT


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
