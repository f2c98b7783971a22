"""Sim-to-real gap diagnosis: localize, attribute, check.

``diagnose(train_records, validate_records)`` fits the nominal FONBW model,
localizes its validation residual, tries the candidate effect blocks of
:mod:`fonbw.gap.effects` (each refit jointly with the nominal model) and
returns a :class:`DiagnosisResult` (``to_dict()`` is the JSON);
``write_json`` and ``write_html`` write it. The command line is
:mod:`fonbw.cli.diagnose`.
"""
from .attribute import Diagnosis, diagnose  # noqa: F401
from .effects import EFFECTS  # noqa: F401
from .report import write_html, write_json  # noqa: F401
from .result import DiagnosisResult  # noqa: F401

__all__ = ["diagnose", "Diagnosis", "DiagnosisResult", "write_html", "write_json", "EFFECTS"]
