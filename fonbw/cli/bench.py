"""The virtual bench's experiments as CSV files with columns t [s], u [V], y [µm]:
the eq.-19 record, sines at the paper's frequencies, a multi-tone, steps and a
bipolar logger record."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("-o", "--output", default="bench-data", metavar="DIR", help="output folder (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default %(default)s)")


def run(ns) -> None:
    from ..bench import Bench

    for p in Bench(seed=ns.seed).write_experiments(ns.output, logger=True):
        print(f"wrote {p}")
