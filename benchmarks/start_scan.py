"""How `fonbw.start.start_state` reads the records of the blind harness' scenarios.

For every record whose input starts at the bottom of its range (the case the
output and the stage's rest input decide) prints whether the scenario cut it
mid-drive, whether the check says so, and how far the output starts above its bottom over the
input's first rise (as a share of the output range)::

    python benchmarks/start_scan.py 12000 12040
"""
from __future__ import annotations

import sys

import numpy as np

from blind_gap import DEFAULTS
from gap_cores import FAMILIES
from gap_truth import draw_scenario, scenario_family


def main(argv=None):
    from fonbw.start import REST_TOL, rest_level, rise_excess, start_state

    a, b = (int(x) for x in (argv or sys.argv[1:3]))
    for seed in range(a, b):
        fam = scenario_family(seed, tuple(FAMILIES))
        sc = draw_scenario(seed, scale=DEFAULTS["scale"], family=fam, mid_drive=DEFAULTS["mid_drive"])
        cut = sc["mid_drive"]
        rest = rest_level([r.u for r in sc["train"] + sc["validate"]])
        for kind, recs in (("train", sc["train"]), ("validate", sc["validate"])):
            for i, r in enumerate(recs):
                u, y = np.asarray(r.u), np.asarray(r.y)
                span = float(np.ptp(u))
                if not (span > 0 and u[0] <= u.min() + REST_TOL * span):
                    continue
                above = rise_excess(u, y) / max(float(np.ptp(y)), 1e-300)
                mid = cut.get(kind) is not None and cut[kind][0] == i
                st = start_state(r, rest=rest)
                print(f"{seed} {fam:8s} {sc['kind']:8s} {','.join(sc['injected']) or '-':18s} {kind:8s} "
                      f"{r.path:18s} {'cut mid-drive' if mid else 'from rest':13s} "
                      f"{'at rest' if st.at_rest else 'mid-drive':9s} output above its bottom {100 * above:.2f} %")


if __name__ == "__main__":
    main()
