"""How a record starts: at rest, or mid-drive with an unknown hysteresis state.

A hysteresis model simulated from the first sample assumes a known initial
state (the demagnetized/at-rest state). A record cut out of a running drive
starts in a state that depends on the unseen history, so its first samples
show a start-up transient that no model block should be credited with. The
state is wiped out once the input has swept close to both extremes of the
record: after that the output no longer depends on the initial state (the
wiping-out property of Preisach-type and Bouc-Wen-type hysteresis). Samples
before that point are the *burn-in* and are excluded from fitting and scoring.

Used by the gap diagnosis and by the identify/validate commands.
"""
from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["StartState", "start_state", "rest_level", "rise_excess", "burn_ins", "backward_burn_in",
           "history_candidates", "estimate_history",
           "HOLD_SAMPLES", "MAX_BURN_IN_SHARE", "HISTORY_LEVELS"]

#: Samples the input must be held at its first value to call the start at rest.
HOLD_SAMPLES = 10
#: Largest share of a record excluded as burn-in (the rest is kept for scoring).
MAX_BURN_IN_SHARE = 0.40
#: How close to its record extremes the input must come [fraction of u range].
EXTREME_TOL = 0.05
#: How close to the bottom of its range the input starts at rest [fraction of range].
REST_TOL = 0.01
#: How close to the bottom of the input's first rise the output starts at rest [fraction
#: of the output range]. Wider than the input's: a non-minimum-phase core (FONBW with
#: k_h ρ < 0) first dips when a fast drive leaves rest, by up to 4.5 % of the range on
#: 20-Hz sines from rest (blind harness), while records cut mid-drive at an input minimum
#: start either as close to the bottom (0.2–2.2 %: the bottom cannot tell those from rest)
#: or far above it (78 %).
REST_TOL_Y = 0.05
#: Levels of the last turning point tried for the unseen history of a record that
#: starts mid-drive (evenly over the record's input range).
HISTORY_LEVELS = 13
#: Longest leg of such a history [burn-ins].
LEG_MAX = 4


@dataclasses.dataclass(frozen=True)
class StartState:
    """How a record starts.

    Attributes
    ----------
    at_rest : bool
        True when the input is held at its first value for at least
        ``HOLD_SAMPLES`` samples and the output does not move meanwhile,
        that value being the bottom of the record's input range and, when
        the stage's rest input is known, that rest input (within
        ``REST_TOL``; a hold half-way up is a pause mid-drive); or when input
        and output both start at the bottom of their ranges (a drive that
        leaves rest at once, e.g. a sine from 0 V), the output within
        ``REST_TOL_Y`` of its bottom over the input's first rise to the middle
        of its range (a fast drive can dip first or undershoot later).
    burn_in : int
        Number of leading samples to exclude (0 when at rest): until the input
        has come within ``EXTREME_TOL`` of both its record minimum and maximum,
        capped at ``MAX_BURN_IN_SHARE`` of the record.
    reason : str
        One sentence saying why.
    """

    at_rest: bool
    burn_in: int
    reason: str

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {"at_rest": bool(self.at_rest), "burn_in": int(self.burn_in), "reason": self.reason}


def noise_level(x: np.ndarray) -> float:
    """Robust white-noise standard deviation of a smooth signal plus noise.

    Uses the median absolute second difference: the second difference of a
    smooth (oversampled) signal is negligible, that of white noise has
    variance 6σ².

    Parameters
    ----------
    x : ndarray
        Signal (any unit).

    Returns
    -------
    float
        Noise standard deviation, same unit as `x`.
    """
    if len(x) < 3:
        return 0.0
    d2 = np.diff(np.asarray(x, float), 2)
    return float(np.median(np.abs(d2 - np.median(d2))) / 0.6745 / np.sqrt(6.0))


def _held(x: np.ndarray, k: int, tol: float) -> bool:
    # against the window's median, not its first sample: one noisy first
    # sample would otherwise make a still output look as if it moved
    w = x[:k]
    return bool(np.max(np.abs(w - np.median(w))) <= tol)


