"""The parts of reading a logger file: text, delimiter, header, columns, rows.

:func:`fonbw.io.read_record` is the one entry point; this module holds the
steps it chains, each of which refuses bad input with a
:class:`fonbw.io.DataError` naming the file, the row (the line number in the
file, one-based) and the reason.

* text: UTF-8 (with or without a byte-order mark), else Latin-1 (loggers on
  Windows write ``µ`` that way); lines starting with ``#`` are comments;
* delimiter: comma, semicolon, tab or runs of whitespace, sniffed from the
  first lines unless given; with a semicolon or tab delimiter a decimal comma
  (``1,25``) is read as a decimal point;
* header: detected (a first row of numbers is data) unless told;
* columns: a mapping ``{"t": COL, "u": COL, "y": COL}`` with COL a header
  name or a one-based position, else the default names ``t``, ``u``, ``y``,
  ``Hd`` (a unit suffix such as ``t [s]`` or ``y (µm)`` is ignored).
"""
from __future__ import annotations

import csv
import math
import os
import re
import shlex

__all__ = ["KEYS", "parse_columns", "read_text", "sniff_delimiter", "split_rows", "resolve_columns",
           "parse_rows", "fmt"]

#: The columns a record can have, as they are named in a column mapping.
KEYS = ("t", "u", "y", "Hd")

#: Header names (lower case, unit removed) that commonly hold each column; used
#: only to suggest a ``--columns`` mapping, never to guess one silently.
_SYNONYMS = {"t": ("time", "t_s", "timestamp", "zeit", "sec", "seconds"),
             "u": ("voltage", "volt", "v", "u_v", "input", "spannung"),
             "y": ("displacement", "disp", "position", "x", "y_um", "output", "weg"),
             "Hd": ("hd", "desired", "reference", "ref")}


def fmt(x) -> str:
    """A number as plain text for messages (never ``np.float64(...)``)."""
    return f"{float(x):.10g}"


def parse_columns(spec) -> dict:
    """A column mapping from ``"t=COL,u=COL,y=COL"`` or a mapping.

    Parameters
    ----------
    spec : str or mapping or None
        COL is a header name or a one-based position (an ``int`` or a string
        of digits). Keys: ``t``, ``u``, ``y``, ``Hd``.

    Returns
    -------
    dict
        ``{key: int position (one-based) or str name}``; empty for None.
    """
    if spec is None:
        return {}
    if isinstance(spec, str):
        items = []
        for part in (p.strip() for p in spec.split(",")):
            key, eq, col = part.partition("=")
            if not eq or not key.strip() or not col.strip():
                raise ValueError(f"--columns: {part!r} is not KEY=COL (expected e.g. t=2,u=4,y=3)")
            items.append((key.strip(), col.strip()))
    else:
        items = list(dict(spec).items())
    out = {}
    for key, col in items:
        k = next((c for c in KEYS if c.lower() == str(key).lower()), None)
        if k is None:
            raise ValueError(f"--columns: unknown column {key!r}; the columns are {', '.join(KEYS)}")
        if isinstance(col, bool) or not isinstance(col, (int, str)):
            raise ValueError(f"--columns: {k}={col!r}: COL must be a header name or a 1-based position")
        if isinstance(col, int) or col.isdigit():
            if int(col) < 1:
                raise ValueError(f"--columns: {k}={col}: positions are 1-based")
            col = int(col)
        if k in out:
            raise ValueError(f"--columns: {k} is given twice")
        # one column read as two quantities is a typing error (a voltage read as a displacement)
        twin = next((c for c, v in out.items() if v == col), None)
        if twin is not None:
            raise ValueError(f"--columns: {k}={col} is the column already given to {twin}")
        out[k] = col
    return out


