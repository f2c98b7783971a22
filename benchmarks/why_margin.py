"""Why does FONBW's margin over CBW not widen with frequency on the virtual bench?

The paper reports FONBW's validation error growing slowly with frequency while
CBW's grows fast (Table 3). On the default bench both grow alike. This script
tests two explanations, each side by side with the default, same seed and
budget:

(a) the error is dominated by effects neither model has (creep, amplifier,
    mechanics): rerun on a bench with only the rate-dependent hysteresis;
(b) the eq.-19 record excites ≤ 1.5 Hz, so 5–20 Hz is extrapolation: add a
    multi-tone record (1–20 Hz) to the training data;
(c) the bench's hysteresis is only mildly rate dependent (loop width x1.16
    from 1 to 20 Hz): rerun (a) with the rate dependence 5x stronger.

Usage: python benchmarks/why_margin.py [--evals 1500] [--seed 0]
Prints Table-3 rows (RMS % of range) per case and the FONBW−CBW margin.
"""
import argparse
import time

from fonbw.bench import Bench, BenchParams
from fonbw.paper import SINE_FREQS
from fonbw.signals import eq19_input, multi_input, sine_input
from fonbw.identify import identify
from fonbw.io import decimate
from fonbw.reproduce import table3


def case(name, bench, extra_train, evals, seed, q):
    train = [decimate(bench.record(eq19_input(bench.fs)[1], "eq19"), q)]
    if extra_train:
        train.append(decimate(bench.record(multi_input(fs=bench.fs, T=4.0)[1], "multi"), q))
    sines = {f: bench.record(sine_input(f, bench.fs, periods=5)[1], f"sine{f}") for f in SINE_FREQS}
    t0 = time.perf_counter()
    models = {k: identify(train, kind=k, seed=seed, max_evals=evals).model for k in ("fonbw", "cbw")}
    t3 = table3(models, sines)
    fo, cb = t3["rows"]["fonbw"], t3["rows"]["cbw"]
    margin = [c - f for f, c in zip(fo, cb)]
    print(f"\n{name}  ({time.perf_counter() - t0:.0f} s)")
    print("  freq [Hz]      " + "".join(f"{f:>8g}" for f in t3["freqs"]))
    print("  FONBW [%]      " + "".join(f"{v:8.2f}" for v in fo))
    print("  CBW [%]        " + "".join(f"{v:8.2f}" for v in cb))
    print("  margin [pp]    " + "".join(f"{v:8.2f}" for v in margin))
    return margin


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--evals", type=int, default=1500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fs-identify", type=float, default=2000.0)
    a = ap.parse_args()
    q = int(round(10_000 / a.fs_identify))
    full = Bench(seed=a.seed)
    bare = Bench(seed=a.seed, creep=False, dynamics=False, amplifier=False, delay=0)
    print(f"identification at {a.fs_identify:g} Hz, {a.evals} evaluations per model, seed {a.seed}")
    case("default bench, eq.-19 training", full, False, a.evals, a.seed, q)
    case("(a) hysteresis only (no creep/amplifier/mechanics/delay), eq.-19 training", bare, False, a.evals, a.seed, q)
    case("(b) default bench, eq.-19 + multi-tone 1-20 Hz training", full, True, a.evals, a.seed, q)
    case("(a)+(b) hysteresis only, eq.-19 + multi-tone training", bare, True, a.evals, a.seed, q)
    strong = Bench(seed=a.seed, creep=False, dynamics=False, amplifier=False, delay=0,
                   params=BenchParams(rate_alpha=5 * BenchParams().rate_alpha))
    case("(c) hysteresis only, rate dependence x5, eq.-19 training", strong, False, a.evals, a.seed, q)


if __name__ == "__main__":
    main()
