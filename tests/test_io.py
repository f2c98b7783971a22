"""CSV records: every refusal names the file, the row and the reason."""
import os

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from fonbw.io import DataError, Record, atomic_open, read_record, write_csv


def _write(path, text):
    path.write_text(text, encoding="utf-8")
    return path


def _good(n=20, dt=1e-4, jitter=0.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt + rng.uniform(-jitter, jitter, n) * dt
    return t, np.linspace(0, 10, n), np.linspace(0, 2, n)


def test_round_trip_is_exact(tmp_path):
    t, u, y = _good(50)
    u = u + np.pi * 1e-9
    write_csv(tmp_path / "r.csv", {"t": t, "u": u, "y": y, "extra": y * 2})
    r = read_record(tmp_path / "r.csv")
    assert np.array_equal(r.t, t) and np.array_equal(r.u, u) and np.array_equal(r.y, y)
    assert r.dt == pytest.approx(1e-4, rel=1e-12)


def test_logger_jitter_is_tolerated(tmp_path):
    t, u, y = _good(200, jitter=2e-4)
    write_csv(tmp_path / "j.csv", {"t": t, "u": u, "y": y})
    r = read_record(tmp_path / "j.csv")
    assert r.dt == pytest.approx(1e-4, rel=1e-3)


@pytest.mark.parametrize("text, row, reason", [
    ("t,u\n0,1\n", 1, "missing column\\(s\\) 'y'"),
    ("t,u,y\n" + "".join(f"{i*1e-3},1,2\n" for i in range(5)) + "0.005,nan,2\n" + "".join(f"{i*1e-3},1,2\n" for i in range(6, 12)), 7, "not finite"),
    ("t,u,y\n" + "".join(f"{i*1e-3},1,2\n" for i in range(5)) + "0.005,abc,2\n" + "".join(f"{i*1e-3},1,2\n" for i in range(6, 12)), 7, "'abc' is not a number"),
    ("t,u,y\n" + "".join(f"{i*1e-3},1,2\n" for i in range(5)) + "0.003,1,2\n" + "".join(f"{i*1e-3},1,2\n" for i in range(6, 12)), 7, "does not increase"),
    ("t,u,y\n" + "".join(f"{i*1e-3},1,2\n" for i in range(5)) + "0.0112,1,2\n" + "".join(f"{i*1e-3},1,2\n" for i in range(12, 18)), 7, "a gap of 0.0072 s \\(7.2 steps of 0.001 s\\)"),
    ("t,u,y\n" + "".join(f"{i*1e-3},1,2\n" for i in range(4)), None, "only 4 data row"),
    ("t,u,y\n" + "".join(f"{i*1e-3},1,2\n" for i in range(5)) + "0.005,1\n" + "".join(f"{i*1e-3},1,2\n" for i in range(6, 12)), 7, "column 'y' is missing"),
    ("", None, "empty file"),
])
def test_refusals_name_file_row_reason(tmp_path, text, row, reason):
    p = _write(tmp_path / "bad.csv", text)
    with pytest.raises(DataError, match=reason) as ei:
        read_record(p)
    msg = str(ei.value)
    assert msg.startswith(str(p))
    if row is not None:
        assert f"row {row}:" in msg


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match="nope.csv: cannot open"):
        read_record(tmp_path / "nope.csv")


def test_trajectory_columns(tmp_path):
    t = np.arange(10) * 1e-3
    write_csv(tmp_path / "h.csv", {"t": t, "Hd": np.sin(t)})
    r = read_record(tmp_path / "h.csv", need=("Hd",))
    assert np.array_equal(r.hd, np.sin(t)) and r.u is None
    with pytest.raises(DataError, match="missing column"):
        read_record(tmp_path / "h.csv")


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    p = tmp_path / "out.csv"
    p.write_text("old\n")
    with pytest.raises(KeyboardInterrupt):
        with atomic_open(p) as fh:
            fh.write("half")
            raise KeyboardInterrupt
    assert p.read_text() == "old\n"
    assert os.listdir(tmp_path) == ["out.csv"]
    with pytest.raises(ValueError, match="different lengths"):
        write_csv(p, {"a": [1, 2], "b": [1]})
    assert p.read_text() == "old\n"


def test_record_from_arrays():
    r = Record.from_arrays(u=[1, 2, 3], y=[0, 1, 2], dt=0.5)
    assert np.array_equal(r.t, [0, 0.5, 1.0]) and r.n == 3


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e12, max_value=1e12), min_size=8, max_size=40))
def test_any_finite_values_round_trip(tmp_path_factory, vals):
    p = tmp_path_factory.mktemp("rt") / "v.csv"
    t = np.arange(len(vals)) * 1e-3
    write_csv(p, {"t": t, "u": vals, "y": vals})
    r = read_record(p, unit_check="off")
    assert np.array_equal(r.u, np.asarray(vals, dtype=float))


def test_non_uniform_sampling_is_refused_without_resampling(tmp_path):
    text = "t,u,y\n" + "".join(f"{i*1e-3},1,2\n" for i in range(5)) + "0.0052,1,2\n" + \
        "".join(f"{i*1e-3},1,2\n" for i in range(6, 12))
    p = _write(tmp_path / "j.csv", text)
    with pytest.raises(DataError) as ei:
        read_record(p, resample=False)
    assert str(ei.value) == (f"{p}: row 7: non-uniform sampling: step 0.0012 s differs from the median step "
                             "0.001 s by 20 % (tolerance 0.1 %); resample it onto the median step (--resample)")
    r = read_record(p)  # by default: resampled, and said so
    assert r.dt == pytest.approx(1e-3) and np.allclose(np.diff(r.t), 1e-3)
    assert r.notes[-1].startswith("resampled onto a uniform step of 0.001 s (the median step): steps deviated "
                                  "from it by up to 20 %")


def test_messages_show_plain_numbers(tmp_path):
    p = _write(tmp_path / "b.csv", "t,u,y\n" + "".join(f"{i*0.2000000110},1,2\n" for i in range(5))
               + "0.200000011,1,2\n" + "".join(f"{i*0.2},1,2\n" for i in range(6, 12)))
    with pytest.raises(DataError) as ei:
        read_record(p, unit_check="off")
    assert "np.float64" not in str(ei.value)
    assert str(ei.value) == f"{p}: row 7: time 0.200000011 does not increase (previous 0.800000044)"


def test_files_get_the_umask_mode(tmp_path):
    for mask, mode in ((0o022, 0o644), (0o077, 0o600), (0o002, 0o664)):
        old = os.umask(mask)
        try:
            p = tmp_path / f"m{mode:o}.csv"
            write_csv(p, {"t": [0.0, 1.0]})
        finally:
            os.umask(old)
        assert p.stat().st_mode & 0o777 == mode
