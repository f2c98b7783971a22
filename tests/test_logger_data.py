"""Real-logger-like data through the command line: jittered time stamps, bipolar
±150 V drive, a sensor offset at rest before the drive starts, noise, drift."""
import json
import subprocess
import sys

import numpy as np
import pytest

from fonbw.bench import Bench
from fonbw.signals import bipolar_input
from fonbw.io import read_record, rest_offset, write_csv


def run(*args):
    return subprocess.run([sys.executable, "-m", "fonbw", *map(str, args)], capture_output=True, text=True,
                          timeout=900)


@pytest.fixture(scope="module")
def logger_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("logger")
    lb = Bench.bipolar_logger(seed=3, fs=5000.0)
    recs = {"train": lb.logger_record(bipolar_input(fs=5000.0, T=4.0, f=1.0)[1], "train"),
            "val": lb.logger_record(bipolar_input(fs=5000.0, T=1.0, f=5.0, amplitude=120.0)[1], "val", t0=99.0)}
    for name, r in recs.items():
        write_csv(d / f"{name}.csv", {"t": r.t, "u": r.u, "y": r.y})
    return d, recs


def test_reader_accepts_logger_files_and_finds_the_offset(logger_files):
    d, recs = logger_files
    r = read_record(d / "train.csv")
    assert np.min(r.u) < -140 and np.max(r.u) > 140
    assert r.dt == pytest.approx(2e-4, rel=1e-4)
    assert np.std(np.diff(r.t)) > 0  # the jitter survived the round trip
    y0, m = rest_offset(r)
    assert 2500 <= m <= 2502  # 0.5 s at rest at 5 kHz (+ the drive's first samples at 0 V)
    assert y0 == pytest.approx(0.8, abs=0.02)  # the bench's offset; noise 0.015 µm averages out


def test_identify_and_validate_logger_data(logger_files):
    d, recs = logger_files
    r = run("identify", d / "train.csv", "--model", "fonbw", "-o", d / "m.json", "--max-evals", 500, "-q",
            "--seed", 1)
    assert r.returncode == 0, r.stderr
    assert "removed the offset at rest" in r.stderr
    r = run("validate", d / "m.json", d / "val.csv", "--json")
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    print(f"logger data: validation RMS {res['rms']:.3f} µm = {res['rms_percent']:.2f} % of range")
    # a 5 Hz bipolar record the model never saw, with drift on the bench: a few % of range
    assert res["rms_percent"] < 6.0


def test_zero_at_rest_removes_exactly_the_rest_mean(logger_files):
    from fonbw.io import zero_at_rest

    d, recs = logger_files
    r = read_record(d / "val.csv")
    z, y0 = zero_at_rest(r)
    y0b, m = rest_offset(r)
    assert y0 == y0b and np.array_equal(z.y, r.y - y0) and np.array_equal(z.u, r.u)
    assert abs(np.mean(z.y[:m])) < 1e-12
