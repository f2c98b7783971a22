"""Models against independent references: CBW ≡ NBW, λ = 1 ≡ backward Euler,
fast ≡ exact, stepper ≡ simulate, JSON round trips, input validation."""
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import optimize

import fonbw
from fonbw import hysteresis as H
from fonbw.paper import TABLE1_FONBW
from fonbw.signals import eq19_input

TABLE1 = TABLE1_FONBW
FIG1 = dict(alpha=0.1, k=1.0, D=1.0, A=0.7, beta=0.6, gamma=0.5, n=1.0)


def eq19(T, dt):
    return eq19_input(1.0 / dt, T)[1]


def sine(f, T, dt, amp=60.0):
    t = np.arange(int(round(T / dt))) * dt
    return amp - amp * np.cos(2 * np.pi * f * t)


@pytest.mark.parametrize("n", [1.0, 2.5])
@pytest.mark.parametrize("sym", [True, False])
def test_cbw_equals_its_nbw(n, sym):
    c = fonbw.CBW(**{**FIG1, "n": n})
    u = np.sin(2 * np.pi * np.arange(3000) / 1000) * 2.0 if sym else sine(1.0, 3.0, 1e-3, 1.5)
    y_c = c.simulate(u, 1e-3)
    y_n = c.to_nbw().simulate(u, 1e-3)
    assert np.max(np.abs(y_c - y_n)) <= 1e-9 * np.max(np.abs(y_c))
    # and the loop is a real hysteresis loop, not a line
    assert np.ptp(y_c - FIG1["alpha"] * FIG1["k"] * u) > 0.1


def test_cbw_to_nbw_constants():
    nb = fonbw.CBW(**FIG1).to_nbw()
    h0 = 0.7 / 1.1
    assert nb.rho == pytest.approx(0.7 / h0)
    assert nb.sigma == pytest.approx(0.6 / 1.1)
    assert nb.kh == pytest.approx(0.9 * h0)
    assert float(nb.ku[0]) == pytest.approx(0.1)
    with pytest.raises(ValueError, match="A/\\(β\\+γ\\) > 0"):
        fonbw.CBW(**{**FIG1, "gamma": -0.6}).to_nbw()


def _backward_euler_nbw(u, ku, kh, rho, sigma, n):
    """Independent reference: brentq on each implicit backward-Euler step."""
    hb, out, up = 0.0, [], u[0]
    for uk in u:
        du = uk - up
        f = lambda x: x - hb - rho * (du - sigma * abs(du) * abs(x) ** (n - 1) * x + (sigma - 1) * du * abs(x) ** n)
        lo, hi = min(0.0, hb + rho * du) - 1.0, max(0.0, hb + rho * du) + 1.0
        hb = optimize.brentq(f, lo, hi, xtol=1e-300, rtol=8.9e-16, maxiter=500)
        out.append(np.polyval([*ku[::-1], 0.0], uk) + kh * hb)
        up = uk
    return np.array(out)


@pytest.mark.parametrize("n", [1.0, 2.0006, 3.4])
def test_lambda_one_is_backward_euler_nbw(n):
    u = sine(5.0, 0.4, 1e-4)
    p = dict(ku=[0.18, -1e-4, 2e-7], kh=-2.0, rho=0.05, sigma=0.8, n=n)
    ref = _backward_euler_nbw(u, **p)
    for eng in ("fast", "exact", "oustaloup"):
        got = fonbw.FONBW(**p, lam1=1.0, lam2=1.0, memory=eng).simulate(u, 1e-4)
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.max(np.abs(ref)))
    np.testing.assert_allclose(fonbw.NBW(**p).simulate(u, 1e-4), ref, rtol=1e-12, atol=1e-12 * np.max(np.abs(ref)))


def test_fast_matches_exact_on_table1_over_1e5_steps():
    u = eq19(10.0, 1e-4)
    assert len(u) == 100_000
    ye = fonbw.FONBW(**TABLE1, memory="exact").simulate(u, 1e-4)
    yf = fonbw.FONBW(**TABLE1, memory="fast").simulate(u, 1e-4)
    rel = np.max(np.abs(yf - ye)) / np.max(np.abs(ye))
    assert rel <= 1e-7
    # the Table-1 model spans the paper's PEA stroke (~15 µm at 120 V)
    assert 10 < np.ptp(ye) < 25


