"""The limits beyond the training range judged on every record and within the training rates, side by side.

Diagnoses blind-harness scenarios (:func:`gap_truth.draw_scenario`, the
family and mid-drive share of :mod:`blind_gap`) up to the stage that
cross-fits a rail and a stroke limit beyond the training range
(:func:`fonbw.gap.beyond.beyond_training`), then runs that stage twice on
the same state: with every record judged (as the stage was first written:
``within_rates=False``) and as the library runs it, on the
reference nominal within the training rates. One line per scenario: the
injected effects, what the greedy steps accepted, and for each way the limit
named and each block's share of what was left (of the whole, and within the
rates) with its refusal. ``--cache DIR`` keeps each diagnosis's state
(cloudpickle) so that a second run only repeats the stage.

Usage::

    python benchmarks/beyond_within_rates.py 62010 57031 56033 ... [--cache DIR]
"""
from __future__ import annotations

import argparse
import copy
import os

import cloudpickle

from fonbw.gap import beyond


def state(seed, cache=None, budget=1000):
    """The diagnosis of scenario `seed` up to the stage beyond training, and the scenario's facts."""
    path = cache and os.path.join(cache, f"{seed}.pkl")
    if path and os.path.exists(path):
        with open(path, "rb") as fh:
            got = cloudpickle.load(fh)
        return got["d"], got["info"]
    from blind_gap import DEFAULTS
    from gap_cores import FAMILIES
    from gap_truth import draw_scenario, scenario_family
    from fonbw.gap import form
    from fonbw.gap.attribute import Diagnosis
    from fonbw.gap.workers import Pool

    family = scenario_family(seed, FAMILIES)
    sc = draw_scenario(seed, family=family, mid_drive=DEFAULTS["mid_drive"])
    d = Diagnosis(sc["train"], sc["validate"], seed=seed, budget=budget, workers=1)
    with Pool(1, preload=()).start() as d.pool:
        d.fit_nominal()
        d.localize_residual()
        d.form_stage()
        d.attribute()
        form.judge_on_effects(d)
    d.pool = None
    info = {"seed": seed, "family": family, "kind": sc["kind"], "starts_at_rest": sc["starts_at_rest"],
            "injected": {k: {"magnitude": v["magnitude"], "params": v["params"]} for k, v in sc["injected"].items()}}
    if path:
        os.makedirs(cache, exist_ok=True)
        with open(path + ".tmp", "wb") as fh:
            cloudpickle.dump({"info": info, "d": d}, fh)
        os.replace(path + ".tmp", path)
    return d, info


def stage(d, within):
    """``d.beyond`` of the stage run on a copy of `d`, judged within the rates or on every record."""
    d = copy.deepcopy(d)
    d.say = lambda *a: None
    beyond.beyond_training(d, within_rates=within)
    return d.beyond or {}


def _tried(b):
    def r(x):
        return "–" if x is None else f"{x:.3f}"
    return "; ".join(f"{k} {r(t['gap_closed'])}/{r(t.get('gap_closed_within'))}"
                     + (" refused" if t["refused"] else "") for k, t in (b.get("tried") or {}).items())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seeds", type=int, nargs="+")
    ap.add_argument("--cache", metavar="DIR", help="keep each diagnosis's state here")
    ap.add_argument("--budget", type=int, default=1000)
    args = ap.parse_args(argv)
    print("| seed | family | injected | accepted | every record | within the rates | shares (whole/within) |")
    print("|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        d, info = state(seed, args.cache, args.budget)
        before, after = stage(d, False), stage(d, True)
        inj = ", ".join(f"{k} {v['magnitude']:.1f} σ" for k, v in info["injected"].items()) or "none"
        print(f"| {seed} | {info['family']} | {inj} | {', '.join(d.accepted) or '–'} | "
              f"{before.get('effect') or '–'} | {after.get('effect') or '–'} | {_tried(after)} |", flush=True)


if __name__ == "__main__":
    main()
