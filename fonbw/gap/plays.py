"""The play operators of the reference hysteresis (:mod:`fonbw.gap.reference`)
and their compiled kernels: a play bank, the filtered input rate, the
Bernstein-weighted columns along each play's Preisach line and their
combinations, made a block of samples at a time."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["play_bank"]


@njit(cache=True)
def _play_kernel(v, r, scale, add, z, out):  # pragma: no cover - compiled
    # One pass over the samples updating every play keeps the bank's state in
    # registers/cache and writes each output row contiguously.
    m = r.shape[0]
    for k in range(v.shape[0]):
        vk = v[k]
        s = scale[k]
        a = add[k]
        for j in range(m):
            rj = r[j] * s + a
            zj = z[j]
            if zj < vk - rj:
                zj = vk - rj
            elif zj > vk + rj:
                zj = vk + rj
            z[j] = zj
            out[k, j] = zj


@njit(cache=True)
def _filtered_rate(u, dt, tau):  # pragma: no cover - compiled
    a = math.exp(-dt / tau)
    out = np.empty_like(u)
    rate = 0.0
    up = u[0]
    for k in range(u.shape[0]):
        rate = a * rate + (1.0 - a) * abs(u[k] - up) / dt
        up = u[k]
        out[k] = rate
    return out


@njit(cache=True)
def _binomials(k):  # pragma: no cover - compiled
    binom = np.ones(k + 2)
    for l in range(1, k + 2):
        binom[l] = binom[l - 1] * (k + 2 - l) / l
    return binom


# Samples per block of the level columns: the arithmetic runs over a block of
# one play's states, in SIMD lanes (the play bank's own loop over samples
# cannot), with the block's columns in cache.
_LEVEL_BLOCK = 256


@njit(cache=True, inline="always")
def _level_block(p, nb, k, lo, width, binom, xp, ep, V):  # pragma: no cover - compiled
    # V[i, :nb] = column i of one play whose states over a block of samples
    # are p[:nb]: relays on the Preisach line α - β = 2 r_j, their density
    # along it a Bernstein polynomial of degree k in the normalized relay
    # centre ξ. Relays below the play state are up, so the line's output is
    # the integral of the density up to ξ (up to a constant), i.e. for the
    # basis b_{i,k}: (width / (k + 1)) Σ_{l > i} b_{l,k+1}(ξ). Non-negative
    # weights give a density ≥ 0 over the input range. Rate-independent plays
    # stay within ξ ∈ [-0.5, 1.5]; clamping there keeps widened thresholds
    # (rate dependence) from extrapolating the polynomial far outside.
    if k == 0:
        V[0, :nb] = p[:nb]  # the classical PI model: the play itself
        return
    g = width / (k + 1)
    for b in range(nb):
        x = min(max((p[b] - lo) / width, -0.5), 1.5)
        xp[1, b] = x
        ep[1, b] = 1.0 - x
    for l in range(2, k + 2):  # products, not pow: pow dominated the cost
        for b in range(nb):
            xp[l, b] = xp[l - 1, b] * xp[1, b]
            ep[l, b] = ep[l - 1, b] * ep[1, b]
    for b in range(nb):
        V[k, b] = binom[k + 1] * xp[k + 1, b]
    for i in range(k - 1, -1, -1):
        c = binom[i + 1]
        for b in range(nb):
            V[i, b] = V[i + 1, b] + c * xp[i + 1, b] * ep[k - i, b]
    for i in range(k + 1):
        for b in range(nb):
            V[i, b] *= g


@njit(cache=True)
def _level_columns(pz, m, k, lo, width, col, dst):  # pragma: no cover - compiled
    # Column i m + j (basis i, play j) goes to dst[:, col[i m + j]], or
    # nowhere when that is negative; pz (the play states) may be dst's own
    # first m columns, as a block of play j is read before its columns are
    # written and column j of dst is written by play j only.
    block = _LEVEL_BLOCK
    binom = _binomials(k)
    xp = np.ones((k + 2, block))
    ep = np.ones((k + 2, block))
    V = np.empty((k + 1, block))
    p = np.empty(block)
    n = pz.shape[0]
    for t0 in range(0, n, block):
        nb = min(block, n - t0)
        for j in range(m):
            for b in range(nb):
                p[b] = pz[t0 + b, j]
            _level_block(p, nb, k, lo, width, binom, xp, ep, V)
            for i in range(k + 1):
                c = col[i * m + j]
                if c >= 0:
                    for b in range(nb):
                        dst[t0 + b, c] = V[i, b]


@njit(cache=True)
def _combined_kernel(u, r, scale, add, z, k, lo, width, row, W, out):  # pragma: no cover - compiled
    # The play bank, its level columns and their combinations W in one pass:
    # out[t] = Σ_a col_a(t) W[a], where column i m + j (basis i of play j)
    # is row[i m + j] of W, or unused when that is negative. The columns are
    # made a block of samples at a time into a buffer that stays in cache,
    # and each block is one matrix product.
    m = r.shape[0]
    nt = W.shape[0]
    block = _LEVEL_BLOCK
    binom = _binomials(k)
    pz = np.empty((m, block))
    xp = np.ones((k + 2, block))
    ep = np.ones((k + 2, block))
    V = np.empty((k + 1, block))
    buf = np.empty((nt, block))
    n = u.shape[0]
    for t0 in range(0, n, block):
        nb = min(block, n - t0)
        # the block's play states, one row a play (the bank writes a transposed view)
        _play_kernel(u[t0:t0 + nb], r, scale[t0:t0 + nb], add[t0:t0 + nb], z, pz[:, :nb].T)
        for j in range(m):
            _level_block(pz[j], nb, k, lo, width, binom, xp, ep, V)
            for i in range(k + 1):
                ri = row[i * m + j]
                if ri >= 0:
                    buf[ri, :nb] = V[i, :nb]
        if nb == block:
            np.dot(buf.T, W, out[t0:t0 + nb])
        else:
            out[t0:t0 + nb] = np.dot(np.ascontiguousarray(buf[:, :nb].T), W)


def play_bank(v, thresholds, z0=None, scale=None) -> np.ndarray:
    """Outputs of a bank of play operators [V], shape (n_samples, n_plays).

    Parameters
    ----------
    v : array_like
        Driving input [V].
    thresholds : array_like
        Thresholds r_j ≥ 0 [V].
    z0 : array_like, optional
        Initial states [V]; default v_0 for every play (centred).
    scale : array_like, optional
        Per-sample threshold multiplier (rate dependence); default 1.
    """
    v = np.ascontiguousarray(v, dtype=float)
    r = np.ascontiguousarray(thresholds, dtype=float)
    z = np.full(r.size, v[0]) if z0 is None else np.array(z0, dtype=float)
    s = np.ones(v.size) if scale is None else np.ascontiguousarray(scale, dtype=float)
    out = np.empty((v.size, r.size))
    _play_kernel(v, r, s, np.zeros(v.shape[0]), z, out)
    return out
