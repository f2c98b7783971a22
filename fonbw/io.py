"""Reading and writing the CSV records every command shares.

A record is a CSV file with the columns ``t`` [s], ``u`` [V] and ``y`` [µm]
(a measured experiment), or ``t`` and ``Hd`` [µm] (a desired trajectory).
Other columns are ignored. Real logger files are read as they are written
(:func:`read_record`): columns mapped by header name or position, with or
without a header row, any of the usual delimiters (sniffed), units scaled,
jittered or irregular time stamps resampled onto their median step (and
reported), implausible magnitudes (a file in mV, nm or ms) flagged. Anything
unusable is refused with a :class:`DataError` that names the file, the row
and the reason.

Writing is atomic: the data go to a temporary file beside the target, which
is renamed over it only once complete, so an interrupted run never leaves a
half-written output; the file gets the permissions of the user's umask, like
any file the user creates.
"""
from __future__ import annotations

import contextlib
import dataclasses
import os
import tempfile
import warnings
from typing import Iterable, Mapping

import numpy as np

from . import reader as _rd

__all__ = ["DataError", "UnitWarning", "Record", "read_record", "parse_columns", "write_csv", "atomic_open",
           "rest_offset", "zero_at_rest", "as_signal", "decimate", "jsonable", "TIME_UNITS", "LIMITS"]

#: Minimum number of samples a record must hold to be usable.
MIN_SAMPLES = 8

#: Seconds per unit of the time column.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6}

#: Plausible magnitudes of a piezo record, after scaling: largest |u| [V],
#: largest and smallest displacement range [µm], sampling step [s], duration [s].
LIMITS = {"u_max": 1000.0, "y_range_max": 1000.0, "y_range_min": 1e-3, "dt_min": 1e-6, "dt_max": 1.0,
          "duration_max": 3600.0}

#: Largest gap in the time stamps (in median steps) that resampling bridges.
MAX_GAP = 5.0

parse_columns = _rd.parse_columns


class DataError(ValueError):
    """Bad input data; the message names the file, the row and the reason."""


class UnitWarning(UserWarning):
    """A record's magnitudes suggest a unit other than V, µm and s."""


@dataclasses.dataclass
class Record:
    """One uniformly sampled experiment.

    Attributes
    ----------
    t : ndarray
        Time stamps [s] as read (jitter kept), or the uniform grid when the
        record was resampled.
    u : ndarray or None
        Actuator voltage [V].
    y : ndarray or None
        Measured displacement [µm].
    dt : float
        Sampling period [s] (median step).
    path : str
        Where it came from (``"<memory>"`` if built in code).
    hd : ndarray or None
        Desired displacement [µm] (trajectory files).
    notes : list of str
        What the reader did to the file's values (delimiter, header, unit
        scaling, resampling), one sentence each, for the user to see.
    """

    t: np.ndarray
    u: np.ndarray | None
    y: np.ndarray | None
    dt: float
    path: str = "<memory>"
    hd: np.ndarray | None = None
    notes: list = dataclasses.field(default_factory=list, repr=False, compare=False)

    @property
    def n(self) -> int:
        return len(self.t)

    @classmethod
    def from_arrays(cls, u=None, y=None, dt=1e-4, t=None, hd=None, path="<memory>"):
        """Build a record from arrays (uniform time axis made if `t` is None)."""
        ref = next(a for a in (u, y, hd) if a is not None)
        n = len(ref)
        if t is None:
            t = np.arange(n) * float(dt)
        conv = lambda a: None if a is None else np.ascontiguousarray(a, dtype=float)
        return cls(t=conv(t), u=conv(u), y=conv(y), dt=float(dt), path=path, hd=conv(hd))


