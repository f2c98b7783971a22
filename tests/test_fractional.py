"""GL weights and memory engines against closed forms and a plain O(N²) sum."""
import math

import numpy as np
import pytest
from scipy import integrate, special

from fonbw import fractional as fr


@pytest.mark.parametrize("lam", [0.2, 0.5, 0.622, 0.9557, 1.0])
def test_weights_are_signed_binomials(lam):
    j = np.arange(40)
    ref = (-1.0) ** j * special.binom(lam, j)
    np.testing.assert_allclose(fr.gl_weights(lam, 40), ref, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("lam", [0.3, 0.6, 0.9])
def test_weights_integral_identity_and_modes(lam):
    # w_j = -(sin πλ/π) ∫ e^{-sj}(e^s-1)^λ ds, and the modes reproduce w_{K+m}
    w = fr.gl_weights(lam, 200)
    for j in (1, 5, 40):
        val, _ = integrate.quad(lambda s: math.exp(lam * (s + math.log1p(-math.exp(-s))) - s * j), 0, np.inf, limit=200)
        assert -math.sin(math.pi * lam) / math.pi * val == pytest.approx(w[j], rel=1e-7)
    K, M = fr.FAST_K, fr.FAST_M
    c, r = fr.tail_modes(lam, K, M)
    m = np.arange(1, 150 - K)
    approx = (c[None, :] * r[None, :] ** m[:, None]).sum(axis=1)
    np.testing.assert_allclose(approx, w[K + 1:150], rtol=1e-6)


@pytest.mark.parametrize("p", [1.0, 1.5, 2.0])
@pytest.mark.parametrize("lam", [0.4, 0.8])
def test_gl_derivative_of_power_is_first_order_accurate(p, lam):
    # D^λ t^p = Γ(p+1)/Γ(p+1-λ) t^(p-λ); the GL error is O(dt)
    T = 1.0
    errs = []
    for n in (2000, 4000):
        dt = T / n
        t = np.arange(n + 1) * dt
        d = fr.gl_derivative(t**p, dt, lam)
        exact = special.gamma(p + 1) / special.gamma(p + 1 - lam) * T ** (p - lam)
        errs.append(abs(d[-1] - exact) / exact)
    assert errs[0] < 2e-3
    assert errs[0] / errs[1] == pytest.approx(2.0, rel=0.1)


@pytest.mark.parametrize("lam", [0.5, 0.9])
def test_gl_derivative_of_sine_matches_caputo_integral(lam):
    # sin(0) = 0, so the RL (GL) and Caputo derivatives agree:
    # D^λ sin(ωt) = ω/Γ(1-λ) ∫_0^t τ^(-λ) cos(ω(t-τ)) dτ
    w, dt, T = 2 * np.pi * 2.0, 1e-4, 1.3
    n = int(round(T / dt))
    t = np.arange(n + 1) * dt
    d = fr.gl_derivative(np.sin(w * t), dt, lam)
    for tk in (0.37, 1.3):
        val, _ = integrate.quad(lambda tau: w * math.cos(w * (tk - tau)), 0, tk, weight="alg", wvar=(-lam, 0))
        ref = val / special.gamma(1 - lam)
        k = int(round(tk / dt))
        assert d[k] == pytest.approx(ref, abs=2e-3 * w**lam)


def _plain_gl(x, dt, lam):
    w = fr.gl_weights(lam, len(x))
    out = np.empty(len(x))
    for k in range(len(x)):
        out[k] = sum(w[j] * x[k - j] for j in range(k + 1))
    return out * dt ** (-lam)


@pytest.mark.parametrize("lam", [0.35, 0.9557])
def test_exact_engine_equals_plain_sum(lam):
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.standard_normal(600))
    dt = 1e-3
    ref = _plain_gl(x, dt, lam)
    got = fr.apply_op(fr.make_op(lam, dt, "exact", n_steps=len(x)), x)
    np.testing.assert_allclose(got, ref, rtol=1e-11, atol=1e-11 * np.max(np.abs(ref)))
    grown = fr.apply_op(fr.make_op(lam, dt, "exact"), x)  # window grows from its default
    np.testing.assert_allclose(grown, ref, rtol=1e-11, atol=1e-11 * np.max(np.abs(ref)))


@pytest.mark.parametrize("lam", [0.3, 0.622, 0.9557])
def test_fast_engine_within_its_tail_bound(lam):
    rng = np.random.default_rng(2)
    n, dt = 20000, 1e-4
    x = np.cumsum(rng.standard_normal(n)) * 1e-2
    exact = fr.apply_op(fr.make_op(lam, dt, "exact", n_steps=n), x)
    fast = fr.apply_op(fr.make_op(lam, dt, "fast"), x)
    E1 = fr.tail_error(lam, horizon=n)
    bound = E1 * dt ** (-lam) * np.max(np.abs(x))
    err = np.max(np.abs(fast - exact))
    assert err <= bound * (1 + 1e-6) + 1e-12 * np.max(np.abs(exact))
    assert err / np.max(np.abs(exact)) < 1e-6


