"""Tests of the virtual PEA bench (fonbw.bench)."""
import math

import numpy as np
import pytest

from fonbw import bench as B
from fonbw import paper
from fonbw import signals as S
from fonbw import plant as P
from fonbw.io import read_record

FS = paper.FS


def _reference_hysteresis(v, params, dt, rate=True, asym=True):
    """Independent, plain-Python rate-dependent PI + polynomial."""
    r0 = np.asarray(params.thresholds, float)
    p = np.asarray(params.weights, float)
    z = list(r0)  # at rest after a previous cycle
    a = math.exp(-dt / params.rate_tau)
    alpha = params.rate_alpha if rate else 0.0
    vp, rf = 0.0, 0.0
    out = []
    for vk in v:
        rf = a * rf + (1 - a) * abs(vk - vp) / dt
        vp = vk
        s = 1 + alpha * rf
        for i in range(len(r0)):
            z[i] = max(vk - r0[i] * s, min(vk + r0[i] * s, z[i]))
        out.append(float(np.dot(p, z)) - float(np.dot(p, r0)))
    w = np.array(out)
    a1, a2, a3 = params.poly
    if asym:
        return a1 * w + a2 * w**2 + a3 * w**3
    return w * (a1 * 120 + a2 * 120**2 + a3 * 120**3) / 120


def _loop_metrics(bench, f, periods=3):
    """Loop width and asymmetry (fractions of stroke), fundamental phase [deg]."""
    _, u = S.sine_input(f, FS, periods=periods)
    y = bench.run(u, noiseless=True)
    n = int(round(FS / f))
    uu, yy, h = u[-n:], y[-n:], n // 2
    g = np.linspace(2, 118, 117)
    ya = np.interp(g, uu[: h + 1], yy[: h + 1])
    yd = np.interp(g, uu[h:][::-1], yy[h:][::-1])
    stroke = yy.max() - yy.min()
    width = (yd - ya).max() / stroke
    # a point-symmetric loop has y_asc(u) + y_desc(120 - u) = const
    asym = np.max(np.abs(ya + yd[::-1] - (ya[0] + yd[-1]))) / stroke
    e = np.exp(-2j * np.pi * np.arange(n) / n)
    phase = np.degrees(np.angle(np.sum(yy * e) / np.sum(uu * e)))
    return width, asym, phase, stroke


def test_ideal_bench_is_the_bare_operator():
    b = B.Bench.ideal()
    _, u = S.eq19_input(FS, T=1.5)
    y = b.run(u)
    assert np.array_equal(y, b.hysteresis(u))
    ref = _reference_hysteresis(u, b.params, b.dt)
    assert np.max(np.abs(y - ref)) < 1e-11
    b2 = B.Bench.ideal(rate_dependent=False, asymmetric=False)
    ref2 = _reference_hysteresis(u, b2.params, b2.dt, rate=False, asym=False)
    assert np.max(np.abs(b2.run(u) - ref2)) < 1e-11


def test_stroke_is_about_20_um_at_120_V():
    _, u = S.sine_input(1.0, FS, periods=2)
    y = B.Bench.ideal(rate_dependent=False).run(u)
    assert y.max() == pytest.approx(19.87, abs=0.05)  # a1*120 + a2*120² + a3*120³
    assert y[0] == pytest.approx(0.0, abs=1e-12)  # zeroed at rest


def test_reproducible_for_a_seed():
    _, u = S.sine_input(5.0, FS, periods=2)
    y1, y2 = B.Bench(seed=7).run(u), B.Bench(seed=7).run(u)
    assert np.array_equal(y1, y2)
    assert not np.array_equal(y1, B.Bench(seed=8).run(u))
    b = B.Bench(seed=7)
    first, second = b.run(u), b.run(u)
    assert np.array_equal(first, y1) and not np.array_equal(first, second)


def test_noise_std_matches_configuration():
    b = B.Bench(seed=1, noise_std=0.02, drift=True)
    u = np.full(200_000, 60.0)
    e = b.run(u) - b.run(u, noiseless=True)
    # std error of a std estimate is σ/sqrt(2n) = 0.16 %; quantization adds q²/12
    assert np.std(e) == pytest.approx(math.hypot(0.02, b.adc_step / math.sqrt(12)), rel=0.01)
    assert abs(np.mean(e)) < 5 * 0.02 / math.sqrt(u.size)


def test_quantization_step_is_range_over_2_to_bits():
    b = B.Bench.ideal(quant_bits=8, noise_std=0.005, seed=3)
    lo, hi = b.params.adc_range
    q = (hi - lo) / 2**8
    assert b.adc_step == q
    _, u = S.sine_input(10.0, FS, periods=1)
    y = b.run(u)
    codes = (y - lo) / q
    assert np.max(np.abs(codes - np.round(codes))) < 1e-9
    steps = np.diff(np.unique(y))
    assert steps.min() == pytest.approx(q, rel=1e-9)
    assert B.Bench().adc_step == pytest.approx(80.0 / 65536, rel=1e-15)