def as_signal(x, what: str, empty_ok: bool = True) -> np.ndarray:
    """`x` as a contiguous 1-D float array of finite values.

    Parameters
    ----------
    x : array_like
        The samples.
    what : str
        What the signal is, with its unit, for the message (``"input u [V]"``).
    empty_ok : bool
        Whether no samples at all is acceptable.

    Raises
    ------
    ValueError
        Not 1-D (or empty when that is refused), or a sample that is NaN or infinite.
    """
    a = np.ascontiguousarray(x, dtype=float)
    if a.ndim != 1 or (a.size == 0 and not empty_ok):
        raise ValueError(f"{what} must be a {'' if empty_ok else 'non-empty '}1-D array, got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        raise ValueError(f"{what} is not finite at sample {int(bad[0])} ({float(a[bad[0]])!r}; "
                         "NaN or infinite values are refused)")
    return a


def input_range(records) -> tuple[float, float]:
    """(lowest, highest) input voltage [V] over `records` (records or input arrays)."""
    us = [np.asarray(getattr(r, "u", r)) for r in records]
    return min(float(np.min(u)) for u in us), max(float(np.max(u)) for u in us)


def decimate(rec: Record, q: int) -> Record:
    """Every q-th sample of a record (u is a zero-order-hold input; y is already
    low-pass filtered by the sensor, so no anti-alias filter is added)."""
    q = int(q)
    if q < 1:
        raise ValueError(f"decimation factor must be ≥ 1, got {q}")
    if q == 1:
        return rec
    keep = lambda a: None if a is None else a[::q]
    return Record(t=rec.t[::q], u=keep(rec.u), y=keep(rec.y), dt=rec.dt * q,
                  path=rec.path + f" (one sample in {q})", hd=keep(rec.hd))


def read_record(path, need: Iterable[str] = ("u", "y"), jitter_tol: float = 1e-3, *, columns=None,
                header: bool | None = None, delimiter: str | None = None, u_scale: float = 1.0,
                y_scale: float = 1.0, time_unit: str = "s", resample: bool | None = None,
                unit_check: str = "warn") -> Record:
    """Read a logger file and check it.

    Parameters
    ----------
    path : str or PathLike
        Delimited text file, one sample per row.
    need : iterable of str
        Columns required besides ``t`` (``("u", "y")`` for experiments,
        ``("Hd",)`` for trajectories, ``("u",)`` for simulation inputs).
    jitter_tol : float
        Largest deviation of a time step from the median step, relative to
        the median step, that is treated as uniform sampling at the median
        step without interpolation.
    columns : str or mapping, optional
        ``"t=COL,u=COL,y=COL"`` or ``{"t": COL, ...}``, COL a header name or a
        one-based position; default: columns named ``t``, ``u``, ``y``, ``Hd``.
    header : bool, optional
        Whether the first row is a header; default: detected (a row of
        numbers is data).
    delimiter : str, optional
        ``","``, ``";"``, ``"\\t"`` or ``" "`` (runs of whitespace); default: sniffed.
    u_scale, y_scale : float
        Factors to V and to µm (0.001 for a voltage column in mV; 1e-3 for y in nm).
        ``y_scale`` applies to ``Hd`` too.
    time_unit : {"s", "ms", "us"}
        Unit of the time column.
    resample : bool, optional
        True: interpolate u, y (linearly) onto the uniform grid of the median
        step; False: refuse steps beyond `jitter_tol`; None (default): resample
        only when a step is beyond `jitter_tol`. What was done is in ``notes``.
    unit_check : {"warn", "error", "off"}
        Magnitudes beyond :data:`LIMITS` issue a :class:`UnitWarning`, raise
        a :class:`DataError`, or pass.

    Returns
    -------
    Record

    Raises
    ------
    DataError
        Missing file or column, a value that is not a finite number, fewer
        than ``MIN_SAMPLES`` rows, time not increasing, a gap of more than
        ``MAX_GAP`` steps, implausible units with ``unit_check="error"``.
    """
    path = os.fspath(path)
    need = ["t"] + [c for c in need if c != "t"]
    cols, linenos, notes = _read_columns(path, need, _rd.parse_columns(columns), header, delimiter)
    n = len(cols["t"])
    if n < MIN_SAMPLES:
        raise DataError(f"{path}: only {n} data row(s); at least {MIN_SAMPLES} are needed")
    scales = _scales(u_scale, y_scale, time_unit)
    arrs = {c: np.asarray(v, dtype=float) * scales[c] for c, v in cols.items()}
    for c, f in scales.items():
        if f != 1.0 and c in arrs:
            notes.append(f"column {c} multiplied by {_rd.fmt(f)}"
                         + (f" (time in {time_unit})" if c == "t" else ""))
    t, dt, arrs = _time_base(path, arrs, linenos, jitter_tol, resample, notes)
    rec = Record(t=t, u=arrs.get("u"), y=arrs.get("y"), dt=dt, path=path, hd=arrs.get("Hd"), notes=notes)
    _check_units(rec, unit_check)
    return rec


def _scales(u_scale, y_scale, time_unit) -> dict:
    """Multipliers of each column to s, V and µm (checked)."""
    if time_unit not in TIME_UNITS:
        raise ValueError(f"time unit must be one of {', '.join(k for k in TIME_UNITS if k != 'µs')}, "
                         f"got {time_unit!r}")
    for name, v in (("u_scale", u_scale), ("y_scale", y_scale)):
        if not (np.isfinite(v) and v != 0):
            raise ValueError(f"{name} must be a finite non-zero factor, got {v!r}")
    return {"t": TIME_UNITS[time_unit], "u": float(u_scale), "y": float(y_scale), "Hd": float(y_scale)}


def _read_columns(path, need, columns, header, delimiter):
    """(columns as float lists, file line of each row, notes) of a logger file."""
    lines = _rd.read_text(path, DataError)
    notes = []
    if delimiter is None:
        delimiter = _rd.sniff_delimiter(lines)
        if delimiter != ",":
            notes.append(f"delimiter {_DELIM_NAMES[delimiter]} (detected)")
    elif delimiter not in _DELIM_NAMES:
        raise ValueError(f"delimiter must be one of {', '.join(map(repr, _DELIM_NAMES))}, got {delimiter!r}")
    rows = _rd.split_rows(lines, delimiter)
    first = next(rows, None)
    if first is None:
        raise DataError(f"{path}: empty file, expected a header row with columns {', '.join(need)}")
    idx, optional, has_header = _rd.resolve_columns(path, first, delimiter, need, columns, header, DataError)
    if not has_header:
        import itertools

        rows = itertools.chain([first], rows)
        if header is None:
            notes.append("no header row (row 1 is data)")
    cols, linenos = _rd.parse_rows(path, rows, delimiter, idx, optional, DataError)
    return cols, np.asarray(linenos), notes


_DELIM_NAMES = {",": "comma", ";": "semicolon", "\t": "tab", " ": "whitespace"}


def _time_base(path, arrs, linenos, jitter_tol, resample, notes):
    """(t, dt, columns): the median step [s], and the columns on a uniform grid
    when the steps deviate from it by more than `jitter_tol` or `resample`."""
    t = arrs["t"]
    dts = np.diff(t)
    bad = np.flatnonzero(dts <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise DataError(f"{path}: row {linenos[i]}: time {_rd.fmt(t[i])} does not increase "
                        f"(previous {_rd.fmt(t[i - 1])})")
    dt = float(np.median(dts))
    dev = np.abs(dts - dt) / dt
    worst = int(np.argmax(dev))
    if resample is None:
        resample = bool(dev[worst] > jitter_tol)
    elif not resample and dev[worst] > jitter_tol:
        raise DataError(
            f"{path}: row {linenos[worst + 1]}: non-uniform sampling: step {_rd.fmt(dts[worst])} s differs "
            f"from the median step {_rd.fmt(dt)} s by {100 * dev[worst]:.3g} % (tolerance "
            f"{100 * jitter_tol:.3g} %); resample it onto the median step (--resample)")
    if not resample:
        return t, dt, arrs
    gap = np.flatnonzero(dts > MAX_GAP * dt)
    if gap.size:
        i = int(gap[0])
        raise DataError(f"{path}: row {linenos[i + 1]}: a gap of {_rd.fmt(dts[i])} s ({dts[i] / dt:.3g} "
                        f"steps of {_rd.fmt(dt)} s) in the time stamps; split the record there")
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt * (1 + 1e-12))) + 1)
    out = {c: (np.interp(grid, t, a) if c != "t" else grid) for c, a in arrs.items()}
    k = np.clip(np.searchsorted(t, grid), 0, len(t) - 1)
    near = np.minimum(np.abs(t[k] - grid), np.abs(t[np.maximum(k - 1, 0)] - grid))
    moved = int(np.count_nonzero(near > 1e-9 * dt))
    notes.append(f"resampled onto a uniform step of {_rd.fmt(dt)} s (the median step): steps deviated from it "
                 f"by up to {100 * dev[worst]:.3g} % (RMS {100 * np.sqrt(np.mean(dev ** 2)):.3g} %); "
                 f"{moved} of {grid.size} samples interpolated linearly ({len(t)} in the file)")
    return grid, dt, out


