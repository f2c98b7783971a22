"""How much of the nominal's misfit at the step edges each lag candidate leaves.

For every given blind-harness seed the scenario is drawn again and diagnosed
up to its first greedy step (the nominal, the form, every lag candidate refit
on the better nominal). Printed per seed: the nominal's mean square error
within the step edges' windows against elsewhere (the training records, in
noise variances), and for each lag candidate the share of the windows'
misfit its refit leaves, with its gap closed and how its checks end
(:meth:`fonbw.gap.edges.StepEdges.left`, which refuses an amplifier, and a
delay where the output moves in the edges' own samples, that leaves more than
:data:`fonbw.gap.edges.LEFT`, and a resonance that leaves more than
:data:`fonbw.gap.edges.MODE_LEFT`, where the edges' misfit is their own,
:data:`fonbw.gap.edges.OWN_MISFIT`).

Usage::

    python benchmarks/edge_misfit.py SEED [SEED ...]

One process per seed is the caller's choice (``xargs -P 2``); each takes
about as long as a diagnosis's first step (30-60 s).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from blind_gap import DEFAULTS  # noqa: E402
from gap_cores import FAMILIES  # noqa: E402
from gap_truth import draw_scenario, scenario_family  # noqa: E402
from spent_rows import LAGS  # noqa: E402

from fonbw.gap.attribute import Diagnosis  # noqa: E402
from fonbw.gap.edges import LEFT  # noqa: E402
from fonbw.gap.workers import Pool  # noqa: E402


def first_step(seed):
    """The diagnosis of blind-harness `seed` after its first greedy step's
    lag candidates: (diagnosis, scenario, candidate results)."""
    fam = scenario_family(seed, tuple(FAMILIES))
    sc = draw_scenario(seed, scale=DEFAULTS["scale"], family=fam, mid_drive=DEFAULTS["mid_drive"])
    d = Diagnosis(sc["train"], sc["validate"], seed=seed, budget=1000, workers=1, progress=False)
    with Pool(1).start() as d.pool:
        d.fit_nominal()
        d.localize_residual()
        d.form_stage()
        d.begin_attribution()
        pool = [i for i, b in enumerate(d.lib) if b.name in LAGS]
        res = d.try_candidates(0, pool, time.perf_counter())
    return d, sc, res


def report(seed):
    d, sc, res = first_step(seed)
    injected = {k: round(v["magnitude"], 1) for k, v in sc["injected"].items()}
    before, lengths = d._residuals_tr(d.att["yref_tr"])
    m = d.edges.misfit(before, lengths, d.att["fitter"].keep)
    b_in, b_out = (math.nan, math.nan) if m is None else (m[0] / d.sigma2, m[1] / d.sigma2)
    print(f"{seed} {sc['family']} {sc['kind']} {injected} on {d.att['core']}: {len(d.edges)} edges, "
          f"nominal misfit {b_in:.1f} σ² within their windows, {b_out:.2f} σ² elsewhere")
    for r in res:
        # the share only: which limit judges it does not change it
        share = d._edges_left(r["fit"], r["eff"], LEFT, "")[1]
        ch = r["checks"]
        gc = "none (diverged)" if ch["gap_closed_step"] is None else f"{ch['gap_closed_step']:.3f}"
        left = "nothing to judge" if share is None else f"{share:.3f}"
        print(f"    {d.lib[r['i']].name:9s} gap closed {gc}, leaves {left} at the edges: "
              f"{'passes' if ch['passed'] else ch['failed']}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seeds", type=int, nargs="+")
    for seed in ap.parse_args(argv).seeds:
        report(seed)


if __name__ == "__main__":
    main()
