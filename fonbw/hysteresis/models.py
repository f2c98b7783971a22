"""The hysteresis model classes and their batch simulation paths.

Parameter checks, the common base :class:`_Model` (parameters, JSON, units)
and the models FONBW, NBW, CBW and Zhu2016. ``simulate`` packs the
parameters and runs :func:`fonbw.hysteresis.kernels.run_kernel`; FONBW with
the exact engine on long runs sums the GL history by blocked FFT
convolutions instead. ``stepper`` returns a :mod:`fonbw.hysteresis.stepper`
object running the same step kernel. Units: u [V], displacement [µm], t [s].
"""
from __future__ import annotations

import json
import math

import numpy as np

from .. import fractional as fr
from ..io import as_signal, atomic_open
from .kernels import (CODE_CBW, CODE_FONBW, CODE_ZHU, FONBW_S0, cbw_core, cbw_step,
                      fonbw_core, fonbw_exact_leaf, fonbw_step, fonbw_views, plain_views,
                      run_kernel, zhu_core, zhu_step)
from .stepper import Stepper, _FONBWStepper

#: Model kinds, as written in the ``kind`` field of a saved model.
KINDS = ("fonbw", "nbw", "cbw", "zhu")


# ---------------------------------------------------------------------------
# validation helpers

def _finite(name, v):
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"parameter {name} must be a number, got {v!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"parameter {name} must be finite, got {v!r}")
    return v


def _positive(name, v):
    v = _finite(name, v)
    if v <= 0:
        raise ValueError(f"parameter {name} must be > 0, got {v!r}")
    return v


def _order_n(v):
    v = _finite("n", v)
    if v < 1:
        raise ValueError(f"parameter n must satisfy n ≥ 1, got {v!r}")
    return v


def _lam(name, v):
    v = _finite(name, v)
    if not 0 < v <= 1:
        raise ValueError(f"parameter {name} must satisfy 0 < {name} ≤ 1, got {v!r}")
    return v


def _ku(ku):
    try:
        arr = np.atleast_1d(np.asarray(ku, dtype=float)) if not isinstance(ku, str) else None
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"parameter ku must be a number or a non-empty list of numbers, got {ku!r}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"parameter ku must be finite, got {list(arr)}")
    return arr


def _input(u):
    return as_signal(u, "input u [V]")


def _dt(dt):
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise ValueError(f"step dt must be a number of seconds, got {dt!r}") from None
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"step dt must be a positive finite number of seconds, got {dt!r}")
    return dt


# ---------------------------------------------------------------------------
# models

#: Optional top-level fields of a model's JSON besides kind, params and units:
#: "u_range" ([u_min, u_max] of the training input [V]) and "invertibility"
#: ({"dt": [s], "slope_min": [µm/V], "margin": …}, see fonbw.invertibility) and
#: "start" (the rest cycle the model was identified after, see fonbw.compensate.rest).
META_KEYS = ("u_range", "invertibility", "start")


class _Model:
    """Common part: parameters, JSON, units."""

    kind = ""
    units: dict = {}
    descriptions: dict = {}

    def to_dict(self) -> dict:
        """JSON-ready description: kind, parameters, units."""
        params = {k: (list(map(float, v)) if isinstance(v, np.ndarray) else v) for k, v in self.params.items()}
        d = {"kind": self.kind, "params": params, "units": {k: self.units[k] for k in params if k in self.units}}
        # where the model came from (training input range, invertibility at a
        # step): written beside the parameters, read back by model_from_dict
        d.update({k: v for k, v in (getattr(self, "meta", None) or {}).items() if k in META_KEYS})
        return d

    def save(self, path) -> None:
        """Write the parameter set as JSON (atomically)."""
        with atomic_open(path, "w", encoding="utf-8") as fh:
            json.dump(self.to_dict(), fh, indent=2, ensure_ascii=False)
            fh.write("\n")

    def __repr__(self):
        inner = ", ".join(f"{k}={v!r}" for k, v in self.to_dict()["params"].items())
        return f"{type(self).__name__}({inner})"

    def __eq__(self, other):
        # the parameters decide, not the provenance fields (META_KEYS)
        def core(m):
            return json.dumps({k: v for k, v in m.to_dict().items() if k not in META_KEYS})
        return type(self) is type(other) and core(self) == core(other)

    def simulate(self, u, dt) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def stepper(self, dt) -> "Stepper":  # pragma: no cover - abstract
        raise NotImplementedError


