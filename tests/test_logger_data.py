"""Real-logger-like data through the command line: jittered time stamps, bipolar
±150 V drive, a sensor offset at rest before the drive starts, noise, drift."""
import json

import numpy as np
import pytest

from fonbw.bench import Bench
from fonbw.signals import bipolar_input
from fonbw.io import read_record, rest_offset, write_csv

from cli_process import run


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


def write_public_like(d, seed=7, fs=5000.0):
    """A stacked-piezo record as a logger writes it, split in two halves.

    ±150 V, 1 Hz sine for 6 s after 0.5 s at 0 V, 5 kHz, on the bipolar bench
    (creep, amplifier, sensor dynamics, drift, noise, quantization); the sensor
    reads -1.6 µm at rest; time stamps start at 12.3456 s with 0.05 % RMS
    jitter. Semicolon-delimited raw columns index;time;displacement;voltage.
    The first half has no header; the second starts mid-drive at -118 V on the
    way down and has an odd header (';time [s];disp [um];U [V]').
    """
    lb = Bench.bipolar_logger(seed=seed, fs=fs)
    rec = lb.logger_record(bipolar_input(fs=fs, T=6.0, f=1.0)[1], "stack", jitter=5e-4, offset=-1.6)
    k = np.arange(rec.n // 2 - 3000, rec.n // 2 + 3000)
    k = k[np.diff(rec.u)[k] < 0]
    split = int(k[np.argmin(np.abs(rec.u[k] + 118))])

    def dump(path, lo, hi, header):
        with open(path, "w", encoding="utf-8") as fh:
            if header:
                fh.write(header + "\n")
            for i in range(lo, hi):
                fh.write(f"{i};{rec.t[i]:.7f};{rec.y[i]:.7f};{rec.u[i]:.5f}\n")

    dump(d / "first.csv", 0, split, None)
    dump(d / "second.csv", split, rec.n, ";time [s];disp [um];U [V]")
    return d / "first.csv", d / "second.csv"


@pytest.mark.slow
def test_public_like_record_split_in_halves(tmp_path):
    first, second = write_public_like(tmp_path)
    cols = ("--columns", "t=2,u=4,y=3")
    r = run("identify", first, *cols, "-o", tmp_path / "m.json", "--max-evals", 1500, "-q",
            "--plot", tmp_path / "fit.png")
    assert r.returncode == 0, r.stderr
    for said in ("delimiter semicolon (detected)", "no header row (row 1 is data)",
                 "resampled onto a uniform step of 0.0002 s", "removed the offset at rest"):
        assert f"{first}: {said}" in r.stderr
    assert r.stdout.startswith(f"wrote {tmp_path / 'm.json'}: fonbw model")
    assert (tmp_path / "fit.png").read_bytes()[:4] == b"\x89PNG"
    alone = run("validate", tmp_path / "m.json", second, *cols, "--json")
    chained = run("validate", tmp_path / "m.json", second, *cols, "--json", "--history", first)
    assert alone.returncode == 0 and chained.returncode == 0, alone.stderr + chained.stderr
    a, c = json.loads(alone.stdout), json.loads(chained.stdout)
    print(f"public-like record: second half alone {a['rms_percent']:.3f} % of range "
          f"(burn-in {a['burn_in_s']:.3f} s), after the first half {c['rms_percent']:.3f} %")
    assert a["at_rest"] is False and a["burn_in_s"] > 0.1 and a["offset_um"] is not None
    assert c["history"] == str(first) and c["burn_in_s"] == 0
    assert a["rms_percent"] <= 1.0 and c["rms_percent"] <= 1.0
    assert a["rms_percent"] <= 1.2 * c["rms_percent"]
    text = run("validate", tmp_path / "m.json", second, *cols)
    assert "scored after a burn-in of" in text.stdout
