"""Tests of fonbw.plant against python-control and closed forms."""
import math

import control as ct
import numpy as np
import pytest

from fonbw import plant as P

DT = 1e-4


def _forced(sysd, u):
    t = np.arange(len(u)) * sysd.dt
    return np.squeeze(ct.forced_response(sysd, T=t, U=u).outputs)


def test_dc_gains_match_closed_forms():
    assert ct.dcgain(P.amplifier()) == pytest.approx(12.0, rel=1e-14)
    assert ct.dcgain(P.mechanics(dc_gain=0.7)) == pytest.approx(0.7, rel=1e-12)
    assert ct.dcgain(P.sensor()) == pytest.approx(1.0, rel=1e-14)
    assert ct.dcgain(P.pea_dynamics(k_pea=0.2)) == pytest.approx(0.2, rel=1e-9)
    assert ct.dcgain(P.pea_dynamics(k_pea=0.2, input="daq")) == pytest.approx(2.4, rel=1e-9)


def test_amplifier_bandwidth_is_one_over_2pi_rc():
    R, C = 50.0, 2e-6
    amp = P.amplifier(gain=12.0, R_out=R, C_load=C)
    fc = 1.0 / (2 * math.pi * R * C)
    mag = abs(complex(np.squeeze(amp(2j * math.pi * fc))))
    assert mag == pytest.approx(12.0 / math.sqrt(2), rel=1e-12)


def test_resonance_from_damp():
    wn, zeta, _ = ct.damp(P.mechanics(f_res=1234.0, zeta=0.07), doprint=False)
    assert wn / (2 * math.pi) == pytest.approx([1234.0, 1234.0], rel=1e-12)
    assert zeta == pytest.approx([0.07, 0.07], rel=1e-12)
    # the series chain keeps every pole where its blocks put it
    wn, zeta, _ = ct.damp(P.pea_dynamics(), doprint=False)
    f = sorted(wn / (2 * math.pi))
    assert f == pytest.approx(sorted([P.F_RES, P.F_RES, P.SENSOR_BW, 1 / (2 * math.pi * P.R_OUT * P.C_LOAD)]), rel=1e-9)


def test_stepper_equals_forced_response_and_batch():
    st = P.LinearStepper(P.pea_dynamics(), DT)
    rng = np.random.default_rng(1)
    u = rng.uniform(0, 120, 3000)
    y_batch = st.simulate(u)
    y_ref = _forced(st.sys, u)
    assert np.max(np.abs(y_batch - y_ref)) <= 1e-12 * max(1.0, np.max(np.abs(y_ref)))
    y_step = np.array([st.step(v) for v in u])
    assert np.array_equal(y_step, y_batch)


def test_stepper_with_feedthrough_follows_y_equals_cx_plus_du():
    # a lead filter has D != 0: y_k must use u_k of the same sample
    sysd = ct.c2d(ct.tf([1.0, 100.0], [1.0, 1000.0]), DT)
    st = P.LinearStepper(sysd)
    assert st.D[0, 0] != 0
    u = np.sin(np.arange(500) * 0.05)
    assert np.max(np.abs(st.simulate(u) - _forced(sysd, u))) <= 1e-12


def test_state_roundtrip_replays_bit_for_bit():
    st = P.LinearStepper(P.pea_dynamics(), DT)
    u = np.linspace(0, 100, 400)
    for v in u[:200]:
        st.step(v)
    saved = st.get_state()
    a = [st.step(v) for v in u[200:]]
    st.set_state(saved)
    b = [st.step(v) for v in u[200:]]
    assert a == b
    assert np.array_equal(st.simulate(u[200:], x0=saved), np.array(a))
    st.reset()
    assert np.all(st.get_state() == 0)


def test_stepper_validation():
    with pytest.raises(ValueError, match="dt is required"):
        P.LinearStepper(P.sensor())
    with pytest.raises(ValueError, match="differs"):
        P.LinearStepper(ct.c2d(P.sensor(), 1e-3), dt=1e-4)
    with pytest.raises(ValueError, match="SISO"):
        P.LinearStepper(ct.rss(2, 2, 1))
    with pytest.raises(ValueError, match="positive"):
        P.amplifier(R_out=-1)
    with pytest.raises(ValueError, match="entries"):
        P.LinearStepper(P.sensor(), DT).set_state([1.0, 2.0])


