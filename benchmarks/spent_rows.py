"""Scans of spent blind-harness rows: what the greedy steps' candidates did.

The rows of ``benchmarks/blind_gap.py`` keep every greedy step's candidates
with their checks and fitted parameters, so a rule on how candidates are
chosen can be measured on runs already made before it is written, without
diagnosing anything again. The scans:

``limits``
    the greedy steps where both a rail (``clip``) and a stroke limit
    (``saturation``) passed every check: which of the two closed more of the
    validation gap, which fitted the training records better (ΔBIC), and
    whether that one was injected (at ≥ 2 σ).
``rails``
    the rails accepted at a greedy step, with their level and knee [V], and
    whether a rail was injected.
``rail-tops``
    the scenarios where a rail passed a greedy step, by how far under the
    training's largest command its level sat (from the rows' coverage
    flags), and which limit was injected there.
``bends``
    the stroke limits (``saturation``) accepted at a later greedy step whose
    slope drop above the knee is under two thirds (a bend alone on the
    nominal), with the effects accepted before them and whether a stroke
    limit was injected.
``orders``
    the order μ of the reference's fractional column, by core family and
    by whether a lag of the drive or the stage (delay, amplifier,
    resonance) was injected (at ≥ 2 σ): how often it went above a cut
    (``--cut``, default 0.9), where the column is nearly a derivative.
``met``
    the scenarios where a resonance and a stroke limit met in a joint refit
    (a later greedy step tried one on top of the other), whose verdicts the
    order of the two can move: their seeds, for ``blind_gap.py --seeds``.

Usage::

    python benchmarks/spent_rows.py limits held45.jsonl held46.jsonl ...
    python benchmarks/spent_rows.py rails held45.jsonl held46.jsonl ...
    python benchmarks/spent_rows.py rail-tops held45.jsonl held46.jsonl ...
    python benchmarks/spent_rows.py met held63.jsonl held64.jsonl ...
    python benchmarks/spent_rows.py bends held64.jsonl held65.jsonl ...
    python benchmarks/spent_rows.py orders held63.jsonl held64.jsonl ... [--cut 0.9]

A seed found in several files counts once, from the first file that holds it
(give the held-out runs' own files first).
"""
from __future__ import annotations

import argparse
import json

from fonbw.gap import effects as fx
from fonbw.gap.checks import top_passed
from fonbw.gap.limits import Clip, Saturation
from gap_summary import MATERIAL

__all__ = ["rows", "steps", "contested_limits", "accepted_rails", "passing_rail_tops", "resonance_met_limit",
           "later_bends", "LAGS", "reference_orders"]


def rows(paths):
    """Diagnosed rows of the JSON-lines files `paths`, one per seed (the first)."""
    out, seen = [], set()
    for path in paths:
        with open(path) as fh:
            for line in fh:
                if not line.strip():
                    continue
                r = json.loads(line)
                if "candidates" in r and r["seed"] not in seen:
                    seen.add(r["seed"])
                    out.append(r)
    return out


def _later(r):
    """The later greedy steps of row `r`: a step judged on top of a limit
    named beyond the training range is none."""
    return [s for s in r.get("later_steps") or [] if not s.get("beyond_training")]


def steps(r):
    """(step number, candidates, effect accepted or None) of each greedy step of row `r`."""
    later = _later(r)
    first = later[0]["on_top_of"][-1] if later else (r["named"][0] if r["named"] else None)
    return [(1, r["candidates"], first)] + [(i + 2, s["candidates"], s.get("accepted"))
                                            for i, s in enumerate(later)]


def _injected(r, name):
    return name in r["injected"] and r["injected"][name]["magnitude"] >= MATERIAL


