"""Simulate a saved model on an input record.

Reads INPUT.csv (columns t [s] and u [V]; the model starts at rest) and writes
OUT.csv with columns t [s], u [V] and y [µm], the model's displacement.
"""
from __future__ import annotations

from .records import add_record_arguments, finite_output, load_model, out_path, read_records


def add_arguments(p) -> None:
    from ..fractional import ENGINES

    p.add_argument("model", metavar="MODEL.json", help="model saved by identify (any kind)")
    p.add_argument("input", metavar="INPUT.csv", help="input record: columns t [s], u [V]")
    p.add_argument("-o", "--output", required=True, metavar="OUT.csv", help="where to write t, u, y")
    p.add_argument("--memory", choices=ENGINES, help="override the model's fractional memory engine "
                   "(default: the model's)")
    add_record_arguments(p, offset=False)


def run(ns) -> None:
    import numpy as np

    from ..hysteresis import model_from_dict
    from ..io import write_csv
    from ..objective import simulate_record

    out = out_path(ns.output, (ns.model, ns.input))
    m = load_model(ns.model)
    if ns.memory and hasattr(m, "memory"):
        d = m.to_dict()
        d["params"]["memory"] = ns.memory
        m = model_from_dict(d, source=ns.model)
    (rec,) = read_records([ns.input], ns, need=("u",))
    with np.errstate(all="ignore"):  # a model that diverges is refused below, once
        y = simulate_record(m, rec.u, rec.dt)  # from the model's recorded start
    finite_output(y, ns.model, rec.path, rec.t)
    write_csv(out, {"t": rec.t, "u": rec.u, "y": y})
    print(f"wrote {ns.output}: {len(y)} samples at dt = {rec.dt:.6g} s, y in [{y.min():.4g}, {y.max():.4g}] µm")