def test_other_engines_differ_from_gl_as_documented():
    u = eq19(2.0, 1e-4)
    ye = fonbw.FONBW(**TABLE1, memory="exact").simulate(u, 1e-4)
    rng = np.ptp(ye)
    d_oust = np.max(np.abs(fonbw.FONBW(**TABLE1, memory="oustaloup").simulate(u, 1e-4) - ye)) / rng
    d_short = np.max(np.abs(fonbw.FONBW(**TABLE1, memory="short").simulate(u, 1e-4) - ye)) / rng
    assert 1e-4 < d_oust < 0.1
    assert 1e-3 < d_short < 0.5


MODELS = {
    "fonbw-fast": lambda: fonbw.FONBW(**TABLE1),
    "fonbw-exact": lambda: fonbw.FONBW(**TABLE1, memory="exact"),
    "fonbw-short": lambda: fonbw.FONBW(**TABLE1, memory="short", L=50),
    "fonbw-oustaloup": lambda: fonbw.FONBW(**TABLE1, memory="oustaloup"),
    "nbw": lambda: fonbw.NBW(ku=[0.18, -1e-4], kh=-2.0, rho=0.05, sigma=0.8, n=1.5),
    "cbw": lambda: fonbw.CBW(ka=0.1547, kb=-3.666e5, D=0.5552, A=6.1987e-7, beta=0.0364, gamma=0.0272, n=1.0003),
    "zhu": lambda: fonbw.Zhu2016(m0=0.1026, c0=258.2, k0=1.5567e5, k1=4.3915e-7, x0=0.0, tau=2.0408e-5,
                                 A=-0.0068, beta=0.0457, gamma=-0.0255, delta=-0.0024, n=1.0483),
}


@pytest.mark.parametrize("name", MODELS)
def test_stepper_equals_simulate_bit_for_bit(name):
    m = MODELS[name]()
    u = eq19(0.35, 1e-4)  # 3500 steps: the exact stepper's window grows past its start size
    y = m.simulate(u, 1e-4)
    s = m.stepper(1e-4)
    ys = np.array([s.step(v) for v in u])
    assert np.array_equal(ys, y)
    assert np.all(np.isfinite(y))


@pytest.mark.parametrize("name", MODELS)
def test_state_rollback_replays_bit_for_bit(name):
    m = MODELS[name]()
    u = eq19(0.3, 1e-4)
    s = m.stepper(1e-4)
    for v in u[:1200]:
        s.step(v)
    saved = s.get_state()
    first = [s.step(v) for v in u[1200:]]
    assert s.peek(u[-1]) == s.peek(u[-1])
    s.set_state(saved)
    second = [s.step(v) for v in u[1200:]]
    assert first == second
    fresh = m.stepper(1e-4)
    fresh.set_state(saved)
    assert [fresh.step(v) for v in u[1200:]] == first


@pytest.mark.parametrize("name", MODELS)
def test_peek_does_not_advance(name):
    m = MODELS[name]()
    u = eq19(0.08, 1e-4)
    a, b = m.stepper(1e-4), m.stepper(1e-4)
    rng = np.random.default_rng(0)
    ya, yb = [], []
    for v in u:
        for trial in rng.uniform(0, 120, 3):
            a.peek(trial)  # trial evaluations must leave no trace
        y_peek = a.peek(v)
        ya.append(a.step(v))
        assert ya[-1] == y_peek
        yb.append(b.step(v))
    assert ya == yb


@pytest.mark.parametrize("name", MODELS)
def test_save_load_round_trip(name, tmp_path):
    m = MODELS[name]()
    path = tmp_path / f"{name}.json"
    m.save(path)
    d = json.loads(path.read_text(encoding="utf-8"))
    assert d["kind"] == m.kind and "units" in d
    m2 = fonbw.load_model(path)
    assert type(m2) is type(m)
    u = eq19(0.2, 1e-4)
    assert np.array_equal(m2.simulate(u, 1e-4), m.simulate(u, 1e-4))


