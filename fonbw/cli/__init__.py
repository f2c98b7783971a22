"""The ``fonbw`` command line: one module per command over one record-reading step."""
from .main import CLIError, build_parser, main  # noqa: F401
