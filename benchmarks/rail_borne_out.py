"""How much of a rail fitted beyond training the measured output bears out, per scenario.

Diagnoses blind-harness scenarios again (:func:`blind_gap.run_scenario`) with
the stage beyond training's rail (``fonbw.gap.beyond._rail``) wrapped: for
each fold's cross-fitted rail it prints the level and
:func:`fonbw.gap.beyond.borne_out` over the samples that rail holds, with the
share of what the model left that the rail closes and whether the stage
refused it. One markdown row per scenario; a scenario whose rail the stage
never tried (none of its validation commands go past the training ones, or a
rail was named at a greedy step) prints no row.

Usage::

    python benchmarks/rail_borne_out.py 53003 50019 49039 ...
"""
from __future__ import annotations

import argparse

from fonbw.gap import beyond

FAMILY = {"fonbw": "FONBW", "preisach": "Preisach", "pi": "Prandtl–Ishlinskii", "rate": "rate-dependent"}
NAMES = {"saturation": "stroke limit", "clip": "rail", "dynamics": "resonance"}


def measure(seed, budget=1000):
    """The scenario's row and, when the stage tried a rail, each fold's (level [V], borne-out share)."""
    from blind_gap import run_scenario

    seen = []
    rail = beyond.BLOCKS["clip"]

    def wrapped(clip, d, ctx):
        (pred, chosen), why = rail(clip, d, ctx)
        out = []
        for c in chosen:
            p = beyond.rail_prediction(clip, d, c["level"], c["knee"])
            held = ctx["u"] >= c["level"]
            out.append((c["level"], beyond.borne_out(ctx["y"], ctx["z"], p, held, ctx["starts"])))
        seen.append((out, why))
        return (pred, chosen), why

    beyond.BLOCKS["clip"] = wrapped
    try:
        row = run_scenario(seed, budget, {"oracle": False})
    finally:
        beyond.BLOCKS["clip"] = rail
    # the stage's own call; later ones cross-fit the rail on top of the
    # candidates a limit hid (fonbw.gap.hidden)
    return row, (seen[0] if seen else None)


def table_row(row, seen):
    """A markdown row: seed, core, injected [σ], the folds' levels, gap closed, borne out, refused."""
    inj = ", ".join(f"{NAMES.get(k, k)} {v['magnitude']:.1f}" for k, v in row["injected"].items()) or "none"
    folds, why = seen
    levels = " / ".join(f"{lv:.1f}" for lv, _ in folds)
    shares = " / ".join("–" if b is None else f"{b:.2f}" for _, b in folds)
    gc = row["beyond_training"]["tried"]["clip"]["gap_closed"]
    gc = "–" if gc is None else f"{gc:.2f}"
    return (f"| {row['seed']} | {FAMILY.get(row['family'], row['family'])} | {inj} | {levels} V | {gc} | "
            f"{shares} | {'yes' if why else 'no'} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("seeds", type=int, nargs="+")
    ap.add_argument("--budget", type=int, default=1000)
    a = ap.parse_args()
    print("| seed | core | injected (σ) | rail, fold 0 / 1 | gap closed | borne out, fold 0 / 1 | refused |")
    print("|---|---|---|---|---|---|---|")
    for s in a.seeds:
        row, seen = measure(s, a.budget)
        if seen is not None:
            print(table_row(row, seen), flush=True)


if __name__ == "__main__":
    main()