def test_zhu_mechanics_equal_python_control_zoh():
    # with β = γ = δ = 0, h = A(u − u0): the model is linear, and with τ huge the
    # direct term is constant, so x is the ZOH response of the mass-spring-damper
    # to the force sampled one step ahead (force held over the step ending at t_k).
    import control

    m0, c0, k0, k1, tau, A = 0.1, 250.0, 1.5e5, 3e-3, 1e9, 0.02
    z = fonbw.Zhu2016(m0=m0, c0=c0, k0=k0, k1=k1, x0=0.5, tau=tau, A=A, beta=0.0, gamma=0.0, delta=0.0, n=1.0)
    dt = 1e-4
    u = sine(20.0, 0.1, dt)
    y = z.simulate(u, dt)
    sys = control.c2d(control.tf([1.0], [m0, c0, k0]), dt, method="zoh")
    t = np.arange(len(u) + 1) * dt
    f = k1 / tau * np.exp(-t[:-1] / tau) * u + A * (u - u[0])
    resp = control.forced_response(sys, T=t, U=np.concatenate([f, [0.0]]))
    np.testing.assert_allclose(y, 0.5 + resp.outputs[1:], rtol=1e-9, atol=1e-12)


def test_population_rows_equal_single_runs_and_bad_rows_are_nan():
    u = eq19(0.5, 1e-4)
    names = H.param_names("fonbw", 3)
    base = np.array([TABLE1["ku"][0], TABLE1["ku"][1], TABLE1["ku"][2], TABLE1["kh"], TABLE1["rho"],
                     TABLE1["sigma"], TABLE1["n"], TABLE1["lam1"], TABLE1["lam2"]])
    th = np.vstack([base, base, base, base])
    th[1, names.index("lam2")] = 0.8
    th[2, names.index("rho")] = -1.0   # invalid
    th[3, names.index("lam1")] = 1.0   # the backward-difference case, different layout
    Y = H.simulate_population("fonbw", th, u, 1e-4)
    assert np.array_equal(Y[0], fonbw.FONBW(**TABLE1).simulate(u, 1e-4))
    assert np.array_equal(Y[1], fonbw.FONBW(**{**TABLE1, "lam2": 0.8}).simulate(u, 1e-4))
    assert np.all(np.isnan(Y[2]))
    assert np.array_equal(Y[3], fonbw.FONBW(**{**TABLE1, "lam1": 1.0}).simulate(u, 1e-4))
    for kind, mk in (("cbw", MODELS["cbw"]), ("zhu", MODELS["zhu"])):
        m = mk()
        vec = [m.params[k] for k in H.param_names(kind)]
        assert np.array_equal(H.simulate_population(kind, [vec], u, 1e-4)[0], m.simulate(u, 1e-4))


def test_divergent_candidate_is_nan_not_a_crash():
    # ρ = 1e308 overflows the implicit step's coefficients on the first moving sample:
    # that row turns NaN from there on, the others are untouched, nothing raises
    u = sine(5.0, 0.05, 1e-4, 60.0)
    good = [0.1, 0.0, 0.0, 1.0, 0.05, 0.8, 2.0]
    bad = [0.1, 0.0, 0.0, 1.0, 1e308, 0.8, 2.0]
    y = H.simulate_population("nbw", [good, bad], u, 1e-4)
    assert np.all(np.isfinite(y[0]))
    assert np.array_equal(y[0], fonbw.NBW(ku=[0.1, 0.0, 0.0], kh=1.0, rho=0.05, sigma=0.8, n=2.0).simulate(u, 1e-4))
    k = int(np.argmax(np.isnan(y[1])))
    assert np.isnan(y[1]).any() and np.all(np.isnan(y[1][k:])) and np.all(np.isfinite(y[1][:k]))
    assert not np.isinf(y).any()


finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6)


@settings(max_examples=60, deadline=None)
@given(rho=st.floats(max_value=0.0, allow_nan=False) | st.just(math.nan) | st.just(math.inf))
def test_rho_must_be_positive_finite(rho):
    with pytest.raises(ValueError, match="rho"):
        fonbw.FONBW(ku=[0.1], kh=1.0, rho=rho, sigma=0.5, n=1.0, lam1=0.5, lam2=0.5)


