"""The closed loop on the native C FMUs.

* FonbwPIDNative against the library's LoopController (every integrator and
  anti-windup, derivative filter, saturation with a feedforward), sample by
  sample through fmpy, and its parameter checks.
* The pass-through variant: the same interface, output = input.
* ``run_cosim(native=True)``: the fmpy master (native hysteresis,
  compensator, plant; library controller) and the libcosim master (the
  native PID too) against the reference master, over the feedback modes
  with and without the plant. Without the plant the traces are identical
  bit for bit; the plant's zero-order hold is computed in C (Padé) and by
  python-control, so with it they agree to round-off.
"""
from __future__ import annotations

import math
import shutil
import zipfile

import numpy as np
import pytest

from fonbw.cli import main as fonbw_main
from fonbw.fmu import native
from fonbw.loop import LoopController, controller_spec, run_cosim
from fonbw.loop.fmus import build_native_fmus
from fonbw.fmu.build import pid_resource

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed: no linux64 binary")
DT = 1e-4
T = 0.05  # 500 steps per run
REL = 1e-9
TRACE = ("u", "y", "e")


@pytest.fixture(scope="module")
def fmu_dir(tmp_path_factory):
    """The loop's native FMUs, built once (with and without the plant)."""
    d = tmp_path_factory.mktemp("native-loop")
    for plant in (None, "dynamics+creep"):
        build_native_fmus(d, plant)
    return d


def _slave(fmu, params, tmp_path):
    """An initialized fmpy FMU2Slave of `fmu` with `params` (name -> value)."""
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    d = tmp_path / fmu.stem
    zipfile.ZipFile(fmu).extractall(d)
    s = FMU2Slave(guid=md.guid, unzipDirectory=str(d), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="t")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    for k, v in params.items():
        (s.setString if isinstance(v, str) else s.setReal)([vr[k]], [v])
    s.exitInitializationMode()
    return s, vr


def _pid_fmu(tmp_path):
    return native.build_native(tmp_path, kinds=["pid"], platforms=["linux64"])[0]


@pytest.mark.slow
def test_pid_agrees_with_library(tmp_path):
    fmu = _pid_fmu(tmp_path)
    rng = np.random.default_rng(1)
    n = 3000
    r = 20.0 * np.sin(np.arange(n) * 2e-3) + rng.normal(0, 2.0, n)
    y = 20.0 * np.sin(np.arange(n) * 2e-3 - 0.3) + rng.normal(0, 2.0, n)
    uff = 30.0 + 30.0 * np.sin(np.arange(n) * 3e-3)
    for integ in ("forward", "backward", "tustin"):
        for aw in ("back-calculation", "clamping", "none"):
            spec = controller_spec(0.5, 400.0, 1e-3, DT, 0.0, 60.0, integrator=integ, anti_windup=aw)
            lc = LoopController(spec)
            s, vr = _slave(fmu, spec, tmp_path / f"{integ}-{aw}")
            ins = [vr["r"], vr["y"], vr["u_ff"]]
            got = np.empty(n)
            for k in range(n):
                s.setReal(ins, [r[k], y[k], uff[k]])
                s.doStep(k * DT, DT)
                got[k] = s.getReal([vr["u"]])[0]
            s.terminate()
            s.freeInstance()
            ref = np.array([lc.step(r[k], y[k], uff[k]) for k in range(n)])
            assert np.any(got == 60.0) and np.any(got == 0.0)  # both limits reached
            np.testing.assert_array_equal(got, ref, err_msg=f"{integ}, {aw}")


def test_pid_refuses_bad_parameters(tmp_path):
    from fmpy.fmi1 import FMICallException

    fmu = _pid_fmu(tmp_path)
    good = controller_spec(1e-3, 100.0, dt=DT)
    for bad in ({"Tt": DT / 2}, {"kp": -1.0}, {"u_min": 10.0, "u_max": 0.0}, {"Tf": math.nan},
                {"integrator": "euler"}):
        with pytest.raises(FMICallException):
            _slave(fmu, {**good, **bad}, tmp_path / str(len(list(tmp_path.iterdir()))))


def test_pass_through(tmp_path):
    fmu = native.build_native_one("pid", pid_resource(), tmp_path, ["linux64"], pass_through=True)
    assert fmu.stem == native.PASS_NAMES["pid"] == "FonbwPassPIDNative"
    s, vr = _slave(fmu, {"kp": 2.0}, tmp_path)
    for k, x in enumerate((1.5, -2.0, 3.25)):
        s.setReal([vr["r"], vr["y"]], [x, 7.0])
        s.doStep(k * DT, DT)
        assert s.getReal([vr["u"]])[0] == x
    s.terminate()
    s.freeInstance()