def test_pid_linear_part_equals_c2d_terms():
    for integ in ("forward", "backward", "tustin"):
        c = P.pid_controller(0.3, 800.0, 2e-4, DT, u_min=-1e9, u_max=1e9, integrator=integ)
        e = np.random.default_rng(2).normal(size=400)
        u = np.array([c.step(v) for v in e])
        ref = _forced(c.to_tf(), e)
        assert np.max(np.abs(u - ref)) <= 1e-9 * max(1.0, np.max(np.abs(ref))), integ


def test_closed_loop_equals_control_feedback():
    plant = P.pea_dynamics()
    pst = P.LinearStepper(plant, DT)
    d = P.design_pi(plant, DT, 100.0)
    c = d.controller(u_min=-1e9, u_max=1e9)  # no saturation
    n = 2000
    r = np.where(np.arange(n) > 50, 10.0, 0.0) + 2.0 * np.sin(np.arange(n) * 2 * np.pi * 30 * DT)
    # explicit loop: the plant has D = 0, so y_k is known before u_k
    x_y = np.empty(n)
    for k in range(n):
        yk = pst.output()
        u = c.step(r[k], yk)
        pst.step(u)
        x_y[k] = yk
    cl = ct.feedback(ct.series(c.to_tf(), pst.sys), 1)
    ref = _forced(cl, r)
    assert np.max(np.abs(x_y - ref)) <= 1e-9
    # and it tracks: the steady state error of the step part is small
    assert abs(x_y[-1] - r[-1]) < 1.0


@pytest.mark.filterwarnings("ignore:stability_margins")
def test_design_pi_hits_crossover_and_margins():
    plant = P.pea_dynamics()
    d = P.design_pi(plant, DT, 80.0)
    assert d.wcp / (2 * math.pi) == pytest.approx(80.0, rel=1e-3)
    # independent check of the reported margins on the same loop
    gm, pm, _, _ = ct.margin(d.loop)
    assert d.pm == pytest.approx(pm) and d.pm >= 45
    assert d.gm >= 2
    assert d.kp == pytest.approx(d.ki / (30 * 2 * math.pi * 80.0), rel=1e-12)
    with pytest.raises(ValueError, match="Nyquist"):
        P.design_pi(plant, DT, 6000.0)
    with pytest.raises(ValueError, match="lower bandwidth_hz"):
        P.design_pi(plant, DT, 100.0, zero_ratio=3.0)


def _saturating_run(anti_windup):
    # static plant y = 0.17 u with a first-order lag; the reference asks for
    # more than 120 V for 0.3 s and then drops to a reachable value
    plant = P.LinearStepper(ct.tf([0.17], [1 / (2 * math.pi * 200), 1]), DT)
    c = P.pi_controller(0.05, 400.0, DT, 0.0, 120.0, anti_windup=anti_windup)
    n = 6000
    r = np.where(np.arange(n) < 3000, 25.0, 10.0)
    y = np.empty(n)
    u = np.empty(n)
    for k in range(n):
        y[k] = plant.output()
        u[k] = c.step(r[k], y[k])
        plant.step(u[k])
    # first sample after the drop from which |y - 10| stays below 0.2 µm
    bad = np.flatnonzero(np.abs(y[3000:] - 10.0) > 0.2)
    settle = (bad[-1] + 1 if bad.size else 0) * DT
    return u, y, settle


def test_anti_windup_limits_and_recovery():
    u_none, _, t_none = _saturating_run("none")
    for aw in ("back-calculation", "clamping"):
        u, y, t_aw = _saturating_run(aw)
        assert u.min() >= 0.0 and u.max() <= 120.0
        assert u.max() == 120.0  # it did saturate
        # the linear loop needs ~4 time constants 1/(0.17 ki) = 60 ms to
        # settle; the wound-up one first has to unwind ~0.3 s of integral
        assert t_aw < 0.08, (aw, t_aw)
        assert t_aw < 0.5 * t_none, (aw, t_aw, t_none)
    assert u_none.max() == 120.0


def test_pid_state_roundtrip_and_validation():
    c = P.pid_controller(0.1, 500.0, 1e-4, DT)
    for e in np.linspace(1, -1, 50):
        c.step(e)
    s = c.get_state()
    a = [c.step(e) for e in np.linspace(0, 2, 30)]
    c.set_state(s)
    assert a == [c.step(e) for e in np.linspace(0, 2, 30)]
    with pytest.raises(ValueError, match="u_min < u_max"):
        P.pi_controller(1, 1, DT, 10, 0)
    with pytest.raises(ValueError, match="integrator"):
        P.pi_controller(1, 1, DT, integrator="rk4")
    with pytest.raises(ValueError, match="Tt"):
        P.pi_controller(1, 1, DT, Tt=DT / 2)
