"""Logger files as they come: column mapping, no header, delimiters, units,
jittered time stamps; every refusal names file, row and reason, and exits 2
from the command line."""
import warnings

import numpy as np
import pytest

import fonbw
from fonbw.io import DataError, UnitWarning, read_record

from cli_process import run

N = 400
DT = 2e-4


def signals(jitter=0.0, seed=0):
    rng = np.random.default_rng(seed)
    k = np.arange(N)
    t = 3.0 + k * DT + jitter * DT * rng.standard_normal(N)
    u = 150 * np.sin(2 * np.pi * 5 * k * DT)
    return t, u, 0.1 * u + 2.0


def write(path, rows, header=None, delim=",", decimal="."):
    with open(path, "w", encoding="utf-8") as fh:
        if header is not None:
            fh.write(delim.join(header) + "\n")
        for row in rows:
            fh.write(delim.join(f"{v:.9g}".replace(".", decimal) for v in row) + "\n")
    return path


def raw_rows(t, u, y, u_scale=1.0, t_scale=1.0):
    return [(i, t[i] * t_scale, y[i], u[i] * u_scale) for i in range(N)]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    p = tmp_path_factory.mktemp("m") / "model.json"
    fonbw.FONBW(ku=[0.1, 0, 0], kh=1.0, rho=0.01, sigma=1.0, n=1.5, lam1=0.9, lam2=0.9).save(p)
    return p


@pytest.mark.parametrize("delim, decimal", [(",", "."), (";", ","), (";", "."), ("\t", "."), ("   ", ".")])
def test_delimiters_are_sniffed(tmp_path, delim, decimal):
    t, u, y = signals()
    p = write(tmp_path / "r.txt", raw_rows(t, u, y), ["index", "time", "displacement", "voltage"], delim, decimal)
    r = read_record(p, columns="t=time,u=voltage,y=displacement")
    assert np.allclose(r.u, u, atol=1e-5) and np.allclose(r.y, y, atol=1e-6) and r.dt == pytest.approx(DT)
    r2 = fonbw.read_record(p, columns={"t": 2, "u": 4, "y": 3})
    assert np.array_equal(r.u, r2.u)


def test_no_header_positions_and_odd_header(tmp_path):
    t, u, y = signals()
    p = write(tmp_path / "raw.csv", raw_rows(t, u, y))
    r = read_record(p, columns="t=2,u=4,y=3")
    assert "no header row (row 1 is data)" in r.notes and r.n == N
    assert np.array_equal(r.u, read_record(p, columns="t=2,u=4,y=3", header=False).u)
    with pytest.raises(DataError) as ei:
        read_record(p)
    assert str(ei.value) == (f"{p}: row 1: the file has no header row (row 1 is data: 4 fields '0', '3', '2', '0'); "
                             "say which column is which with --columns t=COL,u=COL,y=COL (COL a 1-based position)")
    odd = write(tmp_path / "odd.csv", raw_rows(t, u, y), ["", "Zeit [s]", "Weg [µm]", "Spannung [V]"])
    r = read_record(odd, columns="t=Zeit,u=Spannung,y=Weg")
    assert np.allclose(r.u, u, atol=1e-5)
    with pytest.raises(DataError) as ei:
        read_record(odd)
    assert str(ei.value) == (f"{odd}: row 1: missing column(s) 't', 'u', 'y'; header has '', 'Zeit [s]', "
                             "'Weg [µm]', 'Spannung [V]'; map them with --columns 't=Zeit [s],u=Spannung [V],y=Weg [µm]'")
    # the hint, as a shell splits it, reads the file
    import shlex

    flag, mapping = shlex.split(str(ei.value).rsplit("map them with ", 1)[1])
    assert flag == "--columns" and np.array_equal(read_record(odd, columns=mapping).u, r.u)
    # cmd.exe passes single quotes on: on Windows the hint takes double
    # quotes, also without a space (cmd.exe would split at the &)
    from fonbw.reader import _shell_quote, _suggest

    assert _shell_quote(mapping, nt=True) == '"t=Zeit [s],u=Spannung [V],y=Weg [µm]"'
    assert _shell_quote("u=A&B", nt=True) == '"u=A&B"' and _shell_quote("u=A&B", nt=False) == "'u=A&B'"
    # names double quotes cannot carry (a backslash before the closing quote,
    # cmd's %) are given by position
    hint = _suggest(["", "Zeit [s\\]", "Weg [%]", "Spannung [V]"], ["t", "u", "y"])
    assert hint.endswith("--columns " + _shell_quote("t=2,u=Spannung [V],y=3"))


