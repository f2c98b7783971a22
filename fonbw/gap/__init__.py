"""Sim-to-real gap diagnosis (issue 7): localize, attribute, check.

``diagnose(train_records, validate_records)`` fits the nominal FONBW model,
localizes its validation residual, tries the candidate effect blocks of
:mod:`fonbw.gap.effects` (each refit jointly with the nominal model) and
returns the JSON-ready result; ``write_html`` renders it; the CLI pieces are
``add_diagnose_arguments`` and ``diagnose_command``.
"""
from .attribute import diagnose  # noqa: F401
from .effects import EFFECTS  # noqa: F401
from .report import add_diagnose_arguments, diagnose_command, write_html, write_json  # noqa: F401

__all__ = ["diagnose", "write_html", "write_json", "add_diagnose_arguments", "diagnose_command", "EFFECTS"]
