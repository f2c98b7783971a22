"""The paper's Figs. 1-4 (the fractional operators and the model's loops) as PNG files."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("-o", "--output", default="figures", metavar="DIR", help="output folder (default %(default)s)")


def run(ns) -> None:
    from ..figures import make_figures

    for p in make_figures(ns.output):
        print(f"wrote {p}")
