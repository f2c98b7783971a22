"""Each injected effect's magnitude on the training records, added to stored blind-harness rows.

The blind harness calibrates every effect on the validation drives, and rows
written before it also kept the training magnitude (``magnitude_train``) lack
it. This script draws each scenario again (the draw is deterministic in the
seed), measures what every injected effect changes on the training records
[noise σ, RMS] and writes the rows with ``magnitude_train`` filled in, so
that ``python benchmarks/blind_gap.py --summary`` can split top-1 by what
the training records showed of the effect.

Usage::

    python benchmarks/train_magnitudes.py ROWS.jsonl --out ROWS_FILLED.jsonl [--mid-drive 0.3]

The input file is left as it is; the output is written whole or not at all.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

# this checkout's library first, as blind_gap.py does (a frozen worktree draws with its own code)
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from fonbw.io import atomic_open  # noqa: E402
from gap_summary import load  # noqa: E402
from gap_truth import draw_scenario  # noqa: E402


def _differs(row, sc):
    """What of the stored row the scenario drawn again does not match ('' if all)."""
    stored = row["injected"]
    if sc["kind"] != row.get("kind", sc["kind"]) or set(sc["injected"]) != set(stored):
        return f"drawn {sc['kind']} {sorted(sc['injected'])}, stored {row.get('kind')} {sorted(stored)}"
    # the layout decides which record starts mid-drive; a cut on a training
    # record alone leaves every validation magnitude as it was
    if "mid_drive" in row and sc["mid_drive"] != row["mid_drive"]:
        return f"records cut mid-drive at {sc['mid_drive']}, stored {row['mid_drive']}"
    for name, v in stored.items():
        m = sc["injected"][name]["magnitude"]
        if abs(m - v["magnitude"]) > 1e-6 * max(1.0, v["magnitude"]):
            return f"{name} drawn at {m:.4f} σ, stored {v['magnitude']:.4f} σ"
    return ""


def fill(row, mid_drive):
    """`row` with ``magnitude_train`` in every injected effect (drawn again when any lacks it).

    Raises SystemExit when the scenario drawn again is not the row's (its
    kind, effects, mid-drive layout or validation magnitudes differ).
    """
    if not row.get("injected") or all("magnitude_train" in v for v in row["injected"].values()):
        return row
    sc = draw_scenario(row["seed"], scale=row.get("scale", 1.0), family=row.get("family"), mid_drive=mid_drive)
    why = _differs(row, sc)
    if why:
        raise SystemExit(f"seed {row['seed']}: {why}: not the scenario of this row (another --mid-drive?)")
    for name, v in row["injected"].items():
        v["magnitude_train"] = sc["injected"][name]["magnitude_train"]
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rows")
    ap.add_argument("--out", required=True)
    ap.add_argument("--mid-drive", type=float, default=0.3,
                    help="share of scenarios with a record not at rest, as in the run (default 0.3)")
    a = ap.parse_args(argv)
    rows = [fill(r, a.mid_drive) for r in load(a.rows)]
    with atomic_open(a.out, "w") as fh:
        for r in rows:
            fh.write(json.dumps(r) + "\n")
    print(f"{len(rows)} rows → {a.out}")


if __name__ == "__main__":
    main()