_FONBW_UNITS = {
    "ku": "µm/V^i (coefficient of u^i)", "kh": "µm", "rho": "1/V", "sigma": "1", "n": "1",
    "lam1": "1", "lam2": "1", "memory": "-",
}


class FONBW(_Model):
    """Fractional-order normalized Bouc-Wen model, eqs. (9)–(11).

    H(u,t) = Σ_i ku_i u^i + kh ħ(t),
    D^λ2 ħ = ρ (D^λ1 u − σ |D^λ1 u| |ħ|^(n−1) ħ + (σ−1) D^λ1 u |ħ|^n).

    Parameters
    ----------
    ku : float or sequence of float
        Polynomial coefficients k_u1 … k_uN of g(u) [µm/V^i] (eq. 10).
    kh : float
        Hysteretic gain [µm].
    rho : float
        ρ > 0 [1/V] (with λ1 = λ2 = 1; in general [s^(λ1−λ2)/V]).
    sigma : float
        σ (shape; σ ≥ 1/2 gives the bounded, unique-step case).
    n : float
        Sharpness, real n ≥ 1.
    lam1, lam2 : float
        Orders of the derivatives of u and of ħ, 0 < λ ≤ 1.
    memory : {"fast", "exact", "short", "oustaloup"}
        GL memory engine (:mod:`fonbw.fractional`).
    K, M, L : int
        Engine options (fast: exact lags K and modes M; short: window L).
    """

    kind = "fonbw"
    units = _FONBW_UNITS

    def __init__(self, ku, kh, rho, sigma, n, lam1=1.0, lam2=1.0, memory="fast",
                 K=fr.FAST_K, M=fr.FAST_M, L=fr.SHORT_L):
        self.ku = _ku(ku)
        self.kh = _finite("kh", kh)
        self.rho = _positive("rho", rho)
        self.sigma = _finite("sigma", sigma)
        self.n = _order_n(n)
        self.lam1 = _lam("lam1", lam1)
        self.lam2 = _lam("lam2", lam2)
        if memory not in fr.ENGINES:
            raise ValueError(f"unknown memory engine {memory!r}; choose one of {', '.join(fr.ENGINES)}")
        self.memory = memory
        self.K, self.M, self.L = int(K), int(M), int(L)
        if self.K < 1 or self.M < 0 or self.L < 1:
            raise ValueError(f"engine sizes must satisfy K ≥ 1, M ≥ 0, L ≥ 1, got K={K}, M={M}, L={L}")

    @property
    def params(self) -> dict:
        p = {"ku": self.ku, "kh": self.kh, "rho": self.rho, "sigma": self.sigma, "n": self.n,
             "lam1": self.lam1, "lam2": self.lam2, "memory": self.memory}
        # engine sizes only when they differ from the defaults, so saved files stay short
        for name, default in (("K", fr.FAST_K), ("M", fr.FAST_M), ("L", fr.SHORT_L)):
            if getattr(self, name) != default:
                p[name] = getattr(self, name)
        return p

    def _ops(self, dt, n_steps=None):
        kw = dict(K=self.K, M=self.M, L=self.L, n_steps=n_steps)
        return fr.make_op(self.lam1, dt, self.memory, **kw), fr.make_op(self.lam2, dt, self.memory, **kw)

    _step = staticmethod(fonbw_step)
    _code = CODE_FONBW
    _kernels = (fonbw_views, fonbw_core)

    def _pack(self, dt, n_steps=None, ops=None):
        """Packed parameter block and state size (layout in :mod:`fonbw.hysteresis.kernels`)."""
        o1, o2 = ops if ops is not None else self._ops(dt, n_steps)
        P = np.concatenate([[self.kh, self.rho, self.sigma, self.n, len(self.ku)], self.ku,
                            fr.pack(o1), fr.pack(o2)])
        return P, FONBW_S0 + fr.state_size(o1) + fr.state_size(o2)

    def simulate(self, u, dt, return_state=False):
        """Output H [µm] for the input u [V] sampled at step dt [s], from rest.

        With ``return_state`` also returns the hysteretic variable ħ. With
        the exact engine, runs of ``EXACT_BLOCKED_MIN`` steps or more sum
        the GL history by blocked FFT convolutions (O(N log² N), equal to
        the direct sum to round-off).
        """
        u = _input(u)
        if self.memory == "exact" and len(u) >= EXACT_BLOCKED_MIN and min(self.lam1, self.lam2) < 1.0:
            return _simulate_exact_blocked(self, u, _dt(dt), return_state)
        return _simulate(self, u, dt, return_state)

    def stepper(self, dt) -> "Stepper":
        """Per-sample stepper at step dt [s] (same numbers as :meth:`simulate`)."""
        return _FONBWStepper(self, _dt(dt))

    def as_fonbw(self) -> "FONBW":
        """This model as a plain :class:`FONBW` (an NBW becomes λ1 = λ2 = 1 with the
        default memory engine); the FMUs and the closed loop take this form. The
        model's record (``meta``: training range, start, invertibility) comes along:
        the compensators run the start it names."""
        p = dict(self.params)
        p.setdefault("lam1", 1.0)
        p.setdefault("lam2", 1.0)
        m = FONBW(**p)
        meta = getattr(self, "meta", None)
        if meta:
            m.meta = dict(meta)
        return m

    def tail_error(self, dt=None):
        """Fast-engine tail errors E1 of the two derivatives (0 for other engines)."""
        if self.memory != "fast":
            return (0.0, 0.0)
        return (fr.tail_error(self.lam1, self.K, self.M), fr.tail_error(self.lam2, self.K, self.M))


