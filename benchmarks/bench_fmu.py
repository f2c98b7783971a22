"""Per-step cost of the FONBW hysteresis FMU in fmpy vs the library stepper.

    python benchmarks/bench_fmu.py [--steps N] [--fmu PATH] [--memory ENGINE]

One communication step of the FMU = fmi2SetReal(u) + fmi2DoStep(t, dt) +
fmi2GetReal(y), called through fmpy's FMU2Slave at dt = 1e-4 s (10 kHz), i.e.
one internal step per communication step — the costliest ratio.  The library
reference is fonbw's stepper.step(u) on the same input.  Both columns are
printed side by side, together with instantiate/initialize times (the first
initialization of a process includes numba compilation or cache loading).

Run in a fresh process: the FMU is built into a temporary directory (unless
--fmu is given) and its bundled fonbw copy is what runs; the library column
imports the same bundled copy (the FMU loaded it first), so both columns time
the same compiled kernels.  Target: <= 20 us per FMU step.
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DT = 1e-4


def _initialize(s, vr, memory):
    """fmi2SetupExperiment .. fmi2ExitInitializationMode, with the memory engine if one is given."""
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    if memory:
        s.setString([vr["memory"]], [memory])
    s.exitInitializationMode()


def _library_model(s, vr):
    """The FONBW of the FMU's parameter values, from the fonbw module the FMU imported (same kernels)."""
    import fonbw  # only now: the FMU's initialization has put its bundled copy in sys.modules
    names = ("kh", "rho", "sigma", "n", "lam1", "lam2", "dt")
    p = dict(zip(names, s.getReal([vr[k] for k in names])))
    ku = s.getReal([vr[k] for k in sorted(vr) if k.startswith("ku")])
    memory = s.getString([vr["memory"]])[0]
    memory = memory.decode() if isinstance(memory, bytes) else memory
    dt = p.pop("dt")
    return fonbw.FONBW(ku=ku, memory=memory, **p), memory, dt


def _time_steps(s, vr, model, dt, ul, memory_arg):
    """µs per step of the library stepper and of the FMU (reset and re-initialized), one repetition."""
    st = model.stepper(dt)
    step = st.step
    tl = time.perf_counter()
    for x in ul:
        step(x)
    lib = (time.perf_counter() - tl) / len(ul) * 1e6

    s.reset()
    _initialize(s, vr, memory_arg)
    vu, vy = [vr["u"]], [vr["y"]]
    setReal, doStep, getReal = s.setReal, s.doStep, s.getReal
    t = 0.0
    tf = time.perf_counter()
    for k, x in enumerate(ul):
        setReal(vu, [x])
        doStep(t, DT)
        getReal(vy)
        t = (k + 1) * DT
    return (time.perf_counter() - tf) / len(ul) * 1e6, lib


def _report(a, memory, dt, t_inst, t_init, fmu_us, lib_us):
    print(f"FonbwHysteresis FMU, memory={memory}, dt={dt:g} s, {a.steps} steps x {a.repeat}")
    print(f"  instantiate              {1e3 * t_inst:9.1f} ms")
    print(f"  initialize (1st, +numba) {1e3 * t_init:9.1f} ms")
    print(f"  {'per step':24s} {'FMU (fmpy)':>12s} {'library':>12s}")
    print(f"  {'median':24s} {statistics.median(fmu_us):9.2f} us {statistics.median(lib_us):9.2f} us")
    print(f"  {'best':24s} {min(fmu_us):9.2f} us {min(lib_us):9.2f} us")
    ok = statistics.median(fmu_us) <= 20.0
    print(f"  target <= 20 us per FMU step: {'met' if ok else 'NOT met'}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=20000, help="steps per repetition (default 2 s at 10 kHz)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--fmu", type=Path, help="prebuilt FonbwHysteresis.fmu (default: build one)")
    ap.add_argument("--memory", default=None, help="memory engine parameter (default: the FMU's)")
    a = ap.parse_args(argv)

    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    with tempfile.TemporaryDirectory(prefix="bench_fmu_") as tmp:
        fmu = a.fmu
        if fmu is None:
            subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--only", "hysteresis",
                            "-o", tmp], check=True, stdout=subprocess.DEVNULL)
            fmu = Path(tmp) / "FonbwHysteresis.fmu"
        md = read_model_description(str(fmu))
        vr = {v.name: v.valueReference for v in md.modelVariables}
        unzip = extract(str(fmu), str(Path(tmp) / "unzipped"))

        t0 = time.perf_counter()
        s = FMU2Slave(guid=md.guid, unzipDirectory=unzip,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
        s.instantiate()
        t1 = time.perf_counter()
        _initialize(s, vr, a.memory)
        t2 = time.perf_counter()

        model, memory, dt = _library_model(s, vr)
        ul = (60.0 + 50.0 * np.sin(2 * np.pi * 5.0 * np.arange(a.steps) * DT)).tolist()
        fmu_us, lib_us = [], []
        for _ in range(a.repeat):
            f, lib = _time_steps(s, vr, model, dt, ul, a.memory)
            fmu_us.append(f)
            lib_us.append(lib)
        s.terminate()
        s.freeInstance()

    _report(a, memory, dt, t1 - t0, t2 - t1, fmu_us, lib_us)


if __name__ == "__main__":
    main()
