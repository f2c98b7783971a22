"""Models from JSON: :func:`model_from_dict` and :func:`load_model`.

The inverse of :meth:`fonbw.hysteresis.models._Model.to_dict` and ``save``;
error messages name the file (or source) and the offending field.
"""
from __future__ import annotations

import json
import math
import numbers
import os

from .models import CBW, FONBW, KINDS, META_KEYS, NBW, Zhu2016


def model_from_dict(d: dict, source: str = "<dict>"):
    """Build a model from :meth:`to_dict` output; errors name the source and field."""
    if not isinstance(d, dict):
        raise ValueError(f"{source}: expected a JSON object with 'kind' and 'params'")
    kind = d.get("kind")
    params = d.get("params")
    if kind not in KINDS:
        raise ValueError(f"{source}: field 'kind': {kind!r} is not one of {', '.join(KINDS)}")
    if not isinstance(params, dict):
        raise ValueError(f"{source}: field 'params' must be an object")
    cls = {"fonbw": FONBW, "nbw": NBW, "cbw": CBW, "zhu": Zhu2016}[kind]
    meta = _meta(d, source)
    # JSON's true and false would pass for 1 and 0 (Python's bool is an int); an
    # unknown name or the engine's name is left to the checks that name them
    flags = [k for k in _numbers(cls) if k in params and (isinstance(params[k], bool) or (
        isinstance(params[k], list) and any(isinstance(x, bool) for x in params[k])))]
    if flags:
        k = flags[0]
        raise ValueError(f"{source}: field 'params.{k}': expected a number, got {json.dumps(params[k])}")
    try:
        m = cls(**params)
        m.meta = meta
        return m
    except TypeError as exc:
        raise ValueError(f"{source}: field 'params': {_arguments(cls, params) or exc}") from None
    except ValueError as exc:
        raise ValueError(f"{source}: field 'params': {exc}") from None


def _parameters(cls):
    """The named parameters of the model class `cls` (inspect.Parameter by name)."""
    import inspect

    return {k: p for k, p in inspect.signature(cls).parameters.items()
            if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)}


def _numbers(cls):
    """Names of the numeric parameters of the model class `cls` (all but the memory engine)."""
    return [k for k in _parameters(cls) if k != "memory"]


def _arguments(cls, params):
    """What is wrong with the names in `params` for the model class `cls`, in
    the file's words (missing or unknown parameters), or None."""
    sig = _parameters(cls)
    names = list(sig)
    missing = [k for k, p in sig.items() if p.default is p.empty and k not in params]
    unknown = [k for k in params if k not in names]
    parts = ([f"missing parameter(s) {', '.join(missing)}"] if missing else []) + \
        ([f"unknown parameter(s) {', '.join(map(str, unknown))} (a {cls.kind} model takes {', '.join(names)})"]
         if unknown else [])
    return "; ".join(parts) or None


#: Longest rest cycle a model file may ask for [s] (``start.T``; the default cycle is 1 s):
#: it runs at every start of a compensator, sample by sample, so a longer one is a typing
#: error, not a convention (an hour at 10 kHz would be 3.6e7 steps before the first output).
REST_T_MAX = 60.0


def _range(v, source, field):
    """[lo, hi] of two finite numbers with lo < hi, else a one-line error naming `field`."""
    ok = (isinstance(v, (list, tuple)) and len(v) == 2
          and all(isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x) for x in v))
    if not ok or not v[0] < v[1]:
        raise ValueError(f"{source}: field {field!r}: expected [low, high] in V with low < high, got {v!r}")
    return [float(v[0]), float(v[1])]


def _meta(d, source):
    """The provenance fields of `d` (:data:`~fonbw.hysteresis.models.META_KEYS`),
    checked where the tools read them: ``u_range`` ([u_min, u_max] V),
    ``start`` (``{"rest_cycle": [lo, hi], "T": seconds}``) and
    ``invertibility`` (an object); null stands for absent."""
    meta = {k: d[k] for k in META_KEYS if k in d}
    if meta.get("u_range") is not None:
        meta["u_range"] = _range(meta["u_range"], source, "u_range")
    st = meta.get("start")
    if st is not None:
        if not isinstance(st, dict):
            raise ValueError(f"{source}: field 'start': expected an object such as "
                             f'{{"rest_cycle": [0, 120], "T": 1.0}}, got {st!r}')
        # a start without its cycle (or with a misspelt key) would run from the virgin state unsaid
        odd = [k for k in st if k not in ("rest_cycle", "T")]
        if odd or "rest_cycle" not in st:
            raise ValueError(f"{source}: field 'start': expected the keys rest_cycle ([low, high] V) and "
                             f"optionally T (s), got {sorted(map(str, st))}")
        st = {**st, "rest_cycle": _range(st["rest_cycle"], source, "start.rest_cycle")}
        if "T" in st:
            T = st["T"]
            if (isinstance(T, bool) or not isinstance(T, numbers.Real) or not math.isfinite(T)
                    or not 0 < T <= REST_T_MAX):
                raise ValueError(f"{source}: field 'start.T': the rest cycle's duration must be a number of "
                                 f"seconds in (0, {REST_T_MAX:g}], got {T!r}")
            st = {**st, "T": float(T)}
        meta["start"] = st
    if meta.get("invertibility") is not None and not isinstance(meta["invertibility"], dict):
        raise ValueError(f"{source}: field 'invertibility': expected an object, got {meta['invertibility']!r}")
    return meta


def load_model(path):
    """Load a model saved with :meth:`save` (any kind)."""
    path = os.fspath(path)
    try:
        # utf-8-sig: a file saved by an editor that writes a byte-order mark is read as the CSVs are
        with open(path, encoding="utf-8-sig") as fh:
            d = json.load(fh)
    except OSError as exc:
        raise ValueError(f"{path}: cannot open: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: line {exc.lineno}: not valid JSON ({exc.msg})") from None
    return model_from_dict(d, source=path)
