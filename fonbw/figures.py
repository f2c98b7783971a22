"""The paper's Figs. 1–4 recomputed with the library's models (PNG files).

* Fig. 1 — CBW loops at several input frequencies (rate independent: they coincide).
* Fig. 2 — CBW, its exact NBW and the asymmetric NBW (k_u = [0.1, 0.1, 0.01]).
* Fig. 3 — the polynomial input functions g(u) of eq. (10) for symmetric and
  positive inputs (k_u1 = 3, k_u2 = 2, k_u3 = 1).
* Fig. 4 — FONBW loops ħ(u) for ρ = σ = n = 1 and the three (λ1, λ2) cases, at
  several frequencies, the four branches of eqs. (12)–(15) coloured.
"""
from __future__ import annotations

import os

import numpy as np

from . import fractional as fr
from .hysteresis import CBW, FONBW

__all__ = ["make_figures", "FIG1_CBW"]

#: The CBW parameters of Figs. 1–2.
FIG1_CBW = dict(alpha=0.1, k=1.0, D=1.0, A=0.7, beta=0.6, gamma=0.5, n=1.0)

# eqs. (12)–(15): (ħ ≥ 0, D ≥ 0) red, (ħ ≥ 0, D ≤ 0) green, (ħ ≤ 0, D ≤ 0) blue, (ħ ≤ 0, D ≥ 0) magenta
BRANCH_COLORS = ("red", "green", "blue", "magenta")


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path, plt):
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _sine(f, periods=2, amp=1.0, offset=0.0, pts=2000):
    dt = 1.0 / (f * pts)
    t = np.arange(periods * pts + 1) * dt
    return t, offset + amp * np.sin(2 * np.pi * f * t), dt


def branch_index(hbar, d1u):
    """Branch of eqs. (12)–(15) for each sample: 0..3 as in BRANCH_COLORS."""
    pos_h = hbar >= 0
    pos_d = d1u >= 0
    return np.where(pos_h, np.where(pos_d, 0, 1), np.where(pos_d, 3, 2))


def fig1(path, freqs=(1, 5, 10, 20)):
    plt = _plt()
    cbw = CBW(**FIG1_CBW)
    fig, ax = plt.subplots(figsize=(5, 4))
    for f in freqs:
        t, u, dt = _sine(f, amp=2.0)
        ax.plot(u, cbw.simulate(u, dt), label=f"{f} Hz")
    ax.set(xlabel="u [V]", ylabel="H [µm]", title="Fig. 1: CBW at several frequencies")
    ax.legend()
    _save(fig, path, plt)


def fig2(path):
    plt = _plt()
    cbw = CBW(**FIG1_CBW)
    nbw = cbw.to_nbw()
    asym = type(nbw)(ku=[0.1, 0.1, 0.01], kh=nbw.kh, rho=nbw.rho, sigma=nbw.sigma, n=nbw.n)
    t, u, dt = _sine(1.0, amp=2.0)
    fig, ax = plt.subplots(figsize=(5, 4))
    ax.plot(u, cbw.simulate(u, dt), "k-", lw=3, label="CBW")
    ax.plot(u, nbw.simulate(u, dt), "y--", lw=1.5, label="NBW (same loop)")
    ax.plot(u, asym.simulate(u, dt), "r-", label="asymmetric NBW")
    ax.set(xlabel="u [V]", ylabel="H [µm]", title="Fig. 2: CBW, NBW, asymmetric NBW")
    ax.legend()
    _save(fig, path, plt)


def fig3(path):
    plt = _plt()
    k1, k2, k3 = 3.0, 2.0, 1.0
    fig, axes = plt.subplots(1, 2, figsize=(9, 4))
    for ax, (lo, hi), title in zip(axes, ((-1, 1), (0, 2)), ("(a) input symmetric about 0", "(b) positive input")):
        u = np.linspace(lo, hi, 401)
        for g, lab in ((k1 * u + k2 * u**2 + k3 * u**3, "k1u+k2u²+k3u³"), (k1 * u + k3 * u**3, "k1u+k3u³"),
                       (k1 * u + k2 * u**2, "k1u+k2u²"), (k1 * u, "k1u")):
            ax.plot(u, g, label=lab)
        ax.set(xlabel="u", ylabel="g(u)", title=title)
        ax.legend(fontsize=8)
    fig.suptitle("Fig. 3: polynomial input functions, eq. (10)")
    _save(fig, path, plt)


def fig4(path, freqs=(1, 5, 10)):
    plt = _plt()
    cases = [("(a) λ1=0.5, λ2=0.8 at 1 Hz", 0.5, 0.8, (1,)), ("(b) λ1 < λ2: 0.5, 0.8", 0.5, 0.8, freqs),
             ("(c) λ1 > λ2: 0.8, 0.5", 0.8, 0.5, freqs), ("(d) λ1 = λ2 = 0.5", 0.5, 0.5, freqs)]
    fig, axes = plt.subplots(2, 2, figsize=(9, 8))
    for ax, (title, l1, l2, fs) in zip(axes.ravel(), cases):
        m = FONBW(ku=[0.0], kh=1.0, rho=1.0, sigma=1.0, n=1.0, lam1=l1, lam2=l2, memory="exact")
        for f in fs:
            t, u, dt = _sine(f, periods=3, amp=1.0)
            _, hb = m.simulate(u, dt, return_state=True)
            d1 = fr.gl_derivative(u - u[0], dt, l1)
            br = branch_index(hb, d1)
            sl = slice(len(u) // 3, None)  # after the first cycle
            for b, col in enumerate(BRANCH_COLORS):
                sel = np.where(br[sl] == b, hb[sl], np.nan)
                ax.plot(u[sl], sel, color=col, lw=1.2)
            ax.annotate(f"{f} Hz", (u[sl][np.argmax(hb[sl])], np.max(hb[sl])), fontsize=7)
        ax.set(xlabel="u", ylabel="ħ", title=title)
    fig.suptitle("Fig. 4: FONBW loops, ρ = σ = n = 1; red/green/blue/magenta = eqs. (12)/(13)/(14)/(15)")
    _save(fig, path, plt)


def make_figures(out_dir) -> list[str]:
    """Write fig1.png … fig4.png into ``out_dir``; returns the paths."""
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    for name, fn in (("fig1_cbw_frequencies", fig1), ("fig2_cbw_nbw_asym", fig2), ("fig3_polynomials", fig3),
                     ("fig4_fractional_orders", fig4)):
        p = os.path.join(out_dir, name + ".png")
        fn(p)
        paths.append(p)
    return paths
