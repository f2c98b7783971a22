"""Cost and accuracy of the fractional memory engines, measured side by side.

    python benchmarks/bench_memory.py [--repeat 5] [--direct-max 100000] [--sweep]

Model: FONBW with the paper's Table-1 parameters (ku = [0.1811, -1.4037e-4,
-7.7154e-8], kh = -3.2719e4, rho = 6.4808e-7, sigma = 1.3039e5, n = 2.0006,
lam1 = 0.9557, lam2 = 0.6220), input of eq. (19)
u(t) = 60 e^(-0.13 t) [cos(3 pi t e^(-0.09 t) - 3.15) + 1] V, dt = 1e-4 s.

Printed, at N = 1e4, 1e5 and 1e6 steps, in ns per step (time.process_time,
best of --repeat; the machine is shared, so the ratios measured in the same
run are the meaningful part):

* fast    -- the whole FONBW step with the default fast engine: the compiled
             batch loop on preallocated arrays, and ``simulate()`` end to end
             (which adds allocating and first-touching its output arrays);
* nbw     -- the same step without memory (lam1 = lam2 = 1), for reference;
* direct  -- the exact engine's direct full GL sum (O(N^2) per run), measured
             up to --direct-max steps and extrapolated beyond (the cost per
             step grows like N; marked "extrapolated");
* blocked -- the exact engine's blocked-FFT history sum (``simulate`` with
             memory="exact", O(N log^2 N) per run);

their ratios, and the relative errors max|y - y_exact| / max|y_exact| of the
fast, short and oustaloup engines over 1e5 steps (y_exact from the blocked
run, itself compared with the direct sum). --sweep adds the worst fast-vs-exact
error over a grid of orders lam1, lam2 in [0.3, 1] (same model and input).
--baseline REV also times fast, nbw and the direct sum of the fonbw package
as of git revision REV (extracted to a temporary directory, run in a
subprocess with its own numba cache, interleaved with this run's timings).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import fonbw
from fonbw import fractional as fr
from fonbw import hysteresis as H
from fonbw.paper import TABLE1_FONBW
from fonbw.signals import eq19_input

DT = 1e-4
TABLE1 = TABLE1_FONBW
SIZES = (10_000, 100_000, 1_000_000)
SWEEP = (0.3, 0.4, 0.5, 0.6, 0.622, 0.7, 0.8, 0.9, 0.9557, 0.99, 1.0)


def eq19(n):
    return eq19_input(1.0 / DT, n * DT)[1]


def best(fn, repeat):
    """Smallest process time of `repeat` calls [s]."""
    b = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        b = min(b, time.process_time() - t0)
    return b


def kernel_loop(model, u):
    """The compiled batch loop on preallocated, already touched arrays."""
    P, ss = model._pack(DT, n_steps=len(u))
    out = np.zeros(len(u))
    hout = np.zeros(len(u))
    return lambda: H.run_kernel(model._code, u, P, ss, out, hout)


def direct_exact(model, u):
    """The exact engine by its direct full sum, whatever the length."""
    return H._simulate(model, u, DT, False)


def rel(a, ref):
    return float(np.max(np.abs(a - ref)) / np.max(np.abs(ref)))


def machine():
    cpu = platform.processor() or "?"
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    import numba
    return (f"{cpu}, {os.cpu_count()} CPUs, Python {platform.python_version()}, numpy {np.__version__}, "
            f"numba {numba.__version__}; load average {os.getloadavg()[0]:.1f} at start")


_BASELINE = r"""
import json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
import fonbw
from fonbw import hysteresis as H
assert fonbw.__file__.startswith(sys.argv[1])
sys.path.insert(0, sys.argv[2])
import bench_memory as B
fast = fonbw.FONBW(**B.TABLE1)
nbw = fonbw.NBW(ku=B.TABLE1["ku"], kh=B.TABLE1["kh"], rho=B.TABLE1["rho"], sigma=B.TABLE1["sigma"], n=B.TABLE1["n"])
exact = fonbw.FONBW(**B.TABLE1, memory="exact")
res = {}
for N in (10_000, 100_000):
    u = B.eq19(N)
    for name, m, reps in (("fast", fast, 5), ("nbw", nbw, 5), ("direct", exact, 5 if N <= 10_000 else 1)):
        m.simulate(u[:10], B.DT)
        res[f"{name} {N}"] = B.best(lambda: H._simulate(m, u, B.DT, False), reps) / N * 1e9