class NBW(FONBW):
    """Normalized Bouc-Wen model, eqs. (7)–(8); asymmetric with a list ``ku`` (eqs. 9–10).

    Backward Euler, i.e. FONBW with λ1 = λ2 = 1 (no memory engine involved).

    Parameters
    ----------
    ku : float or sequence of float
        k_u [µm/V] or the polynomial coefficients k_u1 … k_uN.
    kh : float
        [µm].
    rho : float
        ρ > 0 [1/V].
    sigma, n : float
        σ, n ≥ 1.
    """

    kind = "nbw"

    def __init__(self, ku, kh, rho, sigma, n):
        super().__init__(ku, kh, rho, sigma, n, 1.0, 1.0, memory="exact")

    @property
    def params(self) -> dict:
        ku = float(self.ku[0]) if len(self.ku) == 1 else self.ku
        return {"ku": ku, "kh": self.kh, "rho": self.rho, "sigma": self.sigma, "n": self.n}


class CBW(_Model):
    """Classical Bouc-Wen model, eqs. (1)–(2), backward Euler in h.

    H = α k u + (1−α) D k h,  ḣ = D⁻¹(A u̇ − β|u̇||h|^(n−1)h − γ u̇|h|^n).

    Give either ``alpha`` and ``k`` or the paper's identification constants
    ``ka = αk`` [µm/V] and ``kb = (1−α)k`` (Sec. IV-B).

    Parameters
    ----------
    alpha, k : float
        Elastic ratio [-] and gain [µm/V].
    D : float
        D > 0 [V].
    A, beta, gamma : float
        A [-], β, γ [1/V^n].
    n : float
        n ≥ 1.
    """

    kind = "cbw"
    units = {"alpha": "1", "k": "µm/V", "ka": "µm/V", "kb": "µm/V", "D": "V", "A": "1",
             "beta": "1/V^n", "gamma": "1/V^n", "n": "1"}

    def __init__(self, alpha=None, k=None, D=1.0, A=1.0, beta=0.5, gamma=0.5, n=1.0, *, ka=None, kb=None):
        if (alpha is None) == (ka is None) or (alpha is None) != (k is None) or (ka is None) != (kb is None):
            raise ValueError("CBW needs either alpha and k, or ka and kb")
        if alpha is not None:
            self.alpha, self.k = _finite("alpha", alpha), _finite("k", k)
            self.ka, self.kb = self.alpha * self.k, (1.0 - self.alpha) * self.k
            self._form = "alpha"
        else:
            self.ka, self.kb = _finite("ka", ka), _finite("kb", kb)
            self.k = self.ka + self.kb
            self.alpha = self.ka / self.k if self.k != 0 else math.nan
            self._form = "ka"
        self.D = _positive("D", D)
        self.A = _finite("A", A)
        self.beta = _finite("beta", beta)
        self.gamma = _finite("gamma", gamma)
        self.n = _order_n(n)

    @property
    def params(self) -> dict:
        head = {"alpha": self.alpha, "k": self.k} if self._form == "alpha" else {"ka": self.ka, "kb": self.kb}
        return {**head, "D": self.D, "A": self.A, "beta": self.beta, "gamma": self.gamma, "n": self.n}

    def to_nbw(self) -> NBW:
        """The exactly equivalent NBW model (Sec. II-B).

        h0 = (A/(β+γ))^(1/n), ρ = A/(D h0), σ = β/(β+γ), k_u = αk,
        k_h = (1−α) D k h0; needs A/(β+γ) > 0.
        """
        s = self.beta + self.gamma
        if s == 0 or self.A / s <= 0:
            raise ValueError(f"CBW → NBW needs A/(β+γ) > 0, got A={self.A}, β+γ={s}")
        h0 = (self.A / s) ** (1.0 / self.n)
        return NBW(ku=self.ka, kh=self.kb * self.D * h0, rho=self.A / (self.D * h0), sigma=self.beta / s, n=self.n)

    _step = staticmethod(cbw_step)
    _code = CODE_CBW
    _kernels = (plain_views, cbw_core)

    def _pack(self, dt, n_steps=None):
        return np.array([self.ka, self.kb, self.D, self.A, self.beta, self.gamma, self.n]), 4

    def simulate(self, u, dt=1.0, return_state=False):
        """Output H [µm] from rest; dt only checks the time step (CBW is rate independent)."""
        return _simulate(self, u, dt, return_state)

    def stepper(self, dt=1.0) -> "Stepper":
        return Stepper(self, _dt(dt))


