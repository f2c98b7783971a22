"""Closed-loop co-simulation: compensator, hysteresis, plant and PI controller
at 10 kHz under one of three masters (reference: library code; fmpy: the FMUs
through fmpy; libcosim: the FMUs in libcosim).

Prints a one-line summary (RMS and max tracking error [µm], RMS input [V],
steps, wall time and real-time factor); --json writes the result without the
trace, --csv the trace (t [s], r [µm], u [V], y [µm], e [µm]). A run that a
block stops early still writes both (up to the stop), then fails with the
block's reason.
"""
from __future__ import annotations

import json


def add_arguments(parser) -> None:
    from ..loop import BANDWIDTH_HZ, DT, MASTERS, MODES, PLANTS, SCENARIOS

    parser.add_argument("--scenario", default="sine5", choices=sorted(SCENARIOS))
    parser.add_argument("--mode", default="ff+fb", choices=MODES)
    parser.add_argument("--master", default="reference", choices=MASTERS)
    parser.add_argument("--plant", default="none", choices=PLANTS,
                        help="linear dynamics after the actuator (default none)")
    parser.add_argument("--T", type=float, default=None, help="duration [s] (scenario default)")
    parser.add_argument("--dt", type=float, default=DT, help="communication step [s] (default 1e-4)")
    parser.add_argument("--model", default=None, help="FONBW model JSON the compensator inverts "
                        "(default models/fonbw_default.json)")
    parser.add_argument("--truth", default=None, help="FONBW model JSON of the true actuator "
                        "(default: the model)")
    parser.add_argument("--bandwidth", type=float, default=BANDWIDTH_HZ,
                        help="feedback crossover [Hz] (default 100)")
    parser.add_argument("--fmu-dir", default=None, help="build/reuse FMUs here (default: a cache)")
    parser.add_argument("--native", action="store_true", help="fmpy and libcosim masters: run the native C "
                        "FMUs (no Python inside the FMUs; needs a C compiler to build them)")
    parser.add_argument("--json", dest="json_out", default=None, help="write the result (no trace) as JSON")
    parser.add_argument("--csv", dest="csv_out", default=None, help="write the trace as CSV")


def run(ns) -> None:
    """Run ``fonbw cosim`` from parsed arguments; raises CosimError (after
    writing the outputs) if the run stopped early, ValueError on bad arguments."""
    import dataclasses

    from ..io import atomic_open, jsonable, write_csv
    from ..loop import CosimError, run_cosim
    from .records import first_wild, out_path

    # checked before the run, which can take minutes
    reads = [ns.model, ns.truth]
    if ns.json_out:
        out_path(ns.json_out, reads)
    if ns.csv_out:
        out_path(ns.csv_out, [*reads, ns.json_out])
    res = run_cosim(ns.scenario, ns.mode, ns.master, T=ns.T, dt=ns.dt, plant=ns.plant,
                    models={"compensator": ns.model, "hysteresis": ns.truth},
                    bandwidth_hz=ns.bandwidth, fmu_dir=ns.fmu_dir, native=ns.native)
    k = None if res.error else first_wild(res.y)
    if k is not None:  # said in the outputs too, as a stop
        res = dataclasses.replace(res, error=f"the stage output is not finite or beyond any stage from "
                                  f"t = {res.t[k]:.6g} s (step {k}): a model diverges; check the parameters "
                                  "of --model and --truth")
    if ns.json_out:
        with atomic_open(ns.json_out, "w", encoding="utf-8") as fh:
            # strict JSON: a figure of a loop that diverged is null
            json.dump(jsonable(res.summary(), strict=True), fh, indent=1, default=str, allow_nan=False)
    if ns.csv_out:
        write_csv(ns.csv_out, {"t": res.t, "r": res.r, "u": res.u, "y": res.y, "e": res.e})
    tag = " native" if ns.native and ns.master != "reference" else ""
    print(f"{ns.scenario} {ns.mode} {ns.master}{tag} plant={ns.plant}: rms_error {res.rms_error:.4f} µm, "
          f"max_error {res.max_error:.4f} µm, rms_input {res.rms_input:.2f} V, "
          f"{res.steps} steps, wall {res.wall_s:.2f} s (rtf {res.rtf:.2f})")
    for path in (ns.json_out, ns.csv_out):
        if path:
            print(f"wrote {path}")
    if res.error:
        # the outputs above hold the trace up to the stop
        raise CosimError(res.error)
