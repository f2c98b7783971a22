"""One identification from record files: the path ``fonbw identify`` and ``fonbw fleet`` share.

Both commands call :func:`identify_paths`, so a model from ``fonbw fleet``
is byte for byte the file ``fonbw identify`` writes with the same options and
seed. It reads the records (through the commands' one reading
step, :func:`fonbw.cli.records.read_records`), leaves out the start of a
record that does not begin at rest, runs :func:`fonbw.identify.identify` and
builds the model's JSON document: the model (kind, parameters, units) plus a
``fit`` object saying what it was fitted on — the records' file names, a
digest of their contents and of every option that decides the model, the
options themselves and the training RMS [µm]. The digest lets a re-run tell
an up-to-date model from a stale one without fitting again.
"""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from types import SimpleNamespace

__all__ = ["FIT_OPTIONS", "Fit", "fit_options", "records_digest", "identify_kwargs", "identify_paths",
           "model_document",
           "model_bytes", "write_model", "read_fit"]

#: Options that decide the model (seed, budget, model kind, memory engine, how
#: the records are read and the compensator's step an invertible model is
#: fitted for), with the value each takes when not given. Options
#: that do not change the result (threads, progress, plots) are not listed.
FIT_OPTIONS = {
    "model": "fonbw", "seed": 0, "max_evals": 5000, "memory": "fast",
    "columns": None, "header": None, "delimiter": None, "time_unit": "s", "u_scale": 1.0, "y_scale": 1.0,
    "resample": False, "unit_check": "error", "keep_offset": False, "for_compensation": None,
    "rest_cycle": False,
}


@dataclass
class Fit:
    """Outcome of :func:`identify_paths`.

    Attributes
    ----------
    result : fonbw.identify.IdentifyResult
        The identification (``result.message == "interrupted"`` after Ctrl-C).
    records : list of fonbw.io.Record
        The records as read (offset at rest removed unless ``keep_offset``).
    burn_in : list of int
        Samples left out at the start of each record [samples].
    document : dict
        The model's JSON document (:func:`model_document`).
    """

    result: object
    records: list
    burn_in: list = field(default_factory=list)
    document: dict = field(default_factory=dict)


def fit_options(ns) -> dict:
    """The options of :data:`FIT_OPTIONS` from parsed command-line options, checked.

    Parameters
    ----------
    ns : argparse.Namespace or mapping
        Options of ``fonbw identify`` or ``fonbw fleet``; a missing one takes
        its default.

    Returns
    -------
    dict
        Plain JSON values in the order of :data:`FIT_OPTIONS` (``max_evals``
        resolved to the evaluation count).
    """
    from ..cli.records import CLIError

    get = ns.get if isinstance(ns, dict) else (lambda k, d: getattr(ns, k, d))
    opts = {k: get(k, d) for k, d in FIT_OPTIONS.items()}
    for k, d in FIT_OPTIONS.items():
        if opts[k] is None:
            opts[k] = d
    if int(opts["seed"]) != opts["seed"] or opts["seed"] < 0:
        raise CLIError(f"--seed must be ≥ 0, got {opts['seed']}")
    if int(opts["max_evals"]) != opts["max_evals"] or opts["max_evals"] < 10:
        raise CLIError(f"--max-evals must be at least 10, got {opts['max_evals']}")
    opts["seed"], opts["max_evals"] = int(opts["seed"]), int(opts["max_evals"])
    dtc = opts["for_compensation"]
    if dtc is not None:
        if not float(dtc) > 0:
            raise CLIError(f"--for-compensation takes the compensator's step in s (> 0), got {dtc}")
        opts["for_compensation"] = float(dtc)
    opts["u_scale"], opts["y_scale"] = float(opts["u_scale"]), float(opts["y_scale"])
    opts["resample"], opts["keep_offset"] = bool(opts["resample"]), bool(opts["keep_offset"])
    if opts["rest_cycle"]:
        opts["rest_cycle"] = True
    else:  # the default leaves the options (and the digests of earlier fits) as they were
        del opts["rest_cycle"]
    return opts


