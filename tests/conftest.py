"""Shared test set-up.

* ``benchmarks/`` on the import path (the truth simulators of the blind harnesses);
* the ``slow`` marker: end-to-end runs of a minute or more (CI runs them too,
  first; ``pytest -m "not slow"`` is the quick loop);
* session fixtures: the paper's Table 1 model and eq.-19 input, one build of the
  closed loop's FMUs shared by every test (and every xdist worker), and one
  wheel install of the library in a fresh environment.
"""
import fcntl
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
# two xdist workers on two cores: a BLAS thread pool per worker oversubscribes
# them (the gap tests' least-squares steps ran about 20 times slower that way),
# and so does numba's for its parallel population kernel (the suite took 8 min
# 05 s with two numba threads a worker, 7 min 35 s with one, back to back)
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
# ... and a diagnosis's worker processes would, too: each test's diagnosis runs
# in its own process (tests/test_gap_workers.py asks for workers explicitly)
os.environ.setdefault("FONBW_WORKERS", "1")


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: end-to-end runs of a minute or more (run by CI too)")


def pytest_collection_modifyitems(config, items):
    # slow tests first: a running test cannot be stolen by an idle worker
    # (``--dist worksteal`` in pyproject.toml), so a minute-long test started
    # last keeps one worker busy while the other idles
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture(scope="session")
def table1():
    """The paper's Table 1 FONBW (fast memory engine)."""
    from fonbw.paper import table1_model

    return table1_model()


@pytest.fixture(scope="session")
def eq19():
    """The identification input of eq. (19) at 10 kHz, 10 s: (t [s], u [V])."""
    from fonbw.signals import eq19_input

    return eq19_input(10_000.0, 10.0)


def _shared_dir(tmp_path_factory, name):
    """A folder shared by the xdist workers of this run (their base temps' parent)."""
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    d = root / name
    d.mkdir(exist_ok=True)
    return d


@pytest.fixture(scope="session")
def loop_fmus_dir(tmp_path_factory):
    """FonbwHysteresis, FonbwCompensator, FonbwPID and the loop's plant FMUs,
    built once for the run (the first worker builds, the others wait)."""
    from fonbw.loop import build_fmus

    d = _shared_dir(tmp_path_factory, "loop-fmus")
    with open(d / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        for plant in (None, "dynamics+creep"):  # what the loop tests run; others build on first use
            build_fmus(d, plant)
    return d


def _tracked_copy(dest: Path) -> Path:
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for rel in filter(None, files.decode().split("\0")):
        if (ROOT / rel).is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / rel, dest / rel)
    return dest


def _install_wheel(base: Path):
    src = _tracked_copy(base / "src")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                        "-w", str(base / "dist"), str(src)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    shutil.rmtree(src)  # nothing of the repository is left to read
    (wheel,) = (base / "dist").glob("fonbw-*.whl")
    venv.create(base / "venv", with_pip=False)
    py = base / "venv" / "bin" / "python"
    purelib = Path(subprocess.check_output(
        [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], text=True).strip())
    # third-party packages of the test environment by a path entry: its .pth
    # files (the editable install of this repository) stay unread
    (purelib / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(purelib),
                        str(wheel)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    return py, purelib


@pytest.fixture(scope="session")
def wheel_env(tmp_path_factory):
    """``(python, site-packages, run)`` of a fresh environment with the library
    installed from a wheel built from a copy of the tracked files, the copy
    deleted; ``run(*args, cwd)`` runs ``python -m fonbw *args`` there."""
    if not (ROOT / ".git").exists():
        pytest.skip("needs a git checkout to list the tracked files")
    d = _shared_dir(tmp_path_factory, "wheel")
    with open(d / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (d / "ready").exists():
            shutil.rmtree(d / "venv", ignore_errors=True)
            _install_wheel(d)
            (d / "ready").write_text("")
    py = d / "venv" / "bin" / "python"
    purelib = Path(subprocess.check_output(
        [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], text=True).strip())
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}

    def run(*args, cwd, timeout=1500):
        # -P: as the `fonbw` console script, without the working folder on the import path
        return subprocess.run([str(py), "-P", "-m", "fonbw", *map(str, args)], cwd=cwd, capture_output=True,
                              text=True, timeout=timeout, env=env)

    return py, purelib, run
