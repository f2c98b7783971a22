"""Preisach operator of the ``preisach`` truth core (:mod:`gap_cores`).

The density lives on α ≥ β and is written in (s, d) = (α + β, α − β): a
mixture of 2–4 components, each exponential or hypoexponential in the relay
width d and Gaussian in s with a centre that shifts with d (asymmetry).
Its Everett function (mass over a triangle β ≤ b ≤ a ≤ α) has a closed form,
so the operator is evaluated exactly on the memory staircase of dominant
reversal points, without a relay grid: the diagnosis under test, whose
reference hysteresis is a threshold-grid operator, never meets its own
discretization here.

``params["density"]`` is a list of components ``{"w", "terms", "ms",
"kappa", "ss"}``: weight, [[c, λ], ...] of the width law Σ c λ e^(−λd),
centre m_s [V] of s, shift κ of that centre per volt of width, and spread
σ_s [V] of s.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = ["density_table", "everett_mass", "preisach_run", "everett", "preisach_density", "draw_density",
           "calibrated_params"]

_SQRT1_2 = 1.0 / math.sqrt(2.0)
_SQRTPI = math.sqrt(math.pi)


@nb.njit(cache=True)
def _phi(z):
    return 0.5 * math.erfc(-z * _SQRT1_2)


@nb.njit(cache=True)
def _erfcx(x):
    """exp(x²) erfc(x) for x ≥ 0 (asymptotic series where exp(x²) would overflow)."""
    if x < 25.0:
        return math.exp(x * x) * math.erfc(x)
    inv = 0.5 / (x * x)
    return (1.0 - inv * (1.0 - 3.0 * inv * (1.0 - 5.0 * inv * (1.0 - 7.0 * inv)))) / (x * _SQRTPI)


@nb.njit(cache=True)
def _exp_phi_integral(a, b, lam, D):
    """∫_0^D λ e^(−λd) Φ(a + b d) dd for λ > 0, b ≠ 0, D ∈ (0, ∞].

    By parts: Φ(a) − e^(−λD) Φ(a + bD) + b J with J = ∫_0^D e^(−λd) φ(a + bd) dd,
    a Gaussian in d (completed square) whose mass is taken through erfcx so that
    no factor overflows when its centre lies far outside [0, D].
    """
    inf = D == np.inf
    tail = 0.0 if inf else math.exp(-lam * D) * _phi(a + b * D)
    ab = abs(b)
    g0 = (a if b > 0 else -a) + lam / ab
    e0 = -0.5 * a * a                      # log of √(2π)·integrand at d = 0
    if inf:
        g1 = np.inf
        e1 = -np.inf
    else:
        g1 = g0 + ab * D
        e1 = -lam * D - 0.5 * (a + b * D) ** 2  # log of √(2π)·integrand at d = D
    if g0 >= 0.0:
        m = 0.5 * _erfcx(g0 * _SQRT1_2) * math.exp(e0)
        if not inf:
            m -= 0.5 * _erfcx(g1 * _SQRT1_2) * math.exp(e1)
    elif g1 <= 0.0:
        m = 0.5 * (_erfcx(-g1 * _SQRT1_2) * math.exp(e1) - _erfcx(-g0 * _SQRT1_2) * math.exp(e0))
    else:
        # the Gaussian's centre is inside (0, D): its peak factor e^C ≤ 1
        m = math.exp(0.5 * (g0 * g0 - a * a)) - 0.5 * _erfcx(-g0 * _SQRT1_2) * math.exp(e0)
        if not inf:
            m -= 0.5 * _erfcx(g1 * _SQRT1_2) * math.exp(e1)
    return _phi(a) - tail + b * m / ab


@nb.njit(cache=True)
def everett_mass(al, be, T):
    """Mass of the density over the triangle β ≤ b ≤ a ≤ α (β may be −∞).

    T rows: (weight·coefficient, λ [1/V], m_s [V], κ, σ_s [V]); the density in
    (s, d) = (a + b, a − b) of a row is c λ e^(−λd) N(s; m_s + κ d, σ_s²), d ≥ 0.
    """
    if al <= be:
        return 0.0
    D = al - be  # inf when be = −inf
    tot = 0.0
    for j in range(T.shape[0]):
        wc, lam, ms, kap, ss = T[j, 0], T[j, 1], T[j, 2], T[j, 3], T[j, 4]
        # triangle in (s, d): 0 ≤ d ≤ α − β, 2β + d ≤ s ≤ 2α − d
        v = _exp_phi_integral((2.0 * al - ms) / ss, -(1.0 + kap) / ss, lam, D)
        if be > -np.inf:
            v -= _exp_phi_integral((2.0 * be - ms) / ss, (1.0 - kap) / ss, lam, D)
        tot += wc * v
    return tot


@nb.njit(cache=True)
def preisach_run(u, T):
    """Preisach output (relays 0/1, density mass units) from negative saturation.

    Keeps the alternating stack of dominant reversal points x[0] = −∞ (a
    minimum), x[1] (max), x[2] (min), … with prefix sums S of the Everett
    terms of the finished segments; an input passing a stored extremum wipes
    it out with its partner (wiping-out property), which also makes a minor
    loop close exactly.
    """
    n = u.size
    y = np.empty(n)
    x = np.empty(n + 2)
    S = np.empty(n + 2)
    x[0] = -np.inf
    S[0] = 0.0
    K = 1  # stored points; K odd: ascending from x[K-1], K even: descending
    c = u[0]
    cur = everett_mass(c, x[0], T)
    y[0] = cur
    for i in range(1, n):
        v = u[i]
        if v != c:
            if (K % 2 == 1 and v < c) or (K % 2 == 0 and v > c):
                x[K] = c  # reversal
                S[K] = S[K - 1] + cur
                K += 1
            c = v
            if K % 2 == 1:
                while K >= 3 and c >= x[K - 2]:
                    K -= 2
                cur = everett_mass(c, x[K - 1], T)
            else:
                while K >= 3 and c <= x[K - 2]:
                    K -= 2
                cur = -everett_mass(x[K - 1], c, T)
        y[i] = S[K - 1] + cur
    return y


def density_table(density):
    """The rows of :func:`everett_mass` for ``params["density"]``, one per exponential term."""
    rows = []
    for comp in density:
        for c, lam in comp["terms"]:
            rows.append([comp["w"] * c, lam, comp["ms"], comp["kappa"], comp["ss"]])
    return np.ascontiguousarray(np.array(rows, dtype=float))


def everett(alpha, beta, density):
    """Everett function of a Preisach density (mass over β ≤ b ≤ a ≤ α).

    Parameters
    ----------
    alpha, beta : float
        Vertex of the triangle [V]; beta may be −inf.
    density : list of dict
        ``params["density"]`` of a preisach core.

    Returns
    -------
    float
        Mass (dimensionless; the core scales it by ``params["gain"]`` µm).
    """
    return float(everett_mass(float(alpha), float(beta), density_table(density)))


def preisach_density(a, b, density):
    """The density μ(α, β) [1/V²] of ``params["density"]`` at α = a, β = b (0 below the diagonal).

    μ(a, b) = 2 Σ_j w_j Σ_m c_m λ_m e^(−λ_m d) N(s; m_s + κ d, σ_s²), with
    s = a + b, d = a − b ≥ 0 (the 2 is the Jacobian of (a, b) → (s, d)).
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    s, d = a + b, a - b
    out = np.zeros(np.broadcast(a, b).shape)
    for comp in density:
        g = np.exp(-0.5 * ((s - comp["ms"] - comp["kappa"] * d) / comp["ss"]) ** 2) / (comp["ss"] * math.sqrt(2 * math.pi))
        e = sum(c * lam * np.exp(-lam * np.maximum(d, 0.0)) for c, lam in comp["terms"])
        out = out + 2.0 * comp["w"] * e * g
    return np.where(d >= 0, out, 0.0)