def _check(res, ref, exact):
    assert res.error is None and ref.error is None and res.steps == ref.steps == round(T / DT)
    for k in TRACE:
        a, b = getattr(res, k), getattr(ref, k)
        if exact:
            np.testing.assert_array_equal(a, b, err_msg=k)
        else:
            assert np.max(np.abs(a - b)) <= REL * np.max(np.abs(b)), k
    assert math.isclose(res.rms_error, ref.rms_error, rel_tol=REL)


def test_fmpy_native_loop(fmu_dir):
    ref = run_cosim("sine5", "ff+fb", "reference", T=T)
    res = run_cosim("sine5", "ff+fb", "fmpy", T=T, native=True, fmu_dir=fmu_dir)
    assert res.config["native"] and all("Native" in p for p in res.config["fmus"].values())
    _check(res, ref, exact=True)


@pytest.mark.slow
@pytest.mark.parametrize("plant", ["none", "dynamics+creep"])
@pytest.mark.parametrize("mode", ["fb", "ff+fb"])
@pytest.mark.parametrize("master", ["fmpy", "libcosim"])
def test_native_masters_agree_with_reference(fmu_dir, master, mode, plant):
    if master == "libcosim":
        pytest.importorskip("libcosimpy")
    ref = run_cosim("sine5", mode, "reference", T=T, plant=plant)
    res = run_cosim("sine5", mode, master, T=T, plant=plant, native=True, fmu_dir=fmu_dir)
    if master == "libcosim":
        assert res.config["fmus"]["ctrl"].endswith("FonbwPIDNative.fmu")
    _check(res, ref, exact=plant == "none")


def test_cli_native(fmu_dir, tmp_path, capsys):
    rc = fonbw_main(["cosim", "--scenario", "sine5", "--mode", "fb", "--master", "fmpy", "--native",
                     "--T", "0.02", "--fmu-dir", str(fmu_dir), "--json", str(tmp_path / "r.json")])
    assert rc == 0
    out = capsys.readouterr().out
    assert "fmpy native" in out and "200 steps" in out


def test_libcosim_exogenous_inputs_both_ways(fmu_dir, monkeypatch):
    """The libcosim master feeds the exogenous inputs from signal FMUs (one
    ex.step call for the run); without a C compiler it sets them with an
    override manipulator before every step. Both give the same trace, bit
    for bit."""
    pytest.importorskip("libcosimpy")
    from fonbw.loop import masters

    a = run_cosim("sine5", "ff+fb", "libcosim", T=T, plant="dynamics+creep", native=True, fmu_dir=fmu_dir)
    monkeypatch.setattr(masters, "_signal_fmu", lambda: None)
    b = run_cosim("sine5", "ff+fb", "libcosim", T=T, plant="dynamics+creep", native=True, fmu_dir=fmu_dir)
    assert a.diagnostics["libcosim"]["exogenous"] == "signal FMUs"
    assert b.diagnostics["libcosim"]["exogenous"] == "override manipulator, per step"
    assert a.error is None and b.error is None and a.steps == b.steps == round(T / DT)
    for k in ("r", *TRACE):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)


def test_libcosim_runs_without_worker_thread(fmu_dir, tmp_path):
    """In a fresh process the libcosim master's execution has no worker
    thread (the steps run on the calling thread) and still agrees with the
    reference master."""
    pytest.importorskip("libcosimpy")
    import subprocess
    import sys

    code = ("import json, sys, numpy as np\n"
            "from fonbw.loop import run_cosim\n"
            "r = run_cosim('sine5', 'fb', 'libcosim', T=0.02, native=True, fmu_dir=sys.argv[1])\n"
            "ref = run_cosim('sine5', 'fb', 'reference', T=0.02)\n"
            "print(json.dumps({'d': r.diagnostics, 'err': r.error, 'dy': float(np.max(np.abs(r.y - ref.y))),"
            " 'y': float(np.max(np.abs(ref.y)))}))\n")
    p = subprocess.run([sys.executable, "-c", code, str(fmu_dir)], capture_output=True, text=True, timeout=300,
                       cwd=str(tmp_path))
    assert p.returncode == 0, p.stderr[-2000:]
    import json

    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["err"] is None
    assert out["d"]["libcosim"]["worker_threads"] == 0, out["d"]
    assert out["dy"] <= REL * out["y"]
