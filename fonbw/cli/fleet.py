"""Identify a fleet of actuators: one model per sub-folder of records.

DIR holds one sub-folder of records (CSV, t [s], u [V], y [µm]) per actuator.
Each actuator is identified exactly as ``fonbw identify`` would identify its
records (all CSV files of its folder, in name order) with the same options
and seed, and its model written to OUT/<actuator>.json. OUT/fleet.csv lists
every actuator (kind, parameters, training RMS [µm], records, status,
outliers) and OUT/fleet.html shows the table, the spread of every parameter
over the fleet, the fit quality and the outliers (robust z-score against the
fleet's median/MAD above 3.5).

A model records a digest of its records' contents and the options; an
actuator whose model is up to date is skipped, so an interrupted run resumes
where it stopped. The identifications run on dask: an embedded cluster (one
single-threaded process per core) unless --scheduler names a running one,
whose workers need the same fonbw version and the records at the same paths.
"""
from __future__ import annotations

from .records import CLIError, add_record_arguments, say



def add_arguments(p) -> None:
    from ..fractional import ENGINES

    p.add_argument("dir", metavar="DIR", help="folder with one sub-folder of records (CSV) per actuator")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="folder for <actuator>.json, fleet.csv and fleet.html (created if needed)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running dask scheduler (tcp://host:8786) or its scheduler file (default: an "
                        "embedded cluster on this machine)")
    p.add_argument("--n-workers", type=int, dest="n_workers", metavar="N",
                   help="processes of the embedded cluster (default: one per core)")
    p.add_argument("--model", choices=("fonbw", "cbw", "nbw", "zhu"), default="fonbw",
                   help="model kind (default %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of every actuator's search, as in fonbw identify (default %(default)s)")
    p.add_argument("--max-evals", type=int, dest="max_evals",
                   help="evaluation budget of each search (default: 5000)")
    p.add_argument("--memory", choices=ENGINES, default="fast", help="fractional memory engine")
    add_record_arguments(p)


def run(ns) -> None:
    from ..fleet import FleetError, fit_options, run_fleet

    opts = fit_options(ns)
    if ns.n_workers is not None and ns.n_workers < 1:
        raise CLIError(f"--n-workers must be ≥ 1, got {ns.n_workers}")
    if ns.scheduler and ns.n_workers:
        raise CLIError("--n-workers sets the embedded cluster; with --scheduler the cluster has its own")
    try:
        rep = run_fleet(ns.dir, ns.output, opts, scheduler=ns.scheduler, n_workers=ns.n_workers, say=say)
    except FleetError as exc:
        raise CLIError(str(exc)) from None
    print(f"{ns.output}: {len(rep['identified'])} identified, {len(rep['skipped'])} up to date; "
          f"summary in fleet.csv and fleet.html")
