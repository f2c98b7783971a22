"""Truth hysteresis cores of the blind gap harness (benchmarks/gap_cores.py),
each checked against a reference computed here by other means."""
import json
import math

import numpy as np
import pytest
from scipy import integrate

import gap_cores as gc

DT = 2e-4


def _ramp(points, n=400):
    """Piecewise-linear input through `points` [V], n samples per segment (ends included once)."""
    segs = [np.linspace(a, b, n + 1)[1:] for a, b in zip(points[:-1], points[1:])]
    return np.concatenate([[points[0]]] + segs)


def _density(a, b, comps):
    """μ(a, b) written out from the parameters, apart from the module's own evaluation."""
    if a < b:
        return 0.0
    s, d = a + b, a - b
    tot = 0.0
    for c in comps:
        ed = sum(cm * lam * math.exp(-lam * d) for cm, lam in c["terms"])
        z = (s - c["ms"] - c["kappa"] * d) / c["ss"]
        tot += 2.0 * c["w"] * ed * math.exp(-0.5 * z * z) / (c["ss"] * math.sqrt(2.0 * math.pi))
    return tot


# short tails (relay widths ≲ 20 V) so that a box of ±700 V holds the whole mass to 1e-14
COMPS = [
    {"w": 0.6, "terms": [[1.0, 1.0 / 12.0]], "ms": 100.0, "kappa": 0.3, "ss": 50.0},
    {"w": 0.4, "terms": [[1.5, 1.0 / 15.0], [-0.5, 3.0 / 15.0]], "ms": 160.0, "kappa": -0.4, "ss": 70.0},
]
LOW = -700.0


def _raw_core():
    return gc.PreisachCore({"density": COMPS, "gain": 1.0, "k1": 0.0, "k2": 0.0, "q": 0.0, "S": 1.0})


def _tri(alpha, beta):
    """∫∫ μ over β ≤ b ≤ a ≤ α by scipy dblquad."""
    val, _ = integrate.dblquad(lambda b, a: _density(a, b, COMPS), beta, alpha, lambda a: beta, lambda a: a,
                               epsabs=1e-13, epsrel=1e-11)
    return val


def test_preisach_first_ascending_branch_is_the_triangle_integral():
    core = _raw_core()
    u = np.linspace(-60.0, 130.0, 200)  # ascending from negative saturation
    P = core.raw(u)
    for k in (0, 90, 199):
        assert P[k] == pytest.approx(_tri(u[k], LOW), rel=1e-9, abs=1e-12)
    # and simulate() is that branch minus its value at 0 V, here gain 1 and no reversible part
    y = core.simulate(u, DT)
    assert y[199] == pytest.approx(_tri(130.0, LOW) - _tri(0.0, LOW), rel=1e-9)


