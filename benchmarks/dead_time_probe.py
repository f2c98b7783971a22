"""The dead time after the records' step edges, and how early each lag candidate's model moves.

Runs the blind-harness diagnosis of each given seed (``blind_gap.run_scenario``,
one process) with a hook on :meth:`fonbw.gap.greedy.GreedySteps.check_candidate`
that changes nothing: for every lag candidate (amplifier, delay, resonance) at
every greedy step it records

* the *dead time* of each training step edge (:class:`fonbw.gap.edges.StepEdges`):
  the samples from the edge's own sample on during which the measured output stays
  within :data:`DEAD_SHARE` of its settled change, and
* the share of its own settled change the candidate's model (nominal, the
  accepted effects and the candidate, as fitted) has made by the edge's last
  still sample (0 where the output moves at once).

A check that refuses a lag whose model moves early was measured with this and
not taken (``BENCHMARKS.md``, "A dead time at the step edges").

Usage::

    python benchmarks/dead_time_probe.py --out FILE.jsonl SEED [SEED ...]

One JSON line per seed: the scenario (family, kind, injected), what was
named and ``probe``, one entry per lag candidate and step.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from fonbw.gap import greedy  # noqa: E402

#: The output is still after an edge while it stays within this share of its settled change.
DEAD_SHARE = 0.05


def dead_time(edges):
    """Still samples after each edge of `edges` (a StepEdges), from the edge's own sample on."""
    out = []
    for i, k0 in edges.edges:
        y = np.asarray(edges.records[i].y, dtype=float)
        base, change = y[k0 - 1], y[k0 + edges.settle] - y[k0 - 1]
        moving = np.nonzero(np.abs((y[k0:k0 + edges.settle] - base) / change) > DEAD_SHARE)[0]
        out.append(int(moving[0]) if moving.size else edges.settle)
    return out


def early(edges, dead, preds):
    """Share of its settled change each prediction has made by the edge's last still sample."""
    out = []
    for (i, k0), d in zip(edges.edges, dead):
        p = np.asarray(preds[i], dtype=float)
        out.append(0.0 if d == 0 else
                   float((p[k0 + d - 1] - p[k0 - 1]) / (p[k0 + edges.settle] - p[k0 - 1])))
    return out


def _hook(log):
    check = greedy.GreedySteps.check_candidate

    def logged(self, i, step, fit, pv, mse, eff):
        out = check(self, i, step, fit, pv, mse, eff)
        if self.lib[i].lag and len(self.edges):
            preds = self.att["fitter"].predict(self.train, fit, eff, self.att["yref_tr"])
            # the training records as given: without the histories run before them
            preds = [p[len(p) - len(r.u):] for p, r in zip(preds, self.rs.raw["train"])]
            dead = dead_time(self.edges)
            log.append({"step": step + 1, "effect": self.lib[i].name, "dead": dead,
                        "early": early(self.edges, dead, preds), "passed": out["passed"],
                        "gap_closed": out["gap_closed_step"]})
        return out

    greedy.GreedySteps.check_candidate = logged


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seeds", nargs="+", type=int)
    ap.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    from blind_gap import run_scenario

    log = []
    _hook(log)
    for seed in args.seeds:
        log.clear()
        row = run_scenario(seed, 1000)
        keep = {k: row.get(k) for k in ("seed", "family", "kind", "injected", "named", "error")}
        keep["probe"] = list(log)
        with open(args.out, "a") as fh:
            fh.write(json.dumps(keep, default=float) + "\n")
        for e in log:
            print(f"{seed} step {e['step']} {e['effect']:9s} dead {e['dead']} early "
                  f"{np.round(e['early'], 3).tolist()} median {np.median(e['early']):.3f}")


if __name__ == "__main__":
    main()