def _first_rise(u: np.ndarray) -> int:
    """Samples until the input first reaches the middle of its range.

    Measured against the range, not the noise or the first turn: a record cut
    just before an input minimum, or a noisy input, turns down within a
    sample or two, and the output's bottom over those would be its start.
    """
    return int(np.argmax(u >= u.min() + 0.5 * float(np.ptp(u)))) + 1


def rise_excess(u, y) -> float:
    """How far the output starts above its bottom over the input's first rise [µm].

    The rise runs until the input first reaches the middle of its range
    (:func:`_first_rise`); :func:`start_state` calls a start from the bottom
    at rest when this is within ``REST_TOL_Y`` of the output range.
    """
    u, y = np.asarray(u, float), np.asarray(y, float)
    return float(y[0] - y[:_first_rise(u)].min())


def rest_level(inputs) -> float:
    """The input of the stage at rest [V], read off all of its records' inputs.

    0 V (the unpowered stage) when the drives reach or straddle it, unipolar
    or bipolar; otherwise the input of the set nearest 0 V (a stage the
    records only show biased: the lowest input of a positive set, the
    highest of a negative one). 0 V when there is no input.

    Parameters
    ----------
    inputs : iterable of array_like
        The inputs [V] of every record of the stage (training, validation,
        history).
    """
    arrays = [a for a in (np.asarray(u, float) for u in inputs) if a.size]
    if not arrays:
        return 0.0
    lo = min(float(np.min(a)) for a in arrays)
    hi = max(float(np.max(a)) for a in arrays)
    return float(min(max(0.0, lo), hi))


def _sweep_end(u: np.ndarray, tol: float) -> int:
    """First sample index after the input has reached both record extremes."""
    lo = np.flatnonzero(u <= u.min() + tol)
    hi = np.flatnonzero(u >= u.max() - tol)
    return int(max(lo[0], hi[0])) + 1


def start_state(record, hold: int = HOLD_SAMPLES, max_share: float = MAX_BURN_IN_SHARE,
                rest: float | None = None) -> StartState:
    """Decide whether a record starts at rest and how many samples to burn in.

    Parameters
    ----------
    record : fonbw.io.Record
        Needs ``u`` [V] and ``y`` [µm]; ``dt`` [s] is not used.
    hold : int
        Samples the input must stay at its first value for an at-rest start.
    max_share : float
        Cap of the burn-in as a share of the record length (0..1).
    rest : float, optional
        The stage's input at rest [V] (:func:`rest_level` of every record of
        the stage). Without it the record's own bottom stands for rest, and a
        record cut at a hold above the stage's rest (a step record paused at
        40 V in a 0–120 V set), whose creep and memory carry the unseen drive
        before it, would pass for one that starts at rest.

    Returns
    -------
    StartState

    Raises
    ------
    ValueError
        When ``u`` or ``y`` holds a NaN or an infinity (naming the record,
        the column and the first such sample).
    """
    u = np.asarray(record.u, float)
    y = np.asarray(record.y, float) if record.y is not None else np.zeros_like(u)
    n = len(u)
    if n == 0:
        return StartState(True, 0, "empty record")
    for name, x in (("u", u), ("y", y)):
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            raise ValueError(f"record {getattr(record, 'path', '<memory>')}: column {name} is not finite at "
                             f"{bad.size} sample(s), the first at index {bad[0]}; fill or cut them before use")
    span_u = float(np.ptp(u))
    if span_u == 0.0:
        return StartState(True, 0, "input constant over the record")
    k = min(hold, n)
    tol_u = max(1e-3 * span_u, 4.0 * noise_level(u))
    tol_y = max(1e-3 * float(np.ptp(y)), 4.0 * noise_level(y))
    # rest is the bottom of the drive (an unpowered stage): a hold half-way up
    # is a pause mid-drive whose hysteresis state the record does not show
    bottom_u = u[0] <= u.min() + REST_TOL * span_u
    if rest is not None:
        bottom_u = bottom_u and abs(u[0] - float(rest)) <= REST_TOL * span_u
    # the output's bottom over the input's first rise, not over the record: a
    # fast or rate-dependent drive can take the output below its start later
    # on (undershoot at 20 Hz), which says nothing about how the record began
    bottom_y = rise_excess(u, y) <= REST_TOL_Y * max(float(np.ptp(y)), 1e-300) + tol_y
    if k >= hold and bottom_u and _held(u, k, tol_u) and _held(y, k, tol_y):
        return StartState(True, 0, f"input held at {u[0]:.4g} V for {k} samples and output still: at rest")
    if bottom_u and bottom_y:
        return StartState(True, 0, f"input and output start at the bottom of their ranges ({u[0]:.4g} V): "
                                   "driven up from rest")
    end = _sweep_end(u, EXTREME_TOL * span_u)
    cap = int(max_share * n)
    if end > cap:
        return StartState(False, cap, f"not at rest; input reaches both extremes only at sample {end}, "
                                      f"burn-in capped at {cap} ({max_share:.0%} of the record)")
    return StartState(False, end, f"not at rest; input reaches both record extremes by sample {end}: "
                                  f"{end} samples burned in")


