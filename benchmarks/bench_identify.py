"""Identification wall time: fonbw.identify (jDE) vs scipy's differential_evolution.

Not a test. Synthetic FONBW record: eq. (19) input, by default 30 s sampled at
5 kHz (1.5e5 samples, the size of a typical logger record; ``--rate 10000
--seconds 10`` is the paper's rate), white noise 0.02 µm on the output.
Every method gets the same evaluation budget and the same thread count for the
compiled population simulator (numba prange over candidates):

1. ``fonbw.identify``: jDE on the 5 nonlinear FONBW parameters, linear ones
   solved by variable projection, budget-capped L-BFGS-B polish;
2. scipy DE on the *same* projected objective and the same unit-cube search
   space (``vectorized=True``, so it also simulates whole populations): the
   optimizer is the only difference;
3. scipy DE on all 9 parameters (no projection; data-driven ranges for the
   linear ones, k_h < 0 assumed known): what the projection buys.

The figures of a run are in BENCHMARKS.md (Identification speed).

Usage::

    .venv/bin/python benchmarks/bench_identify.py [--rate 5000] [--seconds 30]
        [--evals 1500] [--workers 2] [--seeds 1,2,3,4,5] [--no-full]

With several seeds, methods 1 and 2 run once per seed (the record stays the
same) and method 3 with the first seed only; ``--no-full`` skips method 3.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numba  # noqa: E402
import numpy as np  # noqa: E402
from scipy.optimize import differential_evolution  # noqa: E402

import fonbw.hysteresis as hyst  # noqa: E402
from fonbw.de import _Space  # noqa: E402
from fonbw.hysteresis import FONBW  # noqa: E402
from fonbw.identify import _as_records, _Projected, identify, rms_cost, search_space  # noqa: E402
from fonbw.io import Record  # noqa: E402
from fonbw.signals import eq19_input  # noqa: E402

NOISE = 0.02
TRUE = dict(ku=[0.18, -1.4e-4, -7.7e-8], kh=-2.0, rho=0.02, sigma=0.8, n=1.5,
            lam1=0.95, lam2=0.85)


def make_record(n, dt, seed=0):
    t = np.arange(n) * dt
    u = eq19_input(1.0 / dt, n * dt)[1]
    y = FONBW(**TRUE).simulate(u, dt)
    y += NOISE * np.random.default_rng(seed).standard_normal(n)
    return Record.from_arrays(u=u, y=y, dt=dt)


class Counted:
    """Unit-cube objective for scipy (vectorized: X has shape (d, S))."""

    def __init__(self, space, f):
        self.space, self.f, self.nfev, self.best = space, f, 0, np.inf

    def __call__(self, Z):
        Z = np.atleast_2d(np.asarray(Z, dtype=float).T) if np.ndim(Z) == 2 else \
            np.asarray(Z, dtype=float)[None, :]
        c = self.f(self.space.to_natural(Z))
        self.nfev += Z.shape[0]
        c = np.where(np.isfinite(c), c, 1e300)
        self.best = min(self.best, float(c.min()))
        return c if c.size > 1 else float(c[0])


def run_scipy(space, f, budget, popsize, seed):
    obj = Counted(space, f)
    d = space.d
    # Generations so that init + generations fit the budget (scipy's polish off:
    # it is not budget-capped; L-BFGS-B polish of scipy would add evaluations).
    maxiter = max(1, budget // popsize - 1)
    t0 = time.perf_counter()
    r = differential_evolution(obj, [(0.0, 1.0)] * d, popsize=max(1, popsize // d),
                               maxiter=maxiter, tol=0.0, seed=seed, polish=False,
                               vectorized=True, updating="deferred")
    return time.perf_counter() - t0, obj.nfev, float(r.fun)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=5000.0, help="sampling rate [Hz]")
    ap.add_argument("--seconds", type=float, default=30.0, help="record length [s]")
    ap.add_argument("--evals", type=int, default=1500)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seeds", default="1", help="optimizer seeds, comma-separated")
    ap.add_argument("--no-full", action="store_true", help="skip scipy DE on all 9 parameters")
    a = ap.parse_args(argv)
    seeds = [int(v) for v in a.seeds.split(",")]

    n = int(round(a.seconds * a.rate))
    rec = make_record(n, 1.0 / a.rate)
    recs = _as_records(rec)
    numba.set_num_threads(a.workers)
    truth_theta = np.array([[*TRUE["ku"], TRUE["kh"], TRUE["rho"], TRUE["sigma"],
                             TRUE["n"], TRUE["lam1"], TRUE["lam2"]]])
    # Warm-up: compile every kernel before timing.
    rms_true = rms_cost("fonbw", truth_theta, rec)[0]
    t0 = time.perf_counter()
    rms_cost("fonbw", np.repeat(truth_theta, 10, axis=0), rec)
    per_eval = (time.perf_counter() - t0) / 10
    print(f"FONBW, {n} samples at {a.rate / 1e3:g} kHz, noise {NOISE} µm, {a.workers} workers, "
          f"budget {a.evals} evaluations; {os.cpu_count()} cores, load average "
          + " ".join(f"{v:.2f}" for v in os.getloadavg()))
    print(f"truth RMS on the record: {rms_true:.5f} µm;  "
          f"one evaluation ≈ {per_eval * 1e3:.1f} ms (in a population of 10)")

    space = search_space("fonbw", rec)
    pnames = hyst.param_names("fonbw", 3)
    proj = _Projected(space, recs, pnames, "fonbw", "fast", 3)
    unit = _Space(space.bounds, space.log_scale)
    popsize = int(np.clip(10 * unit.d, 20, 100))
    rows, ratios = [], []
    for seed in seeds:
        c0 = time.process_time()
        res = identify(rec, "fonbw", seed=seed, max_evals=a.evals, workers=a.workers)
        c1 = time.process_time()
        rows.append((f"fonbw.identify (seed {seed})", 5, res.nfev, res.wall_time, res.rms))
        w, nf, fun = run_scipy(unit, proj, a.evals, popsize, seed)
        c2 = time.process_time()
        rows.append((f"scipy DE + projection (seed {seed})", unit.d, nf, w, fun))
        ratios.append((seed, w / res.wall_time, res.rms / rms_true, fun / rms_true))
        # CPU seconds of this process: on a machine others load, CPU / workers
        # is what the wall time would be on idle cores.
        print(f"seed {seed}: fonbw.identify {res.wall_time:.1f} s (CPU {c1 - c0:.1f} s) RMS {res.rms:.5f} µm; "
              f"scipy {w:.1f} s (CPU {c2 - c1:.1f} s) RMS {fun:.5f} µm; load "
              + " ".join(f"{v:.2f}" for v in os.getloadavg()), flush=True)
    if a.no_full:
        return _report(rows, ratios)

    # All nine parameters searched, ranges as a user would set them from data.
    U = float(np.max(np.abs(rec.u)))
    R = float(np.ptp(rec.y))
    s = float(rec.u @ rec.y / (rec.u @ rec.u))
    S = max(abs(s), R / U)
    bounds9 = [(s - 2 * S, s + 2 * S), (-2 * R / U ** 2, 2 * R / U ** 2),
               (-2 * R / U ** 3, 2 * R / U ** 3), (-1e3 * R, -1e-3 * R)] + space.bounds
    log9 = [False, False, False, True] + list(space.log_scale)
    full = _Space(bounds9, log9)

    def f9(X):
        th = X.copy()
        rho, n = X[:, 4], X[:, 6]
        th[:, 5] = (X[:, 5] / rho) ** n       # sigma from sigma_rho
        return rms_cost("fonbw", th, rec)

    popsize9 = int(np.clip(10 * full.d, 20, 100))
    w, nf, fun = run_scipy(full, f9, a.evals, popsize9, seeds[0])
    rows.append((f"scipy DE, all 9 parameters (seed {seeds[0]})", full.d, nf, w, fun))
    _report(rows, ratios)


def _report(rows, ratios):
    print()
    print(f"{'method':<44s} {'dim':>4s} {'nfev':>6s} {'wall [s]':>9s} {'RMS [µm]':>10s}")
    for name, d, nf, w, fun in rows:
        print(f"{name:<44s} {d:>4d} {nf:>6d} {w:>9.1f} {fun:>10.5f}")
    for seed, ratio, r_id, r_sp in ratios:
        print(f"seed {seed}: scipy DE on the same objective / fonbw.identify: wall time {ratio:.2f}x; "
              f"RMS / truth's RMS: fonbw.identify {r_id:.4f}, scipy {r_sp:.4f}")
    print("load average after the runs: " + " ".join(f"{v:.2f}" for v in os.getloadavg()))


if __name__ == "__main__":
    main()
