"""Reading and writing the CSV records every command shares.

A record is a CSV file with a header row and the columns ``t`` [s], ``u`` [V]
and ``y`` [µm] (a measured experiment), or ``t`` and ``Hd`` [µm] (a desired
trajectory). Other columns are ignored. Sampling must be uniform; the small
timestamp jitter of real data loggers (``jitter_tol``, relative to the median
step) is tolerated and the record is then treated as sampled at the median
step. Anything else is refused with a :class:`DataError` that names the file,
the row and the reason.

Writing is atomic: the data go to a temporary file beside the target, which
is renamed over it only once complete, so an interrupted run never leaves a
half-written output.
"""
from __future__ import annotations

import contextlib
import csv
import dataclasses
import math
import os
import tempfile
from typing import Iterable, Mapping

import numpy as np

__all__ = ["DataError", "Record", "read_record", "write_csv", "atomic_open", "rest_offset", "zero_at_rest",
           "as_signal", "decimate"]

#: Minimum number of samples a record must hold to be usable.
MIN_SAMPLES = 8


class DataError(ValueError):
    """Bad input data; the message names the file, the row and the reason."""


@dataclasses.dataclass
class Record:
    """One uniformly sampled experiment.

    Attributes
    ----------
    t : ndarray
        Time stamps [s] as read (jitter kept).
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
    """

    t: np.ndarray
    u: np.ndarray | None
    y: np.ndarray | None
    dt: float
    path: str = "<memory>"
    hd: np.ndarray | None = None

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
                  path=rec.path + f" (every {q}th sample)", hd=keep(rec.hd))


def read_record(path, need: Iterable[str] = ("u", "y"), jitter_tol: float = 1e-3) -> Record:
    """Read a CSV record and check it.

    Parameters
    ----------
    path : str or PathLike
        CSV file with a header row.
    need : iterable of str
        Columns required besides ``t`` (``("u", "y")`` for experiments,
        ``("Hd",)`` for trajectories, ``("u",)`` for simulation inputs).
    jitter_tol : float
        Largest tolerated deviation of a time step from the median step,
        relative to the median step.

    Returns
    -------
    Record

    Raises
    ------
    DataError
        Missing file or column, a value that is not a finite number, fewer
        than ``MIN_SAMPLES`` rows, non-increasing or non-uniform time.
    """
    path = os.fspath(path)
    need = ["t"] + [c for c in need if c != "t"]
    cols = _read_columns(path, need)
    n = len(cols["t"])
    if n < MIN_SAMPLES:
        raise DataError(f"{path}: only {n} data row(s); at least {MIN_SAMPLES} are needed")
    t = np.asarray(cols["t"], dtype=float)
    dt = _uniform_step(path, t, jitter_tol)
    arr = lambda c: np.asarray(cols[c], dtype=float) if c in cols else None
    return Record(t=t, u=arr("u"), y=arr("y"), dt=dt, path=path, hd=arr("Hd"))


def _read_columns(path, need) -> dict:
    """The columns `need` (required: every value a finite number) and any of u,
    y, Hd present (optional: unreadable values become NaN) as lists of floats."""
    try:
        fh = open(path, newline="", encoding="utf-8-sig")
    except OSError as exc:
        raise DataError(f"{path}: cannot open: {exc.strerror or exc}") from None
    with fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration:
            raise DataError(f"{path}: empty file, expected a header row with columns {', '.join(need)}") from None
        except (csv.Error, UnicodeDecodeError) as exc:
            raise DataError(f"{path}: row 1: not readable as CSV ({exc})") from None
        names = [h.strip() for h in header]
        missing = [c for c in need if c not in names]
        if missing:
            raise DataError(
                f"{path}: row 1: missing column(s) {', '.join(repr(c) for c in missing)}; "
                f"header has {', '.join(repr(c) for c in names) or 'nothing'}"
            )
        idx = {c: names.index(c) for c in need}
        optional = {c: names.index(c) for c in ("u", "y", "Hd") if c in names and c not in idx}
        try:
            return _parse_rows(path, reader, idx, optional)
        except (csv.Error, UnicodeDecodeError) as exc:
            raise DataError(f"{path}: row {reader.line_num}: not readable as CSV ({exc})") from None


def _parse_rows(path, reader, idx, optional) -> dict:
    cols = {c: [] for c in list(idx) + list(optional)}
    allidx = {**idx, **optional}
    for rowno, row in enumerate(reader, start=2):
        if not row or all(not f.strip() for f in row):
            continue
        for c, j in allidx.items():
            if j >= len(row):
                if c in idx:
                    raise DataError(f"{path}: row {rowno}: column {c!r} is missing (row has {len(row)} fields)")
                cols[c].append(math.nan)
                continue
            field = row[j].strip()
            try:
                v = float(field)
            except ValueError:
                if c in idx:
                    raise DataError(f"{path}: row {rowno}: column {c!r}: {field!r} is not a number") from None
                v = math.nan
            if not math.isfinite(v) and c in idx:
                raise DataError(f"{path}: row {rowno}: column {c!r}: value {field!r} is not finite")
            cols[c].append(v)
    return cols


def _uniform_step(path, t, jitter_tol) -> float:
    """The median time step [s], once every step is positive and within
    `jitter_tol` (relative) of it; rows are named one-based with the header."""
    dts = np.diff(t)
    bad = np.flatnonzero(dts <= 0)
    if bad.size:
        r = int(bad[0]) + 3  # +1 header, +1 one-based, +1 second sample of the pair
        raise DataError(f"{path}: row {r}: time {t[bad[0] + 1]!r} does not increase (previous {t[bad[0]]!r})")
    dt = float(np.median(dts))
    dev = np.abs(dts - dt) / dt
    bad = np.flatnonzero(dev > jitter_tol)
    if bad.size:
        r = int(bad[0]) + 3
        raise DataError(
            f"{path}: row {r}: non-uniform sampling: step {dts[bad[0]]:.6g} s differs from the median "
            f"step {dt:.6g} s by {100 * dev[bad[0]]:.3g} % (tolerance {100 * jitter_tol:.3g} %)"
        )
    return dt


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


@contextlib.contextmanager
def atomic_open(path, mode="w", **kw):
    """Open a temporary file beside `path` and rename it over `path` on success.

    On any exception (including KeyboardInterrupt) the temporary file is
    removed and `path` is left as it was.
    """
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=os.path.basename(path), dir=d)
    try:
        with os.fdopen(fd, mode, **kw) as fh:
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
