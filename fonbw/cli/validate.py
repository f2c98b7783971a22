"""Validate a saved model on measured records.

For each record (t [s], u [V], y [µm]) prints the RMS error [µm], the RMS
error as a percentage of the record's displacement range [µm] and the largest
absolute error [µm]; with --json one JSON object with keys rms,
rms_percent, max_abs, range, at_rest, burn_in_s (the worst record's, and
records with every record's for several).

Every model starts at rest. A record that does not (see fonbw.start: e.g.
the second half of a longer run, or a bipolar drive whose state at 0 V is
unknown) is run from rest through the input history that best explains its
burn-in (rest, an extreme, a turning level, its first input; or a smooth
lead-in straight to its first input: fonbw.start.estimate_history) and
scored only after its burn-in, the samples until the model's state no longer
depends on the unknown state at the start; its sensor offset (unknown
without a rest segment) is taken as the mean error after the burn-in. Both
are reported. Better, when the record that came just before it is at hand,
pass it with --history PREV.csv: the model runs through PREV and then the
record as one run, the offset is taken from PREV (after PREV's own burn-in),
and only the record is scored, whole.
"""
from __future__ import annotations

import json

from ..io import jsonable
from ..start import start_state
from .records import CLIError, add_record_arguments, finite_output, load_model, out_path, read_records

__all__ = ["add_arguments", "run"]


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL.json", help="model saved by identify (any kind)")
    p.add_argument("data", nargs="+", metavar="DATA.csv", help="one or more records")
    p.add_argument("--history", metavar="PREV.csv",
                   help="the record that came just before DATA.csv (one DATA.csv only): simulate PREV then "
                        "DATA as one run and score DATA")
    p.add_argument("--json", action="store_true",
                   help="print a JSON object (keys rms, rms_percent, max_abs, range, at_rest, burn_in_s)")
    p.add_argument("--plot", metavar="FILE.png",
                   help="also write a plot: measured and model y [µm] against t [s], the error, the loop y "
                        "against u [V]")
    add_record_arguments(p)


def _chain(prev, y0, rec):
    """`rec` less `prev`'s sensor offset `y0` [µm], once it is known to continue `prev`."""
    from dataclasses import replace

    if abs(rec.dt - prev.dt) > 1e-6 * prev.dt:
        raise CLIError(f"{rec.path}: time step {rec.dt:.6g} s differs from that of the history {prev.path} "
                       f"({prev.dt:.6g} s)")
    gap = float(rec.t[0] - prev.t[-1])
    if abs(gap - rec.dt) > 0.5 * rec.dt:
        raise CLIError(f"{rec.path}: does not continue the history {prev.path}: it starts at {rec.t[0]:.10g} s, "
                       f"{gap:.6g} s after the history ends (one step is {rec.dt:.6g} s)")
    return replace(rec, y=rec.y - y0)


def _rows(ns, m):
    """One result row per record (and the records, for the plot)."""
    import numpy as np

    from ..objective import score, stage_rest

    if ns.history and len(ns.data) != 1:
        raise CLIError(f"--history takes one DATA.csv, got {len(ns.data)}")
    recs = read_records(ns.data, ns)
    hist = None
    if ns.history:
        (hist,), (y0,) = read_records([ns.history], ns, offsets=True)
        recs = [_chain(hist, y0, recs[0])]
    rest = stage_rest(m, [r.u for r in recs] + ([hist.u] if hist is not None else []))
    hb = 0
    if hist is not None:
        st = start_state(hist, rest=rest)
        hb = 0 if st.at_rest else int(st.burn_in)
    rows, burns = [], []
    for r in recs:
        st = start_state(r, rest=rest)
        b = 0 if (st.at_rest or hist is not None) else int(st.burn_in)
        if b >= r.n - 8:
            raise CLIError(f"{r.path}: {st.reason}, and the burn-in ({b} samples) leaves too few to score; "
                           "pass the record before it with --history")
        with np.errstate(all="ignore"):  # a model that diverges is refused below, once
            met = score(m, r, b, hist, hb, rest=rest)
        before = met.pop("yhat_history")
        if before is not None:
            finite_output(before, ns.model, hist.path, hist.t)
        finite_output(met.pop("yhat"), ns.model, r.path, r.t)
        rows.append({"file": r.path, "samples": int(r.n - b), **met, "at_rest": bool(st.at_rest),
                     "start": st.reason, "burn_in_samples": b, "burn_in_s": round(b * r.dt, 9),
                     "history": ns.history, "history_burn_in_s": round(hb * r.dt, 9) if hist is not None else None})
        burns.append(b)
    return rows, recs, burns, (hist, hb)


def _say_start(r) -> str:
    if r["history"]:
        off = ("" if r["offset_um"] is None else f"; the sensor offset taken as the mean error over the history "
               f"after its burn-in of {r['history_burn_in_s']:.4g} s, {r['offset_um']:.4g} µm")
        return f"  run from rest through its history {r['history']} first; the record alone scored{off}"
    if r["at_rest"]:
        return ""
    return (f"  {r['start']}: scored after a burn-in of {r['burn_in_s']:.4g} s "
            f"({r['burn_in_samples']} samples), the sensor offset taken as the mean error, "
            f"{r['offset_um']:.4g} µm; the model is run first through {r['start_history']}, the history "
            "that best explains the burn-in (--history PREV.csv runs it through the record before this one "
            "instead)")


def run(ns) -> None:
    m = load_model(ns.model)
    if ns.plot:
        out_path(ns.plot, [ns.model, *ns.data, ns.history])
    rows, recs, burns, hist = _rows(ns, m)
    out = rows[0] if len(rows) == 1 else {"records": rows,
                                          **{k: max(r[k] for r in rows) for k in ("rms", "rms_percent", "max_abs")}}
    if ns.json:
        # strict JSON: a figure that is not a number (the % of a record whose output never moves) is null
        print(json.dumps(jsonable({"model": ns.model, "kind": m.kind, **out}, strict=True), indent=2, allow_nan=False))
    else:
        for r in rows:
            print(f"{r['file']}: RMS {r['rms']:.4g} µm = {r['rms_percent']:.3g} % of range {r['range']:.4g} µm, "
                  f"max |error| {r['max_abs']:.4g} µm over {r['samples']} samples")
            if _say_start(r):
                print(_say_start(r))
    if ns.plot:
        from ..fitplot import fit_plot

        fit_plot(m, recs, ns.plot, title=f"validate: {m.kind} model {ns.model}", burn_in=burns, history=hist[0],
                 history_burn_in=hist[1])
        print(f"wrote {ns.plot}")