def test_short_memory_is_inaccurate_as_documented():
    # a slowly varying signal: the truncated tail is what the GL sum needs
    n, dt, lam = 20000, 1e-4, 0.9
    t = np.arange(n) * dt
    x = 1.0 - np.cos(2 * np.pi * 1.0 * t)
    exact = fr.gl_derivative(x, dt, lam)
    short = fr.apply_op(fr.make_op(lam, dt, "short", L=1000), x)
    rel = np.max(np.abs(short - exact)) / np.max(np.abs(exact))
    assert rel > 0.02


@pytest.mark.parametrize("lam", [0.622, 0.9557])
def test_oustaloup_follows_new_fod_formula(lam):
    # the discrete filter's response equals the continuous new_fod formula in band
    dt, N, wb, wh, b, d = 1e-4, 5, 0.01, 1000.0, 10.0, 9.0
    A, B, C, D = fr.oustaloup_ss(lam, dt)
    mu = wh / wb
    k = np.arange(-N, N + 1)
    wz = wb * mu ** ((k + N + 0.5 - 0.5 * lam) / (2 * N + 1))
    wp = wb * mu ** ((k + N + 0.5 + 0.5 * lam) / (2 * N + 1))
    for w in (0.1, 1.0, 31.4, 300.0):
        s = 1j * w
        Hc = (d * wh / b) ** lam * np.prod((s + wz) / (s + wp)) * (d * s**2 + b * wh * s) / (
            d * (1 - lam) * s**2 + b * wh * s + d * lam)
        z = np.exp(1j * w * dt)
        Hd = C @ np.linalg.solve(z * np.eye(len(B)) - A, B) + D
        assert abs(Hd / Hc - 1) < 2e-3
        if not 1.0 <= w <= 100.0:
            continue  # within two decades of the band edges the phase falls off
        # in band: about 0.9^λ |ω|^λ with phase λπ/2 (why it differs from GL by several %)
        assert abs(Hc) / w**lam == pytest.approx(0.9**lam, rel=0.04)
        assert np.angle(Hc) == pytest.approx(lam * np.pi / 2, abs=0.03)


def test_lambda_one_is_backward_difference_for_every_engine():
    x = np.array([0.0, 1.0, 3.0, 2.0, 2.0, -1.0])
    dt = 0.5
    ref = np.diff(np.concatenate([[0.0], x])) / dt
    for eng in fr.ENGINES:
        np.testing.assert_allclose(fr.apply_op(fr.make_op(1.0, dt, eng), x), ref, rtol=1e-15)


@pytest.mark.parametrize("bad", [0.0, -0.1, 1.01, math.nan, math.inf])
def test_bad_order_is_refused(bad):
    with pytest.raises(ValueError, match="0 < λ ≤ 1"):
        fr.make_op(bad, 1e-3)


def test_bad_engine_and_step_are_refused():
    with pytest.raises(ValueError, match="unknown memory engine"):
        fr.make_op(0.5, 1e-3, "quick")
    with pytest.raises(ValueError, match="positive"):
        fr.make_op(0.5, 0.0)


def _tail_modes_numpy(lam, K, M):
    """The fast engine's modes written with numpy and libm per node (the
    library compiles the same arithmetic)."""
    s_hi = 40.0 / (K + 1.0 - lam)
    x = np.linspace(math.log(1e-9), math.log(s_hi), M)
    hx = x[1] - x[0] if M > 1 else math.log(s_hi / 1e-9)
    s = np.array([math.exp(v) for v in x])
    logf = lam * np.array([math.log(math.expm1(v)) for v in s]) - s * K
    q = -(math.sin(math.pi * lam) / math.pi) * hx * s * np.array([math.exp(v) for v in logf])
    g = math.exp(-hx * (1.0 + lam))
    q[0] += -(math.sin(math.pi * lam) / math.pi) * hx * 1e-9 ** (1.0 + lam) * g / (1.0 - g)
    return q, np.array([math.exp(-v) for v in s])


@pytest.mark.parametrize("K, M", [(fr.FAST_K, fr.FAST_M), (8, 1), (16, 2), (100, 23)])
def test_compiled_tail_modes_equal_the_numpy_arithmetic_bit_for_bit(K, M):
    # the native FMUs rebuild the modes in C with libm and are held to the
    # library bit for bit, so the compiled nodes may not move by one ulp
    rng = np.random.default_rng(K * 100 + M)
    for lam in np.concatenate([[1e-6, 0.3, 0.5, 0.999999], rng.uniform(0.0, 1.0, 300)]):
        c, r = fr.tail_modes(float(lam), K, M)
        c0, r0 = _tail_modes_numpy(float(lam), K, M)
        assert c.tobytes() == c0.tobytes() and r.tobytes() == r0.tobytes(), lam
