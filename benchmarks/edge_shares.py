"""The step-edge evidence of the gap diagnosis, replayed on stored blind-harness rows.

For every scenario of the given row files (``benchmarks/blind_gap.py --out``)
the scenario is drawn again, and every first-step candidate that is a lag
(amplifier, delay, resonance) is judged with :class:`fonbw.gap.edges.StepEdges`
on the scenario's training records, at the parameters the row stored: the
share of its step the output moved within each edge's sample, the share the
fitted block lets through, and whether the block would be refused.

Usage::

    python benchmarks/edge_shares.py ROWS.jsonl [ROWS.jsonl ...] [--mid-drive 0.3] [--list]

Prints, per block, how many accepted (and passing) candidates were injected
(at least 2 σ) or not and how many of each the edges refuse; ``--list`` adds
one line per refused candidate.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from fonbw.gap import effects as fx  # noqa: E402
from fonbw.gap.edges import StepEdges  # noqa: E402
from gap_truth import draw_scenario  # noqa: E402

LAGS = ("amplifier", "delay", "dynamics")


def _rows(paths):
    rows = {}
    for p in paths:
        with open(p) as fh:
            for line in fh:
                r = json.loads(line)
                rows[r["seed"]] = r
    return [rows[s] for s in sorted(rows)]


def judge(row, mid_drive):
    """(effect, injected, status, moved, passed, refused) of the row's first-step lag candidates."""
    sc = draw_scenario(row["seed"], scale=row.get("scale", 1.0), family=row["family"], mid_drive=mid_drive)
    train = sc["train"]
    dt = train[0].dt
    U = max(float(np.max(np.abs(r.u))) for r in train)
    blocks = {"amplifier": fx.Amplifier(dt, U), "delay": fx.Delay(dt), "dynamics": fx.Dynamics(dt)}
    # the noise the harness drew stands for the diagnosis's floor estimate
    e = StepEdges(train, dt, row["noise_std"])
    out = []
    for c in row.get("candidates", []):
        if c["effect"] not in LAGS or not c.get("params"):
            continue
        b = blocks[c["effect"]]
        th = np.array([c["params"][n] for n in b.names])
        passed = e.passed([b], [th]) if len(e) else None
        status = "accepted" if c["accepted"] else ("passed" if c["checks"].get("passed") else "failed")
        inj = row["injected"].get(c["effect"], {}).get("magnitude", 0.0) >= 2.0
        out.append((c["effect"], inj, status, float(np.median(e.moved)) if len(e) else math.nan,
                    float(np.median(passed)) if passed is not None else math.nan,
                    e.refuses([b], [th]) is not None))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+")
    ap.add_argument("--mid-drive", type=float, default=0.3, help="the harness's share of mid-drive records")
    ap.add_argument("--list", action="store_true", help="one line per refused candidate")
    a = ap.parse_args(argv)
    counts = {}
    for row in _rows(a.rows):
        for eff, inj, status, moved, passed, refused in judge(row, a.mid_drive):
            key = (eff, "injected" if inj else "not injected", status)
            n = counts.setdefault(key, [0, 0])
            n[0] += 1
            n[1] += refused
            if refused and a.list:
                print(f"{row['seed']} {row['family']:8s} {row['kind']:7s} {eff:9s} {key[1]:12s} {status:8s} "
                      f"moved {moved:.3f} passed {passed:.3f}")
    print("| block | injected (≥ 2 σ) | first step | candidates | refused by the edges |")
    print("|---|---|---|---:|---:|")
    for (eff, inj, status), (n, k) in sorted(counts.items()):
        if status != "failed":
            print(f"| {eff} | {inj} | {status} | {n} | {k} |")


if __name__ == "__main__":
    main()
