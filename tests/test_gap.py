"""Tests of the gap diagnosis (fonbw.gap): effect blocks against independent
references, the noise-floor and localization helpers against closed forms, and
a small fixed-seed blind subset on the separate truth simulator."""
import argparse
import json
import math
import re

import control as ct
import numpy as np
import pytest

import gap_truth as tr
from fonbw import plant
from fonbw.gap import diagnose
from fonbw.gap import effects as fx
from fonbw.gap.checks import coverage, remaining
from fonbw.gap.filters import first_order
from fonbw.gap.fitter import Fitter, decimate
from fonbw.gap.localize import branch, localize, noise_floor, reversal_age
from fonbw.io import Record, write_csv

DT = 2e-4


def test_dynamics_block_equals_python_control_simulation():
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.standard_normal(3000)) * 0.01
    x[0] = 0.0
    eff = fx.Dynamics(DT)
    y = eff.output_op(x[None, :], DT, (350.0, 0.12))[0]
    sysd = ct.c2d(plant.mechanics(350.0, 0.12), DT, method="foh")
    ref = ct.forced_response(sysd, U=x).outputs
    assert np.max(np.abs(y - ref)) < 1e-10 * np.max(np.abs(ref))


def test_dynamics_block_keeps_rest_at_first_value():
    x = np.full(500, 3.0)
    y = fx.Dynamics(DT).output_op(x, DT, (300.0, 0.1))
    np.testing.assert_allclose(y, 3.0, rtol=0, atol=1e-12)


def test_delay_block_integer_and_fractional():
    x = np.arange(50, dtype=float) ** 2
    d = fx.Delay(DT)
    assert d.input_side
    y = d.transform_input(x, DT, (3 * DT,))
    np.testing.assert_array_equal(y[3:], x[:-3])
    np.testing.assert_array_equal(y[:3], x[0])
    ramp = 2.0 * np.arange(40.0)
    y = d.transform_input(ramp, DT, (2.5 * DT,))
    np.testing.assert_allclose(y[5:], ramp[5:] - 5.0, atol=1e-12)
    # a step delayed by half a sample is a two-sample ramp
    step = np.r_[np.zeros(5), np.full(5, 8.0)]
    np.testing.assert_allclose(d.transform_input(step, DT, (0.5 * DT,))[4:8], [0.0, 4.0, 8.0, 8.0])


def test_creep_columns_closed_form_step():
    # creep is the slow part of a step response; a mode needs records of half its length
    assert fx.Creep(DT, t_max=3.0).taus == (0.1, 1.0)
    c = fx.Creep(DT, t_max=6.0)
    assert c.taus == (0.1, 1.0, 10.0)
    h = np.r_[0.0, np.ones(999)]
    C = c.columns({"y_ref": h, "dt": DT, "t": np.arange(1000) * DT}, ())
    k = np.arange(1000)
    for j, tau in enumerate(c.taus):
        a = math.exp(-DT / tau)
        # implicit Euler step response: 1 − a^k, so the column is −a^k after the step
        np.testing.assert_allclose(C[1:, j], -a ** k[1:], rtol=1e-12, atol=1e-14)
    # the logarithmic law: half-decade modes from 10 ms to 10 s, weight 1/2 each
    taus = 10.0 ** np.arange(-2.0, 1.01, 0.5)
    np.testing.assert_allclose(c.log_taus, taus, rtol=1e-12)
    law = -0.5 * sum(np.exp(-DT / tau) ** k[1:] for tau in taus)
    np.testing.assert_allclose(C[1:, 3], law, rtol=1e-12, atol=1e-14)
    assert C.shape == (1000, 4) and c.lin_names[-1] == "gamma"
    # too short for two of the law's modes: none, and no gain for it
    short = fx.Creep(DT, t_max=0.04)
    assert short.log_taus == () and short.lin_names == ("g_0.01s",)
    assert short.columns({"y_ref": h, "dt": DT, "t": np.arange(1000) * DT}, ()).shape == (1000, 1)
    # at 1 kHz twenty samples are 20 ms: the law starts at the next grid mode
    assert fx.Creep(1e-3, t_max=6.0).log_taus[0] == pytest.approx(10 ** -1.5, rel=1e-12)


def test_creep_law_recovers_a_logarithmic_creep():
    # truth: a logarithmic creep of γ per decade as a continuum of modes from
    # 1 ms to 100 s (40 a decade, bilinear), as a stack creeps from its first
    # milliseconds, on steps held 3 s and a 5-Hz sine; the block finds γ,
    # and its free modes alone cannot follow the decades under 0.1 s. (A
    # continuum cut off at 10 ms, the law's first mode, reads 22 % low: that
    # mode stands for the quarter decade under it too.)
    from scipy import signal

    rng = np.random.default_rng(3)
    n = int(12.0 / DT)
    t = np.arange(n) * DT
    h = np.select([t < 3, t < 6, t < 9], [0.0, 8.0, 3.0], 5 + 4 * np.sin(2 * np.pi * 5 * (t - 9)))
    lag = np.zeros(n)
    for tau in 10.0 ** np.linspace(-3.0, 2.0, 201):
        b, a = signal.bilinear([1.0], [tau, 1.0], fs=1 / DT)
        lag += (signal.lfilter(b, a, h) - h) / 40
    c = fx.Creep(DT, 12.0)
    C = c.columns({"y_ref": h, "dt": DT, "t": t}, ())
    noise = 0.002
    for gamma in (0.01, 0.05):
        y = h + gamma * lag + rng.normal(0.0, noise, n)
        A = np.column_stack([h, np.ones(n), C])
        b, r = Fitter.fit_linear(A, y, nonneg=[2, 3, 4, 5])
        assert b[5] == pytest.approx(gamma, rel=0.05)
        _, r3 = Fitter.fit_linear(A[:, :5], y, nonneg=[2, 3, 4])
        rms, rms3 = np.sqrt(np.mean(r ** 2)), np.sqrt(np.mean(r3 ** 2))
        assert rms < 0.6 * rms3
    assert rms < 3.5 * noise < 0.4 * rms3


def test_amplifier_block_filter_and_slew():
    amp = fx.Amplifier(DT, 120.0)
    u = np.r_[np.zeros(10), np.full(2000, 100.0)]
    fc = 200.0
    a = math.exp(-2 * math.pi * fc * DT)
    v = amp.transform_input(u, DT, (fc, 1e12))
    k = np.arange(1, 2001)
    np.testing.assert_allclose(v[10:], 100.0 * (1.0 - a ** k), rtol=1e-12)
    v = amp.transform_input(u, DT, (fc, 1e5))
    assert np.max(np.diff(v)) <= 1e5 * DT * (1 + 1e-12)
    assert v[-1] == pytest.approx(100.0, rel=1e-9)


def test_amplifier_with_its_own_pole_is_the_two_stage_cascade():
    # without a slew limit the block is two implicit first-order stages:
    # (1 - a1)(1 - a2) / ((1 - a1 z^-1)(1 - a2 z^-1)), started at rest at u_0
    from scipy import signal

    amp = fx.Amplifier(DT, 120.0).with_own_pole((200.0, 1e6))
    assert amp.names == ("f_c", "slew", "f_pole") and amp.units["f_pole"] == "Hz"
    # the grid splits the one-pole fit's lag 1/(2π·200 Hz) between the two
    # poles, the fitted slew limit kept: the lags add up to it on every row
    assert amp.grid.shape == (len(fx.POLE_SHARES), 3) and np.all(amp.grid[:, 1] == 1e6)
    np.testing.assert_allclose(1.0 / amp.grid[:, 0] + 1.0 / amp.grid[:, 2], 1.0 / 200.0, rtol=1e-12)
    np.testing.assert_allclose(200.0 / amp.grid[:, 2], fx.POLE_SHARES, rtol=1e-12)
    u = np.r_[np.full(10, 5.0), np.full(500, 100.0), np.full(500, -20.0)]
    a1, a2 = math.exp(-2 * math.pi * 200.0 * DT), math.exp(-2 * math.pi * 900.0 * DT)
    ref = 5.0 + signal.lfilter([(1 - a1) * (1 - a2)], np.convolve([1, -a1], [1, -a2]), u - 5.0)
    np.testing.assert_allclose(amp.transform_input(u, DT, (200.0, 1e12, 900.0)), ref, rtol=1e-12, atol=1e-9)
    # the pole at the top of its bounds (e^-2π of a step left after a sample)
    # is the one-pole block again, to within 0.2 % of the 120-V step
    one = fx.Amplifier(DT, 120.0).transform_input(u, DT, (200.0, 1e12))
    top = amp.bounds[2][1]
    assert np.max(np.abs(amp.transform_input(u, DT, (200.0, 1e12, top)) - one)) < 0.002 * 120.0
    # the slew limit acts on the RC stage, after the pole
    v = amp.transform_input(u, DT, (200.0, 1e5, 900.0))
    assert np.max(np.abs(np.diff(v))) <= 1e5 * DT * (1 + 1e-12)


def test_dynamics_block_fast_resonance_is_nearly_identity():
    x = np.r_[np.zeros(5), np.full(200, 10.0)]
    eff = fx.Dynamics(DT)
    y = eff.output_op(x, DT, (eff.bounds[0][1], 0.7))
    assert np.max(np.abs(y - x)) < 0.3 * 10.0   # no whole-sample delay at the step
    assert np.max(np.abs(y[20:] - 10.0)) < 1e-6


def test_resonance_is_identified_only_below_nyquist_and_inside_the_damping_bound():
    d = fx.Dynamics(DT)  # Nyquist 2500 Hz
    assert d.identified((400.0, 0.1))
    assert not d.identified((3000.0, 0.1))   # above Nyquist: a sub-sample lag
    assert not d.identified((400.0, d.bounds[1][1]))  # at the damping bound: does not ring
    assert fx.Delay(DT).identified((1e-4,)) and fx.Amplifier(DT, 120.0).identified((300.0, 1e5))


def test_saturation_and_drift_blocks():
    s = fx.Saturation(0.0, 20.0)
    y = np.array([0.0, 10.0, 16.0, 18.0, 30.0])
    C = s.columns({"y_ref": y}, (16.0, 0.5))
    np.testing.assert_allclose(C[:, 0], 0.5 * np.log1p(np.exp((y - 16.0) / 0.5)), rtol=1e-12)
    assert C[2, 0] == pytest.approx(0.5 * math.log(2.0), rel=1e-12)  # half the corner at the knee
    # a narrow corner is the hard knee (H − y_k)_+, without overflow far above it
    C = s.columns({"y_ref": y}, (16.0, 1e-4))
    np.testing.assert_allclose(C[:, 0], np.maximum(y - 16.0, 0.0), atol=1e-4)
    d = fx.Drift()
    C = d.columns({"t": np.array([0.0, 10.0, 20.0])}, ())
    np.testing.assert_array_equal(C, [[0, 0], [1, 1], [2, 4]])


def test_saturation_shape_slope_is_its_derivative():
    s = fx.Saturation(0.0, 20.0)
    z = np.linspace(10.0, 22.0, 241)
    th = (16.0, 0.4)
    f, df = s.shape(z, th)
    h = 1e-6
    fd = (s.shape(z + h, th)[0] - s.shape(z - h, th)[0]) / (2 * h)
    np.testing.assert_allclose(df, fd, rtol=0, atol=1e-8)
    assert df[0] < 1e-6 and df[-1] > 1 - 1e-6  # off below the knee, full slope above it


def test_knee_kernels_equal_their_numpy_forms():
    # the compiled softplus, residual and normal equations of the saturation
    # block against the same quantities written with numpy: far below the
    # knee (log1p skipped, then exp underflowing), at it, far above it
    from fonbw.gap import knee

    rng = np.random.default_rng(11)
    th = (16.0, 0.02)
    n = 5000
    B = np.asfortranarray(np.column_stack([rng.uniform(0.0, 1.0, n), rng.normal(size=n), np.ones(n)]))
    b = np.array([20.0, 0.3, -1.0, -0.6])
    z = B @ b[:-1]
    zs = z.copy()
    zs[:4] = [th[0] - 40.0, th[0], th[0] + 1e-3, th[0] + 30.0]  # s = −2000, 0, 0.05, 1500
    s = (zs - th[0]) / th[1]
    f, df = knee.softplus(zs, *th)
    np.testing.assert_allclose(f, th[1] * np.logaddexp(0.0, s), rtol=1e-15, atol=0.0)
    np.testing.assert_allclose(df, 0.5 * (1.0 + np.tanh(0.5 * s)), rtol=0.0, atol=1e-15)
    assert f[0] == 0.0 and f[1] == pytest.approx(th[1] * math.log(2.0), rel=1e-15)
    assert f[3] == pytest.approx(30.0, rel=1e-15) and df[3] == 1.0

    y = z + rng.normal(0.0, 0.01, n)
    r, f, df = np.empty(n), np.empty(n), np.empty(n)
    sse = knee.residual(B, b, y, *th, r, f, df)
    np.testing.assert_allclose(r, y - (z + b[-1] * th[1] * np.logaddexp(0.0, (z - th[0]) / th[1])),
                               rtol=0.0, atol=1e-12)
    assert sse == pytest.approx(float(r @ r), rel=1e-12)
    G, g = knee.normal_equations(B, b[-1], df, f, r)
    J = np.column_stack([B * (1.0 + b[-1] * df)[:, None], f])
    np.testing.assert_allclose(G, J.T @ J, rtol=1e-12)
    np.testing.assert_allclose(g, J.T @ r, rtol=1e-10, atol=1e-12 * float(np.abs(J).sum()))


