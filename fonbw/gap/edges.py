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

import math

import numpy as np

from .checks import longest_run

__all__ = ["StepEdges", "RATIO", "MARGIN", "summary_text"]

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
#: Samples after an edge searched for the output's first move: the delay
#: block's longest delay (25 samples) and a few more.
WINDOW = 30
#: The output holds still while it stays within this share of its step, or
#: within four noise σ of it when that is more.
STILL = 0.05
#: Least share of its step the output moves from the sample before its
#: first move to :data:`LATE` samples after it for the stillness before to
#: count as a dead time. A resonance or a slow amplifier starts smoothly: on
#: the blind harness's cores with a 60-Hz resonance the output moved 0.02-0.04
#: of its step per sample where it first moved, behind a delay 0.18-0.99.
DEAD_JUMP = 0.1
#: Time before and after an edge [s] whose model misfit :meth:`StepEdges.left`
#: weighs: the command's own jump and the 12 ms after it, where an
#: amplifier's lag of up to a few milliseconds has run its course (3 and 60
#: samples at 5 kHz).
FIT_BEFORE_S, FIT_AFTER_S = 0.0006, 0.012
#: The edges hold a misfit of their own when the nominal's mean square error
#: within their windows is this many times that elsewhere: where a lag or a
#: rate-dependent core shaped the steps it was 31-3900 times (43 spent
#: blind-harness scenarios: the 41 below, 32034 and 43022;
#: ``benchmarks/edge_misfit.py``); a nominal that follows the steps leaves
#: about what it leaves elsewhere.
OWN_MISFIT = 10.0
#: Share of the nominal's misfit within the edges' windows an amplifier may
#: leave. A first-order lag of the drive shows whole at a step, so the drive's
#: own amplifier takes nearly all of it: the 16 injected ones of 41 spent
#: blind-harness scenarios (all four core families) left 0.003-0.104 (the
#: most, 37015: a 2.3 σ amplifier on a Preisach core). Fitted to a
#: rate-dependent core without one, whose step response is an instant part
#: and relaxations over 0.2-30 ms, 12 of 13 left 0.15-0.83 (41001: 0.04).
LEFT = 0.125
#: Share of that misfit a resonance may leave. A mode of the stage rings at
#: the edges as its block does: true resonances of 11 spent blind-harness
#: scenarios (all four core families) left 0.002-0.072 where the block was
#: identified, 0.28-0.39 where it sat at its damping bound or above the
#: Nyquist frequency (40018, 36024, 41024); fitted to three rate-dependent
#: cores without one, 0.74-0.93 (41035, 33035, 44004): a sum of relaxations
#: over 0.2-30 ms that no single mode follows.
MODE_LEFT = 0.5
#: Samples the hysteresis may answer its input late. FONBW's fractional
#: derivative answers the first sample of a step with a spike against it,
#: which cancels most of the first response: behind a 3.7-sample delay a
#: FONBW core of the blind harness (seed 35027) moved −0.04 of its step in
#: the sample the delayed step arrived, 0.25 in the next.
LATE = 1


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


def _share(x, k, k0, settle):
    """Share of its change over `settle` samples from the edge k0 that `x` has
    made by sample(s) k."""
    return (x[k] - x[k0 - 1]) / (x[k0 + settle] - x[k0 - 1])


