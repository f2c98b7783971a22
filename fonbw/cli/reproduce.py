"""The paper's Tables 1-3 and Figs. 8-10 on the virtual bench: FONBW, CBW and
Zhu et al.'s model identified on the eq.-19 record and validated at the
paper's five frequencies. With --table4, its feedforward study instead: every
model identified on the same records after a rest cycle (FONBW, CBW and NBW
invertible at the bench's step), each compensator run on the bench."""
from __future__ import annotations

import os


def add_arguments(p) -> None:
    p.add_argument("-o", "--output", default="reproduce-out", metavar="DIR", help="output folder (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="search and noise seed (default %(default)s)")
    p.add_argument("--quick", action="store_true", help="small budgets (a smoke run)")
    p.add_argument("--table4", action="store_true",
                   help="Table 4 (feedforward compensation on the bench) instead of Tables 1-3")
    p.add_argument("--max-evals", type=int, default=None, metavar="N",
                   help="identification evaluations per model for --table4 (default 3000, quick 300)")


def run(ns) -> None:
    if ns.table4:
        from ..reproduce import format_table4, reproduce_table4

        evals = ns.max_evals or (300 if ns.quick else 3000)
        rows = reproduce_table4(ns.output, seed=ns.seed, max_evals=evals, progress=True,
                                T=0.5 if ns.quick else 2.0)
        print(format_table4(rows))
        print(f"wrote {ns.output}/table4.csv, the models and one figure per trajectory")
        return
    from ..reproduce import reproduce

    res = reproduce(ns.output, seed=ns.seed, quick=ns.quick, progress=True)
    with open(os.path.join(ns.output, "tables.md"), encoding="utf-8") as f:
        print(f.read())
    print(f"wrote {ns.output}/tables.md, tables.json and figures in {res['wall_s']:.0f} s")
