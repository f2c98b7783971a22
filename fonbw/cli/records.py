"""Reading records and models for every command, with one set of defaults.

Every command that reads measured records goes through :func:`read_records`,
so the options (and what they default to) are the same everywhere: the sensor
offset at rest before the drive starts is removed unless ``--keep-offset``.
"""
from __future__ import annotations

import os
import sys

__all__ = ["CLIError", "add_record_arguments", "read_records", "load_model", "out_path", "CSV_FORMAT"]

#: What a record file looks like; shown in the help of every command that reads one.
CSV_FORMAT = ("Records are CSV files with a header row: t [s] (uniform steps; logger jitter up to 0.1 % "
              "of the step is tolerated), u [V] and y [µm] (measured displacement), or t and Hd [µm] "
              "for a desired trajectory; other columns are ignored.")


class CLIError(Exception):
    """A user error, reported as one line on stderr with exit code 2."""


def add_record_arguments(p, offset: bool = True) -> None:
    """The record-reading options of a command (`offset`: it reads displacements)."""
    if offset:
        p.add_argument("--keep-offset", action="store_true",
                       help="keep the sensor offset at rest (by default the mean y over the samples before "
                            "the drive starts is removed from each record)")


def read_records(paths, ns=None, need=("u", "y")):
    """Read and check the records at `paths` as the options `ns` say.

    Parameters
    ----------
    paths : sequence of path-like
        CSV files (:data:`CSV_FORMAT`).
    ns : argparse.Namespace, optional
        The command's parsed options (:func:`add_record_arguments`).
    need : tuple of str
        Columns required besides ``t``.

    Returns
    -------
    list of fonbw.io.Record
        One per file, offsets at rest removed from y unless ``--keep-offset``
        (each removal is reported on stderr).
    """
    from ..io import read_record, zero_at_rest

    recs = [read_record(p, need=need) for p in paths]
    if "y" not in need or getattr(ns, "keep_offset", False):
        return recs
    out = []
    for r in recs:
        r2, y0 = zero_at_rest(r)
        if y0:
            print(f"{r.path}: removed the offset at rest, {y0:.4g} µm", file=sys.stderr)
        out.append(r2)
    return out


def load_model(path):
    """A saved model (any kind); a bad file raises a one-line error."""
    from ..hysteresis import load_model as _load

    return _load(path)


def out_path(path):
    """`path`, once its folder is known to exist (checked before long work starts)."""
    d = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(d):
        raise CLIError(f"{path}: output directory {d} does not exist")
    return path