def burn_ins(records, say=None) -> list:
    """Samples to leave out at the start of each record (0 when it starts at rest).

    Parameters
    ----------
    records : sequence of fonbw.io.Record
    say : callable, optional
        Called with one line per record that gets a burn-in (what and why).

    Returns
    -------
    list of int
        One burn-in [samples] per record.
    """
    out = []
    rest = rest_level([r.u for r in records]) if len(records) else None
    for r in records:
        st = start_state(r, rest=rest)
        b = 0 if st.at_rest else int(st.burn_in)
        if b and say is not None:
            say(f"{r.path}: {st.reason}; the first {b} samples ({b * r.dt:.4g} s) are left out of the fit "
                "and its sensor offset is fitted")
        out.append(b)
    return out


def backward_burn_in(x, burn_in: int) -> np.ndarray:
    """Samples 1 … `burn_in` of a record's column `x` played backwards: a
    history that ends next to the first sample and sweeps what the burn-in
    sweeps (the first of :func:`history_candidates`)."""
    return np.array(x[burn_in:0:-1], dtype=float)


def _leg(a: float, c: float, rate: float, n_max: int) -> np.ndarray:
    """A half-cosine sweep from `a` towards `c` [V] at a mean `rate` [V/sample]
    (in at most `n_max` samples), without its end point (the next leg or the
    record starts there)."""
    n = min(int(np.ceil(abs(c - a) / rate)), int(n_max)) if rate > 0 else 0
    if n == 0:
        return np.zeros(0)
    s = 0.5 - 0.5 * np.cos(np.pi * np.arange(n) / n)
    return a + (c - a) * s


