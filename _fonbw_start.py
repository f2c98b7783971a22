"""The start of the ``fonbw`` console command.

It lives outside the ``fonbw`` package on purpose: importing ``fonbw.cli``
first runs ``fonbw/__init__.py``, which loads numpy and numba (about half a
second), and a Ctrl-C in that time would otherwise end in Python's
traceback. Caught here, it ends as Ctrl-C inside a command does: one line
and exit code 130, nothing written.
"""
import sys


def main() -> int:
    try:
        from fonbw.cli import main as run
    except KeyboardInterrupt:
        print("fonbw: interrupted while starting; nothing was written", file=sys.stderr)
        return 130
    return run()
