"""Reading records and models for every command, with one set of defaults.

Every command that reads measured records goes through :func:`read_records`,
so the options (and what they default to) are the same everywhere: columns
mapped by name or position, header detected, delimiter sniffed, units scaled,
irregular time stamps resampled, implausible units refused (unless
``--no-unit-check``), and the sensor offset at rest before the drive starts
removed unless ``--keep-offset``. What the reader did is reported on stderr.
"""
from __future__ import annotations

import os
import sys

__all__ = ["CLIError", "add_record_arguments", "read_records", "load_model", "out_path", "finite_output",
           "first_wild", "OUTPUT_MAX", "CSV_FORMAT", "say"]

#: What a record file looks like; shown in the help of every command that reads one.
CSV_FORMAT = (
    "Records: delimited text (comma, semicolon, tab or whitespace, detected), one sample per row, with "
    "columns t [s], u [V] and y [µm] (measured displacement), or t and Hd [µm] for a desired trajectory; "
    "other columns are ignored. Columns are found by header name (t, u, y, Hd; a unit suffix such as "
    "'t [s]' is ignored) or mapped with --columns t=COL,u=COL,y=COL (COL a header name or a 1-based "
    "position); a file without a header row needs --columns with positions (--no-header if its first row "
    "could be read as names). Other units: --time-unit ms|us, --u-scale, --y-scale. Time steps within "
    "0.1 % of the median step count as uniform; larger jitter or irregular stamps are resampled onto the "
    "median step (linear interpolation, reported). Magnitudes that suggest other units (|u| > 1000 V, "
    "y range > 1000 µm or < 0.001 µm, step < 1 µs or > 1 s, record longer than 1 h) are refused unless "
    "--no-unit-check. A record need not start at rest: the tools detect it and say how they handled it.")


class CLIError(Exception):
    """A user error, reported as one line on stderr with exit code 2."""


def say(msg: str) -> None:
    """A report line on stderr (what was read, done or written besides the result)."""
    sys.stderr.write(msg + "\n")  # one write: a line is never cut by Ctrl-C
    sys.stderr.flush()


def _factor(text):
    import argparse

    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (v == v and abs(v) != float("inf") and v != 0):
        raise argparse.ArgumentTypeError(f"{text!r}: need a finite non-zero factor")
    return v


def add_record_arguments(p, offset: bool = True, y: bool | None = None) -> None:
    """The record-reading options of a command (`offset`: it reads measured
    displacements; `y`: it reads displacements at all, default `offset`).

    Also sets the command's epilog to :data:`CSV_FORMAT` when it has none.
    """
    g = p.add_argument_group("reading records (CSV format below)")
    g.add_argument("--columns", metavar="t=COL,u=COL,y=COL",
                   help="which column is which: COL a header name or a 1-based position (default: the "
                        "columns named t, u, y, Hd)")
    g.add_argument("--no-header", dest="header", action="store_const", const=False, default=None,
                   help="the first row is data, not names (default: detected; a row of numbers is data)")
    g.add_argument("--delimiter", choices=("comma", "semicolon", "tab", "space"),
                   help="field delimiter (default: detected)")
    g.add_argument("--time-unit", choices=("s", "ms", "us"), default="s", help="unit of the time column")
    g.add_argument("--u-scale", type=_factor, default=1.0, metavar="F",
                   help="multiply u by F to get V (0.001 for a column in mV)")
    if offset if y is None else y:
        g.add_argument("--y-scale", type=_factor, default=1.0, metavar="F",
                       help="multiply y (and Hd) by F to get µm (0.001 for nm, 1000 for mm)")
    g.add_argument("--resample", action="store_true",
                   help="always interpolate onto the median time step (default: only when a step deviates "
                        "from it by more than 0.1 %%)")
    g.add_argument("--no-unit-check", dest="unit_check", action="store_const", const="off",
                   help="use magnitudes that look like other units (mV, nm, ms) as they are")
    if offset:
        g.add_argument("--keep-offset", action="store_true",
                       help="keep the sensor offset at rest (by default the mean y over the samples before "
                            "the drive starts is removed from each record)")
    if p.epilog is None:
        p.epilog = CSV_FORMAT


_DELIMS = {"comma": ",", "semicolon": ";", "tab": "\t", "space": " "}


