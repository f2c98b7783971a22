"""Cost of the implicit compensator (eq. 16) against the model it inverts.

    python benchmarks/bench_compensate.py [--steps N] [--repeat R]
    python benchmarks/bench_compensate.py --table1 [--limits LO HI]

Side by side, on the 5-Hz trajectory of Table 4 at 10 kHz, for FONBW (fast
engine), CBW and Zhu2016 (fixed parameter sets that track without
saturation):

* batch: ``fonbw.compensate(model, Hd, dt)`` per sample vs ``model.simulate``
  per sample on the voltage it returns (the ratio is about the number of
  model evaluations each root find needs, printed as evals/sample);
* per step: ``Compensator.step(Hd_k)`` vs the model's ``Stepper.step(u_k)``
  (Python call overhead included, what an FMU pays).

``--table1``: the paper's Table 1 FONBW with its own eq.-19 record's input
range as limits (or ``--limits``), pure simulation (the model is the plant),
1 s of each Table 4 trajectory at 10 kHz and 5 kHz, from rest and after the
rest cycle: the causal and the preview compensator's model error, saturated
and rootless samples, voltage range, RMS step change and wall time.

Each figure is the median of ``--repeat`` runs after a warm-up (numba
compile or cache load excluded). Timings move with the machine's load
(printed); the ratios are the meaningful part.
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

import fonbw
import importlib
from fonbw.signals import trajectory_5hz

C = importlib.import_module("fonbw.compensate")  # fonbw.compensate is the function

DT = 1e-4
WN, ZETA = 2 * np.pi * 1500.0, 0.7
MODELS = {
    "FONBW (fast)": fonbw.FONBW(ku=[0.15, -1e-4, -5e-8], kh=2.0, rho=0.02, sigma=0.8, n=1.5,
                                lam1=0.95, lam2=0.85),
    "CBW": fonbw.CBW(ka=0.15, kb=0.05, D=50.0, A=1.0, beta=0.6, gamma=0.4, n=1.0),
    "Zhu2016": fonbw.Zhu2016(m0=1 / WN**2, c0=2 * ZETA / WN, k0=1.0, k1=0.1, x0=0.0, tau=2e-5,
                             A=0.17, beta=0.001, gamma=0.0005, delta=0.0, n=1.0),
}


def _median_time(fn, repeat):
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def table1_inversion(limits=None, T=1.0):
    """Causal against preview compensator on the paper's Table 1 set (module docstring)."""
    import warnings

    from fonbw.compensate.rest import rest_start_meta
    from fonbw.paper import TABLE1_FONBW
    from fonbw.signals import eq19_input, trajectory_multi

    u19 = eq19_input(10000.0)[1]
    rng = [float(u19.min()), float(u19.max())]
    print(f"load average {os.getloadavg()[0]:.2f}; Table 1 FONBW, limits "
          f"{limits or rng} V, {T:g} s per trajectory")
    for fs in (10000.0, 5000.0):
        dt = 1.0 / fs
        t = np.arange(int(round(T * fs))) * dt
        for start in ("rest", "cycle"):
            m = fonbw.FONBW(**TABLE1_FONBW)
            m.meta = {"u_range": rng}
            if start == "cycle":
                m.meta["start"] = rest_start_meta(rng)
            for name, Hd in (("5-Hz", trajectory_5hz(t)), ("multi", trajectory_multi(t))):
                for pv in (False, True):
                    t0 = time.perf_counter()
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", RuntimeWarning)
                        r = C.compensate(m, Hd, dt, preview=pv, limits=limits)
                    e = np.abs(r.residual)
                    c = r.counts
                    du = np.sqrt(np.mean(np.diff(r.u_full) ** 2))
                    print(f"{fs:5.0f} Hz {start:5s} {name:6s} {'preview' if pv else 'causal':7s}: "
                          f"max |model - Hd| {e.max():.3g} µm (RMS {np.sqrt(np.mean(e ** 2)):.3g}), "
                          f"saturated {c['saturated_low'] + c['saturated_high']}, no root "
                          f"{c['not_converged']}, u {r.u_full.min():.1f}..{r.u_full.max():.1f} V, "
                          f"RMS du {du:.3f} V, lead {r.u_lead.size}, {time.perf_counter() - t0:.0f} s")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=20000, help="samples (default 2 s at 10 kHz)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--table1", action="store_true", help="causal vs preview on the Table 1 set")
    ap.add_argument("--limits", type=float, nargs=2, default=None, metavar=("LO", "HI"))
    a = ap.parse_args(argv)
    if a.table1:
        return table1_inversion(tuple(a.limits) if a.limits else None)
    Hd = trajectory_5hz(np.arange(a.steps) * DT)
    print(f"load average {os.getloadavg()[0]:.2f}; {a.steps} samples at {1 / DT:.0f} Hz, "
          f"median of {a.repeat}")
    print(f"{'model':<14} {'compensate':>11} {'simulate':>9} {'ratio':>6} {'evals/sample':>12} "
          f"{'Comp.step':>10} {'Stepper.step':>12} {'ratio':>6}   [µs per sample]")
    for name, m in MODELS.items():
        res = C.compensate(m, Hd[:100], DT)  # warm-up: compile or cache load
        m.simulate(res.u, DT)
        res = C.compensate(m, Hd, DT)
        assert res.ok, res.summary()
        tc = _median_time(lambda: C.compensate(m, Hd, DT), a.repeat)
        ts = _median_time(lambda: m.simulate(res.u, DT), a.repeat)
        c = C.compensator(m, DT)
        c.step(0.0)

        def comp_steps():
            c.reset()
            step = c.step
            for h in Hd:
                step(h)

        s = m.stepper(DT)

        def model_steps():
            s.reset()
            step = s.step
            for u in res.u:
                step(u)

        tcs = _median_time(comp_steps, a.repeat)
        tms = _median_time(model_steps, a.repeat)
        n = len(Hd)
        print(f"{name:<14} {1e6 * tc / n:>11.3f} {1e6 * ts / n:>9.3f} {tc / ts:>6.1f} "
              f"{res.nfev.mean():>12.2f} {1e6 * tcs / n:>10.2f} {1e6 * tms / n:>12.2f} "
              f"{tcs / tms:>6.1f}")


if __name__ == "__main__":
    main()
