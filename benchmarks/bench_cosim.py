"""Wall time of the 10 kHz closed loop for each co-simulation master.

    python benchmarks/bench_cosim.py [--T 10] [--mode ff+fb] [--plant dynamics+creep]
                                     [--masters reference,fmpy,libcosim] [--fmu-dir DIR]

Each master runs in its own fresh process (FMUs must not share a process with
another master's imports), first a 0.01 s warm-up run (numba compilation or
cache loading, FMU extraction), then the timed run of T seconds of simulated
time at dt = 1e-4 s.  Printed side by side: wall time of the stepping loop,
setup (instantiate + initialize; libcosim initializes inside its first step,
counted here as setup), microseconds per communication step, real-time factor
(simulated / wall time, and simulated / process CPU time of the loop, which
other jobs on the machine disturb less), the wall-time ratio to the
reference master, and the RMS
tracking error (the masters must agree to round-off).  The load average is
printed too: on the shared 2-core machine other jobs change the absolute
numbers; the ratios measured side by side are the meaningful part.

Target: fmpy master real-time factor >= 1.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

RUN = r'''
import json, sys
from fonbw.loop import run_cosim
master, mode, plant, T, fmu_dir = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), sys.argv[5]
run_cosim("sine5", mode, master, T=0.01, plant=plant, fmu_dir=fmu_dir)  # warm-up
r = run_cosim("sine5", mode, master, T=T, plant=plant, fmu_dir=fmu_dir)
print(json.dumps({k: getattr(r, k) for k in ("wall_s", "cpu_s", "setup_s", "rtf", "steps", "rms_error", "error")}))
'''


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--T", type=float, default=10.0, help="simulated time [s] (default 10)")
    ap.add_argument("--mode", default="ff+fb")
    ap.add_argument("--plant", default="dynamics+creep")
    ap.add_argument("--masters", default="reference,fmpy,libcosim")
    ap.add_argument("--fmu-dir", default=None, help="prebuilt/reused FMUs (default: build in a tmp dir)")
    a = ap.parse_args(argv)

    from fonbw.loop import build_fmus

    with tempfile.TemporaryDirectory(prefix="bench_cosim_") as tmp:
        fmu_dir = a.fmu_dir or tmp
        build_fmus(fmu_dir, None if a.plant == "none" else a.plant)
        print(f"closed loop: sine5, mode {a.mode}, plant {a.plant}, T = {a.T} s at 10 kHz; "
              f"load average before: {os.getloadavg()[0]:.2f} (2 cores)")
        rows = {}
        for m in a.masters.split(","):
            r = subprocess.run([sys.executable, "-c", RUN, m, a.mode, a.plant, str(a.T), str(fmu_dir)],
                               capture_output=True, text=True, cwd=tmp)
            if r.returncode != 0:
                print(f"{m}: failed\n{r.stderr[-2000:]}")
                continue
            rows[m] = json.loads(r.stdout.strip().splitlines()[-1])
        ref = rows.get("reference")
        print(f"{'master':10s} {'wall [s]':>9s} {'cpu [s]':>8s} {'setup [s]':>9s} {'us/step':>8s} "
              f"{'RTF':>6s} {'RTF cpu':>8s} {'x ref':>6s} {'rms_error [um]':>16s}")
        for m, d in rows.items():
            us = 1e6 * d["wall_s"] / max(d["steps"], 1)
            ratio = d["wall_s"] / ref["wall_s"] if ref else float("nan")
            rtf_cpu = d["steps"] * 1e-4 / d["cpu_s"] if d["cpu_s"] > 0 else float("inf")
            print(f"{m:10s} {d['wall_s']:9.2f} {d['cpu_s']:8.2f} {d['setup_s']:9.2f} {us:8.1f} "
                  f"{d['rtf']:6.2f} {rtf_cpu:8.2f} {ratio:6.2f} {d['rms_error']:16.12f}" + (f"  ERROR {d['error']}" if d["error"] else ""))
        print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