@settings(max_examples=60, deadline=None)
@given(n=st.floats(max_value=0.999999, allow_nan=False) | st.just(math.nan))
def test_n_must_be_at_least_one(n):
    with pytest.raises(ValueError, match="n"):
        fonbw.NBW(ku=0.1, kh=1.0, rho=1.0, sigma=0.5, n=n)


@settings(max_examples=80, deadline=None)
@given(lam=st.floats(allow_nan=True, allow_infinity=True).filter(lambda v: not (0 < v <= 1)))
def test_orders_must_be_in_unit_interval(lam):
    with pytest.raises(ValueError, match="lam1"):
        fonbw.FONBW(ku=[0.1], kh=1.0, rho=1.0, sigma=0.5, n=1.0, lam1=lam, lam2=0.5)


@settings(max_examples=60, deadline=None)
@given(rho=st.floats(min_value=1e-9, max_value=1e3), sigma=st.floats(min_value=0.5, max_value=1e6),
       n=st.floats(min_value=1.0, max_value=4.0), lam=st.floats(min_value=0.05, max_value=1.0))
def test_valid_parameters_give_finite_bounded_state(rho, sigma, n, lam):
    # σ ≥ 1/2: the implicit step has a unique root; the state stays finite
    m = fonbw.FONBW(ku=[0.1], kh=1.0, rho=rho, sigma=sigma, n=n, lam1=lam, lam2=lam)
    y, hb = m.simulate(sine(10.0, 0.05, 1e-4), 1e-4, return_state=True)
    assert np.all(np.isfinite(y)) and np.all(np.isfinite(hb))


def test_bad_inputs_are_refused():
    m = fonbw.FONBW(**TABLE1)
    with pytest.raises(ValueError, match="NaN"):
        m.simulate([0.0, math.nan], 1e-4)
    with pytest.raises(ValueError, match="1-D"):
        m.simulate(np.zeros((2, 2)), 1e-4)
    with pytest.raises(ValueError, match="dt"):
        m.simulate([0.0, 1.0], -1.0)
    with pytest.raises(ValueError, match="ku"):
        fonbw.FONBW(ku=[], kh=1.0, rho=1.0, sigma=0.5, n=1.0)
    with pytest.raises(ValueError, match="either alpha and k, or ka and kb"):
        fonbw.CBW(alpha=0.1, ka=1.0, D=1, A=1, beta=1, gamma=1, n=1)
    with pytest.raises(ValueError, match="field 'kind'"):
        fonbw.model_from_dict({"kind": "preisach", "params": {}})
    with pytest.raises(ValueError, match="field 'params'"):
        fonbw.model_from_dict({"kind": "nbw", "params": {"ku": 1.0}})


def test_load_model_errors_name_the_file(tmp_path):
    p = tmp_path / "broken.json"
    p.write_text("{not json", encoding="utf-8")
    with pytest.raises(ValueError, match="broken.json: line 1"):
        fonbw.load_model(p)
    with pytest.raises(ValueError, match="missing.json: cannot open"):
        fonbw.load_model(tmp_path / "missing.json")


def test_population_with_one_input_row_per_candidate():
    u = eq19(0.3, 1e-4)
    U = np.vstack([u, 0.5 * u, u[::-1].copy()])
    base = [TABLE1["ku"][0], TABLE1["ku"][1], TABLE1["ku"][2], TABLE1["kh"], TABLE1["rho"],
            TABLE1["sigma"], TABLE1["n"], TABLE1["lam1"], TABLE1["lam2"]]
    th = np.array([base, base, base])
    th[2, 4] = -1.0  # invalid row stays NaN
    Y = H.simulate_population("fonbw", th, U, 1e-4)
    m = fonbw.FONBW(**TABLE1)
    assert np.array_equal(Y[0], m.simulate(u, 1e-4))
    assert np.array_equal(Y[1], m.simulate(0.5 * u, 1e-4))
    assert np.all(np.isnan(Y[2]))
    with pytest.raises(ValueError, match="one row per parameter vector"):
        H.simulate_population("fonbw", th, U[:2], 1e-4)
