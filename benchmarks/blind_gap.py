"""Blind test of the gap diagnosis on the separate truth simulator.

Scenarios are drawn at random with a seed (:func:`gap_truth.draw_scenario`, in
this folder): a hysteresis core of one of four families (:mod:`gap_cores`:
fonbw, preisach, pi, rate; uniform, or restricted with ``--family``); no
effect (null), one effect, two effects, an effect outside the library
(50/150 Hz mains hum) and one effect below the noise floor, with magnitudes
(RMS change on the validation records) from 0.1 to 100 noise standard
deviations; in a share of the scenarios (``--mid-drive``, 30 %) a training
and/or a validation record starts mid-drive. Training records: eq. (19),
steps with holds, multi-tone; validation: 1 and 20 Hz sines, another
multi-tone, other steps; 5 kHz, about 20 s in all.
:func:`fonbw.gap.diagnose` sees only the records.

Usage::

    python benchmarks/blind_gap.py [-n 40] [--seed0 1000] [--out /tmp/blind_gap.jsonl]
                                   [--only single below] [--family preisach pi] [--oracle]
                                   [--scheduler ADDRESS | --workers N]
    python benchmarks/blind_gap.py --summary /tmp/blind_gap.jsonl

The scenarios are independent tasks on dask.distributed (:func:`fonbw.fleet.map_tasks`):
an embedded LocalCluster, one worker process per core, by default; ``--scheduler
ADDRESS`` sends them to a running cluster (whose workers need this folder on
their path, e.g. ``dask worker … --preload`` or a shared checkout). Each scenario
is appended to the JSON-lines file as it finishes, so a long run can be stopped,
resumed (seeds already in the file are skipped) and summarized at any time
(:mod:`gap_summary`). A single
effect is *material* when its magnitude is at least 2 noise standard
deviations. The harness knows the truth and measures two oracles the
diagnosis never sees: for single effects how much of the effect a FONBW
fitted to the noiseless truth leaves (:func:`unabsorbed`), and with
``--oracle`` how far the best FONBW is from the core alone
(:func:`form_excess`, cached by scenario in ``--oracle-cache``).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import sys
import time

import numpy as np

# the package of this checkout before an installed one: a held-out run from a
# frozen worktree must run that worktree's code (an editable install points at
# the main checkout). Spawned dask workers inherit the parent's sys.path.
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from gap_summary import summary  # noqa: E402

DEFAULTS = {"families": None, "scale": 1.0, "mid_drive": 0.3, "oracle": False, "oracle_evals": 1500,
            "cache": None, "diagnose": None, "diagnose_kwargs": None}


def _clean_records(sc, effects):
    """Noiseless truth records over the whole drives (from rest), training and validation.

    The oracles judge the core and the effects, not the initial state: they
    see every drive from rest, whatever the records the diagnosis gets.
    Record indices as in :func:`gap_truth.draw_scenario` (training i,
    validation 50 + i), so the drift's random walk is the same one.
    """
    from fonbw.io import Record

    truth = sc["truth"]
    out = []
    for key, off in (("train_drives", 0), ("validate_drives", 50)):
        out.append([Record.from_arrays(u=u, y=truth.output(u, off + i, effects=effects), dt=truth.dt)
                    for i, (_, u, _) in enumerate(sc[key])])
    return out


def fonbw_excess(sc, effects=None, evals=1500, seed=0):
    """RMS gap [noise stds] on the validation drives between the noiseless truth
    and the best FONBW identified on the noiseless training drives.

    Parameters
    ----------
    sc : dict
        A scenario of :func:`gap_truth.draw_scenario`.
    effects : dict, optional
        Effects of the truth (None: the scenario's; ``{}``: the core alone).
    evals : int
        Evaluation budget of the identification.
    seed : int
        Seed of the identification.

    Returns
    -------
    float or None
        None when the identified FONBW diverges on a validation drive twice.
    """
    from fonbw.identify import identify

    train, val = _clean_records(sc, effects)
    # a short search can end on a FONBW that is fine on the training drives
    # and diverges on a faster validation drive: that says nothing of the
    # form, so try another seed before giving up (None)
    for s in (seed, seed + 1):
        model = identify(train, kind="fonbw", seed=s, max_evals=evals).model
        num = n = 0
        for r in val:
            d = r.y - model.simulate(r.u, r.dt)
            num += float(np.sum(d * d))
            n += r.u.size
        if math.isfinite(num):
            return math.sqrt(num / n) / sc["truth"].noise_std
    return None


def unabsorbed(sc, evals=1500):
    """What of the truth (core and effects) the best FONBW leaves [noise stds].

    The oracle of what a nominal FONBW can absorb of an injected effect
    (creep, for one, is partly a power-law relaxation that the fractional
    memory represents): an effect whose unabsorbed gap is small leaves the
    diagnosis nothing to find, whatever its magnitude against the pure
    hysteresis. On a core that is not a FONBW it includes the form's gap
    (:func:`form_excess`). Uses the truth, so it is the benchmark's, never the
    diagnosis'.
    """
    return fonbw_excess(sc, None, evals)


def form_excess(sc, evals=1500):
    """What of the core alone the best FONBW leaves [noise stds]: the form is
    material at ≥ 2 and absent below 0.5."""
    return fonbw_excess(sc, {}, evals)


def _oracle_keys(seed, sc, scale):
    core = sc["truth"].core
    base = f"{seed}|{getattr(core, 'name', 'fonbw:legacy')}|{scale:g}"
    inj = json.dumps({k: v["params"] for k, v in sc["injected"].items()}, sort_keys=True, default=float)
    return {"form_excess_sigma": base, "unabsorbed": base + "|" + hashlib.sha256(inj.encode()).hexdigest()[:12]}


def _oracles(seed, sc, opt):
    """Oracle values of a scenario, from the cache where there; ``(values, new cache entries)``."""
    cache = opt["cache"] or {}
    keys = _oracle_keys(seed, sc, opt["scale"])
    want = []
    if sc["kind"] in ("single", "below"):
        want.append(("unabsorbed", unabsorbed))
    if opt["oracle"]:
        want.append(("form_excess_sigma", form_excess))
    vals, new = {}, {}
    for name, fn in want:
        k = keys[name]
        if k not in cache:
            new[k] = fn(sc, opt["oracle_evals"])
        vals[name] = cache.get(k, new.get(k))
    if vals.get("unabsorbed") is not None and vals.get("form_excess_sigma") is not None:
        # the part of the unabsorbed gap the form does not already explain
        # (the two gaps are not orthogonal: an estimate)
        vals["unabsorbed_effect"] = math.sqrt(max(0.0, vals["unabsorbed"] ** 2 - vals["form_excess_sigma"] ** 2))
    return vals, new


def _verdict(res):
    """The fields of the diagnosis' JSON the summary reads (``verdict.form`` may be missing), and
    the fitted parameters and checks of every candidate (first and later greedy steps) and of the
    named effects, for reading a miss without running it again."""
    d = res.to_dict() if hasattr(res, "to_dict") else dict(res)
    v, nom = d["verdict"], d.get("nominal", {})
    return {"named": list(v["effects"]), "gap_closed": v["gap_closed"], "unexplained": v["unexplained"],
            "at_floor": v.get("at_noise_floor"), "form": v.get("form"),
            "noise_floor": nom.get("noise_floor"), "rms0": nom.get("rms_validate"),
            "candidates": [{k: c.get(k) for k in ("effect", "gap_closed", "accepted", "checks", "params")}
                           for c in d.get("candidates", [])],
            "later_steps": v.get("later_steps", []), "tones": v.get("tones", []),
            "step_edges": v.get("step_edges"), "within_training_rates": v.get("within_training_rates"),
            "beyond_training": v.get("beyond_training"),
            "effect_params": v.get("params"), "remaining": v.get("remaining"), "at_bounds": nom.get("at_bounds")}


def run_scenario(seed, budget, options=None):
    """Draw scenario `seed`, diagnose it and measure its oracles: one JSON-able row.

    Parameters
    ----------
    seed : int
    budget : int
        Evaluation budget of the diagnosis.
    options : dict, optional
        ``families`` (tuple of family names, default all), ``scale``
        (record durations), ``mid_drive`` (share of scenarios with a record
        not starting at rest), ``oracle`` (measure the form oracle),
        ``oracle_evals``, ``cache`` (oracle values by key, read only),
        ``diagnose`` (the function; None: :func:`fonbw.gap.diagnose`) and
        ``diagnose_kwargs`` (passed on to it).

    Returns
    -------
    dict
        The row; ``row["oracle_cache"]`` holds the oracle values measured
        here (key → value) for the caller to store, and is not part of the
        JSON line.
    """
    from gap_cores import FAMILIES
    from gap_truth import draw_scenario, scenario_family

    opt = {**DEFAULTS, **(options or {})}
    fams = tuple(opt["families"] or FAMILIES)
    t0 = time.perf_counter()
    family = scenario_family(seed, fams)
    sc = draw_scenario(seed, scale=opt["scale"], family=family, mid_drive=opt["mid_drive"])
    core = sc["truth"].core
    row = {"seed": seed, "family": family, "core": {"name": core.name, "params": sc["core_params"]},
           "kind": sc["kind"], "noise_std": sc["noise_std"], "scale": opt["scale"],
           "starts_at_rest": sc["starts_at_rest"], "mid_drive": sc["mid_drive"],
           "injected": {k: {"magnitude": v["magnitude"], "magnitude_train": v["magnitude_train"],
                            "params": v["params"]} for k, v in sc["injected"].items()}}
    diagnose = opt["diagnose"]
    if diagnose is None:
        from fonbw.gap import diagnose
    try:
        t1 = time.perf_counter()
        # the scenarios share the cores, one process each
        kw = {"workers": 1, **(opt["diagnose_kwargs"] or {})}
        res = diagnose(sc["train"], sc["validate"], seed=seed, budget=budget, **kw)
        row["wall_s"] = time.perf_counter() - t1
        row.update(_verdict(res))
    except Exception as exc:  # keep the run going; the summary counts failures
        row["error"] = f"{type(exc).__name__}: {exc}"
    try:
        vals, new = _oracles(seed, sc, opt)
    except Exception as exc:  # an oracle that fails must not end the run either
        vals, new = {"oracle_error": f"{type(exc).__name__}: {exc}"}, {}
    row.update(vals)
    row["total_s"] = time.perf_counter() - t0
    row["oracle_cache"] = new
    return row


def _read_jsonl(path):
    if not path or not os.path.exists(path):
        return []
    with open(path) as fh:
        return [json.loads(line) for line in fh if line.strip()]


def _scenario_task(item):
    """One Dask task: ``(seed, budget, options)`` -> the scenario's row."""
    seed, budget, options = item
    return run_scenario(seed, budget, options)


def _store(row, out, cache, cache_path):
    """Append a finished scenario's row (and its new oracle values) and print a line."""
    new = row.pop("oracle_cache")
    cache.update(new)
    if cache_path and new:
        with open(cache_path, "a") as fh:
            for k, v in new.items():
                fh.write(json.dumps({"key": k, "value": v}) + "\n")
    with open(out, "a") as fh:
        fh.write(json.dumps(row, default=float) + "\n")
    inj = [(k, round(v["magnitude"], 2)) for k, v in row["injected"].items()]
    print(f"seed {row['seed']} {row['family']:8s} {row['kind']:8s} injected {inj}"
          f"{'' if row['starts_at_rest'] else ' mid-drive'} -> named {row.get('named')}"
          f" form {(row.get('form') or {}).get('material')} gap_closed {row.get('gap_closed', float('nan')):.3f}"
          f" unexplained {row.get('unexplained')} ({row['total_s']:.0f} s)", flush=True)


def run(n, seed0, out, budget, only=None, options=None, cache_path=None, scheduler=None, workers=None,
        seeds=None):
    """Run scenarios seed0 … seed0 + n − 1, or the list `seeds` (those not yet
    in `out`), as tasks on dask.distributed, appending one line each as it completes.

    Every scenario draws from its own seed and reads the oracle cache as it
    was at submission, so a row does not depend on the number of workers nor
    on the order in which they finish (only the order of the lines does; the
    summary does not read it). `scheduler` and `workers` are those of
    :func:`fonbw.fleet.map_tasks`: an embedded LocalCluster with `workers`
    processes (default one per core) or a running scheduler's address.
    """
    from fonbw.fleet import map_tasks
    from gap_truth import scenario_kind

    opt = {**DEFAULTS, **(options or {})}
    done = {r["seed"] for r in _read_jsonl(out)}
    cache = {r["key"]: r["value"] for r in _read_jsonl(cache_path)}
    todo = [seed0 + i for i in range(n)] if seeds is None else list(seeds)
    seeds = [s for s in todo if s not in done and not (only and scenario_kind(s) not in only)]
    items = [(seed, budget, {**opt, "cache": dict(cache)}) for seed in seeds]
    for _, row in map_tasks(_scenario_task, items, scheduler, workers, name="blind-gap"):
        _store(row, out, cache, cache_path)


def _timing(seed, budget, family=None, mid_drive=0.0):
    from fonbw.gap import diagnose
    from gap_truth import draw_scenario

    sc = draw_scenario(seed, "single", scale=1.5, family=family, mid_drive=mid_drive)
    n = sum(len(r.u) for r in sc["train"] + sc["validate"])
    t0 = time.perf_counter()
    res = diagnose(sc["train"], sc["validate"], seed=0, budget=budget)
    wall = time.perf_counter() - t0
    print(f"{n} samples ({n * sc['train'][0].dt:.1f} s at {1 / sc['train'][0].dt:.0f} Hz), "
          f"{sc['family']} core, injected {list(sc['injected'])}, named {res['verdict']['effects']}"
          f"{'' if sc['starts_at_rest'] else ' (records starting mid-drive)'}: wall {wall:.0f} s "
          f"(nominal {res['timing']['nominal_s']:.0f} s, attribution {res['timing']['attribute_s']:.0f} s, "
          f"beyond the training range {res['timing'].get('beyond_s', 0.0):.1f} s); "
          f"load average before/after: {os.getloadavg()[0]:.1f}")


def main(argv=None):
    from gap_cores import FAMILIES

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-n", type=int, default=40, help="number of scenarios")
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--seeds", type=int, nargs="+", metavar="SEED",
                    help="run these seeds instead of -n from --seed0 (spent scenarios diagnosed again)")
    ap.add_argument("--out", default="/tmp/blind_gap.jsonl")
    ap.add_argument("--budget", type=int, default=1000)
    ap.add_argument("--only", nargs="+", metavar="KIND",
                    help="run only the seeds that draw these kinds (null single pair outside below)")
    ap.add_argument("--family", nargs="+", choices=FAMILIES, metavar="NAME",
                    help=f"draw the core from these families only ({' '.join(FAMILIES)}; default all, uniform)")
    ap.add_argument("--mid-drive", type=float, default=None,
                    help=f"share of scenarios with a record that starts mid-drive (default "
                         f"{DEFAULTS['mid_drive']:g}; with --timing 0: every record from rest)")
    ap.add_argument("--scale", type=float, default=1.0, help="stretch every record's duration")
    ap.add_argument("--oracle", action="store_true",
                    help="measure the form oracle (one FONBW identification per scenario)")
    ap.add_argument("--oracle-cache", metavar="JSONL", help="oracle values by scenario (default: OUT.oracle.jsonl)")
    ap.add_argument("--summary", metavar="JSONL", help="only summarize an existing run")
    ap.add_argument("--scheduler", metavar="ADDRESS",
                    help="dask scheduler address or scheduler file (default: an embedded LocalCluster)")
    ap.add_argument("--workers", type=int, metavar="N",
                    help="worker processes of the embedded cluster (default: one per core)")
    ap.add_argument("--timing", action="store_true",
                    help="time one diagnosis on ~30 s of 5 kHz data (scenario durations x1.5; "
                         "the core of the first --family, default a FONBW core)")
    ns = ap.parse_args(argv)
    if ns.timing:
        _timing(ns.seed0, ns.budget, ns.family[0] if ns.family else None, ns.mid_drive or 0.0)
        return 0
    if ns.summary:
        print(summary(ns.summary))
        return 0
    mid = DEFAULTS["mid_drive"] if ns.mid_drive is None else ns.mid_drive
    opt = {"families": ns.family, "scale": ns.scale, "mid_drive": mid, "oracle": ns.oracle}
    run(ns.n, ns.seed0, ns.out, ns.budget, ns.only, opt, ns.oracle_cache or ns.out + ".oracle.jsonl",
        scheduler=ns.scheduler, workers=ns.workers, seeds=ns.seeds)
    print(summary(ns.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