def _check_units(rec, mode):
    """Warn about (or refuse) magnitudes that suggest mV, nm, m or ms."""
    if mode not in ("warn", "error", "off"):
        raise ValueError(f"unit_check must be 'warn', 'error' or 'off', got {mode!r}")
    if mode == "off":
        return
    L, f = LIMITS, _rd.fmt
    probs = []
    if rec.u is not None and np.nanmax(np.abs(rec.u)) > L["u_max"]:
        probs.append(f"|u| reaches {f(np.nanmax(np.abs(rec.u)))} V (> {f(L['u_max'])} V); if the column is "
                     "in mV, scale it with --u-scale 0.001")
    for c, a in (("y", rec.y), ("Hd", rec.hd)):
        if a is None:
            continue
        span = float(np.nanmax(a) - np.nanmin(a))
        if span > L["y_range_max"]:
            probs.append(f"{c} spans {f(span)} µm (> {f(L['y_range_max'])} µm); if the column is in nm, "
                         "scale it with --y-scale 0.001")
        elif 0 < span < L["y_range_min"]:
            probs.append(f"{c} spans {f(span)} µm (< {f(L['y_range_min'])} µm); if the column is in mm or m, "
                         "scale it with --y-scale 1000 or 1e6")
    if rec.dt < L["dt_min"]:
        probs.append(f"the time step is {f(rec.dt)} s (< 1 µs); if time is in µs, pass --time-unit us")
    elif rec.dt > L["dt_max"] or rec.t[-1] - rec.t[0] > L["duration_max"]:
        probs.append(f"the time step is {f(rec.dt)} s over {f(rec.t[-1] - rec.t[0])} s (more than "
                     f"{f(L['dt_max'])} s or {f(L['duration_max'])} s); if time is in ms, pass --time-unit ms")
    if not probs:
        return
    msg = f"{rec.path}: implausible units: " + "; ".join(probs)
    if mode == "error":
        raise DataError(msg + " (or --no-unit-check to use the values as they are)")
    warnings.warn(msg, UnitWarning, stacklevel=3)


