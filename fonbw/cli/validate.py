"""Validate a saved model on measured records.

For each record (t [s], u [V], y [µm]) prints the RMS error [µm], the RMS
error as a percentage of the record's displacement range and the largest
absolute error [µm]; with ``--json`` one JSON object with keys rms,
rms_percent and max_abs (the worst record's, and ``records`` for several).
"""
from __future__ import annotations

import json

from .records import CSV_FORMAT, add_record_arguments, load_model, read_records

EPILOG = CSV_FORMAT


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL.json", help="model saved by identify (any kind)")
    p.add_argument("data", nargs="+", metavar="DATA.csv", help="one or more records")
    p.add_argument("--json", action="store_true", help="print a JSON object (keys rms, rms_percent, max_abs)")
    add_record_arguments(p)


def run(ns) -> None:
    from ..reproduce import rms_metrics

    m = load_model(ns.model)
    res = []
    for r in read_records(ns.data, ns):
        met = rms_metrics(m, r)
        met.pop("yhat")
        res.append({"file": r.path, "samples": int(len(r.y)), **met})
    out = res[0] if len(res) == 1 else {"records": res,
                                        **{k: max(r[k] for r in res) for k in ("rms", "rms_percent", "max_abs")}}
    if ns.json:
        print(json.dumps({"model": ns.model, "kind": m.kind, **out}, indent=2))
        return
    for r in res:
        print(f"{r['file']}: RMS {r['rms']:.4g} µm = {r['rms_percent']:.3g} % of range {r['range']:.4g} µm, "
              f"max |error| {r['max_abs']:.4g} µm over {r['samples']} samples")