def contested_limits(rs):
    """One dict per greedy step where a rail and a stroke limit both passed."""
    out = []
    for r in rs:
        for k, cands, accepted in steps(r):
            d = {c["effect"]: c["checks"] for c in cands}
            if not all(n in d and d[n].get("passed") for n in ("clip", "saturation")):
                continue
            by_gc = max(("clip", "saturation"), key=lambda n: d[n]["gap_closed_step"])
            by_bic = min(("clip", "saturation"), key=lambda n: d[n]["delta_bic"])
            out.append({"seed": r["seed"], "family": r["family"], "step": k, "accepted": accepted,
                        "injected": sorted(n for n in ("clip", "saturation") if _injected(r, n)),
                        "by_gap_closed": by_gc, "by_delta_bic": by_bic,
                        **{f"{n}_gap_closed": d[n]["gap_closed_step"] for n in ("clip", "saturation")},
                        **{f"{n}_delta_bic": d[n]["delta_bic"] for n in ("clip", "saturation")}})
    return out


def accepted_rails(rs):
    """One dict per rail accepted at a greedy step: level, knee [V], injected or not."""
    out = []
    for r in rs:
        for k, cands, accepted in steps(r):
            for c in cands:
                if c["effect"] == "clip" and accepted == "clip" and c["checks"].get("passed"):
                    out.append({"seed": r["seed"], "family": r["family"], "step": k,
                                "level": c["params"]["level"], "knee": c["params"]["knee"],
                                "injected": _injected(r, "clip")})
    return out


def passing_rail_tops(rs):
    """One dict per scenario where a rail passed a greedy step: the highest
    such rail's level under the training's largest command [V] (negative
    above it) and that command, and the limits injected (at ≥ 2 σ)."""
    out = []
    for r in rs:
        top = top_passed(f for rem in r.get("remaining") or [] for f in rem["outside"])
        levels = [c["params"]["level"] for _, cands, _ in steps(r) for c in cands
                  if c["effect"] == "clip" and c["checks"].get("passed")]
        if top is None or not levels:
            continue
        out.append({"seed": r["seed"], "family": r["family"], "under": top - max(levels), "top": top,
                    "injected": sorted(n for n in ("clip", "saturation") if _injected(r, n))})
    return out


def resonance_met_limit(rs):
    """The rows where a later greedy step refit a stroke limit on top of an
    accepted resonance, or a resonance on top of an accepted stroke limit."""
    pair = {"dynamics": "saturation", "saturation": "dynamics"}
    return [r for r in rs
            if any(pair.get(c["effect"]) in s["on_top_of"] for s in r.get("later_steps") or [] for c in s["candidates"])]


def later_bends(rs, min_drop=Saturation.min_drop):
    """One dict per stroke limit accepted at a later greedy step with a slope
    drop (−c) under `min_drop`: what it was accepted beside, and whether a
    stroke limit was injected (at ≥ 2 σ)."""
    out = []
    for r in rs:
        for s in _later(r):
            for c in s["candidates"]:
                if c["effect"] == "saturation" and c["accepted"] and -c["params"]["c"] < min_drop:
                    out.append({"seed": r["seed"], "family": r["family"], "beside": list(s["on_top_of"]),
                                "drop": -c["params"]["c"], "gap_closed": c["gap_closed"],
                                "injected": sorted(n for n in r["injected"] if _injected(r, n)),
                                "named": r["named"]})
    return out


#: The injected effects that lag the drive or the stage: the library's lag blocks.
LAGS = tuple(sorted(b.name for b in fx.Effect.__subclasses__() if b.lag))


def reference_orders(rs, cut):
    """The reference's fractional order μ of each row, grouped by (core
    family, whether a lag of :data:`LAGS` was injected at ≥ 2 σ): a dict
    of lists of (μ, seed), and how many μ lie above `cut` in each."""
    groups = {}
    for r in rs:
        mu = (((r.get("form") or {}).get("reference") or {}).get("theta") or {}).get("mu")
        if mu is None:
            continue
        key = (r["family"], any(_injected(r, n) for n in LAGS))
        groups.setdefault(key, []).append((mu, r["seed"]))
    return {k: (sorted(v), sum(m > cut for m, _ in v)) for k, v in sorted(groups.items())}