def test_saturation_is_honoured():
    b = B.Bench(seed=0)
    _, u = S.sine_input(5.0, FS, periods=2, amplitude=90.0)  # -30 … 150 V commanded
    v = b.actuator_voltage(u)
    assert v.max() <= 120.0 + 1e-9 and v.min() >= -1e-9
    assert np.array_equal(b.run(u, noiseless=True), b.run(np.clip(u, 0, 120), noiseless=True))
    assert b.run(u, noiseless=True).max() < 21.0


def test_loop_is_asymmetric_and_rate_dependent():
    ideal = B.Bench.ideal()
    w1, a1, p1, _ = _loop_metrics(ideal, 1.0)
    w20, a20, p20, _ = _loop_metrics(ideal, 20.0)
    # rate dependence of the operator alone: the loop opens by ~16 % from 1 to 20 Hz
    assert w20 / w1 == pytest.approx(1.16, abs=0.03)
    assert p20 < p1 - 0.5
    # a rate-independent operator gives the same loop at every frequency
    ri = B.Bench.ideal(rate_dependent=False)
    w1r, _, _, _ = _loop_metrics(ri, 1.0)
    w20r, _, _, _ = _loop_metrics(ri, 20.0)
    assert w20r / w1r == pytest.approx(1.0, abs=2e-3)
    # asymmetry comes from the output polynomial: ~6 % of stroke vs ~0
    assert a1 > 0.04 and a20 > 0.04
    sym = B.Bench.ideal(asymmetric=False)
    assert _loop_metrics(sym, 1.0)[1] < 1e-3
    # the full bench (creep, amplifier, mechanics, delay) lags more at 20 Hz
    full = B.Bench()
    wf1, _, pf1, _ = _loop_metrics(full, 1.0)
    wf20, _, pf20, _ = _loop_metrics(full, 20.0)
    assert wf20 / wf1 > 1.3
    assert pf20 < p20 - 1.0


def test_creep_step_and_hold_matches_closed_form():
    t, u = S.step_hold_input(levels=(60.0,), hold=10.0, fs=FS, rest=0.1)
    b = B.Bench(seed=0)
    y = b.run(u, noiseless=True)
    yh = b.hysteresis(b.actuator_voltage(u))[-1]  # quasi-static level after the step
    t1, t2 = 0.5, t[-1] - 0.1  # times after the step
    i1, i2 = int(round((0.1 + t1) * FS)), int(round((0.1 + t2) * FS))
    tau, g = np.array(b.params.creep_tau), np.array(b.params.creep_gain)
    expected = yh * np.sum(g * (np.exp(-t1 / tau) - np.exp(-t2 / tau)))
    assert expected == pytest.approx(0.11, abs=0.01)  # about 1.2 % of the 9.2 µm step
    assert y[i2] - y[i1] == pytest.approx(expected, rel=0.03)
    y0 = B.Bench(seed=0, creep=False).run(u, noiseless=True)
    assert abs(y0[i2] - y0[i1]) < 1e-3


def test_delay_shifts_by_whole_samples():
    _, u = S.sine_input(10.0, FS, periods=1)
    y0 = B.Bench.ideal().run(u)
    y3 = B.Bench.ideal(delay=3).run(u)
    assert np.array_equal(y3[3:], B.Bench.ideal().run(u[:-3]))
    assert np.all(y3[:3] == 0.0) and not np.array_equal(y0, y3)


def test_amplifier_and_mechanics_are_the_plant_blocks():
    # step response of the amplifier inside the bench = python-control block
    b = B.Bench.ideal(amplifier=True)
    u = np.full(200, 60.0)
    v = b.actuator_voltage(u)
    ref = P.LinearStepper(P.amplifier(), b.dt).simulate(u / 12.0)
    assert np.max(np.abs(v - ref)) < 1e-12
    tau = P.R_OUT * P.C_LOAD
    k = np.arange(200)
    assert np.max(np.abs(v - 60 * (1 - np.exp(-k * b.dt / tau)))) < 1e-9


def test_inputs():
    t, u = S.eq19_input(FS, T=20.0)
    assert t.size == 200_000 and t[1] == pytest.approx(1e-4)
    assert u[0] == pytest.approx(60 * (math.cos(-3.15) + 1))
    assert u.max() <= 120.0 and u.min() >= 0.0
    assert u[-2000:].max() < 120 * math.exp(-0.13 * 19.8) + 1e-9
    t, u = S.sine_input(20.0, FS, periods=5)
    assert t.size == 2500 and u[0] == 0.0 and u[250] == pytest.approx(120.0)
    _, m = S.multi_input(fs=FS)
    assert m[0] == 0.0 and m.min() >= -1e-12 and m.max() <= 120.0
    with pytest.raises(ValueError, match="positive"):
        S.sine_input(-1.0)


