"""How the records of a diagnosis start, and what the models run before them.

A record that starts mid-drive (:func:`fonbw.start.start_state`) keeps its
burn-in out of every fit and score. The models still have to arrive at its
first sample in some state: they run a history first, at first the burn-in
played backwards and, once a nominal model exists, the candidate history that
best explains the burn-in under it (:func:`fonbw.start.estimate_history`).
Without that, a wrong initial state of the fractional memory decays as a
power law over the scored samples, which a creep block would be credited
with, and a drive cut mid-slope starts at a turn it never made.
"""
from __future__ import annotations

import math

import numpy as np

from ..io import Record
from ..start import backward_burn_in, estimate_history, rest_level, start_state

__all__ = ["RecordStarts"]

KINDS = ("train", "validate")


class RecordStarts:
    """Start states and histories of the training and validation records.

    Parameters
    ----------
    train, validate : list of Record
        The measured records.

    Attributes
    ----------
    raw : dict
        The records as given, by kind ("train", "validate").
    starts : dict
        :class:`fonbw.start.StartState` of each record, by kind.
    history : dict
        Input [V] run before each record (None: it starts at rest), by kind.
    info : dict
        (kind, index) -> {"history": what it is, "rms_burn_in": the RMS error
        [µm] over the burn-in after it of the nominal that chose it,
        "chosen_with": that nominal, "fonbw" or "reference"}, once estimated.
    """

    def __init__(self, train, validate):
        self.raw = {"train": list(train), "validate": list(validate)}
        inputs = [r.u for k in KINDS for r in self.raw[k]]
        self.rest = rest = rest_level(inputs)
        #: the input range the stage is seen to be driven over [V]
        self.stage = (min(float(np.min(u)) for u in inputs), max(float(np.max(u)) for u in inputs))
        self.starts = {k: [start_state(r, rest=rest) for r in self.raw[k]] for k in KINDS}
        self.history = {k: [None if _from_rest(s) else backward_burn_in(r.u, s.burn_in)
                            for r, s in zip(self.raw[k], self.starts[k])] for k in KINDS}
        self.info = {}

    def from_rest(self, kind):
        """Indices of the `kind` records that the models run from rest (no history)."""
        return [i for i, s in enumerate(self.starts[kind]) if _from_rest(s)]

    def at_rest(self, kind):
        """The `kind` records as given that the models run from rest (no history)."""
        return [self.raw[kind][i] for i in self.from_rest(kind)]

    def saved(self, kind):
        """The histories of the `kind` records as they stand, for :meth:`restore`."""
        return list(self.history[kind]), {k: v for k, v in self.info.items() if k[0] == kind}

    def restore(self, kind, saved):
        """Put back the `kind` histories :meth:`saved` returned (the other kind's stay)."""
        self.history[kind] = list(saved[0])
        self.info = {**{k: v for k, v in self.info.items() if k[0] != kind}, **saved[1]}

    def records(self, kind):
        """The `kind` records preceded by their histories, and the samples of
        each to skip (history and burn-in) [samples]."""
        recs, skips = [], []
        for r, s, h in zip(self.raw[kind], self.starts[kind], self.history[kind]):
            b = 0 if h is None else s.burn_in
            recs.append(_preroll(r, h, b))
            skips.append(0 if h is None else h.size + b)
        return recs, skips

    def estimate(self, simulate, by="fonbw"):
        """Choose each mid-drive record's history with the model `simulate`
        (``simulate(u)`` -> output [µm] from rest), the nominal named `by`
        ("fonbw" or "reference"). Returns the kinds ("train", "validate") in
        which a record's history changed (empty: none)."""
        self.info, changed = {}, set()
        for kind in KINDS:
            for i, (r, s) in enumerate(zip(self.raw[kind], self.starts[kind])):
                if _from_rest(s):
                    continue
                h, text, e = estimate_history(simulate, r.u, r.y, s.burn_in, rest=self.rest, stage=self.stage)
                old = self.history[kind][i]
                if old is None or not np.array_equal(old, h):
                    changed.add(kind)
                self.history[kind][i] = h
                self.info[(kind, i)] = {"history": text, "rms_burn_in": math.sqrt(e) if math.isfinite(e) else None,
                                        "chosen_with": by}
        return changed

    def to_dict(self):
        """Per-record start states, with ``history``, ``rms_burn_in`` [µm]
        and ``chosen_with`` (the nominal that chose the history: "fonbw" or
        "reference") for each record that starts mid-drive."""
        return {k: [{**s.to_dict(), **self.info.get((k, i), {})} for i, s in enumerate(self.starts[k])]
                for k in KINDS}

    def report(self):
        """The verdict's ``start``: per-record states and whether any record needed a burn-in."""
        mid = any(not s.at_rest for k in KINDS for s in self.starts[k])
        return {"mid_drive": mid, "records": self.to_dict(),
                "message": ("records starting mid-drive: their start-up transients are burned in and not "
                            "attributed, each run after the history that best explains its burn-in"
                            if mid else "every record starts at rest")}


def _from_rest(start):
    """A record with this :class:`fonbw.start.StartState` is run from rest:
    it starts there, or it has no burn-in to estimate a history on."""
    return start.at_rest or start.burn_in <= 0


def _preroll(rec, hist, b):
    """`rec` preceded by the input history `hist` [V] (None: `rec` itself).

    The history's output is never scored (nor fitted, but by the nominal
    identification): the burn-in played backwards when the history is the
    backward burn-in, the record's first output otherwise.
    """
    if hist is None:
        return rec
    if hist.size == b and np.array_equal(hist, backward_burn_in(rec.u, b)):
        yh = backward_burn_in(rec.y, b)
    else:
        yh = np.full(hist.size, rec.y[0])
    return Record.from_arrays(u=np.concatenate([hist, rec.u]), y=np.concatenate([yh, rec.y]),
                              dt=rec.dt, path=rec.path)


def cut(rec, b):
    """`rec` without its first `b` samples (the part that is scored)."""
    if b <= 0:
        return rec
    return Record(t=rec.t[b:], u=rec.u[b:], y=rec.y[b:], dt=rec.dt, path=rec.path)