#: Fewest leading samples at constant input that count as a rest segment.
MIN_REST = 10


def rest_offset(rec: Record) -> tuple[float, int]:
    """Sensor offset at rest: mean of y over the leading samples at constant u.

    Real loggers start recording before the drive and read a non-zero
    displacement at rest; the models start from H = 0 at rest. Returns
    ``(offset [µm], samples used)``, ``(0.0, 0)`` when the record does not
    start with at least ``MIN_REST`` samples at its first input value.
    """
    if rec.u is None or rec.y is None:
        return 0.0, 0
    scale = max(1.0, float(np.max(np.abs(rec.u))))
    moved = np.flatnonzero(np.abs(rec.u - rec.u[0]) > 1e-9 * scale)
    m = int(moved[0]) if moved.size else len(rec.u)
    if m < MIN_REST:
        return 0.0, 0
    return float(np.mean(rec.y[:m])), m


def zero_at_rest(rec: Record) -> tuple[Record, float]:
    """A copy of the record with its rest offset (:func:`rest_offset`) removed from y."""
    y0, _ = rest_offset(rec)
    if y0 == 0.0:
        return rec, 0.0
    return dataclasses.replace(rec, y=rec.y - y0), y0


def _umask() -> int:
    """The process's umask (read by setting it and restoring it at once)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_open(path, mode="w", **kw):
    """Open a temporary file beside `path` and rename it over `path` on success.

    On any exception (including KeyboardInterrupt) the temporary file is
    removed and `path` is left as it was. The file is created with mode
    ``0o666 & ~umask``, as :func:`open` would create it.
    """
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=os.path.basename(path), dir=d)
    try:
        # mkstemp creates the file 0600; an output is the user's file like any
        # other, so it gets the mode open() would give it (0644 under umask 022).
        with os.fdopen(fd, mode, **kw) as fh:
            os.fchmod(fh.fileno(), 0o666 & ~_umask())
            yield fh
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_csv(path, columns: Mapping[str, Iterable[float]], precision: int = 17) -> None:
    """Write equal-length columns as a CSV file with a header row, atomically.

    Parameters
    ----------
    path : str or PathLike
    columns : mapping of column name to 1-D array
    precision : int
        Significant digits (17 keeps float64 round-trips exact).
    """
    arrays = [np.asarray(v, dtype=float).ravel() for v in columns.values()]
    lens = {len(a) for a in arrays}
    if len(lens) > 1:
        raise ValueError(f"{path}: columns have different lengths {sorted(lens)}")
    data = np.column_stack(arrays) if arrays else np.empty((0, 0))
    with atomic_open(path, "w", newline="") as fh:
        fh.write(",".join(columns.keys()) + "\n")
        np.savetxt(fh, data, delimiter=",", fmt=f"%.{precision}g")


def jsonable(d, strict: bool = False):
    """`d` with numpy scalars turned into Python ones, recursively (lists for tuples).

    With `strict`, a float that is not finite becomes None, so that the result
    is strict JSON (``json.dumps(..., allow_nan=False)``): a figure that is not
    a number is null.
    """
    if isinstance(d, dict):
        return {k: jsonable(v, strict) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [jsonable(v, strict) for v in d]
    if isinstance(d, (np.bool_, bool)):
        return bool(d)
    if isinstance(d, (np.floating, float)):
        return None if strict and not np.isfinite(d) else float(d)
    if isinstance(d, np.integer):
        return int(d)
    return d