def test_preisach_first_descending_branch_is_the_everett_triangle():
    core = _raw_core()
    M = 110.0
    u = np.concatenate([np.linspace(0.0, M, 300), np.linspace(M, 5.0, 300)[1:]])
    P = core.raw(u)
    for m in (80.0, 5.0):
        k = int(np.argmin(abs(u - m) + (np.arange(u.size) < 300) * 1e9))
        assert P[299] - P[k] == pytest.approx(_tri(M, u[k]), rel=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_preisach_wiping_out_minor_loops_close(seed):
    core = gc.draw_core("preisach", np.random.default_rng(seed))
    # 0 → 100 → 30 → 80 (reversal) → 50 → 80: back at the reversal point
    u = _ramp([0.0, 100.0, 30.0, 80.0, 50.0, 80.0])
    y = core.simulate(u, DT)
    i80 = 3 * 400
    assert u[i80] == u[-1] == 80.0
    assert abs(y[-1] - y[i80]) < 1e-10
    # going on to 90 V the minor loop is forgotten: the branch 30 → 90 of the major loop
    y_on = core.simulate(_ramp([0.0, 100.0, 30.0, 80.0, 50.0, 90.0]), DT)[-1]
    y_direct = core.simulate(_ramp([0.0, 100.0, 30.0, 90.0]), DT)[-1]
    assert abs(y_on - y_direct) < 1e-10
    # and a descending one: 80 → 40 (reversal) → 60 → 40
    u2 = _ramp([0.0, 100.0, 30.0, 80.0, 40.0, 60.0, 40.0])
    y2 = core.simulate(u2, DT)
    assert abs(y2[-1] - y2[4 * 400]) < 1e-10


def test_pi_single_play_identity_envelope_is_the_play():
    r = 17.5
    core = gc.PICore({"r": [r], "w": [1.0], "w0": 0.0, "envelope": {"kind": "identity"},
                      "Z": 1.0, "S": 1.0, "g0": 0.0, "gspan": 1.0})
    t = np.arange(20000) * DT
    u = 60.0 * np.sin(2 * np.pi * 2.0 * t) + 20.0 * np.sin(2 * np.pi * 7.0 * t)
    z, ref = 0.0, np.empty_like(u)
    for k, v in enumerate(u):
        z = max(v - r, min(v + r, z))
        ref[k] = z
    y = core.simulate(u, DT)
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-12)
    # on the steady sine loop the branches are u − r (ascending) and u + r (descending)
    assert np.max(np.abs(y - u)) == pytest.approx(r, abs=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_pi_envelope_is_increasing(seed):
    core = gc.draw_core("pi", np.random.default_rng(seed))
    z = np.linspace(-3.0, 3.0, 20001) * core.params["Z"]
    assert np.all(np.diff(core._out(z)) > 0)


def test_rate_element_matches_an_ode_integration():
    from scipy.integrate import solve_ivp

    r, tau, dt = 8.0, 2e-3, DT
    t = np.arange(501) * dt
    u = 50.0 - 50.0 * np.cos(2 * np.pi * 20.0 * t)
    y = gc._maxwell_slip(u, dt, np.array([r]), np.array([tau]), np.array([1.0]), 0.0)
    # the same element by a tight adaptive integration of dx/dt on the piecewise-linear input
    up = np.concatenate([[0.0], u])
    tp = np.concatenate([[-dt], t])

    def rhs(s, x):
        e = np.interp(s, tp, up) - x[0]
        return [math.copysign(max(abs(e) - r, 0.0), e) / tau]

    sol = solve_ivp(rhs, (-dt, t[-1]), [0.0], t_eval=t, method="DOP853", rtol=1e-12, atol=1e-12, max_step=dt / 4)
    np.testing.assert_allclose(y, sol.y[0], atol=2e-6)


def test_rate_loop_depends_on_frequency_and_slow_limit_is_rate_independent():
    core = gc.draw_core("rate", np.random.default_rng(4))
    m1, m20 = gc.loop_metrics(core, 1.0), gc.loop_metrics(core, 20.0)
    assert abs(m20["area"] / m1["area"] - 1.0) > 0.1
    assert m20["width_frac"] > m1["width_frac"]
    # slow limit: plays with the elements' thresholds, written out here
    p = core.params
    r, w = np.array(p["r"]), np.array(p["w"])

    def slow(u):
        zz = np.zeros(r.size)
        out = np.empty_like(u)
        for k, v in enumerate(u):
            zz = np.maximum(v - r, np.minimum(v + r, zz))
            out[k] = p["w0"] * v + w @ zz
        x = out / p["Z"]
        return p["S"] * (x + p["q"] * x * x) / (1.0 + p["q"])

    errs = []
    for f in (0.5, 0.05, 0.005):
        dt = 1e-3 / f  # 1000 samples per period: the element solution is exact for any step
        u = gc._sine(f, dt, periods=2)
        errs.append(np.max(np.abs(core.simulate(u, dt) - slow(u))))
    stroke = m1["stroke"]
    assert errs[2] < 2e-3 * stroke
    assert errs[2] < errs[1] < errs[0]
    # and the slow loop no longer changes with the rate
    a, b = gc.loop_metrics(core, 0.005, dt=0.2), gc.loop_metrics(core, 0.0025, dt=0.4)
    assert abs(a["area"] / b["area"] - 1.0) < 5e-3


@pytest.mark.parametrize("family", gc.FAMILIES)
def test_history_equals_tail_of_one_run(family):
    core = gc.draw_core(family, np.random.default_rng(11))
    rng = np.random.default_rng(5)
    t = np.arange(6000) * DT
    u = 60.0 - 55.0 * np.cos(2 * np.pi * 3.0 * t) + np.convolve(rng.standard_normal(t.size), np.ones(40) / 4, "same")
    hist, rec = gc.mid_drive_record(u, 2345)
    y_tail = core.simulate(u, DT)[2345:]
    y_rec = core.simulate(rec, DT, history=hist)
    assert np.array_equal(y_rec, y_tail)
    # and the state is not at rest: from rest the record differs
    assert np.max(np.abs(core.simulate(rec, DT) - y_tail)) > 1e-3
    # rebuilt from its JSON parameters, the core gives the same numbers
    again = gc.make_core(family, json.loads(json.dumps(core.params)))
    assert np.array_equal(again.simulate(u, DT), core.simulate(u, DT))


@pytest.mark.parametrize("family", gc.FAMILIES)
def test_draws_are_calibrated_and_reproducible(family):
    for seed in (21, 22):
        a = gc.draw_core(family, np.random.default_rng(seed))
        b = gc.draw_core(family, np.random.default_rng(seed))
        assert a.params == b.params and a.name == b.name
        m = gc.loop_metrics(a, 1.0, periods=2)
        assert 9.0 <= m["stroke"] <= 27.0
        assert 0.04 <= m["width_frac"] <= 0.22


@pytest.mark.parametrize("family", gc.FAMILIES)
def test_thirty_seconds_at_5khz_chirp_continues_across_a_split(family):
    # a long, fast record (the size the blind harness draws) stays finite, and
    # running it in two pieces with the first as history gives the same output
    # (its speed is measured in benchmarks, not asserted here)
    core = gc.draw_core(family, np.random.default_rng(2))
    t = np.arange(150000) * DT
    u = 60.0 - 60.0 * np.cos(2 * np.pi * (1.0 + 0.6 * t) * t)  # chirp 1 → 37 Hz
    y = core.simulate(u, DT)
    assert np.all(np.isfinite(y)) and np.ptp(y) > 1.0
    hist, tail = gc.mid_drive_record(u, 100000)
    np.testing.assert_array_equal(core.simulate(tail, DT, history=hist), y[100000:])


def test_clip_input_and_mid_drive_record():
    u = np.linspace(-200.0, 200.0, 4001)
    np.testing.assert_array_equal(gc.clip_input(u, -10.0, 130.0), np.clip(u, -10.0, 130.0))
    s = gc.clip_input(u, -10.0, 130.0, knee=3.0)
    assert np.all(np.diff(s) >= 0) and s.min() >= -10.0 and s.max() <= 130.0
    assert np.max(np.abs(s - u)[(u > 20) & (u < 100)]) < 1e-3  # untouched away from the rails
    h, rec = gc.mid_drive_record(u, 1000)
    np.testing.assert_array_equal(np.concatenate([h, rec]), u)
    assert h.size == 1000
    with pytest.raises(ValueError):
        gc.mid_drive_record(u, u.size + 1)