def draw_density(rng):
    comps = []
    J = int(rng.integers(2, 5))
    w = rng.dirichlet(np.full(J, 2.0))
    for j in range(J):
        mean_d = float(rng.uniform(8.0, 50.0))  # mean relay width [V]
        if rng.random() < 0.5:
            terms = [[1.0, 1.0 / mean_d]]
        else:
            # hypoexponential: zero density on the diagonal, a peak at d > 0
            l1 = 1.0 / mean_d
            l2 = l1 * float(rng.uniform(2.0, 6.0))
            terms = [[l2 / (l2 - l1), l1], [-l1 / (l2 - l1), l2]]
        comps.append({"w": float(w[j]), "terms": terms,
                      "ms": float(2.0 * rng.uniform(-10.0, 130.0)),   # relay centres (α+β)/2 in −10…130 V
                      "kappa": float(rng.uniform(-0.5, 0.5)),          # centre shifts with width: asymmetry
                      "ss": float(2.0 * rng.uniform(15.0, 50.0))})
    return comps


def calibrated_params(density, stroke, width, rng):
    """Parameters of a preisach core (:class:`gap_cores.PreisachCore`) with a drawn stroke and loop width.

    Parameters
    ----------
    density : list of dict
        The drawn density.
    stroke, width : float
        Peak to peak and loop width of its raw output P[u] on the
        calibration sine (density mass units).
    rng : numpy.random.Generator
        Draws the target stroke S [µm], the width fraction, the curvature of
        the reversible part and the output nonlinearity q (in that order).

    Returns
    -------
    dict or None
        ``{"density", "gain", "k1", "k2", "q", "S"}``; None when the linear
        part the targets leave would be under 15 % of the stroke (the caller
        draws another density).
    """
    S = float(rng.uniform(10.0, 25.0))
    W = float(rng.uniform(0.05, 0.2))
    c2 = float(rng.uniform(-0.25, 0.25))  # curvature of the reversible part over 0…120 V
    G = W * S / width
    # stroke = G ΔP + k1·120 (1 + c2); ΔP is the loop's peak to peak
    k1 = (S - G * stroke) / (120.0 * (1.0 + c2))
    if k1 < 0.15 * S / 120.0:
        return None
    return {"density": density, "gain": G, "k1": k1, "k2": k1 * c2 / 120.0,
            "q": float(rng.uniform(-0.1, 0.1)), "S": S}