def test_write_experiments_and_read_back(tmp_path):
    b = B.Bench(seed=2)
    paths = b.write_experiments(tmp_path, T_eq19=2.0, periods=2, logger=True)
    names = [p.split("/")[-1] for p in paths]
    assert names[:6] == ["eq19.csv", "sine_01hz.csv", "sine_05hz.csv", "sine_10hz.csv",
                         "sine_15hz.csv", "sine_20hz.csv"]
    assert "logger_bipolar.csv" in names
    rec = read_record(paths[0])
    assert rec.n == 20_000 and rec.dt == pytest.approx(1e-4)
    assert np.allclose(rec.u, S.eq19_input(FS, 2.0)[1], rtol=1e-15, atol=0)
    assert 15 < rec.y.max() < 21
    log = read_record(paths[-1])  # jittered time stamps are within tolerance
    assert log.u.min() == pytest.approx(-150.0) and log.u.max() == pytest.approx(150.0)
    rest = log.y[: int(0.5 * FS)]
    assert np.mean(rest) == pytest.approx(0.8, abs=0.01)
    assert log.t[0] == pytest.approx(12.3456, abs=1e-7)
    assert np.std(np.diff(log.t) - 1e-4) > 0


def test_validation_messages():
    with pytest.raises(ValueError, match="not finite"):
        B.Bench().run(np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match="u_min < u_max"):
        B.Bench(u_min=-200.0)
    with pytest.raises(ValueError, match="delay"):
        B.Bench(delay=1.5)
    with pytest.raises(ValueError, match="thresholds"):
        B.BenchParams(thresholds=[-1.0, 2.0])
    with pytest.raises(ValueError, match="weights"):
        B.BenchParams(thresholds=[0.0, 2.0], weights=[1.0, -0.1])
    with pytest.raises(ValueError, match="jitter"):
        B.Bench().logger_record(np.zeros(10), jitter=0.5)


def test_stepper_equals_run_bit_for_bit():
    _, u = S.eq19_input(FS, T=0.3)
    u = u * 1.1  # into saturation too
    for kw in ({}, {"drift": True, "delay": 3, "params": B.BenchParams(slew_rate=2e5)},
               {"rate_dependent": False, "asymmetric": False, "quant_bits": 10}):
        y = B.Bench(seed=4, **kw).run(u)
        st = B.Bench(seed=4, **kw).stepper()
        assert np.array_equal(y, [st.step(v) for v in u]), kw


def test_stepper_state_replays():
    st = B.Bench(seed=5, delay=2).stepper()
    _, u = S.sine_input(10.0, FS, periods=1)
    for v in u[:400]:
        st.step(v)
    s = st.get_state()
    a = [st.step(v) for v in u[400:]]
    st.set_state(s)
    assert a == [st.step(v) for v in u[400:]]


def test_slew_limit_and_drift():
    b = B.Bench.ideal(params=B.BenchParams(slew_rate=1e5))  # 10 V per sample
    v = b.actuator_voltage(np.full(20, 60.0))
    assert np.allclose(v[:6], [10, 20, 30, 40, 50, 60]) and np.all(v[6:] == 60.0)
    d = B.Bench.ideal(drift=True)
    y = d.run(np.zeros(50_000))  # no input: drift alone
    t = np.arange(50_000) / FS
    pr = d.params
    assert np.allclose(y, pr.drift_rate * pr.drift_tau * (1 - np.exp(-t / pr.drift_tau)), atol=1e-12)
    assert y[-1] == pytest.approx(0.0484, abs=1e-3)  # 0.01 µm/s for 5 s, slightly bent


def test_pi_loop_around_the_bench_tracks():
    b = B.Bench(seed=6)
    d = P.design_pi(P.pea_dynamics(), b.dt, 100.0)
    c = d.controller(u_min=0.0, u_max=120.0)
    st = b.stepper()
    t, _ = S.sine_input(1.0, FS, periods=2)
    r = 10.0 - 8.0 * np.cos(2 * np.pi * t)
    y = np.empty_like(r)
    yk = 0.0
    for k in range(r.size):
        y[k] = yk  # measurement of the previous sample: one-sample loop delay
        yk = st.step(c.step(r[k], yk))
    err = (y - r)[int(FS):]  # second period
    # open loop the hysteresis alone leaves errors of ~1.5 µm; the 100 Hz
    # loop has ~60x gain at 1 Hz
    assert np.sqrt(np.mean(err**2)) < 0.1
