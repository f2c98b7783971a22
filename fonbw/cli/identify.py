"""Identify a hysteresis model from measured records.

Fits the chosen model to one or more records (t [s], u [V], y [µm]) with a
self-adaptive differential evolution (jDE) on the paper's objective, eq. (18);
the parameters that enter linearly are solved by least squares at every
evaluation. Writes the model as JSON (its kind, parameters and units).
"""
from __future__ import annotations

from .records import CSV_FORMAT, CLIError, add_record_arguments, out_path, read_records

EPILOG = CSV_FORMAT


def add_arguments(p) -> None:
    from ..fractional import ENGINES

    p.add_argument("data", nargs="+", metavar="DATA.csv", help="one or more training records")
    p.add_argument("--model", choices=("fonbw", "cbw", "nbw", "zhu"), default="fonbw",
                   help="model kind (default %(default)s)")
    p.add_argument("-o", "--output", required=True, metavar="MODEL.json", help="where to write the model")
    p.add_argument("--seed", type=int, default=0, help="random seed of the search (default %(default)s)")
    p.add_argument("--max-evals", type=int, dest="max_evals",
                   help="evaluation budget of the search (default: the library's, 1000 to 3000 by model)")
    p.add_argument("--workers", type=int, help="processes evaluating candidates (default: one per core)")
    p.add_argument("--memory", choices=ENGINES, help="fractional memory engine (default fast)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_record_arguments(p)


def run(ns) -> None:
    from ..identify import identify

    recs = read_records(ns.data, ns)
    if ns.seed is not None and ns.seed < 0:
        raise CLIError(f"--seed must be ≥ 0, got {ns.seed}")
    kw = dict(kind=ns.model, seed=ns.seed, progress=not ns.quiet)
    if ns.max_evals is not None:
        if ns.max_evals < 10:
            raise CLIError(f"--max-evals must be at least 10, got {ns.max_evals}")
        kw["max_evals"] = ns.max_evals
    if ns.workers is not None:
        if ns.workers < 1:
            raise CLIError(f"--workers must be ≥ 1, got {ns.workers}")
        kw["workers"] = ns.workers
    if ns.memory:
        kw["memory"] = ns.memory
    res = identify(recs, **kw)
    res.model.save(out_path(ns.output))
    msg = getattr(res, "message", "")
    print(f"wrote {ns.output}: {res.model.kind} model, training RMS {res.rms:.4g} µm"
          + (f" ({msg})" if msg else ""))