def read_text(path, DataError) -> list:
    """The file's lines (UTF-8, else Latin-1)."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except OSError as exc:
        raise DataError(f"{path}: cannot open: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return text.splitlines()


def _content(lines, limit=None):
    """(line number, line) of the non-empty, non-comment lines."""
    out = []
    for i, line in enumerate(lines, start=1):
        s = line.strip()
        if s and not s.startswith("#"):
            out.append((i, line))
            if limit and len(out) >= limit:
                break
    return out


def sniff_delimiter(lines) -> str:
    """The delimiter of the first lines: ``;``, tab, ``,`` or ``" "`` (whitespace runs).

    The first of these that splits the data lines into a constant number of
    fields (more than one) wins; a semicolon before a comma, because a file
    delimited by semicolons often writes decimal commas.
    """
    sample = [ln for _, ln in _content(lines, 21)]
    body = sample[1:] or sample
    for d in (";", "\t", ","):
        counts = {len(next(csv.reader([ln], delimiter=d))) for ln in body}
        if len(counts) == 1 and counts.pop() > 1:
            return d
    counts = {len(ln.split()) for ln in body}
    if len(counts) == 1 and counts.pop() > 1:
        return " "
    return ","


def split_rows(lines, delimiter):
    """(line number, fields) of the content lines, fields stripped."""
    for lineno, line in _content(lines):
        if delimiter == " ":
            fields = line.split()
        else:
            fields = next(csv.reader([line], delimiter=delimiter, skipinitialspace=True), [])
        yield lineno, [f.strip() for f in fields]


def to_float(field, delimiter):
    """`field` as a float (a decimal comma accepted when it is not the delimiter); ValueError otherwise."""
    try:
        return float(field)
    except ValueError:
        if delimiter != "," and "," in field:
            return float(field.replace(",", "."))
        raise


def _is_data(fields, delimiter) -> bool:
    """Whether a row is numbers (empty fields aside), i.e. data rather than a header."""
    nums = 0
    for f in fields:
        if not f:
            continue
        try:
            to_float(f, delimiter)
            nums += 1
        except ValueError:
            return False
    return nums > 0


def _norm(name) -> str:
    """A header name without its unit and case: ``"Y [µm]"`` -> ``"y"``."""
    return re.sub(r"\s*([\[(].*[\])]|/\s*\S+)\s*$", "", name).strip().lower()


#: Characters of a header name that the ``--columns`` hint gives by position
#: instead: the mapping's separator, and what cmd.exe or the C runtime would
#: read inside double quotes (a quote, a variable's %, and a backslash, which
#: escapes the closing quote when a name ends in one; any backslash is
#: refused, so the rule does not depend on the name's place in the mapping).
_BY_POSITION = ',"%\\'


def _shell_quote(arg: str, nt: bool | None = None) -> str:
    """`arg` quoted so that the user's shell reads it back as one argument.

    POSIX shells take single quotes; Windows' cmd.exe passes those on
    literally, so there (`nt`, default: this system) it is put in double
    quotes, inside which cmd.exe leaves ``&``, ``|``, ``<``, ``>`` and ``^``
    alone. The names that double quotes cannot carry never get here
    (:data:`_BY_POSITION`).
    """
    if nt is None:
        nt = os.name == "nt"
    return f'"{arg}"' if nt else shlex.quote(arg)


def _suggest(names, wanted) -> str:
    """A ``--columns`` mapping built from common header names, or a generic hint."""
    found = {}
    for k in wanted:
        for j, n in enumerate(names):
            if _norm(n) in _SYNONYMS[k] or _norm(n) == k.lower():
                found[k] = n if n and not any(c in n for c in _BY_POSITION) else str(j + 1)
                break
    if len(found) == len(wanted):
        # quoted as a shell needs it: header names often hold spaces and brackets
        return "map them with --columns " + _shell_quote(",".join(f"{k}={v}" for k, v in found.items()))
    return ("map them with --columns " + ",".join(f"{k}=COL" for k in wanted)
            + " (COL a header name or a 1-based position)")


def resolve_columns(path, first, delimiter, need, columns, header, DataError):
    """Column positions (zero-based) and whether the first content row is a header.

    Parameters
    ----------
    path : str
    first : (int, list of str)
        Line number and fields of the first content row.
    need : list of str
        Required columns (``t`` first).
    columns : dict
        Parsed mapping (:func:`parse_columns`); mapped columns are required too.
    header : bool or None
        None: detected.

    Returns
    -------
    (dict, dict, bool)
        Required ``{key: index}``, optional ``{key: index}`` (default-named
        columns present but not required), and whether row one is a header.
    """
    lineno, fields = first
    data_like = _is_data(fields, delimiter)
    if header is None:
        header = not data_like
    shown = ", ".join(repr(f) for f in fields)
    required = list(dict.fromkeys(list(need) + list(columns)))
    if not header:
        missing = [k for k in required if k not in columns]
        if missing:
            raise DataError(
                f"{path}: row {lineno}: the file has no header row (row {lineno} is data: {len(fields)} fields "
                f"{shown}); say which column is which with --columns "
                + ",".join(f"{k}=COL" for k in required) + " (COL a 1-based position)")
        names = None
    else:
        names = fields
    idx = {}
    for k in required:
        col = columns.get(k)
        if col is None:
            j = next((j for j, n in enumerate(names) if n == k), None)
            j = next((j for j, n in enumerate(names) if _norm(n) == k.lower()), None) if j is None else j
            if j is None:
                missing = [c for c in required if c not in columns and not any(_norm(n) == c.lower() for n in names)]
                hint = ("; row 1 looks like data: pass --no-header and " if data_like else "; ")
                raise DataError(
                    f"{path}: row {lineno}: missing column(s) {', '.join(repr(c) for c in missing)}; header has "
                    f"{shown or 'nothing'}{hint}{_suggest(names, missing)}")
        elif isinstance(col, int):
            j = col - 1
            if j >= len(fields):
                raise DataError(f"{path}: row {lineno}: column {k!r} mapped to position {col}, but the row has "
                                f"{len(fields)} field(s)")
        else:
            if names is None:
                raise DataError(f"{path}: column {k!r} mapped to the name {col!r}, but the file has no header "
                                "row; give 1-based positions")
            j = next((j for j, n in enumerate(names) if n == col), None)
            j = next((j for j, n in enumerate(names) if _norm(n) == _norm(col)), None) if j is None else j
            if j is None:
                raise DataError(f"{path}: row {lineno}: column {k!r} mapped to {col!r}, which is not in the "
                                f"header ({shown})")
        idx[k] = j
    optional = {}
    if names is not None and not columns:
        for k in ("u", "y", "Hd"):
            j = next((j for j, n in enumerate(names) if n == k), None)
            if k not in idx and j is not None:
                optional[k] = j
    return idx, optional, header


def parse_rows(path, rows, delimiter, idx, optional, DataError):
    """Columns as lists of floats and the file line number of each data row.

    Required columns (`idx`) must hold a finite number in every row; optional
    ones read NaN where they do not.
    """
    cols = {c: [] for c in list(idx) + list(optional)}
    linenos = []
    for lineno, row in rows:
        for c, j in {**idx, **optional}.items():
            req = c in idx
            if j >= len(row):
                if req:
                    raise DataError(f"{path}: row {lineno}: column {c!r} is missing (row has {len(row)} fields)")
                cols[c].append(math.nan)
                continue
            field = row[j]
            try:
                v = to_float(field, delimiter)
            except ValueError:
                if req:
                    raise DataError(f"{path}: row {lineno}: column {c!r}: {field!r} is not a number") from None
                v = math.nan
            if req and not math.isfinite(v):
                raise DataError(f"{path}: row {lineno}: column {c!r}: value {field!r} is not finite")
            cols[c].append(v)
        linenos.append(lineno)
    return cols, linenos
