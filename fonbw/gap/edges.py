"""The records' step edges: how far the output moves within a step's own sample.

A lag in the drive (amplifier), a transport delay or a mechanical resonance
slows every step the actuator sees: in the sample where the command jumps,
the voltage behind an amplifier at f_c has moved only 1 − e^(−2π f_c dt) of
the way, behind a whole-sample delay not at all. A rate-independent
hysteresis downstream passes that share on, scaled by its slope there, so
the output cannot move much further. A hysteresis with its own rate
dependence can: a bank of viscous sliders answers a step with its elastic
part at once and the rest over milliseconds. Fitted to sines, that slow part
looks like a lag of the drive, and a lag block closes much of the gap. At a
step edge the two disagree, which is the evidence this module reads.

Measured on the stored first-step candidates of 240 blind-harness scenarios
(seeds 29000-29039, 30000-31039, 32000-34039, training records only,
``benchmarks/edge_shares.py``): at the edges of every amplifier, delay and
resonance accepted where one was injected (26, 16 and 22), the output moved
no more than 1.5 times the share the block let through plus 0.05 of the
step; at those of 17 of the 44 accepted where none was (16 amplifiers on
rate-dependent cores) it moved more.
"""
from __future__ import annotations

import numpy as np

__all__ = ["StepEdges", "RATIO", "MARGIN"]

#: How many times the share a lag block passes within the step's sample the
#: output may move, plus :data:`MARGIN`, before the block is refused. A
#: rate-independent hysteresis scales a partial step by its slope there
#: against its mean slope over the step: the injected amplifiers of the
#: blind harness came out at 0.75 of the block's share at most (29012, a
#: Preisach core: 1.18).
RATIO = 1.5
#: Share of the step the output may move beyond RATIO times the block's.
MARGIN = 0.05
#: A step edge: the command jumps by at least this share of its largest
#: magnitude in one sample, held before for HOLD_S and after for SETTLE_S [s]
#: to within HOLD_TOL of the jump (a logged command carries its own noise).
MIN_JUMP = 0.2
HOLD_S = 0.01
SETTLE_S = 0.05
HOLD_TOL = 0.02
#: Least settled output change of an edge, in noise standard deviations, so
#: that the share moved in one sample is known to a few hundredths.
MIN_SNR = 50.0


def _samples(seconds, dt):
    """A duration in samples of `dt`, at least one."""
    return max(1, int(round(seconds / dt)))


def find(u, dt):
    """Indices k0 of the step edges of command `u` (u[k0] is the first sample after the jump)."""
    u = np.asarray(u, dtype=float)
    hold, settle = _samples(HOLD_S, dt), _samples(SETTLE_S, dt)
    U = float(np.max(np.abs(u))) if u.size else 0.0
    if U == 0.0:
        return []
    du = np.diff(u)
    out = []
    for k in np.nonzero(np.abs(du) >= MIN_JUMP * U)[0]:
        k0 = int(k) + 1
        if k0 - hold < 0 or k0 + settle >= u.size:
            continue
        tol = HOLD_TOL * abs(du[k])
        if np.ptp(u[k0 - hold:k0]) <= tol and np.ptp(u[k0:k0 + settle + 1]) <= tol:
            out.append(k0)
    return out


def _share(x, k0, settle):
    """Share of its change over `settle` samples that `x` makes in sample k0."""
    return (x[k0] - x[k0 - 1]) / (x[k0 + settle] - x[k0 - 1])


class StepEdges:
    """Step edges of measured records and the share the output moves within each.

    Parameters
    ----------
    records : list of fonbw.io.Record
        Measured records (command u [V], displacement y [µm]), as given.
    dt : float
        Sampling period [s].
    sigma : float
        Noise standard deviation [µm]; edges whose settled change is below
        :data:`MIN_SNR` of it are left out.

    Attributes
    ----------
    edges : list of (int, int)
        (record index, k0) of every edge used.
    moved : ndarray
        Share of each edge's settled change [-] the output makes in the
        edge's own sample.
    """

    def __init__(self, records, dt, sigma):
        self.records, self.dt = records, float(dt)
        self.settle = _samples(SETTLE_S, dt)
        self.edges, moved = [], []
        for i, r in enumerate(records):
            y = np.asarray(r.y, dtype=float)
            for k0 in find(r.u, dt):
                # an output that does not move (noise-free records: σ = 0) tells nothing
                if abs(y[k0 + self.settle] - y[k0 - 1]) > max(MIN_SNR * sigma, 0.0):
                    self.edges.append((i, k0))
                    moved.append(_share(y, k0, self.settle))
        self.moved = np.asarray(moved)

    def __len__(self):
        return len(self.edges)

    def passed(self, blocks, ths):
        """Share of each edge's settled change that the lags among `blocks`
        (parameters `ths`) let through together in the edge's own sample: the
        input-side ones run on the record's command in turn, then the output
        operators on what they give (all have unit gain at rest). None when no
        block is a lag."""
        lags = [(b, th) for b, th in zip(blocks, ths) if b.lag]
        if not lags:
            return None
        # input side first: that is where the model runs them
        lags.sort(key=lambda bt: not bt[0].input_side)
        out, by_rec = [], {}
        for i, k0 in self.edges:
            if i not in by_rec:
                v = np.asarray(self.records[i].u, dtype=float)
                for b, th in lags:
                    v = b.transform_input(v, self.dt, th) if b.input_side else b.output_op(v, self.dt, th)
                by_rec[i] = v
            out.append(_share(by_rec[i], k0, self.settle))
        return np.asarray(out)

    def refuses(self, blocks, ths):
        """Why the lags among `blocks` at `ths` together contradict the edges,
        in words, or None (no edges, no lag, or the output moves no faster than
        the lags allow)."""
        passed = self.passed(blocks, ths) if len(self) else None
        if passed is None:
            return None
        moved, passed = float(np.median(self.moved)), float(np.median(passed))
        if moved <= RATIO * passed + MARGIN:
            return None
        names = " and ".join(b.name for b in blocks if b.lag)
        return (f"at the {len(self)} step edges of the training records the output moves {moved:.0%} "
                f"of its step within the step's sample, where the {names} let {passed:.0%} through: "
                f"the lag is the hysteresis's own rate dependence")
