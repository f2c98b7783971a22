"""A wheel install runs everything: no file of the repository is read at run time.

The environment comes from the ``wheel_env`` fixture (conftest.py): a wheel
built from a copy of the tracked files, the copy deleted, installed into a
fresh environment. Commands run from an empty folder elsewhere. The quick
demo runs from the same install in tests/test_demo.py.
"""
import json
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow


def test_wheel_imports_the_installed_copy(wheel_env, tmp_path):
    py, purelib, _ = wheel_env
    out = subprocess.check_output([str(py), "-c", "import fonbw, fonbw.data, fonbw.fmu.slaves as s; "
                                   "print(fonbw.__file__); print(fonbw.data.DEFAULT_MODEL.is_file()); "
                                   "print(s.SLAVES_DIR)"], cwd=tmp_path, text=True).split()
    assert Path(out[0]).is_relative_to(purelib) and out[1] == "True"
    assert (Path(out[2]) / "fonbw_hysteresis_fmu.py").is_file()
    # the console command's start module rides in the wheel beside the package
    out = subprocess.check_output([str(py), "-c", "import importlib.metadata as m, _fonbw_start as s; "
                                   "print(m.entry_points(group='console_scripts')['fonbw'].value); "
                                   "print(s.__file__)"], cwd=tmp_path, text=True).split()
    assert out[0] == "_fonbw_start:main" and Path(out[1]).is_relative_to(purelib)


def test_wheel_builds_fmus_and_closes_the_loop(wheel_env, tmp_path):
    py, _, run = wheel_env
    r = run("build-fmu", "-o", "fmus", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "fmus").glob("*.fmu")) == [
        "FonbwCompensator.fmu", "FonbwHysteresis.fmu", "FonbwLinearPlant.fmu"]
    for line in r.stdout.splitlines():
        assert line.startswith("wrote ") and "no problem" in line
    r = run("cosim", "--scenario", "sine5", "--mode", "ff+fb", "--master", "fmpy", "--T", "0.05",
            "--fmu-dir", "loop-fmus", "--json", "loop.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    res = json.loads((tmp_path / "loop.json").read_text())
    ref = run("cosim", "--scenario", "sine5", "--mode", "ff+fb", "--master", "reference", "--T", "0.05",
              "--json", "ref.json", cwd=tmp_path)
    assert ref.returncode == 0, ref.stderr
    # the FMUs built by the installed copy close the loop exactly as the library does
    assert res["rms_error"] == json.loads((tmp_path / "ref.json").read_text())["rms_error"]
    assert sorted(p.name for p in (tmp_path / "loop-fmus").glob("*.fmu")) == [
        "FonbwCompensator.fmu", "FonbwHysteresis.fmu", "FonbwPID.fmu"]


def test_wheel_builds_native_fmus(wheel_env, tmp_path):
    import shutil
    import zipfile

    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed: no linux64 binary")
    _, _, run = wheel_env
    r = run("build-fmu", "--native", "-o", "d", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    fmus = sorted((tmp_path / "d").glob("*.fmu"))
    assert [p.name for p in fmus] == [
        "FonbwCompensatorNative.fmu", "FonbwHysteresisNative.fmu", "FonbwLinearPlantNative.fmu"]
    for p in fmus:  # the C sources came from the installed package data
        names = zipfile.ZipFile(p).namelist()
        assert f"binaries/linux64/{p.stem}.so" in names and "sources/fonbw_pid.c" in names
    assert sum(line.startswith("wrote ") and "no problem" in line for line in r.stdout.splitlines()) == 3


def test_wheel_builds_from_a_clone_of_the_repository(wheel_env, tmp_path):
    # run from the root of a clone (as the README's main command does), the
    # builder's own process must import the installed package, not the
    # clone's fonbw/ source folder (which has no data/ of its own)
    _, _, run = wheel_env
    (tmp_path / "fonbw").mkdir()
    (tmp_path / "fonbw" / "__init__.py").write_text('raise ImportError("the source folder, not the installed package")')
    r = run("cosim", "--scenario", "sine5", "--mode", "ff", "--master", "fmpy", "--T", "0.01",
            "--fmu-dir", "fresh-fmus", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "fresh-fmus" / "FonbwHysteresis.fmu").is_file()

