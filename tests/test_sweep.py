"""Closed-loop sweeps on dask (fonbw.loop.sweep): the rows from an embedded
cluster of two worker processes equal the same runs in this process, bit for
bit and in the order of the cases; bad arguments are refused at the door."""
import pytest

from fonbw.loop import run_cosim
from fonbw.loop.sweep import ROW_KEYS, grid, sweep

COMMON = {"scenario": "sine5", "T": 0.05, "master": "reference"}


def test_grid_is_the_cartesian_product_last_axis_fastest():
    assert grid(mode=["fb", "ff+fb"], bandwidth_hz=[50, 100]) == [
        {"mode": "fb", "bandwidth_hz": 50}, {"mode": "fb", "bandwidth_hz": 100},
        {"mode": "ff+fb", "bandwidth_hz": 50}, {"mode": "ff+fb", "bandwidth_hz": 100}]
    with pytest.raises(ValueError, match="needs a sequence"):
        grid(mode="fb")


def test_sweep_on_two_workers_equals_the_runs_in_process():
    cases = grid(mode=["fb", "ff+fb"], bandwidth_hz=[25.0, 100.0])
    rows = sweep(cases, n_workers=2, **COMMON)
    assert [{k: r[k] for k in c} for r, c in zip(rows, cases)] == cases
    for row, case in zip(rows, cases):
        ref = run_cosim(**COMMON, **case)
        assert row["error"] is None and ref.error is None
        for k in ROW_KEYS:
            if k != "wall_s":
                assert row[k] == getattr(ref, k), (case, k)
    # feedback alone tracks better with the wider bandwidth (a property of the loop, not of the sweep)
    fb = {r["bandwidth_hz"]: r["rms_error"] for r in rows if r["mode"] == "fb"}
    assert fb[100.0] < 0.7 * fb[25.0]


def test_sweep_refuses_unknown_arguments():
    with pytest.raises(ValueError, match=r"case 1: unknown run_cosim argument\(s\) \['bandwith_hz'\]"):
        sweep([{"mode": "fb"}, {"bandwith_hz": 10}], **COMMON)
    with pytest.raises(ValueError, match=r"^sweep: unknown run_cosim argument\(s\) \['tt'\]"):
        sweep([{"mode": "fb"}], tt=1.0)