def test_output_saturation_fit_equals_scipy_least_squares():
    # y = z + c f(z), z = B b: the Gauss-Newton solve of the fitter against
    # scipy's trust-region least squares on the same nonlinear problem
    from scipy.optimize import least_squares

    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 1.0, 4000)
    B = np.column_stack([np.sin(2 * np.pi * 3 * t), t, t * t, np.ones_like(t)])
    s = fx.Saturation(0.0, 20.0)
    th = np.array([12.0, 0.8])
    z = B @ np.array([8.0, 5.0, 2.0, 6.0])
    y = z - 0.7 * s.shape(z, th)[0] + rng.normal(0.0, 0.01, t.size)
    # started from a regressor driven by a wrong reference output, as in diagnose
    A = np.column_stack([B, s.shape(0.9 * z + 0.5, th)[0]])
    b, r = Fitter.fit_linear(A, y, (s, th))

    def res(p):
        zz = B @ p[:-1]
        return zz + p[-1] * s.shape(zz, th)[0] - y

    ref = least_squares(res, Fitter.solve(A, y)[0], xtol=1e-14, ftol=1e-14, gtol=1e-14)
    np.testing.assert_allclose(b, ref.x, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(r, -ref.fun, atol=1e-9)
    np.testing.assert_allclose(Fitter.output(A, b, (s, th)), y - r, atol=1e-12)
    assert b[-1] == pytest.approx(-0.7, abs=0.01)


def test_a_stroke_limit_only_lowers_the_slope_at_most_to_flat():
    # data whose top steepens (c = +0.5): the bounded optimum is c = 0; data
    # whose top turns back (c = -1.6): c = -1, a flat top. scipy's bounded
    # least squares confirms both; a compressive top keeps its c
    from scipy.optimize import least_squares

    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 1.0, 3000)
    B = np.column_stack([np.sin(2 * np.pi * 2 * t), t, np.ones_like(t)])
    s = fx.Saturation(0.0, 20.0)
    th = np.array([11.0, 1.0])
    z = B @ np.array([6.0, 4.0, 7.0])
    A = np.column_stack([B, s.shape(z, th)[0]])

    def res(p, y):
        zz = B @ p[:-1]
        return zz + p[-1] * s.shape(zz, th)[0] - y

    for c_true, c_fit in ((0.5, 0.0), (-0.4, -0.4), (-1.6, -1.0)):
        y = z + c_true * s.shape(z, th)[0] + rng.normal(0.0, 0.01, t.size)
        b, r = Fitter.fit_linear(A, y, (s, th))
        x0 = np.r_[Fitter.solve(B, y)[0], -0.1]
        ref = least_squares(res, x0, args=(y,), bounds=([-np.inf] * 3 + [-1.0], [np.inf] * 3 + [0.0]),
                            xtol=1e-14, ftol=1e-14, gtol=1e-14)
        if c_fit == -1.0:
            # a top that turns back is no flat top: the residual is large
            # (0.95 µm RMS), where Gauss-Newton converges linearly, so it is
            # given 30 steps (8 in the diagnosis: 1.1e-4 above the optimum's
            # sum of squares). Started from the plain least squares and from
            # just inside the bound (the last column scaled so that its
            # coefficient is c = −1 + 1e-9): a step that crosses the bound
            # must stop there; clipped at it instead, the fit from that start
            # stalls 14 % above the optimum
            assert ref.x[-1] == pytest.approx(-1.0, abs=1e-12)
            c_ls = Fitter.solve(A, y)[0][-1]
            for scale in (1.0, c_ls / (-1.0 + 1e-9)):
                b, r = Fitter.fit_linear(A * np.r_[1.0, 1.0, 1.0, scale], y, (s, th), iters=30)
                assert b[-1] == -1.0
                assert float(r @ r) == pytest.approx(2.0 * ref.cost, rel=1e-8)
                # the valley is flat along the base coefficients
                np.testing.assert_allclose(b, ref.x, atol=2e-4)
            continue
        np.testing.assert_allclose(b, ref.x, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(r, -ref.fun, atol=1e-8)
        assert b[-1] == (0.0 if c_fit == 0.0 else pytest.approx(c_fit, abs=0.01))


def test_a_stroke_limit_ahead_of_a_resonance_fit_equals_scipy_least_squares():
    # y = H[z + c f(z)] + d t, z = M b: the limit acts before the resonance H,
    # so the output rings past it at the steps. The fitter's Gauss-Newton
    # against scipy's trust-region least squares on the same problem; without
    # noise it finds the truth, where the limit after the resonance cannot
    from scipy.optimize import least_squares

    from fonbw.gap import prelimit

    rng = np.random.default_rng(8)
    dt, n = 2e-4, 6000
    t = np.arange(n) * dt
    u = np.where(t < 0.6, 60 - 60 * np.cos(2 * np.pi * 2 * t), np.where(t % 0.2 < 0.1, 110.0, 10.0))
    M = np.column_stack([u / 120, (u / 120) ** 2, np.sin(u / 40)])
    dyn, sat = fx.Dynamics(dt), fx.Saturation(0.0, 20.0)
    th_d, th = np.array([800.0, 0.1]), np.array([14.0, 0.2])

    def H(v):
        return dyn.output_op(np.atleast_2d(v), dt, th_d).reshape(np.shape(v))

    def model(p):
        z = M @ p[:3]
        return H(z + p[-1] * sat.shape(z, th)[0]) + p[3] * t

    truth = np.array([18.0, 2.0, 0.5, 0.3, -0.9])
    HM = H(M.T).T
    pre = prelimit.PreLimit(sat, th, M, H)
    for noise in (0.0, 0.01):
        y = model(truth) + rng.normal(0.0, noise, n)
        assert np.sum(y > 14.3) > 1000  # past the knee: the slope above it and the ringing
        # started from the limit driven by a wrong nominal output, as in diagnose
        A = np.column_stack([HM, t, H(sat.shape(0.97 * (M @ truth[:3]), th)[0])])
        b, r = Fitter.fit_linear(A, y, pre)
        np.testing.assert_allclose(Fitter.output(A, b, pre), y - r, atol=1e-12)
        if noise == 0.0:
            np.testing.assert_allclose(b, truth, rtol=1e-9)
            # the same limit after the resonance cannot follow the ringing
            _, r_after = Fitter.fit_linear(np.column_stack([HM, t, sat.shape(H(M @ truth[:3]), th)[0]]), y,
                                           (sat, th))
            assert math.sqrt(float(r_after @ r_after) / n) > 0.1
            continue
        ref = least_squares(lambda p: model(p) - y, Fitter.solve(A, y)[0], xtol=1e-14, ftol=1e-14, gtol=1e-14)
        np.testing.assert_allclose(b, ref.x, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(r, -ref.fun, atol=1e-8)  # 1e-6 of the noise
        # seen on a subset of the samples (a burn-in left out), the limit
        # filters the whole record first: scipy on the same rows
        idx = np.arange(1000, n)
        sub = Fitter.limit_on(pre, idx)
        np.testing.assert_allclose(Fitter.output(A[idx], b, sub), Fitter.output(A, b, pre)[idx], atol=1e-12)
        b_s, r_s = Fitter.fit_linear(A[idx], y[idx], sub)
        ref = least_squares(lambda p: model(p)[idx] - y[idx], Fitter.solve(A[idx], y[idx])[0],
                            xtol=1e-14, ftol=1e-14, gtol=1e-14)
        np.testing.assert_allclose(b_s, ref.x, rtol=1e-6, atol=1e-8)
        assert not np.allclose(b_s, b, rtol=1e-6, atol=1e-8)  # another fit than on every row
        # a gain bounded below by 0 among the filtered regressors (creep's): held
        # at 0, its regressor leaves the limit's too; scipy's bounded fit agrees
        yb = model(np.array([18.0, -2.0, 0.5, 0.3, -0.9])) + rng.normal(0.0, noise, n)
        b_b, _ = Fitter.fit_linear(A, yb, pre, nonneg=[1])
        lo, hi = [-np.inf, 0.0, -np.inf, -np.inf, -1.0], [np.inf, np.inf, np.inf, np.inf, 0.0]
        ref = least_squares(lambda p: model(p) - yb, np.clip(Fitter.solve(A, yb)[0], np.add(lo, 1e-9), hi),
                            bounds=(lo, hi), xtol=1e-14, ftol=1e-14, gtol=1e-14)
        assert b_b[1] == 0.0 and ref.x[1] == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(b_b, ref.x, rtol=1e-5, atol=1e-6)


def test_the_design_puts_a_stroke_limit_ahead_of_a_resonance():
    # beside a resonance the design's limit is a PreLimit: its regressors are
    # the design's without the resonance, its start column the resonance's
    # output of the usual one; without a resonance nothing changes
    from fonbw.gap.prelimit import PreLimit
    from fonbw.identify import search_space

    sc = tr.draw_scenario(5, "null", scale=0.25)
    recs = sc["train"]
    fit = Fitter(recs, search_space("fonbw", recs, N=3))
    sat, dyn = fx.Saturation(0.0, 20.0), fx.Dynamics(DT)
    X = np.array([[0.5, 0.5, 1.0, 1.0, 1.0]])
    th_s, th_d = np.array([[15.0, 0.5]]), np.array([[900.0, 0.2]])
    yref = [np.linspace(0.0, 17.0, len(r.u)) for r in recs]
    A0, o0 = fit.design_limit(recs, X, [sat], [th_s], yref)
    A1, o1 = fit.design_limit(recs, X, [dyn, sat], [th_d, th_s], yref)
    assert o0[0] is sat and not isinstance(o0, PreLimit) and isinstance(o1, PreLimit)
    np.testing.assert_array_equal(o1.M, A0[:, :-1])
    k = 0
    for r in recs:
        seg = slice(k, k + len(r.u))
        np.testing.assert_allclose(A1[seg].T, dyn.output_op(A0[seg].T, DT, th_d[0]), atol=1e-12)
        k += len(r.u)
    assert k == len(A1)


def test_creep_gains_are_bounded_below_by_zero():
    # a lead (g < 0) on two of three mode columns: the bounded fit matches
    # scipy's bounded linear least squares; with every g >= 0 the bound is
    # inactive and the fit is the plain one
    from scipy.optimize import lsq_linear

    rng = np.random.default_rng(11)
    t = np.linspace(0.0, 3.0, 4000)
    u = 50 + 40 * np.sin(2 * np.pi * 1.3 * t) + 10 * np.sign(np.sin(2 * np.pi * 0.4 * t))
    base = np.column_stack([u / 100, (u / 100) ** 2, np.ones_like(t)])
    modes = np.column_stack([first_order(u, np.exp(-(t[1] - t[0]) / tau)) - u for tau in (0.01, 0.1, 1.0)])
    A = np.column_stack([base, modes])
    nn = [3, 4, 5]
    for g in ([-0.1, 0.05, -0.03], [0.1, 0.05, 0.03]):
        y = base @ [10.0, 2.0, 0.5] + modes @ g + rng.normal(0.0, 0.01, t.size)
        b, r = Fitter.fit_linear(A, y, nonneg=nn)
        ref = lsq_linear(A, y, bounds=([-np.inf] * 3 + [0.0] * 3, [np.inf] * 6), tol=1e-14, lsmr_tol="auto")
        np.testing.assert_allclose(b, ref.x, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(r, y - A @ ref.x, atol=1e-9)
        assert np.all(b[nn] >= 0.0) and np.count_nonzero(b[nn] == 0.0) == sum(v < 0 for v in g)
        if min(g) >= 0:
            np.testing.assert_array_equal(b, Fitter.solve(A, y)[0])
    assert fx.Creep(DT, 3.0).lin_nonneg and not fx.Drift().lin_nonneg


def test_solve_leaves_an_unexcited_regressor_at_zero():
    rng = np.random.default_rng(4)
    A = np.column_stack([rng.standard_normal(500), np.ones(500), np.full(500, 1e-300)])
    y = A[:, 0] * 2.0 + 1.0
    b, r = Fitter.solve(A, y)
    np.testing.assert_allclose(b, [2.0, 1.0, 0.0], atol=1e-12)
    assert np.max(np.abs(r)) < 1e-12


def test_linear_parameters_are_read_in_design_column_order():
    # drift's regressors are not filtered and go after creep's, and the output
    # nonlinearity goes last, whatever the order of the effects
    from fonbw.identify import search_space

    sc = tr.draw_scenario(5, "null", scale=0.25)
    fit = Fitter(sc["train"], search_space("fonbw", sc["train"], N=3))
    effs = [fx.Saturation(0.0, 20.0), fx.Drift(), fx.Creep(DT, 6.0)]
    sl = fit.lin_slices(effs)
    assert [(x.start, x.stop) for x in sl] == [(10, 11), (8, 10), (4, 8)]
    assert fit.nonneg(effs) == [4, 5, 6, 7]  # creep's gains
    X = np.array([[0.5, 0.5, 1.0, 1.0, 1.0]])
    TH = [np.array([[15.0, 0.5]]), np.zeros((1, 0)), np.zeros((1, 0))]
    yref = [np.linspace(0.0, 17.0, len(r.u)) for r in sc["train"]]
    A = fit.design(sc["train"], X, effs, TH, yref)[0]
    assert A.shape[1] == 11
    np.testing.assert_array_equal(A[:, 10], np.concatenate([effs[0].shape(y, (15.0, 0.5))[0] for y in yref]))
    t = np.concatenate([np.arange(len(r.u)) * DT for r in sc["train"]]) / 10.0
    np.testing.assert_array_equal(A[:, 8], t)
    beta = np.arange(11.0)
    p = fit.effect_params({"x": X[0], "th": [t[0] for t in TH], "beta": beta}, effs)
    assert p["saturation"]["c"] == 10.0 and p["drift"] == {"d1_um": 8.0, "d2_um": 9.0}
    assert p["creep"] == {"g_0.1s": 4.0, "g_1s": 5.0, "g_10s": 6.0, "gamma": 7.0}


def test_noise_floor_ignores_low_frequencies_and_transients():
    rng = np.random.default_rng(1)
    n = 40000
    t = np.arange(n) * DT
    sig = 0.02
    r = rng.normal(0, sig, n) + 0.5 * np.sin(2 * np.pi * 3 * t)
    r[10000:10040] += np.linspace(1.0, 0.0, 40)  # a model transient at a step edge
    assert math.sqrt(noise_floor([r], DT)) == pytest.approx(sig, rel=0.05)


def _tone_case(rng, line_amp, harmonic_in_model):
    """A 1-Hz drive whose model output (10 µm swing, a 9th harmonic of 0.3 µm)
    leaves white noise (σ = 0.01 µm), a shape misfit at the 9th harmonic
    (0.05 µm) and a 50-Hz line of amplitude `line_amp` [µm]."""
    from fonbw.gap.localize import tones

    t = np.arange(50_000) * DT   # 10 s at 5 kHz: 1-Hz bins
    h9 = np.sin(2 * np.pi * 9 * t)
    pred = 5 - 5 * np.cos(2 * np.pi * t) + (0.3 * h9 if harmonic_in_model else 0.0)
    y = pred + 0.05 * h9 + line_amp * np.sin(2 * np.pi * 50 * t + 0.4) + rng.normal(0, 0.01, t.size)
    rec = Record.from_arrays(u=12 * pred, y=y, dt=DT)
    excess = 0.05 ** 2 / 2 + line_amp ** 2 / 2
    return tones([rec], [pred], DT, 0.01 ** 2), excess


def test_a_line_the_model_does_not_make_is_named_with_its_share_of_what_is_left():
    rng = np.random.default_rng(5)
    found, excess = _tone_case(rng, 0.1, harmonic_in_model=True)
    # the 50-Hz line holds 0.005 of the 0.00625 µm² left; the 9th harmonic's
    # misfit is a line too, but the model's output carries 36 times its power there
    assert [t["hz"] for t in found] == [50.0]
    assert found[0]["share"] == pytest.approx((0.1 ** 2 / 2) / excess, abs=0.01)
    # without the harmonic in the model's output the misfit (0.2 of what is left) is named as well
    found, excess = _tone_case(rng, 0.1, harmonic_in_model=False)
    assert [t["hz"] for t in found] == [50.0, 9.0]
    assert found[1]["share"] == pytest.approx((0.05 ** 2 / 2) / excess, abs=0.01)
    # a line under a tenth of what is left is not
    found, _ = _tone_case(rng, 0.015, harmonic_in_model=True)
    assert found == []
    # the verdict says so where the gap is left unexplained
    from fonbw.gap.selection import verdict

    kw = dict(mse0=0.01, excess0=0.0099, at_floor=False, coverage=[], params={},
              steps=[{"label": "nominal", "rms_validate": 0.1}])
    v = verdict([], mse=0.009, tones=[{"hz": 50.0, "share": 0.8}], **kw)
    assert v["tones"] == [{"hz": 50.0, "share": 0.8}]
    assert "a narrow line the model's own output lacks holds 80 % of what is left at 50 Hz" in v["message"]
    assert "narrow line" not in verdict([], mse=0.009, **kw)["message"]


def test_branch_and_reversal_age_on_triangle():
    u = np.r_[np.linspace(0, 1, 11), np.linspace(0.9, 0, 10), np.zeros(5)]
    s = branch(u)
    assert list(s[1:11]) == [1] * 10 and list(s[11:21]) == [-1] * 10 and list(s[21:]) == [0] * 5
    age = reversal_age(u, 0.5)
    assert age[10] == pytest.approx(5.0)   # from t = 0 (no reversal yet)
    assert age[11] == 0.0                  # reversal at sample 11
    assert age[-1] == pytest.approx(0.5 * (len(u) - 1 - 11))  # holds do not reset it


def test_localize_flags_rate_dependent_residual():
    t = np.arange(20000) * DT
    u = 60 - 60 * np.cos(2 * np.pi * 2 * t)
    rate = np.gradient(u, DT)
    rng = np.random.default_rng(2)
    y = 1e-4 * rate + rng.normal(0, 0.01, t.size)  # error grows with the input rate
    rec = Record.from_arrays(u=u, y=y, dt=DT)
    loc = localize([rec], [np.zeros_like(u)], DT, 1e-4)
    assert loc["dominant"] in ("input_rate", "branch")
    assert loc["features"]["branch"]["eta2"] > 0.5
    rr = loc["records"][0]
    assert rr["rms"] == pytest.approx(math.sqrt(np.mean(y ** 2)))
    assert rr["rms_pct_range"] == pytest.approx(100 * rr["rms"] / np.ptp(y))


def test_coverage_flags_faster_validation():
    t = np.arange(10000) * DT
    slow = Record.from_arrays(u=60 - 60 * np.cos(2 * np.pi * 1 * t), y=np.zeros(t.size), dt=DT)
    fast = Record.from_arrays(u=60 - 60 * np.cos(2 * np.pi * 20 * t), y=np.zeros(t.size), dt=DT)
    flags = {f["condition"] for f in coverage([slow], [fast], DT)}
    assert {"rate_p99", "f95"} <= flags
    assert coverage([fast], [slow], DT) == []


def test_coverage_flags_a_hold_longer_than_the_trainings():
    def held(n, k):
        # a 1-Hz sine with its input held for k sample steps from sample 300 on
        u = 60 - 60 * np.cos(2 * np.pi * np.arange(n) * DT)
        u[300:301 + k] = u[300]
        return Record.from_arrays(u=u, y=np.zeros(n), dt=DT)

    def holds(tr, va):
        # the hold's flags only (a longer hold also moves the input's spectrum)
        return [(x["condition"], x["train"], x["validate"]) for x in coverage([tr], [va], DT)
                if x["condition"] == "hold_s"]

    assert holds(held(6000, 800), held(6000, 2000)) == [("hold_s", 800 * DT, 2000 * DT)]
    # 10 % longer is still covered; a hold under 50 ms is a turning point
    assert holds(held(6000, 800), held(6000, 880)) == []
    assert holds(held(6000, 10), held(6000, 200)) == []
    assert holds(held(6000, 10), held(6000, 260)) == [("hold_s", 10 * DT, 260 * DT)]


def test_the_longest_run_is_found_by_its_ends():
    from fonbw.gap.checks import longest_run

    assert longest_run(np.array([0, 1, 1, 0, 1, 1, 1, 0], dtype=bool)) == (4, 7)
    assert longest_run(np.array([1, 1, 0, 1, 1], dtype=bool)) == (0, 2)  # the first of equals
    assert longest_run(np.array([0, 1, 1, 1], dtype=bool)) == (1, 4)     # a run to the end
    assert longest_run(np.zeros(5, dtype=bool)) == (0, 0) and longest_run(np.zeros(0, dtype=bool)) == (0, 0)


def test_coverage_flags_inputs_past_the_training_range_by_its_span():
    t = np.arange(10000) * DT
    zero = np.zeros(t.size)

    def sine(lo, hi):
        return Record.from_arrays(u=lo + (hi - lo) * (0.5 - 0.5 * np.cos(2 * np.pi * t)), y=zero, dt=DT)

    # 5.2 V past 114.8 V is 4.5 % of the span: the memory sees relays training never turned
    f = coverage([sine(0.0, 114.8)], [sine(0.0, 120.0)], DT)
    assert [(x["condition"], x["train"], x["validate"]) for x in f] == [("u_max", 114.8, 120.0)]
    assert coverage([sine(0.0, 114.8)], [sine(0.0, 116.8)], DT) == []   # 1.7 % of the span
    # a drive below 0 V is judged by the span as well: the same range is no excess,
    # 4 V past its top (4.2 %) is, and so is 4 V past its bottom
    neg = sine(-100.0, -5.0)
    assert coverage([neg], [sine(-100.0, -5.0)], DT) == []
    assert [x["condition"] for x in coverage([neg], [sine(-100.0, -1.0)], DT)] == ["u_max"]
    assert [x["condition"] for x in coverage([neg], [sine(-104.0, -5.0)], DT)] == ["u_min"]


def test_remaining_shares_are_each_records_excess_over_the_floor():
    # residuals of known power: 0.3 µm and 0.1 µm square waves on 4000 and 2000 samples, σ² = 0.005
    a = Record.from_arrays(u=np.zeros(4000), y=0.3 * np.where(np.arange(4000) % 2, 1, -1), dt=DT, path="a")
    b = Record.from_arrays(u=np.zeros(2000), y=0.1 * np.where(np.arange(2000) % 2, 1, -1), dt=DT, path="b")
    flag = {"condition": "rate_p99", "train": 10.0, "validate": 30.0, "record": "a", "index": 1}
    left = remaining([b, a], [np.zeros(2000), np.zeros(4000)], 0.005, [flag])
    ea, eb = 4000 * (0.09 - 0.005), 2000 * (0.01 - 0.005)    # weighted by length: 0.971, 0.029
    assert [r["record"] for r in left] == ["a", "b"]
    assert left[0]["share"] == pytest.approx(ea / (ea + eb)) and left[1]["share"] == pytest.approx(eb / (ea + eb))
    assert left[0]["rms"] == pytest.approx(0.3) and left[0]["outside"] == [flag] and left[1]["outside"] == []
    assert all(r["share"] == 0.0 for r in remaining([b], [np.zeros(2000)], 0.02))
    # two records of one name: the flag goes to the one at its position
    c = Record.from_arrays(u=np.zeros(2000), y=b.y, dt=DT, path="a")
    left = remaining([c, a], [np.zeros(2000), np.zeros(4000)], 0.005, [flag])
    assert [len(r["outside"]) for r in left] == [1, 0] and left[0]["rms"] == pytest.approx(0.3)
    assert all(r["beyond_input_range"] is None for r in left)   # no amplitude flag


def test_remaining_says_how_much_of_a_records_gap_lies_beyond_the_training_range():
    # 1000 samples, 100 of them above the training's 114.8 V and 50 below its
    # 0.5 V; residual 0.4 µm on the 100, 0.1 µm elsewhere, σ² = 0.002
    u = np.full(1000, 60.0)
    u[200:300], u[600:650] = 118.0, 0.0
    e = np.full(1000, 0.1)
    e[200:300] = 0.4
    r = Record.from_arrays(u=u, y=e, dt=DT, path="sine")
    hi = {"condition": "u_max", "train": 114.8, "validate": 118.0, "record": "sine", "index": 0}
    lo = {"condition": "u_min", "train": 0.5, "validate": 0.0, "record": "sine", "index": 0}
    total = 100 * 0.16 + 900 * 0.01 - 1000 * 0.002
    (only_hi,) = remaining([r], [np.zeros(1000)], 0.002, [hi])
    assert only_hi["beyond_input_range"]["samples"] == pytest.approx(0.1)
    assert only_hi["beyond_input_range"]["gap"] == pytest.approx((100 * 0.16 - 100 * 0.002) / total)
    (both,) = remaining([r], [np.zeros(1000)], 0.002, [hi, lo])
    assert both["beyond_input_range"]["samples"] == pytest.approx(0.15)
    assert both["beyond_input_range"]["gap"] == pytest.approx((100 * 0.16 + 50 * 0.01 - 150 * 0.002) / total)
    # the verdict's words: the record, its flags and the split
    from fonbw.gap.selection import verdict
    v = verdict([], mse0=0.3, excess0=0.3, mse=0.3, at_floor=False, steps=[], coverage=[hi], params={},
                remaining=[{**only_hi, "share": 0.9}])
    assert "highest input 118 against 114.8 V" in v["message"]
    assert "69 % of it on the 10 % of its samples where the input leaves the training range" in v["message"]


def test_unexplained_verdict_says_where_the_gap_lies_and_which_bounds_bind():
    from fonbw.gap.selection import verdict

    flag = {"condition": "rate_p99", "train": 2190.0, "validate": 7537.0, "record": "sine20"}
    left = [{"record": "sine20", "share": 0.95, "rms": 2.75, "outside": [flag]},
            {"record": "steps", "share": 0.05, "rms": 0.31, "outside": []}]
    kw = dict(mse0=0.58, excess0=0.58, at_floor=False, steps=[], coverage=[flag], params={})
    v = verdict([], mse=0.58, remaining=left, at_bounds=["n", "lam2"], **kw)
    assert v["unexplained"] and v["remaining"] == left
    assert "95 % of the gap left lies on sine20" in v["message"]
    assert "7537 against 2190 V/s" in v["message"] and "n, lam2" in v["message"]
    # a covered record is named without the extrapolation advice; a spread-out
    # remainder names no record; an explained gap adds nothing
    inside = verdict([], mse=0.58, remaining=[{**left[1], "share": 0.6}, {**left[0], "share": 0.4}], **kw)
    assert "60 % of the gap left lies on steps" in inside["message"] and "extrapolate" not in inside["message"]
    assert "lies on" not in verdict([], mse=0.58, remaining=[{**r, "share": 0.4} for r in left], **kw)["message"]
    done = verdict([], mse=0.01, remaining=left, at_bounds=["n"], **kw)
    assert not done["unexplained"] and "lies on" not in done["message"] and "bounds" not in done["message"]


def test_effects_are_listed_strongest_first_in_the_order_they_were_accepted():
    from fonbw.gap.selection import pick_best, verdict

    def cand(name, gc, dbic, identified=True):
        return {"effect": name, "checks": {"passed": True, "gap_closed_step": gc, "delta_bic": dbic,
                                           "identified": identified}}

    # first steps of two spent blind-harness scenarios: a Preisach core with a
    # 62 σ amplifier (seed 33036) and a FONBW core with an 8.6 σ delay (33034);
    # the delay and a resonance at its damping bound close the most alone
    preisach = [cand("delay", 0.892, -83011), cand("dynamics", 0.837, -87692, False),
                cand("amplifier", 0.686, -91727)]
    fonbw = [cand("dynamics", 0.875, -86550, False), cand("delay", 0.875, -79435),
             cand("amplifier", 0.812, -75037)]
    assert pick_best(preisach)["effect"] == "amplifier" and pick_best(fonbw)["effect"] == "delay"
    steps = [{"label": "nominal", "rms_validate": 0.5}, {"label": "+amplifier", "rms_validate": 0.1},
             {"label": "+delay", "rms_validate": 0.05}]
    v = verdict(["amplifier", "delay"], mse0=0.25, mse=0.0025, excess0=0.249, at_floor=False, steps=steps,
                coverage=[], params={})
    assert v["effects"] == ["amplifier", "delay"]
    assert [w["step"] for w in v["waterfall"]] == ["nominal", "+amplifier", "+delay"]
    assert v["gap_closed"] == pytest.approx((0.25 - 0.0025) / 0.249)


def test_the_verdict_says_which_effect_was_judged_within_the_training_rates():
    from fonbw.gap.selection import verdict

    # a delay that closes 0.81 of the gap of the two records within the
    # training rates and makes the whole gap 0.33 wider (seed 38038's figures)
    w = {"delay": {"records": ["steps_v", "sine1"], "gap_closed": 0.809, "gap_closed_all": -0.333}}
    kw = dict(mse0=0.39, excess0=0.39, at_floor=False, coverage=[], params={},
              steps=[{"label": "nominal", "rms_validate": 0.6245}])
    v = verdict(["delay"], mse=0.0152, within_rates=w, **kw)
    assert v["within_training_rates"] == w and v["effects"] == ["delay"]
    assert v["message"] == ("explained by delay; delay closes 0.81 of the gap on the validation records within the "
                            "training records' input rates (steps_v, sine1) and -0.33 on all: the faster ones, "
                            "where the models extrapolate, do not show it")
    assert verdict(["delay"], mse=0.0152, **kw)["within_training_rates"] == {}
    assert verdict(["delay"], mse=0.0152, **kw)["message"] == "explained by delay"
    # at the noise floor nothing is named, nor said of it
    floor = verdict(["delay"], mse=0.0152, within_rates=w, **{**kw, "at_floor": True})
    assert floor["effects"] == [] and "delay" not in floor["message"]

def test_the_waterfall_starts_from_exactly_zero_at_the_nominal():
    from fonbw.gap.selection import verdict

    # the demo bench's nominal, whose RMS squared is not its MSE to the last bit
    assert math.sqrt(0.43086) ** 2 != 0.43086
    demo = verdict([], mse0=0.43086, mse=0.1, excess0=0.43086 - 0.015 ** 2, at_floor=False, coverage=[], params={},
                   steps=[{"label": "nominal", "rms_validate": math.sqrt(0.43086)}])
    assert demo["waterfall"][0]["gap_closed_cum"] == 0.0


def test_retry_pool_keeps_every_effect_the_first_step_found_something_for():
    from fonbw.gap.selection import retry_pool

    def step(rows):
        return [{"i": i, "checks": {"delta_bic": b, "gap_closed_step": g}} for i, b, g in rows]

    # indices 0-5 stand for creep, dynamics, amplifier, delay, saturation and
    # clip, with first-step figures as on held-out scenarios 29037 and 29011:
    # the clip's refit beside an unmodelled drift made the validation error
    # worse (-0.51) but lowered the training BIC, so it is retried; creep's
    # refit moved nothing, so it is not
    first = step([(0, 33.0, 0.001), (1, -112.0, -0.005), (2, -71.0, -0.001), (3, -94.0, -0.006),
                  (4, -1.54e3, 0.012), (5, -1.24e3, -0.51)])
    assert retry_pool([0, 1, 2, 3, 4, 5], 4, first, first_step=True) == [1, 2, 3, 5]
    assert retry_pool([0, 1, 2, 3, 4, 5], 5, first, first_step=True) == [1, 2, 3, 4]
    # a later step: only the three that closed most (and something) at that step
    second = step([(1, -9.2e3, 0.04), (2, -5.4e3, 0.012), (3, 23.0, 0.3), (5, -3.9e3, 0.006), (0, -40.0, -0.01)])
    assert retry_pool([0, 1, 2, 3, 5], 1, second, first_step=False) == [2, 5]
    assert retry_pool([0, 1, 2, 3, 5], 4, second, first_step=False) == [1, 2, 5]
    second.append({"i": 4, "checks": {"delta_bic": -50.0, "gap_closed_step": 0.02}})
    assert retry_pool([0, 1, 2, 3, 4, 5], 3, second, first_step=False) == [1, 2, 4]
    # an effect outside the pool is never brought back, a diverged one (None) never kept
    second[0]["checks"]["gap_closed_step"] = None
    assert retry_pool([1, 2, 4, 5], 3, second, first_step=False) == [2, 4, 5]


def test_the_passing_candidate_with_the_best_training_fit_is_accepted():
    from fonbw.gap.selection import pick_best

    def cand(name, gc, dbic, passed=True, identified=True):
        return {"name": name, "checks": {"passed": passed, "gap_closed_step": gc, "delta_bic": dbic,
                                         "identified": identified}}

    # a 65 σ drift on a FONBW core (blind harness, seed 31017): the amplifier
    # closed more of the validation gap, the drift fitted the training far better
    res = [cand("amplifier", 0.830, -5.32e4), cand("drift", 0.578, -1.62e5), cand("creep", 0.545, -9.05e4),
           cand("saturation", 0.066, -9.56e3, passed=False)]
    assert pick_best(res)["name"] == "drift"
    assert pick_best(res, tie_margin=0.05)["name"] == "amplifier"  # the validation share alone
    # a failed candidate never wins, whatever its training fit
    res.append(cand("clip", 0.9, -1e6, passed=False))
    assert pick_best(res)["name"] == "drift"
    # a resonance that is only a lag yields to an identified block
    lag = [cand("dynamics", 0.90, -2e5, identified=False), cand("amplifier", 0.88, -1.7e5)]
    assert pick_best(lag)["name"] == "amplifier"
    assert pick_best([cand("dynamics", 0.9, -2e5, identified=False)])["name"] == "dynamics"
    assert pick_best([cand("drift", 0.5, -1e5, passed=False)]) is None


def test_between_a_rail_and_a_stroke_limit_the_validation_share_decides():
    from fonbw.gap.selection import pick_best

    def cand(name, gc, dbic, passed=True):
        return {"name": name, "range_limit": name in ("clip", "saturation"),
                "checks": {"passed": passed, "gap_closed_step": gc, "delta_bic": dbic, "identified": True}}

    # spent blind-harness steps: a stroke limit the training records reach
    # at 0.5 σ, refit beside a delay (seed 49013, second step), and a rail on
    # a FONBW core (48009); the other limit fitted the training records better
    assert pick_best([cand("saturation", 0.153, -2040), cand("clip", 0.131, -3435)])["name"] == "saturation"
    assert pick_best([cand("clip", 0.815, -11334), cand("saturation", 0.487, -11635)])["name"] == "clip"
    # only passing limits compete; a block that is no limit keeps its win on
    # the training fit, and a limit that wins there does not yield to it
    assert pick_best([cand("clip", 0.2, -3e3), cand("saturation", 0.6, -1e3, passed=False)])["name"] == "clip"
    mixed = [cand("delay", 0.5, -9e4), cand("clip", 0.7, -3e4), cand("saturation", 0.8, -2e4)]
    assert pick_best(mixed)["name"] == "delay"
    mixed[0]["checks"]["delta_bic"] = -1e3
    assert pick_best(mixed)["name"] == "saturation"
    assert pick_best([cand("clip", 0.5, -9e4), cand("drift", 0.9, -1e4)])["name"] == "clip"
    # a rail above every training command (not identified) takes no identified limit's place ...
    above = cand("clip", 0.9, -1e3)
    above["checks"]["identified"] = False
    assert pick_best([cand("saturation", 0.6, -5e3), above])["name"] == "saturation"
    # ... and, chosen within a finite margin where the identified one is not
    # competing, is not handed over to an identified limit that closes less
    above["checks"]["delta_bic"] = -9e3
    assert pick_best([cand("saturation", 0.8, -5e3), above], tie_margin=0.05)["name"] == "clip"


def test_a_failed_candidate_says_which_check_it_failed_first():
    from fonbw.gap.greedy import _failed_check

    # not material: no bootstrap or leave-one-out was run
    assert _failed_check({"material": False, "delta_bic": -5.6e4, "own_bic": -5.6e4, "refused": "a bend"}) == "closes too little"
    assert _failed_check({"material": True, "delta_bic": -7.4, "own_bic": -7.4, "refused": None}) == (
        "ΔBIC -7.4 on the training records, not below -10")
    assert _failed_check({"material": True, "delta_bic": 33.3, "own_bic": 33.3, "refused": None}).startswith("ΔBIC 33.3 ")
    # a block refused for its shape fails before its evidence is weighed
    assert _failed_check({"material": True, "delta_bic": 33.3, "own_bic": 33.3, "refused": "a bend"}) == "a bend"
    # a block that accounts for less than half of its refit's ΔBIC itself
    assert _failed_check({"material": True, "delta_bic": -3.18e4, "own_bic": -109.0, "refused": None}).startswith(
        "the block itself accounts for ΔBIC -109 of its refit's -3.18e+04, not more than 0.5 of it")
    boot = {"material": True, "delta_bic": -5.59e4, "own_bic": -6.1e4, "refused": None, "bootstrap": {"p10": -0.0123},
            "loro": {"pooled_ratio": 0.9}}
    assert _failed_check(boot) == "bootstrap 10th percentile -0.0123"
    boot["bootstrap"]["p10"] = 0.21
    boot["loro"]["pooled_ratio"] = 1.0417
    assert _failed_check(boot) == "held-out records fit worse (pooled ratio 1.042)"
    # a true clip's ratio fails without a slack and passes with a clip's 2 %
    boot["loro"]["pooled_ratio"] = 1.009
    assert _failed_check(boot) == "held-out records fit worse (pooled ratio 1.009)"
    assert _failed_check(boot, 0.02) is None
    boot["loro"]["pooled_ratio"] = 0.97
    assert _failed_check(boot) is None
    # a drift must help the held-out records by a quarter: the mains hum's 0.981 does not
    boot["loro"]["pooled_ratio"] = 0.981
    assert _failed_check(boot, fx.Drift.loro_slack) == (
        "held-out records fit too little better (pooled ratio 0.981, "
        "not below 0.75): the other records' fit does not carry over")
    boot["loro"]["pooled_ratio"] = 0.408
    assert _failed_check(boot, fx.Drift.loro_slack) is None
    boot["loro"] = None  # nothing to hold out
    assert _failed_check(boot) is None


def test_a_rail_passes_the_held_out_records_check_by_a_small_slack_only():
    from fonbw.gap.checks import loro_passes
    from fonbw.gap.effects import Clip, Creep, Saturation, library

    clip, creep = Clip(120.0), Creep(2e-4, 10.0)
    # pooled ratios of true rails (1.009) and of rails that were not there (1.109, 1.248)
    assert loro_passes({"pooled_ratio": 1.009}, clip.loro_slack)
    assert not loro_passes({"pooled_ratio": 1.109}, clip.loro_slack)
    assert not loro_passes({"pooled_ratio": 1.248}, clip.loro_slack)
    # every other block still needs the held-out records to fit better
    assert not loro_passes({"pooled_ratio": 1.002}, creep.loro_slack)
    assert loro_passes({"pooled_ratio": 0.999}, creep.loro_slack) and loro_passes(None)
    slack = {e.name: e.loro_slack for e in library(2e-4, 120.0, 10.0)}
    assert slack.pop("clip") == 0.02 and slack.pop("drift") == -0.25 and set(slack.values()) == {0.0}
    assert Saturation.loro_slack == 0.0


def test_nominal_at_bounds_reads_linear_and_log_ranges():
    from types import SimpleNamespace

    from fonbw.gap.attribute import Diagnosis

    space = SimpleNamespace(names=["rho", "n", "lam2", "fixed"], bounds=[(1e-4, 1.0), (1.0, 4.0), (0.05, 1.0), (2.0, 2.0)],
                            log_scale=[True, False, False, False])
    d = SimpleNamespace(space=space, base={"x": np.array([1.0005e-4, 3.99, 0.05, 2.0])})
    # 1.0005e-4 is 5e-5 of the log range above its bound; 3.99 is 3e-3 of its range below 4
    assert Diagnosis.nominal_at_bounds(d) == ["rho", "lam2"]
    assert Diagnosis.nominal_at_bounds(d, tol=5e-3) == ["rho", "n", "lam2"]


def test_truth_amplifier_is_the_exact_two_pole_response_under_zoh():
    # no slew limit: the sub-stepped ODE is the linear 1/((s/(8π f_c) + 1)(s/(2π f_c) + 1))
    # under a zero-order hold, read at the end of each interval (u_k included)
    fc = 400.0
    u = np.r_[np.zeros(5), np.full(60, 80.0), np.full(60, 20.0)]
    v = tr._amplifier_ode(u, DT, fc, math.inf)
    sys = ct.tf([1.0], np.polymul([1 / (8 * math.pi * fc), 1.0], [1 / (2 * math.pi * fc), 1.0]))
    d = ct.c2d(ct.ss(sys), DT, method="zoh")
    A, B, C = (np.asarray(m, dtype=float) for m in (d.A, d.B, d.C))
    x = np.zeros((A.shape[0], 1))
    ref = []
    for uk in u:
        x = A @ x + B * uk
        ref.append(float((C @ x)[0, 0]))
    np.testing.assert_allclose(v, ref, rtol=0, atol=1e-4 * 80.0)  # midpoint sub-steps: O(h²)
    # a current limit: the voltage moves at most slew·dt per sample and still settles
    v = tr._amplifier_ode(u, DT, fc, 1e5)
    assert np.max(np.abs(np.diff(v))) <= 1e5 * DT * (1 + 1e-12)
    assert np.max(np.abs(np.diff(v))) == pytest.approx(1e5 * DT, rel=1e-9)
    assert v[64] == pytest.approx(80.0, abs=1e-6)


def test_truth_effects_are_not_the_candidate_blocks():
    # the truth's delay (monotone cubic on the input) and the candidate's delay
    # (linear interpolation of the input) agree at whole samples; at 1.5
    # samples they differ visibly
    sc = tr.draw_scenario(5, "null", scale=0.25)
    truth = sc["truth"]
    u = sc["validate"][0].u
    d = fx.Delay(DT)
    a = truth.output(u, effects={"delay": {"seconds": 2 * DT}})
    b = truth.output(d.transform_input(u, DT, (2 * DT,)), effects={})
    assert np.max(np.abs(a - b)) < 1e-9 * np.ptp(a)
    a = truth.output(u, effects={"delay": {"seconds": 1.5 * DT}})
    b = truth.output(d.transform_input(u, DT, (1.5 * DT,)), effects={})
    assert np.max(np.abs(a - b)) > 1e-6
    # and the truth's amplifier is not the candidate's RC stage
    p = {"f_c": 300.0, "slew": None}
    a = truth.output(u, effects={"amplifier": p})
    b = truth.output(fx.Amplifier(DT, 120.0).transform_input(u, DT, (300.0, 1e12)), effects={})
    assert np.max(np.abs(a - b)) > 1e-3


def test_diagnose_refuses_bad_input():
    r = Record.from_arrays(u=np.linspace(0, 1, 100), y=np.zeros(100), dt=DT)
    r2 = Record.from_arrays(u=np.linspace(0, 1, 100), y=np.zeros(100), dt=2 * DT)
    with pytest.raises(ValueError, match="sampling period"):
        diagnose([r], [r2])
    with pytest.raises(ValueError, match="at least 64"):
        diagnose([r], [Record.from_arrays(u=np.zeros(10), y=np.zeros(10), dt=DT)])
    with pytest.raises(ValueError, match="validation"):
        diagnose([r], [])


def test_decimate_keeps_every_qth_sample():
    r = Record.from_arrays(u=np.arange(20.0), y=np.arange(20.0) * 2, dt=DT)
    (d,) = decimate([r], 5)
    assert d.dt == pytest.approx(5 * DT)
    np.testing.assert_array_equal(d.u, [0, 5, 10, 15])
    # the name a report shows for it
    assert d.path == f"{r.path} (one sample in 5)"


# ---------------------------------------------------------------------------
# fixed-seed blind subset (the full run is benchmarks/blind_gap.py)

FAST = dict(budget=500, global_evals=160, refit_evals=45)


@pytest.fixture(scope="module")
def dynamics_case(tmp_path_factory):
    """A strong resonance, diagnosed through the CLI pieces (CSV in, JSON + HTML out)."""
    from fonbw.cli import diagnose as cli_diagnose

    sc = tr.draw_scenario(11, "null", scale=0.5)
    truth = sc["truth"]
    truth.effects = {"dynamics": {"f_res": 150.0, "zeta": 0.08}}
    tr_in, va_in = tr.default_experiments(scale=0.5)
    d = tmp_path_factory.mktemp("gap")
    args = ["--json", str(d / "out.json"), "--html", str(d / "out.html"), "--seed", "3", "--budget", "500"]
    for kind, ins, off in (("train", tr_in, 0), ("validate", va_in, 50)):
        for i, (name, u) in enumerate(ins):
            rec = truth.record(u, name, off + i)
            p = d / f"{name}.csv"
            write_csv(p, {"t": rec.t, "u": rec.u, "y": rec.y})
            args += [f"--{kind}", str(p)]
    ns = cli_diagnose.add_arguments(argparse.ArgumentParser()).parse_args(args)
    # the CLI's defaults are the library's; the test runs a smaller budget
    import fonbw.gap.attribute as att

    real = att.diagnose
    att.diagnose = lambda *a, **k: real(*a, **{**k, **FAST})
    try:
        assert cli_diagnose.run(ns) == 0
    finally:
        att.diagnose = real
    res = json.loads((d / "out.json").read_text(), parse_constant=_not_json)
    return res, (d / "out.html").read_text(), truth


def _not_json(c):
    raise AssertionError(f"not strict JSON: {c}")


def test_the_diagnosis_json_is_strict_with_null_for_what_is_not_a_number(tmp_path):
    from fonbw.gap.report import write_json

    res = {"verdict": {"gap_closed": np.float64(0.5), "form": {"bootstrap": {"p10": float("nan")}}},
           "candidates": [{"effect": "clip", "gap_closed": -np.inf, "checks": {"passed": np.bool_(False)}}]}
    write_json(res, tmp_path / "g.json")
    got = json.loads((tmp_path / "g.json").read_text(encoding="utf-8"), parse_constant=_not_json)
    assert got == {"verdict": {"gap_closed": 0.5, "form": {"bootstrap": {"p10": None}}},
                   "candidates": [{"effect": "clip", "gap_closed": None, "checks": {"passed": False}}]}


def test_blind_resonance_is_named_first(dynamics_case):
    res, _, _ = dynamics_case
    v = res["verdict"]
    assert v["effects"][:1] == ["dynamics"]
    assert not v["at_noise_floor"]
    # the truth has a weak second mode at 3.3 f_res the one-mode block cannot
    # follow, and the test runs a reduced search budget
    assert v["gap_closed"] > 0.6
    p = v["params"]["dynamics"]
    assert p["f_res"] == pytest.approx(150.0, rel=0.2)


def test_json_contract_and_gap_closed_definition(dynamics_case):
    res, _, truth = dynamics_case
    json.dumps(res, allow_nan=False)  # strict JSON
    assert set(res) >= {"nominal", "localization", "candidates", "verdict"}
    assert set(res["nominal"]) >= {"model", "rms_validate", "noise_floor"}
    assert set(res["verdict"]) >= {"effects", "gap_closed", "unexplained", "form", "waterfall", "start"}
    assert set(res["verdict"]["form"]) >= {"material", "gap_closed", "where"}
    assert not res["verdict"]["form"]["material"]     # a FONBW core: no form
    wf = res["verdict"]["waterfall"]
    assert wf[0]["step"] == "nominal" and wf[-1]["step"] == "noise floor"
    assert wf[-1]["gap_closed_cum"] == pytest.approx(1.0)
    assert res["nominal"]["noise_floor"] == pytest.approx(truth.noise_std, rel=0.1)
    s2 = res["nominal"]["noise_floor"] ** 2
    m0 = res["nominal"]["rms_validate"] ** 2
    for c in res["candidates"]:
        assert {"effect", "gap_closed", "accepted", "params"} <= set(c)
        if c["gap_closed"] is not None:
            assert c["gap_closed"] == pytest.approx((m0 - c["rms_validate"] ** 2) / (m0 - s2), rel=1e-9)
    assert {c["effect"] for c in res["candidates"]} == set(fx.EFFECTS)
    # where the gap left lies: shares of the final model's excess, one per validation record
    left = res["verdict"]["remaining"]
    assert len(left) == len(res["records"]["validate"])
    assert sum(r["share"] for r in left) == pytest.approx(1.0) or all(r["share"] == 0 for r in left)
    assert [r["share"] for r in left] == sorted((r["share"] for r in left), reverse=True)
    assert isinstance(res["nominal"]["at_bounds"], list)


def test_html_report_is_self_contained(dynamics_case):
    _, page, _ = dynamics_case
    # localization (2), waterfall, and the loop-shape residual of FONBW and the reference
    assert page.count("data:image/png;base64,") == 4
    assert "Hysteresis form" in page and "Where the gap left lies" in page
    assert "src=\"http" not in page and "<script" not in page


def test_global_search_budgets(monkeypatch):
    # every candidate's global search gets GLOBAL_SHARE of the budget, a new
    # output nonlinearity (the saturation block's knee) all of it; an explicit
    # global_evals is what every candidate gets
    from fonbw.gap import attribute
    from fonbw.gap.fitter import Fitter

    seen = []
    refit = Fitter.refit

    def spy(self, effects, *a, **k):
        if k.get("local") is False:
            seen.append((effects[-1].name, k["evals"]))
        return refit(self, effects, *a, **k)

    monkeypatch.setattr(Fitter, "refit", spy)
    _, train, val = tr.fixed_case(12, {}, scale=0.25)
    diagnose(train, val, seed=0, budget=80, refit_evals=10, effects=("saturation", "delay"),
             max_effects=1, workers=1)
    assert attribute.GLOBAL_SHARE == 0.6
    # on the FONBW nominal the amplifier's search runs from two seeds
    assert [e.search_seeds for e in fx.library(1e-3, 100.0, 1.0)] == [1, 1, 2, 1, 1, 1, 1]
    seen.clear()
    diagnose(train, val, seed=0, budget=80, global_evals=30, refit_evals=10,
             effects=("saturation", "delay", "amplifier"), max_effects=1, workers=1)
    assert sorted(seen) == [("amplifier", 30)] * 2 + [("delay", 30), ("saturation", 30)]


def test_the_amplifier_on_the_fonbw_nominal_keeps_its_best_training_fit_of_two_seeds(monkeypatch):
    # each seed's search and polish, recorded as it runs, against what the
    # candidate is credited with: the lower full-rate training RMS of the two
    from fonbw.gap.attribute import Diagnosis

    runs, kept = [], []
    one, whole = Diagnosis._search_and_polish, Diagnosis.refit_candidate

    def spy_one(self, eff, start, a, seed, grid):
        fit = one(self, eff, start, a, seed, grid)
        runs.append((eff[-1].name, seed, fit["rms"], a["core"]))
        return fit

    def spy_whole(self, active, start, att=None):
        out = whole(self, active, start, att)
        kept.append((self.lib[active[-1]].name, out[0]["rms"]))
        return out

    monkeypatch.setattr(Diagnosis, "_search_and_polish", spy_one)
    monkeypatch.setattr(Diagnosis, "refit_candidate", spy_whole)
    _, train, val = tr.fixed_case(12, {"amplifier": {"f_c": 250.0, "slew": None}}, scale=0.25)
    diagnose(train, val, seed=6, budget=200, refit_evals=20, effects=("amplifier", "delay"),
             max_effects=1, workers=1)
    assert [k for k, _ in kept] == ["amplifier", "delay"] and all(r[3] == "fonbw" for r in runs)
    # the amplifier from seeds 6 and 1006, the delay from 6 alone
    assert [(n, sd) for n, sd, _, _ in runs] == [("amplifier", 6), ("amplifier", 1006), ("delay", 6)]
    # the two searches end in different valleys (0.046 and 0.030 µm when
    # measured) and the lower is the one credited
    assert runs[1][2] < 0.8 * runs[0][2]
    assert kept[0][1] == runs[1][2] and kept[1][1] == runs[2][2]


def test_blind_null_names_nothing():
    sc = tr.draw_scenario(7, "null", scale=0.5)
    res = diagnose(sc["train"], sc["validate"], seed=1, **FAST)
    assert res["verdict"]["effects"] == []
    assert not res["verdict"]["form"]["material"]    # a FONBW core has no form error
    assert res["nominal"]["noise_floor"] == pytest.approx(sc["noise_std"], rel=0.1)


def test_blind_amplifier_lag_is_not_taken_for_a_delay():
    # an RC amplifier (two poles in the truth, one in the candidate): the
    # delay and the resonance blocks lag too and close part of the gap, but
    # the amplifier must be named
    _, train, val = tr.fixed_case(12, {"amplifier": {"f_c": 250.0, "slew": None}}, scale=0.5)
    res = diagnose(train, val, seed=4, **FAST)
    v = res["verdict"]
    assert v["effects"][:1] == ["amplifier"]
    # 0.79: a one-pole candidate for a two-pole truth; what it leaves lies on the
    # 20-Hz validation sine, beyond the training records' input rates
    assert v["gap_closed"] > 0.75
    assert v["remaining"][0]["record"].endswith("sine20>") and v["remaining"][0]["share"] > 0.5
    assert {f["condition"] for f in v["remaining"][0]["outside"]} >= {"rate_p99"}
    # a FONBW core has no form: the rate-dependent reference beside the one-pole
    # block would take up its misfit (0.84 of what it leaves) if it were asked,
    # but the reference alone is worse than FONBW alone
    assert not v["form"]["material"] and v["form"]["gap_closed"] < 0
    assert [w["step"] for w in v["waterfall"]] == ["nominal", "+amplifier", "noise floor"]
    # the one-pole candidate's corner sits between the truth's two poles' lag sum
    # (1/(2π·250) + 1/(2π·1000) → 204 Hz) and the main pole
    assert 150.0 < v["params"]["amplifier"]["f_c"] < 400.0


def test_a_lag_on_top_of_an_amplifier_is_first_its_own_pole(tmp_path):
    # a 30-Hz amplifier whose driver has a pole of its own at 120 Hz, no slew
    # limit: on top of the one-pole block a delay and a resonance
    # each close a little more (both named without the pole: amplifier, delay).
    # The amplifier with a pole of its own fits the training records better,
    # takes the one-pole block's place, and the two lags, tried again on top
    # of it, close nothing
    _, train, val = tr.fixed_case(12, {"amplifier": {"f_c": 30.0, "slew": None}}, scale=0.5)
    res = diagnose(train, val, seed=4, effects=("amplifier", "delay", "dynamics"), max_effects=2, workers=1,
                   budget=500, global_evals=160, refit_evals=90)
    v = res["verdict"]
    assert v["effects"] == ["amplifier"]
    assert [w["step"] for w in v["waterfall"]] == ["nominal", "+amplifier", "+amplifier's own pole", "noise floor"]
    first, second = v["later_steps"]
    assert first["accepted"] is None and second["on_top_of"] == ["amplifier"] and second["accepted"] is None
    pole = first["own_pole"]
    for c in first["candidates"]:
        # each passed every other check and is refused for the pole alone
        assert c["checks"]["own_pole"] == pole and c["checks"]["bootstrap"]["p10"] > 0
        assert c["checks"]["failed"].startswith("the amplifier with a pole of its own at")
    assert {c["effect"] for c in first["candidates"]} == {"delay", "dynamics"}
    assert all(c["gap_closed"] is not None and c["gap_closed"] < 0.005 for c in second["candidates"])
    # the two poles: the RC stage near the truth's 30 Hz, the driver's above it
    # (265 Hz measured against the truth's 120: on these records the split of
    # the lag between the two is loosely held)
    p = v["params"]["amplifier"]
    assert p == pole["params"] and 25.0 < p["f_c"] < 35.0 and 100.0 < p["f_pole"] < 400.0
    assert v["gap_closed"] > 0.99 and pole["gap_closed"] > 0.0
    # the HTML report says what that step added
    from fonbw.gap.report import write_html

    write_html(res, tmp_path / "gap.html")
    assert f"the amplifier takes a pole of its own at {p['f_pole']:.4g} Hz" in (tmp_path / "gap.html").read_text()


@pytest.fixture(scope="module")
def stroke_limit():
    # a limit at the 99.9 % quantile of the training displacements (4 σ on
    # the validation set): it touches the eq.-19 peaks, flattens the 1 Hz
    # validation peaks and clips FONBW's one-sample spikes at the step edges.
    # The knee sits at the top of the range the training data reach, and
    # which record reaches it decides leave-one-record-out: the block must
    # act on the model's own output and be judged over the displacements
    # the other records span (the earlier version left it unexplained)
    sc = tr.draw_scenario(13, "null", scale=0.5)
    truth = sc["truth"]
    tr_in, va_in = tr.default_experiments(scale=0.5)
    top = max(float(np.quantile(truth.output(u, effects={}), 0.999)) for _, u in tr_in)
    truth.effects = {"saturation": {"knee": top, "width": 0.3}}
    train = [truth.record(u, n, i) for i, (n, u) in enumerate(tr_in)]
    val = [truth.record(u, n, 50 + i) for i, (n, u) in enumerate(va_in)]
    return top, diagnose(train, val, seed=2, **FAST)


def test_blind_stroke_limit_at_the_top_of_the_training_range_is_named(stroke_limit):
    top, res = stroke_limit
    v = res["verdict"]
    # a FONBW core: the reference hysteresis does not beat it, no form is named
    assert not v["form"]["material"]
    assert v["effects"][0] == "saturation"
    assert v["gap_closed"] > 0.7
    # a softplus corner against the truth's tanh one: the knee within 0.3 µm
    assert v["params"]["saturation"]["knee"] == pytest.approx(top, abs=0.3)
    assert -1.0 < v["params"]["saturation"]["c"] < -0.5


def test_blind_stroke_limit_is_the_only_effect_named(stroke_limit):
    # at the second step every block closed 0.21 of the gap, with ΔBIC −141
    # to −159, and taken out of its refit each fitted as well: the refit of
    # the nominal and the stroke limit had closed it, not the block
    assert stroke_limit[1]["verdict"]["effects"] == ["saturation"]
    # the steps record's three edges (40, 100, 60 V), which the core answers at once
    edges = stroke_limit[1]["verdict"]["step_edges"]
    assert edges["count"] == 3 and edges["dead_time_s"] is None


def test_later_steps_say_why_no_second_effect_was_named(stroke_limit, tmp_path):
    from fonbw.gap.report import write_html

    res = stroke_limit[1]
    v = res["verdict"]
    (st,) = v["later_steps"]
    assert st["on_top_of"] == ["saturation"] and st["accepted"] is None
    assert st["rms_validate"] == v["waterfall"][1]["rms_validate"]
    s2, m0 = res["nominal"]["noise_floor"] ** 2, res["nominal"]["rms_validate"] ** 2
    gcs = [c["gap_closed"] for c in st["candidates"]]
    assert gcs == sorted(gcs, reverse=True) and "saturation" not in {c["effect"] for c in st["candidates"]}
    for c in st["candidates"]:
        # a share of the nominal's excess, what the step's refit removes from the configuration before it
        assert c["gap_closed"] == pytest.approx((st["rms_validate"] ** 2 - c["rms_validate"] ** 2) / (m0 - s2),
                                                rel=1e-9)
        assert not c["accepted"] and c["checks"]["failed"]
    # the five the first step found something for each close about a fifth of
    # the gap, and none accounts for its refit's ΔBIC itself
    assert len(gcs) == 5 and 0.2 < min(gcs) and max(gcs) < 0.22
    why = {c["effect"]: c["checks"]["failed"] for c in st["candidates"]}
    # the rail's refit sits above every command, which the training records cannot judge
    clip = why.pop("clip")
    assert clip.startswith("it sits at 126.2") and ", at or above the largest training command (114.7" in clip
    assert all(w.startswith("the block itself accounts for") for w in why.values())
    write_html(res, tmp_path / "r.html")
    page = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert "On top of saturation" in page and "the block itself accounts for" in page
    assert "3 step edges in the training records" in page
    # the validation sines go to 120 V, training to 114.8 V: the samples above
    # it are the top 13 % of a 60 − 60 cos sine (cos θ < −0.913)
    up = [r for r in v["remaining"] if any(f["condition"] == "u_max" for f in r["outside"])]
    assert up and all(r["beyond_input_range"]["samples"] == pytest.approx(0.133, abs=0.01) for r in up)
    assert "samples out of range)" in page


def test_the_report_says_what_became_of_each_candidate():
    from fonbw.gap.selection import outcome_text as _outcome

    assert _outcome({"accepted": True, "checks": {"passed": True, "failed": None}}) == "yes"
    # named at the second step, after failing at the first
    assert _outcome({"accepted": True, "checks": {"passed": False, "failed": "closes too little"}}) == \
        "yes, at a later step (here: closes too little)"
    assert _outcome({"accepted": False, "checks": {"passed": False, "failed": "bootstrap 10th percentile -0.04"}}) == \
        "no: bootstrap 10th percentile -0.04"
    assert _outcome({"accepted": False, "checks": {"passed": True, "failed": None}}) == "no: passed, another was added"
    # a candidate judged within the training rates shows both shares
    from fonbw.gap.report import _candidate_row
    row = _candidate_row({"effect": "delay", "gap_closed": -0.333, "rms_validate": 0.12, "params": {},
                          "accepted": True, "checks": {"passed": True, "failed": None, "delta_bic": -8.4e4,
                                                       "within_training_rates": {"records": [0, 3],
                                                                                 "gap_closed": 0.809}}})
    assert "<td>-0.333 (0.809 within the training rates)</td>" in row
    # checks that did not run (no bootstrap, no ΔBIC) and a diverged refit show a dash, not "nan"
    row = _candidate_row({"effect": "clip", "gap_closed": None, "rms_validate": math.inf, "params": {},
                          "accepted": False, "checks": {"passed": False, "failed": "closes too little",
                                                        "delta_bic": math.nan}})
    cells = re.findall(r"<td>(.*?)</td>", row)
    assert cells[1:6] == ["–"] * 5 and "nan" not in row and "inf" not in row


def test_result_object_reads_as_its_json():
    from fonbw.gap import DiagnosisResult

    verdict = {"effects": ["delay"], "gap_closed": 0.9, "unexplained": False, "at_noise_floor": False,
               "message": "explained by delay"}
    res = DiagnosisResult({"rms_validate": 1.0}, {"dominant": "branch"}, [{"effect": "delay"}], verdict,
                          {"total_s": 1.0}, {"train": [], "validate": []})
    d = res.to_dict()
    assert list(d) == ["nominal", "localization", "candidates", "verdict", "timing", "records"]
    assert res["verdict"] is res.verdict is d["verdict"]
    assert res.get("candidates", []) == [{"effect": "delay"}] and res.get("nope") is None
    assert dict(res) == d and json.loads(json.dumps(d))["verdict"] == verdict
    assert (res.effects, res.gap_closed, res.unexplained, res.message) == (["delay"], 0.9, False, "explained by delay")
    with pytest.raises(KeyError):
        res["model"]


def test_a_nominal_that_diverges_is_refused_naming_the_record():
    # A Bouc-Wen with sigma < 1/2 can diverge on a record faster than the training
    # samples: the diagnosis refuses with the record's name, not a numerics traceback.
    from types import SimpleNamespace

    from fonbw.gap.attribute import Diagnosis

    stub = SimpleNamespace(nominal=SimpleNamespace(params={"sigma": 3e-4, "n": 2.15}))
    rec = lambda name: SimpleNamespace(path=name)
    ok = np.zeros(5)
    Diagnosis._check_finite(stub, [rec("a.csv")], [ok], [rec("b.csv")], [ok])
    with pytest.raises(ValueError, match=r"diverges on the validation record fast\.csv"):
        Diagnosis._check_finite(stub, [rec("a.csv")], [ok], [rec("b.csv"), rec("fast.csv")],
                                [ok, np.array([0.0, np.nan])])


def test_a_nominal_of_its_own_that_diverges_is_refit_bounded():
    # Harness scenario 18035 (Prandtl-Ishlinskii core, drift): the FONBW that the
    # diagnosis identifies on the decimated training records has sigma = 2.8e-7
    # and diverges on the validation steps. The diagnosis refits it with
    # sigma >= 1/2, where every input keeps the state bounded, and goes on.
    import blind_gap as bg
    import gap_cores as gc
    import gap_truth as tr

    from fonbw.gap.attribute import Diagnosis
    from fonbw.identifiable import SIGMA_BOUNDED

    seed = 18035
    sc = tr.draw_scenario(seed, scale=bg.DEFAULTS["scale"], family=tr.scenario_family(seed, tuple(gc.FAMILIES)),
                          mid_drive=bg.DEFAULTS["mid_drive"])
    d = Diagnosis(sc["train"], sc["validate"], seed=seed)
    d.fit_nominal()
    assert d.sigma_floor == SIGMA_BOUNDED and d.nominal.params["sigma"] >= SIGMA_BOUNDED * (1 - 1e-12)
    assert all(np.all(np.isfinite(p)) for p in d.p0_va + d.yref_tr)
    # and it still fits the loop: training RMS 0.22 µm, under 2 % of the output span
    span = max(float(np.ptp(r.y)) for r in sc["train"])
    assert d.base["rms"] < 0.02 * span


def test_a_nominal_refit_with_no_finite_fit_is_refit_bounded():
    # Harness scenario 54001 (rate-dependent core, 11.5 σ delay, a training
    # record starting mid-drive): the first refit of the identified FONBW
    # diverged on a training record after its history, so its linear solve
    # had no coefficients and the diagnosis ended in a TypeError. It is a
    # nominal that diverges: refit with sigma >= 1/2, and the diagnosis goes on.
    import blind_gap as bg
    import gap_cores as gc
    import gap_truth as tr

    from fonbw.gap.attribute import Diagnosis
    from fonbw.identifiable import SIGMA_BOUNDED

    seed = 54001
    sc = tr.draw_scenario(seed, scale=bg.DEFAULTS["scale"], family=tr.scenario_family(seed, tuple(gc.FAMILIES)),
                          mid_drive=bg.DEFAULTS["mid_drive"])
    assert sc["mid_drive"]["train"] is not None
    said = []
    d = Diagnosis(sc["train"], sc["validate"], seed=seed)
    d.say = said.append
    d.fit_nominal()
    assert any("diverges on one of them" in s and "refitting with sigma >= 0.5" in s for s in said)
    assert d.sigma_floor == SIGMA_BOUNDED and d.nominal.params["sigma"] >= SIGMA_BOUNDED * (1 - 1e-12)
    assert all(np.all(np.isfinite(p)) for p in d.p0_va + d.yref_tr)
    # the bounded refit still fits the loop: training RMS 0.38 µm, under 3 % of the output span
    span = max(float(np.ptp(r.y)) for r in sc["train"])
    assert d.base["rms"] < 0.03 * span


def test_a_second_identification_that_diverges_is_not_taken(monkeypatch):
    # Harness scenario 38028 (rate-dependent core, no effect, records starting
    # mid-drive): the second, longer FONBW identification fits the training
    # records better with sigma = 2e-12 and diverges on the 20-Hz validation
    # sine; the diagnosis ended there. The first nominal stays and it goes on.
    import blind_gap as bg
    import gap_cores as gc
    import gap_truth as tr

    from fonbw.gap.attribute import Diagnosis

    seed = 38028
    sc = tr.draw_scenario(seed, scale=bg.DEFAULTS["scale"], family=tr.scenario_family(seed, tuple(gc.FAMILIES)),
                          mid_drive=bg.DEFAULTS["mid_drive"])
    taken, real = [], Diagnosis.try_nominal
    monkeypatch.setattr(Diagnosis, "try_nominal", lambda self, fit: taken.append((fit, real(self, fit))) or taken[-1][1])
    d = Diagnosis(sc["train"], sc["validate"], seed=seed)
    d.fit_nominal()
    d.localize_residual()
    first = d.base
    d.form_stage()
    ((second, ok),) = taken
    assert not ok and second["rms"] < first["rms"]
    assert d.fitter.model(second).params["sigma"] < 0.5
    # the first stays: as it was, or with its weights solved again after
    # histories the reference chose
    assert np.array_equal(d.base["x"], first["x"])
    assert d.base is first or all(v["chosen_with"] == "reference" for v in d.rs.info.values())
    assert all(np.all(np.isfinite(p)) for p in d.p0_va + d.yref_tr) and d.form["gap_closed"] is not None


def test_a_candidate_that_diverges_on_validation_is_listed_without_a_gap():
    # a refit whose validation error is not finite has no gap closed (None in its
    # checks); a step still lists it, last, and the JSON carries null
    from types import SimpleNamespace

    from fonbw.gap.attribute import Diagnosis

    lib = [SimpleNamespace(name="clip"), SimpleNamespace(name="creep")]
    fitter = SimpleNamespace(effect_params=lambda fit, eff: {e.name: {"level": 1.0} for e in eff})
    me = SimpleNamespace(lib=lib, att={"fitter": fitter})
    results = [{"i": 0, "fit": {}, "mse": math.inf, "eff": [lib[0]],
                "checks": {"gap_closed_step": None, "passed": False}},
               {"i": 1, "fit": {}, "mse": 0.04, "eff": [lib[1]],
                "checks": {"gap_closed_step": 0.37, "passed": True}}]
    entries = Diagnosis.entries(me, results)
    creep, clip = entries
    assert clip["effect"] == "clip" and clip["gap_closed"] is None and clip["rms_validate"] is None
    assert creep["gap_closed"] == 0.37 and creep["rms_validate"] == pytest.approx(0.2)
    json.dumps(entries, allow_nan=False)


def test_an_effect_needs_a_bic_drop_of_more_than_ten_on_the_training_records(monkeypatch):
    # a candidate that closes 0.42 of the validation gap but barely moves the
    # training fit (ΔBIC −5: its gap is how it extrapolates) fails before its
    # bootstrap; the same candidate with ΔBIC −20 goes on to the checks and
    # passes, unless the block itself accounts for no more than half of it
    from types import SimpleNamespace

    from fonbw.gap import checks
    from fonbw.gap.attribute import Diagnosis
    from fonbw.gap.edges import StepEdges

    monkeypatch.setattr(checks, "bootstrap", lambda *a: {"p05": 0.2, "p10": 0.3, "p50": 0.4})
    monkeypatch.setattr(checks, "loro", lambda *a: {"ratios": [0.5], "pooled_ratio": 0.5})
    n, mse_tr = 10_000, 0.01
    block = SimpleNamespace(name="a", names=("a", "b"), lin_names=(), lin_names_on=lambda core: (), identified=lambda th: True, loro_slack=0.0,
                            refuses=lambda params: None, lag=False, edges_left_most=None,
                            transport_delay=False)
    me = SimpleNamespace(current={"mse": 0.02, "mse_tr": mse_tr, "pred": None, "fit": None, "eff": []},
                         lib=[block], sigma2=0.001, min_gap_closed=0.2, val_s=None, seed=0, candidates=[],
                         edges=StepEdges([], 1e-4, 1.0),
                         att={"core": "fonbw", "excess": 0.019, "fitter": SimpleNamespace(y=np.zeros(n), effect_params=lambda fit, eff: {"a": {}}),
                              "yref_tr": None})

    def checked(dbic, own=None):
        # the training RMS whose BIC change against the nominal is `dbic` (k = 2);
        # the block keeps `own` of it when taken out of its refit (all by default)
        me._own_bic = lambda fit, eff, k, ntr: dbic if own is None else own
        rms = math.sqrt(mse_tr * math.exp((dbic - 2 * math.log(n)) / n))
        return Diagnosis.check_candidate(me, 0, 0, {"rms": rms, "th": [np.zeros(2)]}, None, 0.012, [block])

    assert checks.BIC_EVIDENCE == -10.0 and checks.OWN_SHARE == 0.5
    weak, strong = checked(-5.0), checked(-20.0)
    assert weak["delta_bic"] == pytest.approx(-5.0) and strong["delta_bic"] == pytest.approx(-20.0)
    assert weak["material"] and weak["gap_closed_step"] == pytest.approx(0.008 / 0.019)
    assert not weak["passed"] and "bootstrap" not in weak
    assert strong["passed"] and strong["bootstrap"]["p10"] == 0.3
    # the refit gained ΔBIC −20000, the block itself −9000 of it: the rest was
    # the refit polishing the model it was added to
    polished = checked(-20000.0, own=-9000.0)
    assert not polished["passed"] and "bootstrap" not in polished
    assert polished["failed"] == ("the block itself accounts for ΔBIC -9e+03 of its refit's -2e+04, not more "
                                  "than 0.5 of it: the rest is the refit of the model it was added to")
    assert checked(-20000.0, own=-11000.0)["passed"]
    # ... and whatever its share, the block's own part must be evidence by itself
    assert checked(-15.0, own=-9.0)["failed"].endswith("(the refit with the block taken out), not below -10")
    assert checked(-15.0, own=-11.0)["passed"]
    # held-out records pooled 0.9 % worse: only a block with a slack (a rail's) passes
    monkeypatch.setattr(checks, "loro", lambda *a: {"ratios": [1.009], "pooled_ratio": 1.009})
    assert not checked(-20.0)["passed"]
    block.loro_slack = 0.02
    assert checked(-20.0)["passed"]


def test_the_creep_law_is_counted_only_on_the_nominal_it_is_fitted_on(monkeypatch):
    # the training BIC charges creep's logarithmic law (one gain) on the FONBW
    # nominal, where it is fitted, and not on the reference nominal, where the
    # block is its three free modes: the same refit costs log(n) more on the
    # FONBW nominal
    from types import SimpleNamespace

    from fonbw.gap import checks
    from fonbw.gap.attribute import Diagnosis
    from fonbw.gap.edges import StepEdges

    monkeypatch.setattr(checks, "bootstrap", lambda *a: {"p05": 0.2, "p10": 0.3, "p50": 0.4})
    monkeypatch.setattr(checks, "loro", lambda *a: {"ratios": [0.5], "pooled_ratio": 0.5})
    creep = fx.Creep(DT, t_max=6.0)
    n, mse_tr, rms = 10_000, 0.01, 0.09
    seen, out = {}, {}
    for core in ("fonbw", "reference"):
        me = SimpleNamespace(current={"mse": 0.02, "mse_tr": mse_tr, "pred": None, "fit": None, "eff": []},
                             lib=[creep], sigma2=0.001, min_gap_closed=0.2, val_s=None, seed=0, candidates=[],
                             edges=StepEdges([], 1e-4, 1.0),
                             att={"core": core, "excess": 0.019, "yref_tr": None, "fitter": SimpleNamespace(
                                 y=np.zeros(n), effect_params=lambda fit, eff: {"creep": {}})})

        def own_bic(fit, eff, k, ntr, core=core):
            seen[core] = k
            return -1e3

        me._own_bic = own_bic
        out[core] = Diagnosis.check_candidate(me, 0, 0, {"rms": rms, "th": [np.zeros(0)]}, None, 0.012, [creep])
    assert seen == {"fonbw": 4, "reference": 3}
    fit_term = n * math.log(rms ** 2 / mse_tr)
    assert out["fonbw"]["delta_bic"] == pytest.approx(fit_term + 4 * math.log(n), rel=1e-12)
    assert out["reference"]["delta_bic"] == pytest.approx(fit_term + 3 * math.log(n), rel=1e-12)


def test_a_saturation_that_only_bends_the_top_of_the_loop_is_refused(monkeypatch):
    # slope drops measured on the blind harness: saturations fitted on cores
    # without one (their envelopes) dropped it by 0.04 to 0.57 (seed 29029);
    # the softest injected stroke limit by 0.78 alone on the nominal (seed
    # 32028) and by 0.30 beside the resonance accepted before it
    from types import SimpleNamespace

    from fonbw.gap import checks
    from fonbw.gap.attribute import Diagnosis
    from fonbw.gap.edges import StepEdges
    from fonbw.gap.effects import Saturation

    monkeypatch.setattr(checks, "bootstrap", lambda *a: {"p05": 0.2, "p10": 0.3, "p50": 0.4})
    monkeypatch.setattr(checks, "loro", lambda *a: {"ratios": [0.5], "pooled_ratio": 0.5})
    sat = Saturation(0.0, 20.0)
    assert sat.refuses({"knee": 17.2, "width": 2.2, "c": -0.571}).startswith("the slope above the knee drops by 57%")
    assert sat.refuses({"knee": 17.2, "width": 2.2, "c": -0.04}) is not None
    assert sat.refuses({"knee": 11.6, "width": 0.3, "c": -0.779}) is None
    assert sat.refuses({"knee": 18.9, "width": 0.1, "c": -1.417}) is None  # past a stop: bends back
    assert Saturation.min_drop == pytest.approx(2 / 3)

    c_now = {"c": 0.0}
    me = SimpleNamespace(current={"mse": 0.02, "mse_tr": 0.01, "pred": None, "fit": None, "eff": []},
                         lib=[sat], sigma2=0.001, min_gap_closed=0.2, val_s=None, seed=0, candidates=[],
                         edges=StepEdges([], 1e-4, 1.0), _own_bic=lambda *a: -math.inf,  # the block is all of it
                         att={"core": "fonbw", "excess": 0.019, "yref_tr": None, "fitter": SimpleNamespace(
                             y=np.zeros(10_000), effect_params=lambda fit, eff: {"saturation": dict(c_now)})})

    def checked(step, c):
        # closes 0.42 of the gap with ΔBIC far below -10: only the shape can fail it
        c_now["c"] = c
        return Diagnosis.check_candidate(me, 0, step, {"rms": 0.05, "th": [np.zeros(2)]}, None, 0.012, [sat])

    bend = checked(0, -0.571)
    assert bend["material"] and bend["delta_bic"] < -1e4
    assert not bend["passed"] and bend["failed"] == bend["refused"] and "bootstrap" not in bend
    assert checked(0, -0.779)["passed"]
    # a later step keeps the verdict of the block alone on the nominal
    # beside a resonance, whose peaks trade with the corner; beside a delay
    # the bend is refused again
    from fonbw.gap.effects import Delay, Dynamics

    me.candidates = [{"effect": "saturation", "checks": checked(0, -0.779)}]
    me.current["eff"] = [Dynamics(1e-4)]
    assert checked(1, -0.30)["passed"]
    me.current["eff"] = [Delay(1e-4)]
    assert checked(1, -0.30)["refused"].startswith("the slope above the knee drops by 30%")
    assert checked(1, -0.9)["passed"]  # a stop beside the other effect is one
    me.current["eff"] = [Dynamics(1e-4)]
    me.candidates = [{"effect": "saturation", "checks": checked(0, -0.441)}]
    assert not checked(1, -0.30)["passed"]
    assert checked(1, -0.9)["passed"]


def test_a_saturation_refused_as_a_bend_is_judged_again_when_a_rail_passes_and_closes_less(monkeypatch):
    # the stroke limit of blind-harness seed 41009 (a Prandtl-Ishlinskii
    # core): its block dropped the slope by 56 % and closed 0.94 of the gap,
    # the rail passed with 0.89 and was named in its place
    from types import SimpleNamespace

    from fonbw.gap import checks
    from fonbw.gap.attribute import Diagnosis
    from fonbw.gap.edges import StepEdges
    from fonbw.gap.effects import Clip, Saturation

    monkeypatch.setattr(checks, "bootstrap", lambda *a: {"p05": 0.2, "p10": 0.3, "p50": 0.4})
    monkeypatch.setattr(checks, "loro", lambda *a: {"ratios": [0.5], "pooled_ratio": 0.5})
    sat, clip = Saturation(0.0, 20.0), Clip(120.0)
    assert sat.overruled_by == "clip" and clip.overruled_by is None
    params = {"saturation": {"knee": 9.96, "width": 1.76, "c": -0.56}, "clip": {"level": 104.0, "knee": 1.8}}
    said = []
    me = SimpleNamespace(current={"mse": 0.02, "mse_tr": 0.01, "pred": None, "fit": None, "eff": []},
                         lib=[sat, clip], sigma2=0.001, min_gap_closed=0.2, val_s=None, seed=0, candidates=[],
                         edges=StepEdges([], 1e-4, 1.0), _own_bic=lambda *a: -math.inf, say=said.append,
                         att={"excess": 0.019, "yref_tr": None, "core": "reference", "fitter": SimpleNamespace(
                             y=np.zeros(10_000), effect_params=lambda fit, eff: params)})
    me.check_candidate = lambda *a, **k: Diagnosis.check_candidate(me, *a, **k)

    def step(gc_sat, gc_clip, clip_passes=True):
        said.clear()
        out = []
        for i, gc in ((0, gc_sat), (1, gc_clip)):
            mse = 0.02 - gc * 0.019
            fit = {"rms": 0.05 if i == 0 or clip_passes else 0.2, "th": [np.zeros(2)]}
            out.append({"i": i, "fit": fit, "pv": None, "mse": mse, "eff": [me.lib[i]],
                        "checks": me.check_candidate(i, 0, fit, None, mse, [me.lib[i]])})
        Diagnosis._overrule(me, 0, out)
        return [r["checks"] for r in out]

    s, c = step(0.94, 0.89)
    assert c["passed"] and s["passed"] and s["refused"] is None
    assert s["overruled"].startswith("the slope above the knee drops by 56%")
    assert s["gap_closed_step"] == pytest.approx(0.94) and s["bootstrap"]["p10"] == 0.3
    assert said == ['step 1: +saturation closes more than +clip, which passes: judged again without '
                    '"the slope above the knee drops by 56%, less than a stroke limit\'s 67%: a bend of the '
                    'loop", passes']
    # a later step (the rail accepted first, on its ΔBIC) does not take it for
    # a stop alone on the nominal: it is judged with its refusal again
    me.candidates = [{"effect": "saturation", "checks": s}]
    fit = {"rms": 0.05, "th": [np.zeros(2)]}
    later = me.check_candidate(0, 1, fit, None, 0.015, [clip, sat])
    assert not later["passed"] and later["refused"].startswith("the slope above the knee drops by 56%")
    me.candidates = []
    # the rail closes more (a rail, seeds 33001 and 42015): the bend stays refused
    s, c = step(0.69, 0.998)
    assert c["passed"] and not s["passed"] and "overruled" not in s and said == []
    # the rail fails (its ΔBIC > 0: no flat top in the records): refused
    s, c = step(0.94, 0.2, clip_passes=False)
    assert not c["passed"] and not s["passed"] and s["refused"].startswith("the slope above") and said == []
    # a saturation that is a stop passes on its own and is left as it was
    params["saturation"]["c"] = -0.9
    s, c = step(0.94, 0.89)
    assert s["passed"] and "overruled" not in s and said == []


def test_nominal_of_a_set_with_a_mid_drive_record_is_identified_on_the_records_at_rest():
    # a FONBW core whose eq.-19 training record is cut mid-drive at 3.5 s (the
    # other two start at rest and sweep 0-104 V): the identification leaves the
    # cut record out, the refit takes it after its estimated history
    import blind_gap as bg
    import gap_cores as gc
    import gap_truth as tr

    from fonbw.gap.attribute import Diagnosis
    from fonbw.gap.checks import mse

    seed = 22023
    sc = tr.draw_scenario(seed, scale=bg.DEFAULTS["scale"], family=tr.scenario_family(seed, tuple(gc.FAMILIES)),
                          mid_drive=bg.DEFAULTS["mid_drive"])
    d = Diagnosis(sc["train"], sc["validate"], seed=seed)
    assert [s.at_rest for s in d.rs.starts["train"]] == [False, True, True]
    assert len(d.coarse_id) == 2 and len(d.coarse) == 3
    d.fit_nominal()
    assert d.rs.info[("train", 0)]["history"].startswith("from rest through 120 V")
    # measured: validation RMS 0.0251 µm (noise 0.0248); identified on all three
    # records, the backward burn-in included, 0.218 µm
    assert math.sqrt(mse(d.val_s, d.p0_va)) < 0.035


def test_refit_on_new_training_histories_is_undone_when_it_fits_the_records_at_rest_worse():
    # a Preisach core (a form no FONBW reaches) whose eq.-19 training record is
    # cut mid-drive: the refit nominal chooses another history for it, and the
    # refit on that one fits the two training records at rest worse (MSE 0.1358
    # against 0.1193 µm²) and validates at 0.489 µm; undone, 0.453 µm
    import blind_gap as bg
    import gap_cores as gc
    import gap_truth as tr

    from fonbw.gap.attribute import Diagnosis
    from fonbw.gap.checks import mse

    seed = 23019
    sc = tr.draw_scenario(seed, scale=bg.DEFAULTS["scale"], family=tr.scenario_family(seed, tuple(gc.FAMILIES)),
                          mid_drive=bg.DEFAULTS["mid_drive"])
    d = Diagnosis(sc["train"], sc["validate"], seed=seed)
    assert d.rs.from_rest("train") == [1, 2] and d.rs.from_rest("validate") == [0, 1, 2, 3]
    d.fit_nominal()
    assert d._rest_mse([1, 2]) == pytest.approx(0.1193, rel=0.01)
    assert math.sqrt(mse(d.val_s, d.p0_va)) == pytest.approx(0.453, abs=0.01)


def test_a_block_accounts_for_its_own_bic_and_one_that_does_nothing_for_none(monkeypatch):
    # a 1-ms delay on a FONBW core: the block accounts for at least all of its
    # refit's ΔBIC, since taken out of the refit it leaves a nominal that fits
    # no better than the one fitted without it (measured: -13414 for both; the
    # refit left the nominal where it was)
    from fonbw.gap import checks

    _, train, val = tr.fixed_case(12, {"delay": {"seconds": 1e-3}}, scale=0.25)
    kw = dict(seed=0, budget=80, refit_evals=10, effects=("delay",), max_effects=1, workers=1)
    ch = diagnose(train, val, **kw)["candidates"][0]["checks"]
    assert ch["passed"] and ch["delta_bic"] < -1000.0
    assert math.isfinite(ch["own_bic"]) and ch["own_bic"] <= ch["delta_bic"] + 1e-9 * abs(ch["delta_bic"])
    assert ch["own_bic"] == pytest.approx(-13414, rel=0.05) and ch["delta_bic"] == pytest.approx(-13414, rel=0.05)
    # made the identity, the block changes no sample: taken out, the fit is the
    # same and its own ΔBIC is exactly its one parameter's penalty, ln n. The
    # refit still lowered the training BIC (by polishing the nominal, which
    # the delay in the records had pulled off), and only the own part refuses it
    monkeypatch.setattr(fx.Delay, "transform_input", lambda self, u, dt, th: u)
    ch = diagnose(train, val, **kw)["candidates"][0]["checks"]
    n = sum(len(r.u) for r in train)
    assert ch["own_bic"] == pytest.approx(math.log(n), rel=1e-12)
    assert ch["delta_bic"] < checks.BIC_EVIDENCE
    assert checks.lacks_evidence(ch["delta_bic"], ch["own_bic"]).startswith("the block itself accounts for")


def test_a_block_without_which_its_refit_diverges_accounts_for_all_of_it():
    from types import SimpleNamespace

    from fonbw.gap.greedy import GreedySteps

    def own(rms_with, rms_without):
        fitter = SimpleNamespace(cost_at=lambda x, eff, th, yref: rms_without)
        me = SimpleNamespace(att={"fitter": fitter, "yref_tr": None})
        fit = {"x": np.zeros(3), "th": [np.zeros(1), np.zeros(2)], "rms": rms_with}
        return GreedySteps._own_bic(me, fit, [None, None], 2, 1000)

    # n ln(with² / without²) + k ln n, and the two ends where a fit is not finite
    assert own(0.1, 0.2) == pytest.approx(1000 * math.log(0.25) + 2 * math.log(1000))
    assert own(0.1, math.inf) == -math.inf
    assert own(math.inf, 0.2) == math.inf
