"""Identify a hysteresis model from measured records.

Fits the chosen model to one or more records (t [s], u [V], y [µm]) with a
self-adaptive differential evolution (jDE) on the paper's objective, eq. (18);
the parameters that enter linearly are solved by least squares at every
evaluation. Writes the model as JSON (its kind, parameters and units, and a ``fit``
object: the records' names and digest, the options and the training RMS),
through the same code as ``fonbw fleet``, so both give the same file.

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

from .records import CLIError, add_record_arguments, out_path, say


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
    p.add_argument("--rest-cycle", action="store_true", dest="rest_cycle",
                   help="the records start with the stage at rest after a previous drive cycle, its "
                        "sensor zeroed there (as a stage is after power-up and a first sweep): the model "
                        "runs a 1-s cycle rest -> top -> rest over the records' voltage range before each "
                        "record and counts its output from the end of it; the saved model records that "
                        "start, and the compensators and FMUs run it first. Without it a model starts "
                        "from its virgin state, whose descending branch does not come back to 0 um")
    p.add_argument("--no-holdout", action="store_true",
                   help="with several records, skip the fit on all but one and the check on the one left out")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_record_arguments(p)


def _options(ns) -> dict:
    """The options that decide the model (:func:`fonbw.fleet.fit.fit_options`), checked,
    and the thread count."""
    from ..fleet.fit import fit_options

    if ns.workers is not None and ns.workers < 1:
        raise CLIError(f"--workers must be ≥ 1, got {ns.workers}")
    return fit_options(ns)


def partial_path(output) -> str:
    """Where an interrupted run writes its best-so-far model."""
    return f"{output}.partial.json"


def run(ns) -> None:
    from ..fleet.fit import identify_kwargs, identify_paths, write_model

    out = out_path(ns.output, ns.data)
    if ns.plot:
        out_path(ns.plot, [*ns.data, out])
    options = _options(ns)
    started = []

    def announce(recs, kw):
        started.append(True)
        say(f"identifying a {ns.model} model on {len(recs)} record(s), {sum(r.n for r in recs)} samples, "
            f"{kw['max_evals']} evaluations at most; Ctrl-C stops it (the best model so far goes to "
            f"{partial_path(out)})")

    try:
        # the one identification path, shared with `fonbw fleet`
        fit = identify_paths(ns.data, options, progress=not ns.quiet, workers=ns.workers, announce=announce)
    except KeyboardInterrupt:
        if not started:  # while reading: nothing to say beyond the interrupt
            raise
        # the search had no best candidate yet (e.g. while compiling the kernels)
        raise KeyboardInterrupt(f"the search had no best model yet; {out} left as it was") from None
    res, recs = fit.result, fit.records
    if res.message == "interrupted":
        part = partial_path(out)
        res.model.save(part)
        raise KeyboardInterrupt(f"{out} left as it was; the best model so far (training RMS {res.rms:.4g} µm "
                                f"after {res.nfev} evaluations) is in {part}")
    write_model(out, fit.document)
    try:
        print(f"wrote {out}: {res.model.kind} model, training RMS {res.rms:.4g} µm"
              + (f" ({res.message})" if res.message else ""))
        for w in getattr(res, "warnings", []):
            say(f"warning: {w}")
        if len(recs) > 1 and not ns.no_holdout:
            _holdout(recs, identify_kwargs(options, fit.burn_in, workers=ns.workers))
        if ns.plot:
            from ..fitplot import fit_plot

            fit_plot(res.model, recs, ns.plot, title=f"identify: {res.model.kind} on {len(recs)} record(s)",
                     burn_in=fit.burn_in)
            print(f"wrote {ns.plot}")
    except KeyboardInterrupt:
        # whatever the interrupted step said, the model is written by now
        raise KeyboardInterrupt(f"{out} was written; the held-out check or the plot was cut short") from None


def _holdout(recs, kw) -> None:
    """Fit on all records but one, validate on that one; print each held-out RMS.
    A record the others cannot be fitted without (they hold a constant input,
    every candidate diverges on them) is said and skipped: the model on every
    record is written by then, and this check only reports on it."""
    import numpy as np

    from ..identify import identify
    from ..objective import DivergedError, score
    from ..start import rest_level
    from .records import OUTPUT_MAX, first_wild

    kw = {**kw, "progress": False}
    rest_u = rest_level([r.u for r in recs])  # the stage's, read off every record
    for i, r in enumerate(recs):
        rest = [x for j, x in enumerate(recs) if j != i]
        sub = {**kw, "burn_in": [b for j, b in enumerate(kw["burn_in"]) if j != i]}
        try:
            fit = identify(rest, **sub)
        except (ValueError, DivergedError) as exc:
            say(f"warning: {r.path} not held out: the other record(s) cannot be fitted alone ({exc})")
            continue
        if fit.message == "interrupted":
            raise KeyboardInterrupt
        with np.errstate(all="ignore"):  # a model that diverges on the record is said so below
            met = score(fit.model, r, kw["burn_in"][i], rest=rest_u)
        k = first_wild(met["yhat"])
        if k is not None:
            # the written model is fitted on every record; this one says only how the others generalize
            say(f"warning: held out {r.path}: the model fitted on the other {len(rest)} record(s) diverges "
                f"on it (its output passes {OUTPUT_MAX:g} µm or is not finite from sample {k}, "
                f"t = {r.t[k]:.6g} s): no RMS")
            continue
        print(f"held out {r.path}: RMS {met['rms']:.4g} µm = {met['rms_percent']:.3g} % of range "
              f"(model fitted on the other {len(rest)} record(s))")
