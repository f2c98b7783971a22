"""Models from JSON: :func:`model_from_dict` and :func:`load_model`.

The inverse of :meth:`fonbw.hysteresis.models._Model.to_dict` and ``save``;
error messages name the file (or source) and the offending field.
"""
from __future__ import annotations

import json
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
    try:
        m = cls(**params)
        m.meta = {k: d[k] for k in META_KEYS if k in d}
        return m
    except TypeError as exc:
        raise ValueError(f"{source}: field 'params': {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{source}: field 'params': {exc}") from None


def load_model(path):
    """Load a model saved with :meth:`save` (any kind)."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as fh:
            d = json.load(fh)
    except OSError as exc:
        raise ValueError(f"{path}: cannot open: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: line {exc.lineno}: not valid JSON ({exc.msg})") from None
    return model_from_dict(d, source=path)
