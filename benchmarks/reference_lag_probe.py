"""Does an input lag still help once the viscous reference's θ is searched with it?

For each seed, draws the blind harness's scenario as the held-out runs do and
fits the viscous reference hysteresis alone (relaxations at 2, 5, 10, 20,
50 ms, started at rest) on the raw input and on the input through a one-pole
lag at each corner f_c, θ searched afresh every time. Prints the training and
validation RMS [µm] and θ::

    python benchmarks/reference_lag_probe.py --seeds 21036 21003 21030 --fc 100 200 400

A lag that helps as much on a case without an amplifier as on one with it
cannot be told from the core's rate dependence by this reference.
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from blind_gap import DEFAULTS
from gap_cores import FAMILIES
from gap_truth import draw_scenario, scenario_family

RELAX = (0.002, 0.005, 0.01, 0.02, 0.05)


def _lagged(records, fc):
    from fonbw.gap.filters import first_order
    from fonbw.io import Record

    if fc is None:
        return records
    return [Record.from_arrays(u=first_order(r.u, math.exp(-2 * math.pi * fc * r.dt)), y=r.y, dt=r.dt)
            for r in records]


def main(argv=None):
    from fonbw.gap.reference import ReferenceHysteresis

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--fc", type=float, nargs="+", default=[100.0, 200.0, 400.0], help="lag corners [Hz]")
    ap.add_argument("--evals", type=int, default=60, help="θ evaluations of each fit")
    a = ap.parse_args(argv)
    for seed in a.seeds:
        fam = scenario_family(seed, tuple(FAMILIES))
        sc = draw_scenario(seed, scale=DEFAULTS["scale"], family=fam, mid_drive=DEFAULTS["mid_drive"])
        inj = {k: (round(v["magnitude"], 1), v.get("params")) for k, v in sc["injected"].items()}
        print(f"seed {seed}: {fam} core, {sc['kind']} {inj or ''}, noise {sc['noise_std']:.4f} µm", flush=True)
        ref = ReferenceHysteresis(n_plays=16, degree=5, level=6, rate="viscous", initial="rest",
                                  relax=RELAX).with_range(sc["train"])
        for fc in [None] + a.fc:
            t0 = time.perf_counter()
            fit = ref.fit(_lagged(sc["train"], fc), seed=0, max_evals=a.evals)
            val = _lagged(sc["validate"], fc)
            rv = math.sqrt(np.mean(np.concatenate([(r.y - fit.predict(r)) ** 2 for r in val])))
            theta = ", ".join(f"{n} {v:.3g}" for n, v in zip(ref.theta_names, fit.theta))
            print(f"  input {'raw' if fc is None else f'lagged at {fc:g} Hz'}: train {fit.rms_train:.4f}, "
                  f"validation {rv:.4f} µm ({theta}; {time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
