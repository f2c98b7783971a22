"""Diagnose the sim-to-real gap of the nominal FONBW model on measured records.

Fits the nominal FONBW model on the training records (or takes ``--model``)
and a flexible reference hysteresis beside it, localizes the residual on the
validation records, reports the hysteresis form (what no FONBW reaches but
the reference does) apart from the unmodelled effects (creep, dynamics,
amplifier, delay, drift, saturation, clip), each refit jointly with the better
nominal, with the gap each closes; records that start mid-drive get a burn-in
that is reported, never credited to an effect. Writes the result as JSON (and
optionally a self-contained HTML report) and prints the verdict in one line.
"""
from __future__ import annotations

from .records import add_record_arguments, out_path, read_records


def add_arguments(parser):
    """Arguments of ``fonbw diagnose`` on an argparse parser (or subparser); returns it."""
    parser.add_argument("--train", action="append", required=True, metavar="CSV",
                        help="training record (t, u, y); repeat for several")
    parser.add_argument("--validate", action="append", required=True, metavar="CSV",
                        help="validation record; repeat for several")
    parser.add_argument("--json", required=True, metavar="OUT.json", help="write the result here")
    parser.add_argument("--html", metavar="OUT.html", help="also write a self-contained HTML report")
    parser.add_argument("--model", metavar="MODEL.json", help="nominal FONBW/NBW model (identified if omitted)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--budget", type=int, default=1000,
                        help="evaluations of the nominal identification and of each candidate's "
                             "global search (default 1000)")
    parser.add_argument("--progress", action="store_true", help="report each step on stderr")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="processes for the candidate refits of each step (default: $FONBW_WORKERS, "
                             "else the cores, at most 4; 1 runs everything in this process)")
    add_record_arguments(parser)
    return parser


def run(ns):
    """Run ``fonbw diagnose`` from parsed arguments; returns the exit code (0).

    Bad input (unreadable CSV, bad model) raises ValueError (DataError is a
    ValueError) with a one-line message for the CLI to print.
    """
    from .. import load_model
    from ..gap import write_html, write_json
    from ..gap.attribute import diagnose

    reads = [*ns.train, *ns.validate, getattr(ns, "model", None)]
    out_path(ns.json, reads)
    if getattr(ns, "html", None):
        out_path(ns.html, [*reads, ns.json])
    train = read_records(ns.train, ns)
    val = read_records(ns.validate, ns)
    model = load_model(ns.model) if getattr(ns, "model", None) else None
    res = diagnose(train, val, model=model, seed=ns.seed, progress=getattr(ns, "progress", False),
                   budget=getattr(ns, "budget", 1000), workers=getattr(ns, "workers", None))
    write_json(res, ns.json)
    if getattr(ns, "html", None):
        write_html(res, ns.html)
    v = res.verdict
    print(f"{v.get('message', '')}; nominal RMS {res.nominal['rms_validate']:.4g} µm, "
          f"noise floor {res.nominal['noise_floor']:.4g} µm, gap closed {v['gap_closed']:.3f}")
    return 0
