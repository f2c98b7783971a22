"""The gap diagnosis's two compiled hot spots against what they replaced, side by side.

Not a test. Two measurements, each the old and the new arithmetic on the same
arrays in one run, with the machine's load average printed:

* **The saturation block's Gauss-Newton** (``Fitter.fit_linear`` with an
  output nonlinearity): the numpy form it had (the Jacobian stacked column by
  column, ``logaddexp`` and ``tanh`` over every sample; kept here as the
  reference) against the library's fused kernels (:mod:`fonbw.gap.knee`), on
  a synthetic stroke limit y = z − 0.7 f(z) + noise at the sizes of a global
  search (3e4 samples, the records decimated to 1 kHz) and of a local refit
  (1.5e5 samples), for a soft, a sharp and a wide knee. Also printed: the
  largest relative difference of the coefficients and the two RMS residuals.
  The same at the reference core's width (25 base columns, with the
  column-major layout the fitter hands the kernels).
* **The reference core's active columns**
  (:meth:`fonbw.gap.reference.ReferenceHysteresis.columns` with ``keep=``)
  against the whole matrix and a column copy, as the refits built them
  before, for the diagnosis's reference (16 plays, density degree 6, rate
  variant "both"), a quarter of the columns kept, on 1.5e5 samples; the two
  are equal bit for bit (checked).
* **The reference core's combinations** (``columns(..., keep=, basis=)``,
  summed in the play kernel) against the kept columns times the basis, as
  the joint refits built them before, at the diagnosis's size (44 of 112
  play columns and the 7 others kept, 24 combinations); the largest
  difference relative to the largest entry is printed.

Usage::

    .venv/bin/python benchmarks/bench_gap_kernels.py [--repeat 10]
"""
from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from fonbw.gap.effects import Saturation
from fonbw.gap.fitter import Fitter
from fonbw.gap.reference import ReferenceHysteresis


def _numpy_shape(z, th):
    w = float(th[1])
    s = (np.asarray(z, dtype=float) - float(th[0])) / w
    return w * np.logaddexp(0.0, s), 0.5 * (1.0 + np.tanh(0.5 * s))


def numpy_fit(A, y, th, iters=8):
    """The Gauss-Newton of the saturation block as it was written with numpy."""
    b, _ = Fitter.solve(A, y)
    B = A[:, :-1]
    b = b.copy()

    def resid(b):
        f, df = _numpy_shape(B @ b[:-1], th)
        return y - (B @ b[:-1] + b[-1] * f), f, df

    r, f, df = resid(b)
    sse = float(r @ r)
    for _ in range(iters):
        J = np.column_stack([B * (1.0 + b[-1] * df)[:, None], f])
        step, _ = Fitter.solve(J, r)
        if step is None:
            break
        lam, better = 1.0, False
        for _ in range(6):
            bn = b + lam * step
            rn, fn, dfn = resid(bn)
            sn = float(rn @ rn)
            if sn < sse:
                better = True
                break
            lam *= 0.5
        if not better:
            break
        gain = (sse - sn) / max(sse, 1e-300)
        b, r, f, df, sse = bn, rn, fn, dfn, sn
        if gain < 1e-9:
            break
    if b[-1] > 0.0:
        b0, r0 = Fitter.solve(B, y)
        return np.r_[b0, 0.0], r0
    return b, r


def _best(fn, repeat):
    fn()
    t = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        t.append(time.perf_counter() - t0)
    return min(t)


def _knee_line(n, z, base, th, rng, repeat, note=""):
    """Time the numpy and the compiled fit on one synthetic stroke limit; one printed line."""
    sat = Saturation(0.0, 10.0)
    y = z - 0.7 * _numpy_shape(z, th)[0] + rng.normal(0.0, 0.01, n)
    # the block's regressor driven by a slightly wrong nominal output, as in a refit
    A = np.asfortranarray(np.column_stack([base, _numpy_shape(0.95 * z + 0.2, th)[0]]))
    b0, r0 = numpy_fit(A, y, th)
    b1, r1 = Fitter.fit_linear(A, y, (sat, th))
    t0 = _best(lambda: numpy_fit(A, y, th), repeat)
    t1 = _best(lambda: Fitter.fit_linear(A, y, (sat, th)), repeat)
    dif = float(np.max(np.abs(b0 - b1) / np.maximum(np.abs(b0), 1e-12)))
    print(f"  {n:7d}  {th[0]:.1f}/{th[1]:<5g} {1e3 * t0:7.2f} / {1e3 * t1:6.2f}  {t0 / t1:4.2f}x  "
          f"{dif:.1e}  {math.sqrt(np.mean(r0 ** 2)):.6f} / {math.sqrt(np.mean(r1 ** 2)):.6f}  "
          f"({note}load {os.getloadavg()[0]:.1f})")


