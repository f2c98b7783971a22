"""Identify a hysteresis model from measured records.

Fits the chosen model to one or more records (t [s], u [V], y [µm]) with a
self-adaptive differential evolution (jDE) on the paper's objective, eq. (18);
the parameters that enter linearly are solved by least squares at every
evaluation. Writes the model as JSON (its kind, parameters and units).

A record that does not start at rest (its input starts away from 0 V) is
simulated from rest all the same, but its first samples, until the model's
state no longer depends on the unknown initial state, are left out of the fit
(and its sensor offset, unknown without a rest segment, is fitted); this is
reported. Each parameter that ends at a bound of the search or is poorly
determined by the data is named, with an approximate 95 % interval. With
several records, the model is also fitted on all but one of them and checked
on the one left out (the held-out RMS error).

Ctrl-C stops the search: the output file is left as it was, and the best
model found so far goes to MODEL.json.partial.json, if there is one.
"""
from __future__ import annotations

from ..start import burn_ins
from .records import CLIError, add_record_arguments, out_path, read_records, say


def add_arguments(p) -> None:
    from ..fractional import ENGINES

    p.add_argument("data", nargs="+", metavar="DATA.csv", help="one or more training records")
    p.add_argument("--model", choices=("fonbw", "cbw", "nbw", "zhu"), default="fonbw",
                   help="model kind (default %(default)s)")
    p.add_argument("-o", "--output", required=True, metavar="MODEL.json", help="where to write the model")
    p.add_argument("--seed", type=int, default=0, help="random seed of the search (default %(default)s)")
    p.add_argument("--max-evals", type=int, dest="max_evals",
                   help="evaluation budget of the search (default: 5000)")
    p.add_argument("--workers", type=int, help="threads evaluating candidates (default: one per core)")
    p.add_argument("--memory", choices=ENGINES, default="fast", help="fractional memory engine")
    p.add_argument("--plot", metavar="FILE.png",
                   help="also write a plot of the fit: measured and model y [µm] against t [s], the "
                        "residual, and the loop y against u [V]")
    p.add_argument("--for-compensation", type=float, metavar="DT", dest="for_compensation",
                   help="identify a model whose per-step inverse exists at the compensator's step DT [s]: "
                        "its one-step slope stays positive, with margin, at every state the records visit "
                        "(the saved model records the slope and margin)")
    p.add_argument("--no-holdout", action="store_true",
                   help="with several records, skip the fit on all but one and the check on the one left out")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_record_arguments(p)


def _options(ns) -> dict:
    """identify()'s keyword arguments from the parsed options (checked)."""
    if ns.seed is not None and ns.seed < 0:
        raise CLIError(f"--seed must be ≥ 0, got {ns.seed}")
    kw = dict(kind=ns.model, seed=ns.seed, progress=not ns.quiet, memory=ns.memory)
    if ns.max_evals is not None:
        if ns.max_evals < 10:
            raise CLIError(f"--max-evals must be at least 10, got {ns.max_evals}")
        kw["max_evals"] = ns.max_evals
    if ns.workers is not None:
        if ns.workers < 1:
            raise CLIError(f"--workers must be ≥ 1, got {ns.workers}")
        kw["workers"] = ns.workers
    if ns.for_compensation is not None:
        if not ns.for_compensation > 0:
            raise CLIError(f"--for-compensation takes the compensator's step in s (> 0), got {ns.for_compensation}")
        kw["for_compensation"] = ns.for_compensation
    return kw


def partial_path(output) -> str:
    """Where an interrupted run writes its best-so-far model."""
    return f"{output}.partial.json"


def run(ns) -> None:
    from ..identify import identify

    out = out_path(ns.output)
    if ns.plot:
        out_path(ns.plot)
    recs = read_records(ns.data, ns)
    kw = _options(ns)
    kw["burn_in"] = burn_ins(recs, say)
    try:
        say(f"identifying a {ns.model} model on {len(recs)} record(s), {sum(r.n for r in recs)} samples, "
            f"{kw.get('max_evals', 5000)} evaluations at most; Ctrl-C stops it (the best model so far goes to "
            f"{partial_path(out)})")
        res = identify(recs, **kw)
    except KeyboardInterrupt:  # before the search had a best candidate (e.g. while compiling)
        raise KeyboardInterrupt(f"the search had no best model yet; {out} left as it was") from None
    if res.message == "interrupted":
        part = partial_path(out)
        res.model.save(part)
        raise KeyboardInterrupt(f"{out} left as it was; the best model so far (training RMS {res.rms:.4g} µm "
                                f"after {res.nfev} evaluations) is in {part}")
    res.model.save(out)
    print(f"wrote {out}: {res.model.kind} model, training RMS {res.rms:.4g} µm"
          + (f" ({res.message})" if res.message else ""))
    for w in getattr(res, "warnings", []):
        say(f"warning: {w}")
    if len(recs) > 1 and not ns.no_holdout:
        _holdout(recs, kw)
    if ns.plot:
        from ..fitplot import fit_plot

        fit_plot(res.model, recs, ns.plot, title=f"identify: {res.model.kind} on {len(recs)} record(s)",
                 burn_in=kw["burn_in"])
        print(f"wrote {ns.plot}")


def _holdout(recs, kw) -> None:
    """Fit on all records but one, validate on that one; print each held-out RMS."""
    from ..identify import identify
    from ..objective import score

    kw = {**kw, "progress": False}
    for i, r in enumerate(recs):
        rest = [x for j, x in enumerate(recs) if j != i]
        sub = {**kw, "burn_in": [b for j, b in enumerate(kw["burn_in"]) if j != i]}
        fit = identify(rest, **sub)
        if fit.message == "interrupted":
            raise KeyboardInterrupt("the model was written; the held-out check was cut short")
        met = score(fit.model, r, kw["burn_in"][i])
        print(f"held out {r.path}: RMS {met['rms']:.4g} µm = {met['rms_percent']:.3g} % of range "
              f"(model fitted on the other {len(rest)} record(s))")