def _zhu_discrete(m0, c0, k0, dt):
    """Exact ZOH discretization of m0 ẍ + c0 ẋ + k0 x = f: (Φ, Γ)."""
    from scipy.linalg import expm

    Ac = np.array([[0.0, 1.0], [-k0 / m0, -c0 / m0]])
    Bc = np.array([0.0, 1.0 / m0])
    Mx = np.zeros((3, 3))
    Mx[:2, :2] = Ac * dt
    Mx[:2, 2] = Bc * dt
    E = expm(Mx)
    return np.ascontiguousarray(E[:2, :2]), np.ascontiguousarray(E[:2, 2])


class Zhu2016(_Model):
    """Rate-dependent Bouc-Wen model of Zhu et al. (2016), eq. (20) as written.

    m0 ẍ + c0 ẋ + k0 (x − x0) = (k1/τ) e^(−t/τ) u + h,
    ḣ = A u̇ − β|u̇||h|^(n−1)h − γ u̇|h|^n + δ u sgn(u̇).

    As written, the direct input term decays with absolute time t: after a few
    τ (τ = 2e-5 s in Table 1) only the hysteretic force h drives the
    mechanics. Output x [µm] starts at x0.
    """

    kind = "zhu"
    names = ("m0", "c0", "k0", "k1", "x0", "tau", "A", "beta", "gamma", "delta", "n")
    units = {"m0": "kg", "c0": "N s/m", "k0": "N/m", "k1": "-", "x0": "µm", "tau": "s", "A": "-",
             "beta": "-", "gamma": "-", "delta": "1/s", "n": "1"}

    def __init__(self, m0, c0, k0, k1, x0, tau, A, beta, gamma, delta, n):
        self.m0 = _positive("m0", m0)
        self.c0 = _finite("c0", c0)
        if self.c0 < 0:
            raise ValueError(f"parameter c0 must be ≥ 0, got {c0!r}")
        self.k0 = _positive("k0", k0)
        self.k1 = _finite("k1", k1)
        self.x0 = _finite("x0", x0)
        self.tau = _positive("tau", tau)
        self.A = _finite("A", A)
        self.beta = _finite("beta", beta)
        self.gamma = _finite("gamma", gamma)
        self.delta = _finite("delta", delta)
        self.n = _order_n(n)

    @property
    def params(self) -> dict:
        return {k: getattr(self, k) for k in self.names}

    _step = staticmethod(zhu_step)
    _code = CODE_ZHU
    _kernels = (plain_views, zhu_core)

    def _pack(self, dt, n_steps=None):
        Phi, Gam = _zhu_discrete(self.m0, self.c0, self.k0, dt)
        head = [dt, self.k1, self.tau, self.A, self.beta, self.gamma, self.delta, self.n, self.x0]
        return np.concatenate([head, Phi.ravel(), Gam]), 7

    def simulate(self, u, dt, return_state=False):
        """Displacement x [µm] from rest (x = x0) for the input u [V] at step dt [s]."""
        return _simulate(self, u, dt, return_state)

    def stepper(self, dt) -> "Stepper":
        return Stepper(self, _dt(dt))


