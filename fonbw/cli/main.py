"""The ``fonbw`` command line: a registry of commands and one error policy.

Every command validates its input at the boundary. On bad input it prints one
line ``fonbw <command>: error: <file>: <field/row>: <reason>`` on stderr and
exits with code 2, with no traceback, and without writing or half-writing
any output file (outputs are written atomically; an output file whose path
names an input is refused up front, :func:`fonbw.cli.records.out_path`). Two
exits with code 2 write their output on purpose and say so: ``compensate``
on a trajectory out of the model's reach (the closest input) and ``cosim``
when a run stops early (the trace up to the stop). Ctrl-C exits with code
130 and leaves previous outputs untouched.

Each command is a module of this package with a module docstring (its
description), ``add_arguments(parser)`` and ``run(ns)``; its one-line help
stands in :data:`COMMANDS`.
Only the module of the command being run is imported: some pull in
python-control and fmpy, which take about a second.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from .records import CLIError

__all__ = ["main", "build_parser", "CLIError", "COMMANDS"]

#: command -> (module of this package, one-line help shown by ``fonbw --help``)
COMMANDS = {
    "simulate": ("simulate", "simulate a saved model on an input CSV (t, u)"),
    "identify": ("identify", "identify a model from measured records (t, u, y) by jDE"),
    "validate": ("validate", "RMS, %% of range and max error of a model on records (t, u, y)"),
    "compensate": ("compensate", "feedforward input u [V] for a desired trajectory (t, Hd), eq. (16)"),
    "cosim": ("cosim", "closed-loop co-simulation of the FMUs (reference, fmpy, libcosim)"),
    "diagnose": ("diagnose", "localize and attribute the sim-to-real gap"),
    "fleet": ("fleet", "identify a model per actuator sub-folder, on dask, with a fleet summary"),
    "build-fmu": ("build_fmu", "build the FMUs (hysteresis, compensator, plant) into a folder"),
    "figures": ("figures", "the paper's Figs. 1-4 as PNG files"),
    "bench": ("bench", "write the virtual bench's experiments (eq. 19, sines, …) as CSV"),
    "reproduce": ("reproduce", "the paper's Tables 1-3 and Figs. 8-10 on the virtual bench"),
    "demo": ("demo", "the whole workflow on the virtual bench, with an HTML report"),
}


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions kept as written; every option's default shown unless its
    help already says it or there is none to show (None, False)."""

    def _get_help_string(self, action):
        h = action.help or ""
        if "%(default)" in h or "default" in h or action.default in (None, False, argparse.SUPPRESS):
            return h
        if action.option_strings or action.nargs in ("?", "*"):
            h += " (default %(default)s)"
        return h


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (argparse prints usage + message by default)
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _command_module(name):
    return importlib.import_module(f"{__package__}.{COMMANDS[name][0]}")


def build_parser(command=None) -> argparse.ArgumentParser:
    """The argument parser; only `command` (the one about to run) gets its
    arguments and description, the others their one-line help."""
    from .. import __version__

    p = _Parser(prog="fonbw", description="Fractional-order normalized Bouc-Wen hysteresis of piezoelectric "
                "actuators: simulate, identify, compensate, co-simulate FMUs, diagnose the sim-to-real gap.")
    p.add_argument("--version", action="version", version=f"fonbw {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, (_, help_) in COMMANDS.items():
        if name != command:
            sub.add_parser(name, help=help_)
            continue
        mod = _command_module(name)
        s = sub.add_parser(name, help=help_, description=mod.__doc__, epilog=getattr(mod, "EPILOG", None),
                           formatter_class=_Formatter)
        mod.add_arguments(s)
        s.set_defaults(func=mod.run)
    return p


def main(argv=None) -> int:
    """Run the command line; returns the exit code (0, 2 on bad input, 130 on Ctrl-C)."""
    args = sys.argv[1:] if argv is None else list(argv)
    command = next((a for a in args if not a.startswith("-")), None)
    try:
        # building the parser imports the command's module, which may take a second
        parser = build_parser(command if command in COMMANDS else None)
        ns = parser.parse_args(args)
    except KeyboardInterrupt:
        print("fonbw: interrupted", file=sys.stderr)
        return 130
    if not getattr(ns, "command", None):
        parser.print_help()
        return 2
    prog = f"fonbw {ns.command}"
    from ..io import DataError
    from ..objective import DivergedError

    try:
        ns.func(ns)
    except (CLIError, DataError, ValueError, OSError, DivergedError) as exc:
        msg = " ".join(str(exc).split()) or type(exc).__name__
        print(f"{prog}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        # a command that saved something on the way out says what in the exception
        done = str(exc) or "no output was written; earlier outputs are as they were"
        print(f"{prog}: interrupted; {done}", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
