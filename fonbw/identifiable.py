"""What the records can identify: the rate span of their input and the ranges it allows.

The fractional orders λ1, λ2 of FONBW act on the input through GL derivatives,
whose gain on a swing of frequency f grows as (2πf)^λ. Only records that drive
the actuator at several rates show that growth; on records with a single rate
it is a constant factor, which ρ and the gains absorb, and the search is free
to run off to the corner λ → 0 (an operator close to the identity, no rate
dependence left) where the parameters no longer mean what they say.

:func:`rate_span` measures the spread of swing frequencies in the records:
the input is cut into monotone swings (between reversals, a reversal counting
once the input has come back by :data:`REVERSAL_SHARE` of its range), each
swing of duration T gets the frequency 1/(2T), and the span is the ratio of
the 90th to the 10th percentile of those frequencies, each swing weighted by
its stroke |Δu|. The first and last swings of a record are cut by its ends and
left out when it has more. :func:`lambda_floor` turns the span into the lower
bound of λ1 and λ2 (:data:`LAM_FLOOR_SINGLE` for one rate, down to the full
:data:`LAM_MIN` once the records span :data:`LAM_FULL_SPAN` or more).

σ is bounded by :data:`SIGMA_MAX`: at fixed σ^(1/n)ρ (what the output fixes
while ħ stays small) σ changes the loop only through (σ − 1)/σ = 1 − 1/σ and
through ħ reaching its saturation level, which ρ = σ^(1/n)ρ / σ^(1/n) pushes
out of reach as σ grows. Past 1e3 the loop moves by less than 0.1 % of the
hysteretic term: the data cannot tell σ = 1e3 from 1e7.
"""
from __future__ import annotations

import numpy as np

__all__ = ["REVERSAL_SHARE", "LAM_MIN", "LAM_FLOOR_SINGLE", "LAM_FULL_SPAN", "SIGMA_MAX",
           "SIGMA_BOUNDED", "swings", "rate_span", "lambda_floor"]

#: Share of the input's range the input must come back by for a reversal to count
#: (sensor noise on a measured input makes no reversals).
REVERSAL_SHARE = 0.02
#: Lowest fractional order searched when the records span rates enough.
LAM_MIN = 0.05
#: Lowest fractional order searched on records with a single rate.
LAM_FLOOR_SINGLE = 0.5
#: Rate span (ratio of swing frequencies) from which the full range [LAM_MIN, 1] is searched.
LAM_FULL_SPAN = 10.0
#: Largest σ searched (module docstring).
SIGMA_MAX = 1e3
#: Smallest σ for which every input keeps the Bouc-Wen state bounded (the
#: per-step root is then unique, :mod:`fonbw.hysteresis.kernels`). Smaller σ
#: can fit the records and still diverge on another input.
SIGMA_BOUNDED = 0.5


def swings(u, dt) -> tuple[np.ndarray, np.ndarray]:
    """Monotone swings of an input between its reversals.

    Parameters
    ----------
    u : ndarray
        Input [V].
    dt : float
        Sampling step [s].

    Returns
    -------
    freq : ndarray
        1/(2 T) of each swing of duration T [Hz].
    stroke : ndarray
        |Δu| of each swing [V].
    """
    u = np.asarray(u, dtype=float)
    thr = REVERSAL_SHARE * float(np.ptp(u))
    if thr <= 0.0:
        return np.zeros(0), np.zeros(0)
    # Running extremes and the points where the input turned back by thr.
    piv, ext, direction, ends = 0, 0, 0, []
    for k in range(1, u.size):
        v = u[k]
        if direction == 0:
            if abs(v - u[0]) >= thr:
                direction, ext = (1 if v > u[0] else -1), k
        elif direction * (v - u[ext]) > 0.0:
            ext = k
        elif direction * (u[ext] - v) >= thr:
            ends.append((piv, ext))
            piv, ext, direction = ext, k, -direction
    if direction != 0:
        ends.append((piv, ext))
    if len(ends) > 2:
        ends = ends[1:-1]  # cut by the record's start and end
    idx = np.asarray(ends, dtype=int).reshape(-1, 2)
    dur = (idx[:, 1] - idx[:, 0]) * float(dt)
    ok = dur > 0
    return 0.5 / dur[ok], np.abs(u[idx[ok, 1]] - u[idx[ok, 0]])


def _weighted_quantile(x, w, q):
    """Smallest x whose cumulative weight (x ascending) reaches the share q of the total."""
    order = np.argsort(x, kind="stable")
    c = np.cumsum(w[order])
    return float(x[order][np.searchsorted(c, q * c[-1] * (1 - 1e-12))])


def rate_span(records) -> float:
    """Ratio of the 90th to the 10th percentile of the records' swing frequencies.

    Parameters
    ----------
    records : list of (u, dt) pairs or of objects with ``u`` [V] and ``dt`` [s]

    Returns
    -------
    float
        ≥ 1; 1 for records of a single rate (or without a reversal).
    """
    fs, ws = [], []
    for r in records:
        u, dt = (r.u, r.dt) if hasattr(r, "u") else (r[0], r[-1])
        f, w = swings(u, dt)
        fs.append(f)
        ws.append(w)
    f, w = np.concatenate(fs), np.concatenate(ws)
    if f.size == 0:
        return 1.0
    return max(1.0, _weighted_quantile(f, w, 0.9) / _weighted_quantile(f, w, 0.1))


def lambda_floor(span: float) -> float:
    """Lower bound of λ1 and λ2 for a rate span: LAM_FLOOR_SINGLE at 1, LAM_MIN from
    LAM_FULL_SPAN on, linear in log10(span) between."""
    s = np.log10(max(float(span), 1.0)) / np.log10(LAM_FULL_SPAN)
    return float(np.clip(LAM_FLOOR_SINGLE - (LAM_FLOOR_SINGLE - LAM_MIN) * s, LAM_MIN, LAM_FLOOR_SINGLE))
