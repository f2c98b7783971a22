"""The command line as a user runs it: a fresh ``python -m fonbw`` process."""
import subprocess
import sys


def run(*args, cwd=None, timeout=900):
    """Run ``fonbw *args`` (each turned into a string) in a fresh process; the
    CompletedProcess with its exit code and text stdout and stderr."""
    return subprocess.run([sys.executable, "-m", "fonbw", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout)
