"""The ``fonbw`` command line: one module per command over one record-reading step."""
from .main import COMMANDS, build_parser, main  # noqa: F401
from .records import CLIError  # noqa: F401
