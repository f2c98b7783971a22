"""Sim-to-real gap diagnosis: localize, attribute, check.

``diagnose(train_records, validate_records)`` fits the nominal FONBW model,
localizes its validation residual, tries the candidate effect blocks of
:mod:`fonbw.gap.effects` (each refit jointly with the nominal model) and
returns a :class:`DiagnosisResult` (``to_dict()`` is the JSON);
``write_json`` and ``write_html`` write it. The command line is
:mod:`fonbw.cli.diagnose`.
"""
import importlib

__all__ = ["diagnose", "Diagnosis", "DiagnosisResult", "write_html", "write_json", "EFFECTS"]

# Imported on first use: a diagnosis's worker process (fonbw.gap.workers)
# starts in 0.9 s instead of 4 s when nothing else of the package is needed.
_HOME = {"diagnose": "attribute", "Diagnosis": "attribute", "EFFECTS": "effects",
         "write_html": "report", "write_json": "report", "DiagnosisResult": "result"}


def __getattr__(name):
    if name in _HOME:
        return getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
    try:  # a submodule, as ``fonbw.gap.effects`` after ``import fonbw.gap``
        return importlib.import_module(f".{name}", __name__)
    except ModuleNotFoundError as exc:
        if exc.name != f"{__name__}.{name}":
            raise  # the submodule exists and lacks a dependency: say that
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None


def __dir__():
    return sorted(set(globals()) | set(__all__))
