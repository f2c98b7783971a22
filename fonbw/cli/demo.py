"""The whole workflow on the virtual bench, with an HTML report: identification,
validation, compensation, the FMUs, the closed loop and the gap diagnosis."""
from __future__ import annotations

import os
import sys

from .records import CLIError


def add_arguments(p) -> None:
    p.add_argument("-o", "--output", default="demo-out", metavar="DIR", help="output folder (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="search and noise seed (default %(default)s)")
    p.add_argument("--quick", action="store_true", help="reduced budgets (about a minute)")


def run(ns) -> None:
    from ..demo import run_demo

    res = run_demo(ns.output, seed=ns.seed, quick=ns.quick)
    print(f"wrote {os.path.join(ns.output, 'report.html')} and report.md in {res['wall_s']:.0f} s")
    for k, v in res["errors"].items():
        print(f"stage {k} failed: {v}", file=sys.stderr)
    if res["errors"]:
        raise CLIError(f"{len(res['errors'])} stage(s) failed ({', '.join(res['errors'])}); see the report")
