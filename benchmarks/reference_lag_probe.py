"""Does an input lag still help once the viscous reference's θ is searched with it?

For each seed, draws the blind harness's scenario as the held-out runs do and
fits the viscous reference hysteresis alone (relaxations at 2, 5, 10, 20,
50 ms, started at rest) on the raw input and on the input through a one-pole
lag at each corner f_c, θ searched afresh every time. Prints the training and
validation RMS [µm] and θ::

    python benchmarks/reference_lag_probe.py --seeds 21036 21003 21030 --fc 100 200 400

A lag that helps as much on a case without an amplifier as on one with it
cannot be told from the core's rate dependence by this reference.

With ``--rows FILE`` (a held-out run's rows) it asks the same of the
diagnosis's own reference (:data:`fonbw.gap.form.REFERENCE_RATE` and the
settings beside it, the row's initial state) for the delay and the amplifier
the row's first greedy step fitted: the share of the reference's excess
validation MSE each closes with θ held at the reference's own, as the joint
refits hold it, and with θ searched again beside the block (records at rest
only)::

    python benchmarks/reference_lag_probe.py --seeds 70037 64034 --rows held70.jsonl held64.jsonl
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from blind_gap import DEFAULTS
from gap_cores import FAMILIES
from gap_truth import draw_scenario, scenario_family
import spent_rows

RELAX = (0.002, 0.005, 0.01, 0.02, 0.05)


def _lagged(records, fc):
    from fonbw.gap.filters import first_order
    from fonbw.io import Record

    if fc is None:
        return records
    return [Record.from_arrays(u=first_order(r.u, math.exp(-2 * math.pi * fc * r.dt)), y=r.y, dt=r.dt)
            for r in records]


def _val_mse(fit, records):
    """Pooled MSE [µm²] of a reference fit on `records`."""
    from fonbw.gap.checks import mse

    return mse(records, [fit.predict(r) for r in records])


def _row_lags(sc, row, evals):
    """Shares of the reference's excess validation MSE that the row's fitted
    delay and amplifier close, θ held and θ searched again: printed."""
    from fonbw.gap import form
    from fonbw.gap.effects import Amplifier, Delay
    from fonbw.gap.reference import ReferenceFit, ReferenceHysteresis
    from fonbw.io import Record

    tr, va, s2 = sc["train"], sc["validate"], sc["noise_std"] ** 2
    ref = ReferenceHysteresis(rate=form.REFERENCE_RATE, initial=row["form"]["reference"]["initial"],
                              degree=form.REFERENCE_DEGREE, level=form.REFERENCE_LEVEL,
                              memory=form.REFERENCE_MEMORY).with_range(tr)

    base = ref.fit(tr, seed=row["seed"], max_evals=evals)
    m0 = _val_mse(base, va)

    def excess_closed(fit, recs):
        return (m0 - _val_mse(fit, recs)) / (m0 - s2)

    print(f"  reference alone: validation {math.sqrt(m0):.4f} µm, θ {[f'{t:.3g}' for t in base.theta]}")
    dt = tr[0].dt
    for c in row["candidates"]:
        if c["effect"] not in ("delay", "amplifier"):
            continue
        # U only sizes the block's search box; the input transform reads th alone
        blk = Delay(dt) if c["effect"] == "delay" else Amplifier(dt, 1.0)
        th = [c["params"][k] for k in blk.names]
        tr_x, va_x = ([Record.from_arrays(u=blk.transform_input(r.u, dt, th), y=r.y, dt=dt) for r in recs]
                      for recs in (tr, va))
        Phi = np.concatenate([ref.columns(r.u, dt, base.theta) for r in tr_x])
        held = ReferenceFit(ref, ref.solve(Phi, np.concatenate([r.y for r in tr_x]))[0], base.theta, nfev=1,
                            wall_time=0.0, build_time=0.0, solve_time=0.0)
        again = ref.fit(tr_x, seed=row["seed"], max_evals=evals, theta0=base.theta)
        print(f"  {c['effect']} as fitted ({', '.join(f'{v:.4g}' for v in th)}): closed {c['gap_closed']:.3f} "
              f"in the diagnosis; θ held {excess_closed(held, va_x):.3f}, θ searched again "
              f"{excess_closed(again, va_x):.3f} (θ {[f'{t:.3g}' for t in again.theta]})", flush=True)


def main(argv=None):
    from fonbw.gap.reference import ReferenceHysteresis

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--fc", type=float, nargs="+", default=[100.0, 200.0, 400.0], help="lag corners [Hz]")
    ap.add_argument("--evals", type=int, default=60, help="θ evaluations of each fit")
    ap.add_argument("--rows", nargs="+", metavar="JSONL",
                    help="held-out rows: the lags their first greedy step fitted, on the diagnosis's reference")
    a = ap.parse_args(argv)
    rows = {r["seed"]: r for r in spent_rows.rows(a.rows)} if a.rows else None
    for seed in a.seeds:
        fam = scenario_family(seed, tuple(FAMILIES))
        sc = draw_scenario(seed, scale=DEFAULTS["scale"], family=fam, mid_drive=DEFAULTS["mid_drive"])
        inj = {k: (round(v["magnitude"], 1), v.get("params")) for k, v in sc["injected"].items()}
        print(f"seed {seed}: {fam} core, {sc['kind']} {inj or ''}, noise {sc['noise_std']:.4f} µm", flush=True)
        if rows is not None:
            if seed not in rows or not sc["starts_at_rest"]:
                print("  skipped: no row for it, or a record starting mid-drive")
            else:
                _row_lags(sc, rows[seed], a.evals)
            continue
        ref = ReferenceHysteresis(n_plays=16, degree=5, level=6, rate="viscous", initial="rest",
                                  relax=RELAX).with_range(sc["train"])
        for fc in [None] + a.fc:
            t0 = time.perf_counter()
            fit = ref.fit(_lagged(sc["train"], fc), seed=0, max_evals=a.evals)
            val = _lagged(sc["validate"], fc)
            rv = math.sqrt(_val_mse(fit, val))
            theta = ", ".join(f"{n} {v:.3g}" for n, v in zip(ref.theta_names, fit.theta))
            print(f"  input {'raw' if fc is None else f'lagged at {fc:g} Hz'}: train {fit.rms_train:.4f}, "
                  f"validation {rv:.4f} µm ({theta}; {time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
