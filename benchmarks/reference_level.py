"""How the reference's density degree along its plays fits the blind harness' cores.

For each seed, draws the harness scenario (records from rest) and fits the
reference hysteresis alone (rate independent, 16 plays, quintic input
polynomial) with the density along each play's line of degree ``level``,
from each start state. Prints the training RMS and the RMS on each
validation record [µm], the number of columns and the fitting time::

    python benchmarks/reference_level.py 15001 15011 15009
"""
from __future__ import annotations

import sys
import time

from blind_gap import DEFAULTS
from gap_cores import FAMILIES
from gap_truth import draw_scenario, scenario_family

LEVELS = (2, 4, 6, 8)


def main(argv=None):
    from fonbw.gap.reference import ReferenceHysteresis

    for seed in (int(a) for a in (argv if argv is not None else sys.argv[1:])):
        fam = scenario_family(seed, tuple(FAMILIES))
        sc = draw_scenario(seed, scale=DEFAULTS["scale"], family=fam, mid_drive=0.0)
        print(f"seed {seed}: {fam} core, {sc['kind']} {sorted(sc['injected']) or ''}, "
              f"noise {sc['noise_std']:.4f} µm; validation: {', '.join(r.path for r in sc['validate'])}")
        for init in ("rest", "ascended"):
            for level in LEVELS:
                ref = ReferenceHysteresis(n_plays=16, level=level, rate=None, initial=init, degree=5)
                t0 = time.perf_counter()
                fit = ref.fit(sc["train"])
                dt = time.perf_counter() - t0
                val = " ".join(f"{fit.rms(r):.4f}" for r in sc["validate"])
                print(f"  {init:9s} level {level}  {ref.n_columns:3d} columns  train {fit.rms_train:.4f}  "
                      f"validate {val}  ({dt:.2f} s)")


if __name__ == "__main__":
    main()