def _print_orders(rs, cut):
    for (family, lag), (found, above) in reference_orders(rs, cut).items():
        seeds = " ".join(str(s) for m, s in found if m > cut)
        print(f"{family:9s} {'a lag' if lag else 'no lag':6s}: μ above {cut:g} on {above} of {len(found)}"
              + (f" ({seeds})" if seeds else ""))


def _print_bends(rs):
    found = later_bends(rs)
    for s in found:
        print(f"{s['seed']} {s['family']:9s} beside {s['beside']}: slope drop {s['drop']:.2f}, closing "
              f"{s['gap_closed']:.3f}; injected {s['injected'] or '-'}, named {s['named']}")
    true = sum("saturation" in s["injected"] for s in found)
    print(f"{len(found)} accepted over {len(rs)} scenarios: a stroke limit injected in {true}, "
          f"none in {len(found) - true}")


def _print_met(rs):
    found = resonance_met_limit(rs)
    for r in found:
        inj = {k: round(v["magnitude"], 1) for k, v in r["injected"].items()}
        print(f"{r['seed']} {r['family']:9s} injected {inj or '-'} named {r['named']}")
    print(f"{len(found)} of {len(rs)} scenarios; seeds: {' '.join(str(r['seed']) for r in found)}")


def _print_limits(rs):
    found = contested_limits(rs)
    for s in found:
        print(f"{s['seed']} {s['family']:9s} step {s['step']} injected {s['injected'] or '-'} "
              f"accepted {s['accepted']}: rail {s['clip_gap_closed']:.3f} / {s['clip_delta_bic']:.0f}, "
              f"stroke limit {s['saturation_gap_closed']:.3f} / {s['saturation_delta_bic']:.0f}")
    gc = sum(s["by_gap_closed"] in s["injected"] for s in found)
    bic = sum(s["by_delta_bic"] in s["injected"] for s in found)
    print(f"{len(found)} steps with both limits passing, over {len(rs)} scenarios: the one closing more "
          f"was injected on {gc}, the better training fit on {bic}")


def _print_rails(rs):
    found = accepted_rails(rs)
    for s in found:
        print(f"{s['seed']} {s['family']:9s} step {s['step']} {'injected' if s['injected'] else 'not there'}: "
              f"level {s['level']:.1f} V, knee {s['knee']:.2f} V")
    for inj in (True, False):
        knees = sorted(s["knee"] for s in found if s["injected"] is inj)
        span = f"{knees[0]:.2f}-{knees[-1]:.2f} V" if knees else "-"
        print(f"{'injected' if inj else 'not injected'}: {len(knees)} rails accepted, knees {span}")


def _print_rail_tops(rs, share=Clip.top_share):
    found = passing_rail_tops(rs)
    for s in sorted(found, key=lambda s: s["under"]):
        print(f"{s['seed']} {s['family']:9s} {s['under']:+7.2f} V under {s['top']:.2f} V, "
              f"injected {s['injected'] or '-'}")
    near = [s for s in found if s["under"] <= share * s["top"]]
    for what, group in (("within %.1f %% of the top or above it" % (100 * share), near),
                        ("lower", [s for s in found if s not in near])):
        rail = sum("clip" in s["injected"] for s in group)
        stop = sum("saturation" in s["injected"] and "clip" not in s["injected"] for s in group)
        print(f"{what}: {len(group)} scenarios, a rail injected in {rail}, a stroke limit (no rail) in {stop}, "
              f"neither in {len(group) - rail - stop}")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scan", choices=("limits", "rails", "rail-tops", "met", "bends", "orders"))
    p.add_argument("files", nargs="+", help="JSON-lines files of blind_gap.py runs")
    p.add_argument("--cut", type=float, default=0.9, help="the order μ counted above (orders only)")
    a = p.parse_args(argv)
    rs = rows(a.files)
    {"limits": _print_limits, "rails": _print_rails, "rail-tops": _print_rail_tops, "met": _print_met,
     "bends": _print_bends, "orders": lambda rs: _print_orders(rs, a.cut)}[a.scan](rs)


if __name__ == "__main__":
    main()
