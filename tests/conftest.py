"""Shared test set-up: the benchmarks folder (truth simulators of the blind
harnesses) on the import path, and the ``slow`` marker."""
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: end-to-end runs of a minute or more (run by CI too)")