def records_digest(paths, options) -> str:
    """Digest of the records' contents (in the given order) and the options.

    Parameters
    ----------
    paths : sequence of path-like
        The record files; their bytes count, not their names or times.
    options : dict
        :func:`fit_options` output.

    Returns
    -------
    str
        ``"sha256:<hex>"``; it also covers the fonbw version, since another
        version may identify differently.
    """
    from .. import __version__

    h = hashlib.sha256()
    h.update(json.dumps({"fonbw": __version__, "options": options}, sort_keys=True).encode())
    for p in paths:
        f = hashlib.sha256()
        with open(p, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                f.update(block)
        h.update(f.digest())
    return "sha256:" + h.hexdigest()


def identify_kwargs(options, burn_in, *, progress: bool = False, workers: int | None = None) -> dict:
    """Keyword arguments of :func:`fonbw.identify.identify` for :func:`fit_options` output.

    Parameters
    ----------
    options : dict
        :func:`fit_options` output.
    burn_in : list of int
        Samples left out at the start of each record [samples].
    progress : bool
        Show identify's progress bar.
    workers : int, optional
        Threads of the population simulator (left to numba when None).

    Returns
    -------
    dict
    """
    kw = dict(kind=options["model"], seed=options["seed"], max_evals=options["max_evals"],
              memory=options["memory"], burn_in=list(burn_in), progress=progress)
    if workers is not None:
        kw["workers"] = workers
    if options.get("for_compensation") is not None:
        kw["for_compensation"] = options["for_compensation"]
    return kw


def identify_paths(paths, options, *, progress: bool = False, workers: int | None = None,
                   announce=None) -> Fit:
    """Read the records at `paths` and identify a model: what ``fonbw identify`` does.

    Parameters
    ----------
    paths : sequence of path-like
        Record files (t [s], u [V], y [µm]; :data:`fonbw.cli.records.CSV_FORMAT`).
    options : dict
        :func:`fit_options` output (model kind, seed, budget, reader options).
    progress : bool
        Show identify's progress bar.
    workers : int, optional
        Threads of the population simulator; the result does not depend on it.
    announce : callable, optional
        ``announce(records, kwargs)`` once the records are read, just before the
        search starts (the command's report line; a Ctrl-C after it falls in
        the search).

    Returns
    -------
    Fit
        ``document`` holds the model and its provenance (empty when the search
        was interrupted: an interrupted model is not the one these options give).
    """
    from ..cli.records import read_records, say
    from ..io import input_range
    from ..start import burn_ins
    from ..identify import identify
    from ..objective import DivergedError, as_records

    # Read first: a missing or malformed file is reported by the reader, not by the digest.
    recs = read_records(paths, SimpleNamespace(**options))
    digest = records_digest(paths, options)
    burn_in = burn_ins(recs, say)
    # records that cannot be identified are refused by name, before a rest cycle is put in front of them
    as_records(recs)
    if options.get("rest_cycle"):
        late = [r.path for r, b in zip(recs, burn_in) if b > 0]
        if late:
            from ..cli.records import CLIError

            raise CLIError(f"--rest-cycle needs records that start at rest after a drive cycle; "
                           f"{', '.join(map(str, late))} start(s) mid-drive (drop --rest-cycle: such "
                           "records get a burn-in instead)")
        u_range = input_range(recs)
        recs, burn_in = _after_rest_cycle(recs, burn_in, u_range)
    kw = identify_kwargs(options, burn_in, progress=progress, workers=workers)
    if announce is not None:
        announce(recs, kw)
    try:
        res = identify(recs, **kw)
    except DivergedError as exc:
        raise DivergedError(f"{', '.join(map(str, paths))}: {exc}") from None
    if options.get("rest_cycle") and res.model is not None:  # the partial model too
        from ..compensate.rest import rest_start_meta

        res.model.meta = {**(getattr(res.model, "meta", None) or {}), "start": rest_start_meta(u_range)}
    doc = {} if res.message == "interrupted" else model_document(res, paths, options, digest)
    return Fit(result=res, records=recs, burn_in=burn_in, document=doc)


def _after_rest_cycle(recs, burn_in, u_range):
    """The records behind a rest cycle over `u_range` [V]
    (:func:`fonbw.compensate.rest.with_rest_cycle`), the cycle added to each
    burn-in: the stage was zeroed at rest after a previous drive cycle."""
    from ..compensate.rest import with_rest_cycle

    cycled, pre = with_rest_cycle(recs, u_range)
    return cycled, [p + b for p, b in zip(pre, burn_in)]


def model_document(result, paths, options, digest) -> dict:
    """The saved model: ``result.model.to_dict()`` plus its ``fit`` provenance.

    Only what the data and options decide goes in (no times, hosts or full
    paths), so equal inputs give equal bytes wherever they were fitted.
    """
    doc = result.model.to_dict()
    doc["fit"] = {
        "records": [os.path.basename(os.fspath(p)) for p in paths],
        "digest": digest,
        "options": dict(options),
        "training_rms_um": float(result.rms),
        "evaluations": int(result.nfev),
        "warnings": list(getattr(result, "warnings", []) or []),
    }
    return doc


def model_bytes(document) -> bytes:
    """The JSON file's bytes (the layout of ``Model.save``: indented, UTF-8, final newline)."""
    return (json.dumps(document, indent=2, ensure_ascii=False) + "\n").encode("utf-8")


def write_model(path, document) -> None:
    """Write a model document atomically (never half-written)."""
    from ..io import atomic_open

    with atomic_open(path, "wb") as fh:
        fh.write(model_bytes(document))


def read_fit(path) -> dict | None:
    """The whole saved document at `path`, or None if it is missing or unreadable."""
    try:
        with open(path, encoding="utf-8") as fh:
            d = json.load(fh)
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) and isinstance(d.get("fit"), dict) else None