def test_units_are_scaled_and_implausible_ones_flagged(tmp_path):
    t, u, y = signals()
    p = write(tmp_path / "mv.csv", raw_rows(t, u, y, u_scale=1000.0, t_scale=1000.0), ["i", "t", "y", "u"])
    with pytest.warns(UnitWarning, match=r"\|u\| reaches 150000 V \(> 1000 V\)"):
        read_record(p)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = read_record(p, u_scale=1e-3, time_unit="ms")
    assert np.allclose(r.u, u, atol=1e-5) and r.dt == pytest.approx(DT)
    assert "column u multiplied by 0.001" in r.notes and "column t multiplied by 0.001 (time in ms)" in r.notes


def test_jittered_time_is_resampled_and_reported(tmp_path):
    t, u, y = signals(jitter=5e-4)  # 0.05 % RMS of the step
    p = write(tmp_path / "j.csv", [(t[i], u[i], y[i]) for i in range(N)], ["t", "u", "y"])
    r = read_record(p)
    assert np.allclose(np.diff(r.t), r.dt, rtol=1e-9, atol=0) and r.dt == pytest.approx(DT, rel=1e-3)
    (note,) = r.notes
    assert note.startswith(f"resampled onto a uniform step of {r.dt:.10g} s (the median step): steps deviated")
    assert "samples interpolated linearly" in note
    assert np.max(np.abs(r.u - 150 * np.sin(2 * np.pi * 5 * (r.t - 3.0)))) < 0.1  # 150 V · 2π·5 Hz · jitter


@pytest.mark.parametrize("make, flags, message", [
    (lambda t, u, y: raw_rows(t, u, y), (), "{p}: row 1: the file has no header row (row 1 is data: 4 fields "
     "'0', '3', '2', '0'); say which column is which with --columns t=COL,u=COL,y=COL (COL a 1-based position)"),
    (lambda t, u, y: raw_rows(t, u, y, u_scale=1000.0), ("--columns", "t=2,u=4,y=3"),
     "{p}: implausible units: |u| reaches 150000 V (> 1000 V); if the column is in mV, scale it with "
     "--u-scale 0.001 (or --no-unit-check to use the values as they are)"),
    (lambda t, u, y: [(r[0], r[1], r[2] * 1000, r[3]) for r in raw_rows(t, u, y)], ("--columns", "t=2,u=4,y=3"),
     "{p}: implausible units: y spans 15000 µm (> 1000 µm); if the column is in nm, scale it with "
     "--y-scale 0.001 (or --no-unit-check to use the values as they are)"),
    (lambda t, u, y: raw_rows(t, u, y, t_scale=1e4), ("--columns", "t=2,u=4,y=3"),
     "{p}: implausible units: the time step is 2 s over 798 s (more than 1 s or 3600 s); if time is in ms, "
     "pass --time-unit ms (or --no-unit-check to use the values as they are)"),
    (lambda t, u, y: raw_rows(t, u, y), ("--columns", "t=2,u=9,y=3"),
     "{p}: row 1: column 'u' mapped to position 9, but the row has 4 field(s)"),
    (lambda t, u, y: raw_rows(t, u, y), ("--columns", "t=2,v=4,y=3"),
     "--columns: unknown column 'v'; the columns are t, u, y, Hd"),
])
def test_bad_logger_files_exit_2_with_the_exact_message(tmp_path, model, make, flags, message):
    t, u, y = signals()
    p = write(tmp_path / "raw.csv", make(t, u, y))
    r = run("validate", model, p, *flags)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr == f"fonbw validate: error: {message.format(p=p)}\n"


def test_cli_reads_a_semicolon_file_in_mv_and_ms(tmp_path, model):
    t, u, y = signals(jitter=5e-4)
    p = write(tmp_path / "r.csv", raw_rows(t, u, y, u_scale=1000.0, t_scale=1000.0), delim=";", decimal=",")
    r = run("validate", model, p, "--columns", "t=2,u=4,y=3", "--u-scale", "0.001", "--time-unit", "ms")
    assert r.returncode == 0, r.stderr
    for note in ("delimiter semicolon (detected)", "no header row (row 1 is data)", "column u multiplied by 0.001",
                 "column t multiplied by 0.001 (time in ms)", "resampled onto a uniform step of"):
        assert f"{p}: {note}" in r.stderr