def bench_knee(repeat):
    rng = np.random.default_rng(0)
    print("saturation Gauss-Newton: samples, knee/width [µm], numpy / compiled [ms], ratio, "
          "max rel. coefficient difference, RMS numpy / compiled [µm]")
    for n in (30_000, 150_000):
        t = np.linspace(0.0, 30.0, n)
        z = 5.0 + 5.0 * np.sin(2 * np.pi * 0.5 * t) * np.exp(-t / 20.0)
        base = np.column_stack([z / 10, (z / 10) ** 2, (z / 10) ** 3, np.sin(3 * t), np.ones(n)])
        for th in (np.array([7.0, 0.3]), np.array([8.5, 0.01]), np.array([6.0, 2.0])):
            _knee_line(n, z, base, th, rng, repeat)


def bench_knee_wide(repeat):
    # the reference core's refits: about 25 base columns, column-major
    rng = np.random.default_rng(2)
    n = 150_000
    t = np.linspace(0.0, 30.0, n)
    z = 5.0 + 5.0 * np.sin(2 * np.pi * 0.5 * t) * np.exp(-t / 20.0)
    cols = [np.sin(2 * np.pi * f * t + p) for f, p in zip(rng.uniform(0.1, 5.0, 23), rng.uniform(0, 6, 23))]
    base = np.column_stack([z / 10] + cols + [np.ones(n)])
    _knee_line(n, z, base, np.array([7.0, 0.3]), rng, repeat, f"{base.shape[1]} base columns; ")


def _reference_case():
    """The diagnosis's reference (16 plays, degree 6, "both") on 1.5e5 samples: (u, dt, ref, theta)."""
    dt = 2e-4
    t = np.arange(150_000) * dt
    u = 60.0 + 50.0 * np.sin(2 * np.pi * 3 * t) * np.exp(-t / 10.0) + 5.0 * np.sin(2 * np.pi * 17 * t)
    ref = ReferenceHysteresis(rate="both", initial="ascended", degree=5, level=6, u_range=(0.0, 120.0))
    return u, dt, ref, (1e-5, 0.6)


def bench_combinations(repeat):
    u, dt, ref, theta = _reference_case()
    rng = np.random.default_rng(3)
    keep = np.zeros(ref.n_columns, dtype=bool)
    keep[rng.choice(ref.n_play_columns, 44, replace=False)] = True
    keep[ref.n_play_columns:] = True
    B = rng.standard_normal((int(keep.sum()), 24))
    want = ref.columns(u, dt, theta, keep=keep) @ B
    got = ref.columns(u, dt, theta, keep=keep, basis=B)
    t0 = _best(lambda: ref.columns(u, dt, theta, keep=keep) @ B, repeat)
    t1 = _best(lambda: ref.columns(u, dt, theta, keep=keep, basis=B), repeat)
    print(f"reference combinations, {u.size} samples, {int(keep.sum())} kept columns, {B.shape[1]} "
          f"combinations: kept columns @ basis {1e3 * t0:.1f} ms, summed in the kernel {1e3 * t1:.1f} ms, "
          f"{t0 / t1:.2f}x (largest difference {np.abs(got - want).max() / np.abs(want).max():.1e} "
          f"of the largest entry; load {os.getloadavg()[0]:.1f})")


def bench_columns(repeat):
    u, dt, ref, theta = _reference_case()
    keep = np.random.default_rng(1).random(ref.n_columns) < 0.25
    whole = ref.columns(u, dt, theta)[:, keep]
    assert np.array_equal(whole, ref.columns(u, dt, theta, keep=keep)), "kept columns differ"
    t0 = _best(lambda: ref.columns(u, dt, theta)[:, keep], repeat)
    t1 = _best(lambda: ref.columns(u, dt, theta, keep=keep), repeat)
    print(f"reference columns, {u.size} samples, {int(keep.sum())} of {ref.n_columns} kept: whole + copy "
          f"{1e3 * t0:.1f} ms, kept only {1e3 * t1:.1f} ms, {t0 / t1:.2f}x (equal bit for bit; "
          f"load {os.getloadavg()[0]:.1f})")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=10, help="timed runs of each (the best is printed)")
    ns = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.1f}, {os.cpu_count()} cores")
    bench_knee(ns.repeat)
    bench_knee_wide(max(2, ns.repeat // 3))
    bench_columns(max(2, ns.repeat // 3))
    bench_combinations(max(2, ns.repeat // 3))


if __name__ == "__main__":
    main()