def summary_text(summary):
    """:meth:`StepEdges.summary` in words (the report's)."""
    if not summary or not summary.get("count"):
        return "no clear step edges in the training records: they say nothing about lags"
    text = (f"{summary['count']} step edges in the training records; the output moves {summary['moved']:.0%} "
            f"of its step within the step's own sample")
    dead = summary.get("dead_time_s")
    if dead:
        text += (f", and after most edges it holds still and then jumps: a dead time, which a delay of "
                 f"{1e3 * dead[0]:.2f}-{1e3 * dead[1]:.2f} ms explains")
    return text


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
    profile : ndarray
        (edges, window + 1): share of each edge's settled change the output
        has made by each sample from the edge's own on.
    onset : list of int or None
        Per edge, the first sample (0: the edge's own) at which the output
        leaves its level before the step by more than it holds still within
        (:data:`STILL`); None when it does not within the window.
    """

    def __init__(self, records, dt, sigma):
        self.records, self.dt = records, float(dt)
        self.settle = _samples(SETTLE_S, dt)
        self.window = min(WINDOW, self.settle)
        self.edges, profile, self.onset = [], [], []
        j = np.arange(self.window + 1)
        for i, r in enumerate(records):
            y = np.asarray(r.y, dtype=float)
            for k0 in find(r.u, dt):
                step = y[k0 + self.settle] - y[k0 - 1]
                # an output that does not move (noise-free records: σ = 0) tells nothing
                if abs(step) > max(MIN_SNR * sigma, 0.0):
                    self.edges.append((i, k0))
                    m = _share(y, k0 + j, k0, self.settle)
                    profile.append(m)
                    still = max(STILL, 4.0 * sigma / abs(step))
                    out = np.nonzero(np.abs(m) > still)[0]
                    self.onset.append(int(out[0]) if out.size else None)
        self.profile = np.asarray(profile).reshape(len(self.edges), self.window + 1)
        self.moved = self.profile[:, 0].copy()

    def __len__(self):
        return len(self.edges)

    def passed(self, blocks, ths):
        """Share of each edge's settled change that the lags among `blocks`
        (parameters `ths`) let through together in the edge's own sample: the
        input-side ones run on the record's command in turn, then the output
        operators on what they give (all have unit gain at rest). None when no
        block is a lag."""
        prof = self.passed_profile(blocks, ths)
        return None if prof is None else prof[:, 0]

    def passed_profile(self, blocks, ths):
        """As :meth:`passed`, by each sample of the window (like :attr:`profile`)."""
        lags = [(b, th) for b, th in zip(blocks, ths) if b.lag]
        if not lags:
            return None
        # input side first: that is where the model runs them
        lags.sort(key=lambda bt: not bt[0].input_side)
        out, by_rec = [], {}
        j = np.arange(self.window + 1)
        for i, k0 in self.edges:
            if i not in by_rec:
                v = np.asarray(self.records[i].u, dtype=float)
                for b, th in lags:
                    v = b.transform_input(v, self.dt, th) if b.input_side else b.output_op(v, self.dt, th)
                by_rec[i] = v
            out.append(_share(by_rec[i], k0 + j, k0, self.settle))
        return np.asarray(out).reshape(len(self.edges), self.window + 1)

    def refuses(self, blocks, ths):
        """Why the lags among `blocks` at `ths` together contradict the edges,
        in words, or None (no edges, no lag, or the output moves no faster than
        the lags allow, in the edge's own sample and where it first moves)."""
        prof = self.passed_profile(blocks, ths) if len(self) else None
        if prof is None:
            return None
        names = " and ".join(b.name for b in blocks if b.lag)
        moved, passed = float(np.median(self.moved)), float(np.median(prof[:, 0]))
        if moved > RATIO * passed + MARGIN:
            return (f"at the {len(self)} step edges of the training records the output moves {moved:.0%} "
                    f"of its step within the step's sample, where the {names} let {passed:.0%} through: "
                    f"the lag is the hysteresis's own rate dependence")
        return self._after_dead_time(prof, names)

    def moves_at_once(self):
        """Whether the output moves in the edge's own sample at most edges
        (onset 0): a delay of the drive is then under a sample, a lag over
        within the edge's window like an amplifier's (:meth:`left`)."""
        return bool(len(self)) and 2 * sum(j == 0 for j in self.onset) > len(self)

    def _held(self):
        """(edge, onset) of the edges after which the output holds still before
        it moves, when they are most of them; else an empty list."""
        held = [(e, j) for e, j in enumerate(self.onset) if j is not None and j > 0]
        return held if 2 * len(held) > len(self) else []

    def dead_time(self):
        """(shortest, longest) transport delay [s] the edges allow when the output
        holds still after most of them and then jumps (:data:`DEAD_JUMP`), or
        None. A delay of d samples lets its first share through in sample
        floor(d), and the output may answer up to :data:`LATE` samples later
        and show the first share only in the next sample when it is small."""
        held = self._held()
        if not held:
            return None
        jumps = [self.profile[e, min(j + LATE, self.window)] - self.profile[e, j - 1] for e, j in held]
        if float(np.median(jumps)) < DEAD_JUMP:
            return None
        # the edges that jump bracket it: one that rises smoothly would widen it to nothing
        first = [j for (_, j), jump in zip(held, jumps) if jump >= DEAD_JUMP]
        return max(0, min(first) - 1 - LATE) * self.dt, (max(first) + 1) * self.dt

    def delays_within_dead_time(self, block, others=(), other_ths=(), step=0.05):
        """(shortest, longest) delay [s] of `block` (a lag whose one parameter
        is a delay in s) that the edges accept beside the blocks `others` at
        `other_ths` (:meth:`refuses`; the effects accepted before it), the
        longest such run on a grid of `step` samples across :meth:`dead_time`,
        half a step either side when it is a single point; None without a
        dead time or when they accept none.

        :meth:`dead_time` brackets the edges' onsets one by one, the test
        takes their median: on a rate-dependent core behind a 14.6-sample
        delay (blind harness, seed 38038; onsets 15, 14, 15) the bracket
        began at 12 samples and the test refused every delay to 13, where a
        refit on the reference settled (12.6: the reference's own lag took
        the rest)."""
        dead = self.dead_time()
        if dead is None:
            return None
        d = np.arange(dead[0], dead[1] + 0.5 * step * self.dt, step * self.dt)
        blocks, ths = list(others) + [block], list(other_ths)
        ok = np.array([self.refuses(blocks, ths + [np.array([x])]) is None for x in d])
        if not ok.any():
            return None
        start, stop = longest_run(ok)
        lo, hi = float(d[start]), float(d[stop - 1])
        if lo == hi:  # a range the block can be searched over
            lo, hi = lo - 0.5 * step * self.dt, hi + 0.5 * step * self.dt
        return lo, hi

    def windows(self, lengths):
        """Mask of the samples within :data:`FIT_BEFORE_S` before and
        :data:`FIT_AFTER_S` after each edge, over records of `lengths` samples
        laid end to end: the records as given, each at the end of its own
        (a model may run a history before a record that starts mid-drive)."""
        before, after = _samples(FIT_BEFORE_S, self.dt), _samples(FIT_AFTER_S, self.dt)
        masks = [np.zeros(int(n), dtype=bool) for n in lengths]
        for i, k0 in self.edges:
            k = int(lengths[i]) - len(self.records[i].u) + k0
            masks[i][max(0, k - before):k + after] = True
        return np.concatenate(masks) if masks else np.zeros(0, dtype=bool)

    def misfit(self, before, lengths, keep=None):
        """Mean square [µm²] of residuals `before` within the edges' windows
        (:meth:`windows`) and elsewhere, over the samples `keep` scores, and
        the mask of the scored ones within; None when either part is empty.
        Residuals run over records of `lengths` samples end to end."""
        win = self.windows(lengths)
        keep = np.ones(win.size, dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
        inside, outside = win & keep, ~win & keep
        if not (inside.any() and outside.any()):
            return None
        return float(np.mean(before[inside] ** 2)), float(np.mean(before[outside] ** 2)), inside

    def left(self, before, after, lengths, keep=None, most=LEFT, who="a lag of the drive"):
        """Why a block whose fit has residuals `after` is not the records' own
        lag (`who`, the block's ``edges_who``: an amplifier, a delay under a
        sample, :meth:`moves_at_once`, a mode), in words, or None: it leaves
        more than `most` of the
        misfit of residuals `before` (the nominal's) within the edges'
        windows (:meth:`windows`), where that misfit is the edges' own
        (:data:`OWN_MISFIT`). Residuals [µm] run over records of `lengths`
        samples end to end; `keep` masks the samples that are scored. Also
        returns the share left (None when the edges hold no misfit of their own)."""
        m = self.misfit(before, lengths, keep)
        if m is None:
            return None, None
        b_in, b_out, inside = m
        if not b_in > OWN_MISFIT * b_out:
            return None, None
        share = float(np.mean(after[inside] ** 2)) / b_in
        if not math.isfinite(share):  # a refit that diverges is judged by the other checks
            return None, None
        if share <= most:
            return None, share
        return (f"at the {len(self)} step edges of the training records it leaves {share:.0%} of the "
                f"nominal's misfit, where {who} leaves at most {most:.1%} of it: the lag is the "
                f"hysteresis's own rate dependence"), share

    def summary(self):
        """The edges for a report: ``count``; ``moved`` (median share of its
        step the output makes in the edge's own sample) and ``dead_time_s``
        ([shortest, longest] delay the edges allow, :meth:`dead_time`), None
        without edges or without a dead time."""
        dead = self.dead_time()
        return {"count": len(self), "moved": float(np.median(self.moved)) if len(self) else None,
                "dead_time_s": None if dead is None else [float(dead[0]), float(dead[1])]}

    def _after_dead_time(self, prof, names):
        """The same test where the output first moves, when it holds still
        after most edges (a dead time): what it moves in that one sample
        against what the lags let through in it and the :data:`LATE` samples
        before, edge by edge."""
        held = self._held()
        if not held:
            return None
        jump = np.array([self.profile[e, j] - self.profile[e, j - 1] for e, j in held])
        let = np.array([prof[e, j] - (prof[e, j - 1 - LATE] if j > LATE else 0.0) for e, j in held])
        if float(np.median(jump - RATIO * let)) <= MARGIN:
            return None
        still = int(np.median([j for _, j in held]))
        return (f"at {len(held)} of the {len(self)} step edges of the training records the output holds "
                f"still for {still} sample{'s' if still != 1 else ''} and then moves "
                f"{float(np.median(jump)):.0%} of its step in one sample, where the {names} let "
                f"{float(np.median(let)):.0%} through: they do not match the dead time the records hold")