#: From this many steps on, a batch run with the exact engine sums the GL
#: history by blocked FFT convolutions (O(N log² N)) instead of directly
#: (O(N²)); the two agree to round-off (about 1e-13 relative), and below
#: this length the direct sum is as fast and stays bit-identical to the
#: stepper.
EXACT_BLOCKED_MIN = 8192


def _simulate_exact_blocked(model, u, dt, return_state):
    """FONBW with memory="exact" by :func:`fonbw.fractional.blocked_solve`."""
    from scipy import fft as sfft

    n = len(u)
    P, _ = model._pack(dt, n_steps=1)  # operator windows unused: the weights come from here
    x1 = u - u[0]
    w1 = fr.gl_weights(model.lam1, n) * dt ** (-model.lam1)
    w2 = fr.gl_weights(model.lam2, n) * dt ** (-model.lam2)
    # u is explicit: its whole history sum is one FFT convolution (lags ≥ 1)
    nfft = sfft.next_fast_len(2 * n - 1, real=True)
    w1[0] = 0.0
    h1 = sfft.irfft(sfft.rfft(x1, nfft) * sfft.rfft(w1, nfft), nfft)[:n]
    S = np.zeros(FONBW_S0)
    hb = np.zeros(n)
    out = np.empty(n)

    L = fr.EXACT_LEAF
    wr = np.zeros(L + 1)
    wr[:min(n, L + 1)] = w2[:L + 1]
    wr = wr[::-1].copy()  # wr[t] = w2[L - t]

    def leaf(lo, hi, hist2):
        return fonbw_exact_leaf(lo, hi, u, x1, h1, wr, hist2, P, S, hb, out)

    done = fr.blocked_solve(w2, hb, leaf)
    out[done:] = math.nan
    hb[done:] = math.nan
    return (out, hb) if return_state else out


def _simulate(model, u, dt, return_state):
    u = _input(u)
    dt = _dt(dt)
    P, ss = model._pack(dt, n_steps=len(u))
    out = np.empty(len(u))
    hout = np.empty(len(u))
    if len(u):
        run_kernel(model._code, u, P, ss, out, hout)
    return (out, hout) if return_state else out