print(json.dumps(res))
"""


def baseline(rev):
    """ns per step of fast, nbw and the direct sum at 1e4 and 1e5 for git revision `rev`."""
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory(prefix="bench_memory_") as tmp:
        tar = Path(tmp) / "src.tar"
        subprocess.run(["git", "-C", str(root), "archive", rev, "fonbw", "-o", str(tar)], check=True)
        subprocess.run(["tar", "-xf", str(tar), "-C", tmp], check=True)
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "cache"))
        out = subprocess.run([sys.executable, "-c", _BASELINE, tmp, str(Path(__file__).parent)],
                             check=True, env=env, capture_output=True, text=True, cwd=tmp).stdout
        return json.loads(out.strip().splitlines()[-1])


def timings(models, u_all, repeat, direct_max):
    """ns per step of each engine at every N of SIZES (one dict per N), printing progress."""
    fast, nbw, exact = models
    rows = []
    direct_per_step = None
    for N in SIZES:
        u = u_all[:N]
        r = {"N": N}
        r["fast"] = best(kernel_loop(fast, u), repeat) / N * 1e9
        r["fast_sim"] = best(lambda: fast.simulate(u, DT), repeat) / N * 1e9
        r["nbw"] = best(kernel_loop(nbw, u), repeat) / N * 1e9
        r["blocked"] = best(lambda: exact.simulate(u, DT), max(1, repeat if N <= 100_000 else 2)) / N * 1e9
        if N <= direct_max:
            reps = repeat if N <= 10_000 else 1
            r["direct"] = best(lambda: direct_exact(exact, u), reps) / N * 1e9
            r["direct_note"] = "measured"
            direct_per_step = (N, r["direct"])
        else:
            N0, c0 = direct_per_step
            r["direct"] = c0 * N / N0
            r["direct_note"] = f"extrapolated from {N0:.0e} (cost/step ~ N)"
        rows.append(r)
        print(f"  N = {N:.0e} done", flush=True)
    return rows


def print_timings(rows):
    print()
    print("ns per step (process time, best of runs)")
    print(f"{'N':>8} {'fast':>8} {'fast sim()':>10} {'nbw':>7} {'direct':>11} {'blocked':>9} "
          f"{'direct/fast':>12} {'blocked/fast':>12} {'direct/blocked':>14}  direct")
    for r in rows:
        print(f"{r['N']:>8.0e} {r['fast']:>8.1f} {r['fast_sim']:>10.1f} {r['nbw']:>7.1f} {r['direct']:>11.0f} "
              f"{r['blocked']:>9.0f} {r['direct'] / r['fast']:>12.0f} {r['blocked'] / r['fast']:>12.1f} "
              f"{r['direct'] / r['blocked']:>14.0f}  {r['direct_note']}")


def print_baseline(rev, models, u_all, repeat):
    """This revision against `rev`, re-measured here right after the baseline run."""
    fast, nbw, exact = models
    # interleaved with a re-measurement of this revision, so both see the same load
    old = baseline(rev)
    print()
    print(f"ns per step, this revision vs {rev} (simulate(), process time, measured back to back)")
    print(f"{'':>14} {'this':>9} {rev:>9} {'speed-up':>9}")
    for N in (10_000, 100_000):
        u = u_all[:N]
        now = {"fast": best(lambda: fast.simulate(u, DT), repeat) / N * 1e9,
               "nbw": best(lambda: nbw.simulate(u, DT), repeat) / N * 1e9,
               "direct": best(lambda: direct_exact(exact, u), repeat if N <= 10_000 else 1) / N * 1e9}
        for k, v in now.items():
            o = old[f"{k} {N}"]
            print(f"{k + ' ' + format(N, '.0e'):>14} {v:>9.1f} {o:>9.1f} {o / v:>9.2f}")
        print(f"{'direct/fast':>14} {now['direct'] / now['fast']:>9.0f} "
              f"{old[f'direct {N}'] / old[f'fast {N}']:>9.0f}   (at {N:.0e})")


def print_errors(exact, u, with_direct):
    """Relative error of each engine against the blocked exact run (and that against the direct sum)."""
    y_ex = exact.simulate(u, DT)
    print()
    print(f"relative error max|y - y_exact| / max|y_exact| over {len(u):.0e} steps (Table 1, eq. 19):")
    if with_direct:
        print(f"  blocked exact vs direct exact sum: {rel(y_ex, direct_exact(exact, u)):.2e}")
    for eng in ("fast", "short", "oustaloup"):
        y = fonbw.FONBW(**TABLE1, memory=eng).simulate(u, DT)
        print(f"  {eng:>9}: {rel(y, y_ex):.2e}")


def print_sweep(u):
    print()
    print(f"fast vs exact over lam1, lam2 in {SWEEP}, {len(u):.0e} steps:")
    worst = (0.0, None)
    for l1 in SWEEP:
        for l2 in SWEEP:
            p = {**TABLE1, "lam1": l1, "lam2": l2}
            e = rel(fonbw.FONBW(**p).simulate(u, DT), fonbw.FONBW(**p, memory="exact").simulate(u, DT))
            worst = max(worst, (e, (l1, l2)))
    print(f"  worst {worst[0]:.2e} at (lam1, lam2) = {worst[1]}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="best of this many runs (default 5)")
    ap.add_argument("--direct-max", type=int, default=100_000,
                    help="longest run of the direct exact sum actually measured (default 1e5)")
    ap.add_argument("--sweep", action="store_true", help="worst fast-vs-exact error over a grid of orders")
    ap.add_argument("--baseline", metavar="REV", help="also time the fonbw package of this git revision")
    a = ap.parse_args(argv)

    print(machine())
    print(f"fast engine: K = {fr.FAST_K}, M = {fr.FAST_M}; blocked exact from "
          f"{H.EXACT_BLOCKED_MIN} steps, leaf {fr.EXACT_LEAF}")
    fast = fonbw.FONBW(**TABLE1)
    nbw = fonbw.NBW(ku=TABLE1["ku"], kh=TABLE1["kh"], rho=TABLE1["rho"], sigma=TABLE1["sigma"], n=TABLE1["n"])
    exact = fonbw.FONBW(**TABLE1, memory="exact")
    u_all = eq19(max(SIZES))
    # compile / load caches outside the timings
    for m in (fast, nbw, exact):
        m.simulate(u_all[:H.EXACT_BLOCKED_MIN + 10], DT)
        direct_exact(m, u_all[:10])

    print_timings(timings((fast, nbw, exact), u_all, a.repeat, a.direct_max))
    if a.baseline:
        print_baseline(a.baseline, (fast, nbw, exact), u_all, a.repeat)
    N = 100_000
    print_errors(exact, u_all[:N], a.direct_max >= N)
    if a.sweep:
        print_sweep(u_all[:N])
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