def history_candidates(u, burn_in: int, rest: float = 0.0, stage=None) -> list:
    """Input histories [V] that could have preceded a record starting mid-drive.

    The first is the record's burn-in played backwards (a turn at its first
    sample), the second a plain sweep from rest to the first input.
    Each of the others leaves rest, sweeps to one extreme of
    the record's input range, turns at one of :data:`HISTORY_LEVELS` levels
    and arrives at the record's first input, at the burn-in's mean rate. For
    hysteresis with wiping out, the last extreme and the last turning point
    set the state: a drive cut mid-slope arrives moving, where a backward
    burn-in would put a turn at the first sample.

    When the stage's input range (`stage`) reaches beyond the record's, the
    same histories are tried once more after a full cycle over the stage's
    range: a record cut out of a drive whose swings decay (eq. 19) was
    preceded by larger ones, and a fractional memory keeps them for seconds.
    On the blind harness's FONBW core of seed 22023 (eq. 19 cut at 3.5 s), the
    nominal model then explains the burn-in to 0.072 µm instead of 0.38 µm.

    Parameters
    ----------
    u : array_like
        The record's input [V].
    burn_in : int
        Samples of the record the history is judged on (≥ 1).
    rest : float
        The stage's input at rest [V] (:func:`rest_level`), where every
        history but the backward burn-in starts.
    stage : (float, float), optional
        The stage's input range [V] (all of its records, or a model's
        training range); None: the record's own.

    Returns
    -------
    list of (str, ndarray)
        Each history's description and input, to be run before ``u[0]``.
    """
    u = np.asarray(u, float)
    b = int(min(max(1, burn_in), u.size - 1))
    lo, hi = float(u.min()), float(u.max())
    # the burn-in's mean rate (a burn-in that reaches both extremes sweeps the
    # range about once); one sweep per burn-in when it moves by less than a
    # quarter of that (a capped burn-in over a pause, input noise only, would
    # ask for legs of millions of samples); and no leg longer than LEG_MAX
    # burn-ins (the first starts at rest, which may lie outside the record's range)
    rate = float(np.mean(np.abs(np.diff(u[:b + 1]))))
    if rate * LEG_MAX * b < hi - lo:
        rate = (hi - lo) / b
    legs = lambda a, c: _leg(a, c, rate, LEG_MAX * b)  # noqa: E731
    out = [("the burn-in played backwards", backward_burn_in(u, b)),
           # a stage brought up to a bias and left there (a step record that
           # starts at its hold): no turn since rest
           (f"from rest straight to {u[0]:.4g} V", legs(rest, float(u[0])))]
    starts = [("from rest", np.zeros(0), rest)]
    if stage is not None:
        s_lo, s_hi = min(float(stage[0]), lo), max(float(stage[1]), hi)
        # only a range the record does not sweep itself adds anything
        if s_hi - hi > EXTREME_TOL * (hi - lo) or lo - s_lo > EXTREME_TOL * (hi - lo):
            starts.append((f"from rest through {s_hi:.4g} V and {s_lo:.4g} V",
                           np.concatenate([legs(rest, s_hi), legs(s_hi, s_lo)]), s_lo))
    for text, pre, u_pre in starts:
        for ua in np.linspace(lo, hi, HISTORY_LEVELS):
            ub = hi if ua <= u[0] else lo
            out.append((f"{text} to {ub:.4g} V, turning at {ua:.4g} V",
                        np.concatenate([pre, legs(u_pre, ub), legs(ub, ua), legs(ua, float(u[0]))])))
    return out


def estimate_history(simulate, u, y, burn_in: int, offset: bool = False, rest: float = 0.0, stage=None):
    """The history of :func:`history_candidates` that best explains a record's burn-in.

    The burn-in samples are never scored, so they are free to estimate the
    unseen state with: a model run through each candidate history and then
    the burn-in is compared with the measured output there.

    Parameters
    ----------
    simulate : callable
        ``simulate(u)`` -> output [µm] of the model from rest.
    u, y : array_like
        The record's input [V] and output [µm].
    burn_in : int
        Samples at the record's start the history is judged on.
    offset : bool
        The output carries an unknown constant sensor offset: judge each
        history on the error's variance over the burn-in, not its mean square.
    rest : float
        The stage's input at rest [V] (:func:`rest_level`).
    stage : (float, float), optional
        The stage's input range [V] (:func:`history_candidates`).

    Returns
    -------
    history : ndarray
        Input [V] to run before the record.
    text : str
        What it is (:func:`history_candidates`).
    mse : float
        Mean squared error [µm²] over the burn-in, its variance with
        `offset` (inf when no candidate gives a finite output).
    """
    u, y = np.asarray(u, float), np.asarray(y, float)
    b = int(min(max(1, burn_in), u.size - 1))
    cands = history_candidates(u, b, rest, stage)
    best = (cands[0][1], cands[0][0], np.inf)
    for text, h in cands:
        with np.errstate(all="ignore"):  # a diverging model scores inf and is passed over
            p = np.asarray(simulate(np.concatenate([h, u[:b]])), float)[h.size:]
            r = y[:b] - p
            e = float(np.var(r) if offset else np.mean(r ** 2))
        if np.isfinite(e) and e < best[2]:
            best = (h, text, e)
    return best
