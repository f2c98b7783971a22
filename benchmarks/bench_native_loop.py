"""Speed of the 10 kHz closed loop on the native C FMUs, beside the same
master running pass-through FMUs.

For each master (fmpy, libcosim) the loop ff+fb with the plant's dynamics
(compensator, controller, hysteresis, plant; in libcosim the controller is
FonbwPIDNative, in fmpy the library's LoopController) runs on the native
FMUs, then on their pass-through variants (the same interface, parameters
and checks, output = first input), alternately, `--repeat` times; the best
real-time factor of each is printed with the CPU-time one and the load
average, so the master's own share of the cost is visible.

The libcosim master runs the whole horizon in one ``ex.step`` call: the
exogenous inputs come from signal FMUs (FonbwSignalNative playing the
sequences), the outputs from libcosim's time-series observer, and the
execution is created with no worker thread (fonbw.loop.lc_threads), so its
figures are libcosim's fixed-step algorithm plus the FMUs, with no Python
per step. What that thread costs is measured after the loops: libcosim
alone, stepping 1 and 4 pass-through slaves with no connections, with its
worker thread (as libcosimpy creates executions), with that thread and the
caller pinned to one CPU, and with no worker.

    python benchmarks/bench_native_loop.py [--T 1.0] [--repeat 2]
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from unittest import mock

from fonbw.loop import run_cosim
from fonbw.loop.fmus import build_native_fmus

MODE, PLANT, SCENARIO = "ff+fb", "dynamics", "sine5"
TARGETS = {"fmpy": 2.0, "libcosim": 20.0}


def _run(master, T, fmu_dir, passthrough=None):
    """One run; with `passthrough` ({role: path}) the loop's FMUs are replaced by those."""
    if passthrough is None:
        return run_cosim(SCENARIO, MODE, master, T=T, plant=PLANT, native=True, fmu_dir=fmu_dir)
    with mock.patch("fonbw.loop.run.build_fmus", lambda *a, **k: dict(passthrough)):
        return run_cosim(SCENARIO, MODE, master, T=T, plant=PLANT, native=True, fmu_dir=fmu_dir)


def _libcosim_alone(fmus, n, how):
    """Wall time per step [µs] of libcosim's fixed-step algorithm stepping
    the FMUs `fmus` (no connections, no observer) n times in one call;
    `how`: "worker", "pinned" (the caller and the worker on one CPU) or
    "no worker"."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimSlave import CosimLocalSlave

    from fonbw.loop import lc_threads

    mask = os.sched_getaffinity(0)
    if how == "pinned":  # threads inherit the mask when the execution creates them
        os.sched_setaffinity(0, {min(mask)})
    try:
        with lc_threads.single_thread(how == "no worker") as info:
            ex = CosimExecution.from_step_size(100_000)
            for j, f in enumerate(fmus):
                ex.add_local_slave(CosimLocalSlave(fmu_path=str(f), instance_name=f"s{j}"))
        assert ex.step(1)  # initialization
        t0 = time.perf_counter()
        assert ex.step(n)
        wall = time.perf_counter() - t0
        del ex
    finally:
        os.sched_setaffinity(0, mask)
    return 1e6 * wall / n, info["workers"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--T", type=float, default=1.0, help="simulated time per run [s] (default 1)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--masters", nargs="+", default=["fmpy", "libcosim"])
    ns = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        build_native_fmus(tmp, PLANT)
        passthrough = build_native_fmus(tmp, PLANT, pass_through=True)
        print(f"{MODE}, plant {PLANT}, {SCENARIO}, T = {ns.T} s at 10 kHz ({round(ns.T / 1e-4)} steps); "
              f"load average before: {os.getloadavg()}")
        for master in ns.masters:
            best = {}
            for _ in range(ns.repeat):
                for tag, pt in (("native", None), ("pass-through", passthrough)):
                    r = _run(master, ns.T, tmp, pt)
                    assert r.error is None, r.error
                    prev = best.get(tag)
                    if prev is None or r.rtf > prev.rtf:
                        best[tag] = r
            for tag, r in best.items():
                print(f"{master:8s} {tag:12s}: rtf {r.rtf:7.2f} (CPU {r.sim_time_s / r.cpu_s:7.2f}), "
                      f"{1e6 * r.wall_s / r.steps:7.1f} us/step, setup {r.setup_s:.3f} s")
            lc = best["native"].diagnostics.get("libcosim")
            if lc:
                print(f"{master:8s} stepping: {lc['stepping']} (worker threads {lc['worker_threads']}); "
                      f"exogenous inputs: {lc['exogenous']}; one ex.step call for the run"
                      if lc["exogenous"] == "signal FMUs" else f"{master:8s} stepping: {lc['stepping']}; "
                      f"exogenous inputs: {lc['exogenous']}")
            n, p = best["native"], best["pass-through"]
            print(f"{master:8s} native / pass-through wall time: {n.wall_s / p.wall_s:.2f} "
                  f"(the FMUs' own share {max(0.0, 1 - p.wall_s / n.wall_s):.0%}); target rtf >= "
                  f"{TARGETS.get(master, 0):g}: {'met' if n.rtf >= TARGETS.get(master, 0) else 'NOT met'}; "
                  f"load {os.getloadavg()}")
        if "libcosim" in ns.masters:
            n = round(ns.T / 1e-4)
            pts = list(passthrough.values())
            print(f"libcosim alone, {n} steps of pass-through slaves in one ex.step call (no connections, "
                  f"no observer), best of {ns.repeat}, us/step:")
            for slaves in (pts[:1], pts[:4]):
                row = {how: min(_libcosim_alone(slaves, n, how) for _ in range(ns.repeat))
                       for how in ("worker", "pinned", "no worker")}
                print(f"  {len(slaves)} slave(s): " + ", ".join(
                    f"{how} {us:6.1f} ({w} worker thread{'s' * (w != 1)})" for how, (us, w) in row.items()))
            print(f"load {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