def reader_options(ns) -> dict:
    """Keyword arguments of :func:`fonbw.io.read_record` from parsed options."""
    g = lambda k, d=None: getattr(ns, k, d) if ns is not None else d
    return dict(columns=g("columns"), header=g("header"), delimiter=_DELIMS.get(g("delimiter")),
                u_scale=g("u_scale", 1.0), y_scale=g("y_scale", 1.0), time_unit=g("time_unit", "s"),
                resample=True if g("resample") else None, unit_check=g("unit_check") or "error")


def read_records(paths, ns=None, need=("u", "y"), offsets=False):
    """Read and check the records at `paths` as the options `ns` say.

    Parameters
    ----------
    paths : sequence of path-like
        CSV files (:data:`CSV_FORMAT`).
    ns : argparse.Namespace, optional
        The command's parsed options (:func:`add_record_arguments`).
    need : tuple of str
        Columns required besides ``t``.
    offsets : bool
        Also return the offset removed from each record [µm].

    Returns
    -------
    list of fonbw.io.Record
        One per file, offsets at rest removed from y unless ``--keep-offset``;
        each note of the reader and each removal is reported on stderr.
    list of float
        With `offsets`: the offset removed from each [µm] (0 if none).
    """
    from ..io import read_record, zero_at_rest

    opts = reader_options(ns)
    recs = []
    for p in paths:
        r = read_record(p, need=need, **opts)
        for note in r.notes:
            say(f"{r.path}: {note}")
        recs.append(r)
    if "y" not in need or getattr(ns, "keep_offset", False):
        return (recs, [0.0] * len(recs)) if offsets else recs
    out, y0s = [], []
    for r in recs:
        r2, y0 = zero_at_rest(r)
        if y0:
            say(f"{r.path}: removed the offset at rest, {y0:.4g} µm")
        out.append(r2)
        y0s.append(y0)
    return (out, y0s) if offsets else out


def load_model(path):
    """A saved model (any kind); a bad file raises a one-line error."""
    from ..hysteresis import load_model as _load

    return _load(path)


#: Largest model output [µm] the commands write or score: a kilometre, far past any
#: stage, and far below where squaring it for an RMS overflows.
OUTPUT_MAX = 1e9


def finite_output(y, model, path, t):
    """Refuse (:class:`CLIError`) a model output `y` [µm] at times `t` [s] on
    the record `path` that is not finite or beyond :data:`OUTPUT_MAX`: the
    model file `model` diverges on that input, and a file of NaN or an RMS of
    inf with exit code 0 would pass for a result."""
    import numpy as np

    k = first_wild(y)
    if k is not None:
        what = "is not finite" if not np.isfinite(y[k]) else f"reaches {y[k]:.3g} µm"
        raise CLIError(f"{model}: the model's output on {path} {what} at sample {k} "
                       f"(t = {t[k]:.6g} s): it diverges on this input; check its parameters")


def first_wild(y):
    """Index of the first sample of `y` that is not finite or beyond
    :data:`OUTPUT_MAX` in magnitude, or None."""
    import numpy as np

    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(np.asarray(y, dtype=float)) <= OUTPUT_MAX)
    return int(np.argmax(bad)) if bad.any() else None


def _same_file(a, b):
    """Whether paths `a` and `b` name one file (relative, through links, or hard-linked)."""
    a, b = os.fspath(a), os.fspath(b)
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist yet
        return False


def out_path(path, inputs=()):
    """`path`, once it is known to be writable, checked before long work starts.

    Refused (:class:`CLIError`): an empty path, an existing directory, a
    folder that does not exist or cannot be written in (tried with a file
    that is removed at once), and a path that names one of `inputs` (the
    files the command reads or its other outputs), which the output would
    replace.
    """
    import tempfile

    path = os.fspath(path)
    if not path.strip():
        raise CLIError("the output path is empty")
    if os.path.isdir(path):
        raise CLIError(f"{path}: is a directory; give a file name for the output")
    d = os.path.dirname(os.path.abspath(path))
    if os.path.exists(d) and not os.path.isdir(d):
        raise CLIError(f"{path}: {d} is a file, not a folder")
    if not os.path.isdir(d):
        raise CLIError(f"{path}: output directory {d} does not exist")
    same = next((os.fspath(q) for q in inputs if q and _same_file(q, path)), None)
    if same is not None:
        raise CLIError(f"{path}: is also {same}, which this command reads or writes; write the output elsewhere")
    try:
        with tempfile.NamedTemporaryFile(dir=d, prefix=".fonbw-write-check-"):
            pass
    except OSError as exc:
        raise CLIError(f"{path}: cannot write in {d}: {exc.strerror or exc}") from None
    return path
