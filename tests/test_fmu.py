"""Tests of the FMUs: FonbwHysteresis, FonbwCompensator, FonbwLinearPlant.

Layout, and why:

* The FMUs are built in subprocesses (the builder imports the slave scripts
  and edits sys.path; the test process stays clean): the default model's
  hysteresis and compensator once per run for every test (the ``loop_fmus_dir``
  fixture), the others by build_fmu.py here.
* Every FMU is loaded only in fresh subprocesses started with sys.executable
  and with the tmp dir as working directory: an FMU loaded into the test
  process would silently use the test process's imports, which hides a
  missing bundled file.  One driver process per master (fmpy, libcosim) runs
  all scenarios and writes arrays + a JSON report; the tests assert on those.
  The driver scripts are in fmu_drivers.py.
* References come from a separate subprocess that runs fonbw's batch
  functions (simulate, compensate) on the fonbw sources bundled in the FMU,
  imported without any FMU code: those are byte-identical to this
  repository's fonbw/ at build time, and using them keeps a concurrent edit of
  fonbw/ from racing the build (and shares numba's cache).  The plant's
  reference is python-control in the test process.

Sampling convention checked here (fmu_src/fonbw_fmu_common.py): with h = dt
the FMU output at t_{k+1} is the library's y[k] = F(u[0..k]); the plant
output at t_k is the exact ZOH response, i.e. control.forced_response of the
c2d system at sample k.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

# tests/ is on sys.path: pytest inserts the folder of a test module without __init__.py
from fmu_drivers import COSIM_DRIVER, FMPY_DRIVER, REFERENCE

ROOT = Path(__file__).resolve().parents[1]
DT = 1e-4
N = 20000              # 2 s at 10 kHz
N_SHORT = 2000         # instance independence, engines, libcosim runs
REL_TOL = 1e-10
# Parameters changed through fmi2SetReal in initialization mode (instance B)
SET_PARAMS = {"lam1": 0.9, "lam2": 0.8, "kh": -2.5e4}
# Parameter changes of the second build (--params), loaded next to the default
ALT_PARAMS = {"lam2": 0.7, "sigma": 5.0e4, "n": 1.5}
ENGINES = ["fast", "exact", "short", "oustaloup"]
FREQS = [0.0, 20.0, 500.0, 1500.0, 5000.0]  # Hz, plant transfer-function check
# Desired displacements with unreachable stretches (um), for the compensator status
Y_SAT = [5.0] * 3 + [500.0] * 3 + [5.0] * 2 + [-50.0] * 2 + [5.0] * 2
# A first-order plant with direct feedthrough, custom names/units: w = lowpass(v)/2 + v/2
PLANT_FT = {"kind": "linear_plant", "description": "test plant with feedthrough",
            "input": {"name": "v", "unit": "V", "description": "test input"},
            "output": {"name": "w", "unit": "um/V", "description": "test output"},
            "A": [[-100.0]], "B": [[100.0]], "C": [[0.5]], "D": [[0.5]], "sys_dt": None}
# Each refused parameter: (name, value); the name must appear in the log lines
BAD_PARAMS = [("lam1", 1.5), ("n", 0.5), ("dt", -1e-4), ("kh", float("nan")),
              ("rho", -1.0), ("memory", "bogus")]


def _signals():
    t = np.arange(N + 1) * DT
    u = 60.0 + 50.0 * np.sin(2 * np.pi * 5.0 * t) + 5.0 * np.sin(2 * np.pi * 40.0 * t)  # V
    y_ref = 10.0 + 8.0 * np.sin(2 * np.pi * 5.0 * t) + 0.5 * np.sin(2 * np.pi * 40.0 * t)  # um
    h = 10.0 + 5.0 * np.sin(2 * np.pi * 300.0 * t) + 5.0 * (t >= 0.05)  # um
    return t, u, y_ref, h


def _run(args, cwd, timeout=600):
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)  # nothing but the FMU may provide fonbw
    r = subprocess.run([sys.executable, *map(str, args)], cwd=str(cwd), env=env,
                       capture_output=True, text=True, timeout=timeout)
    if r.returncode != 0:
        pytest.fail(f"subprocess {args[:2]} failed with exit code {r.returncode}\n"
                    f"--- stdout\n{r.stdout[-4000:]}\n--- stderr\n{r.stderr[-4000:]}")
    return r


@pytest.fixture(scope="module")
def work(tmp_path_factory, loop_fmus_dir):
    """Build the FMUs (default + a second parameter set) and the references."""
    w = tmp_path_factory.mktemp("fmu")
    t, u, y_ref, h = _signals()
    np.savez(w / "signals.npz", t=t, u=u, y_ref=y_ref, h=h)
    (w / "config.json").write_text(json.dumps(dict(
        N=N, N_SHORT=N_SHORT, DT=DT, SET_PARAMS=SET_PARAMS, ALT_PARAMS=ALT_PARAMS,
        BAD_PARAMS=BAD_PARAMS, ENGINES=ENGINES, FREQS=FREQS, Y_SAT=Y_SAT)))
    # the hysteresis and compensator FMUs of the default model are the closed
    # loop's (one build per run); the default plant is built here by the shim
    (w / "default").mkdir()
    for name in ("FonbwHysteresis.fmu", "FonbwCompensator.fmu"):
        shutil.copy2(loop_fmus_dir / name, w / "default" / name)
    _run([ROOT / "build_fmu.py", "--only", "plant", "-o", w / "default"], cwd=w)
    # The references run the library sources the FMUs carry (not fonbw/ of the
    # working tree, which may be edited while the tests run), via the FMU's own
    # import path, which also lets them share numba's cache with the drivers.
    with zipfile.ZipFile(w / "default" / "FonbwHysteresis.fmu") as z:
        z.extractall(w / "bundle", [n for n in z.namelist() if n.startswith("resources/")])
    _run(["-c", REFERENCE, ROOT, w, w / "bundle" / "resources"], cwd=w)
    _run([ROOT / "build_fmu.py", "--only", "hysteresis", "--params", w / "alt.json",
          "-o", w / "alt"], cwd=w)
    (w / "plant_ft.json").write_text(json.dumps(PLANT_FT))
    _run([ROOT / "build_fmu.py", "--only", "plant", "--plant", w / "plant_ft.json",
          "-o", w / "ft"], cwd=w)
    return w


@pytest.fixture(scope="module")
def ref(work):
    return dict(np.load(work / "reference.npz"))


@pytest.fixture(scope="module")
def fmpy_run(work):
    _run(["-c", FMPY_DRIVER, work], cwd=work)
    return dict(np.load(work / "fmpy_out.npz")), json.loads((work / "fmpy_report.json").read_text())


@pytest.fixture(scope="module")
def cosim_run(work):
    _run(["-c", COSIM_DRIVER, work], cwd=work)
    return dict(np.load(work / "cosim_out.npz")), json.loads((work / "cosim_report.json").read_text())


def _rel(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert a.shape == b.shape, (a.shape, b.shape)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


FMUS = ["default/FonbwHysteresis.fmu", "default/FonbwCompensator.fmu",
        "default/FonbwLinearPlant.fmu", "alt/FonbwHysteresis.fmu"]


@pytest.mark.parametrize("name", FMUS)
def test_model_description_validates(work, name):
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    fmu = work / name
    assert validate_fmu(str(fmu)) == []
    # the command line tool says the same
    r = _run(["-m", "fmpy", "validate", fmu], cwd=work)
    assert "No problems found" in r.stdout

    md = read_model_description(str(fmu))
    units = {u.name for u in md.unitDefinitions}
    for v in md.modelVariables:
        assert v.description, f"{v.name} has no description"
        if v.type == "Real":
            assert v.unit in units, f"{v.name} has no declared unit"
    outs = [v for v in md.modelVariables if v.causality == "output"]
    assert [o.variable for o in md.outputs] == outs
    assert [o.variable for o in md.initialUnknowns] == outs
    # no direct feedthrough: hysteresis/compensator always, the plant because D = 0
    assert all(o.dependencies == [] for o in md.outputs)
    assert float(md.defaultExperiment.stepSize) == DT
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate


def test_parameters_carry_start_values_of_the_parameter_set(work):
    from fmpy import read_model_description

    for sub, path in (("default", ROOT / "models" / "fonbw_default.json"),
                      ("alt", work / "alt.json")):
        p = json.loads(Path(path).read_text())["params"]
        md = read_model_description(str(work / sub / "FonbwHysteresis.fmu"))
        start = {v.name: v.start for v in md.modelVariables if v.causality == "parameter"}
        expected = {f"ku{i}": k for i, k in enumerate(p["ku"], 1)}
        expected.update({k: p[k] for k in ("kh", "rho", "sigma", "n", "lam1", "lam2")})
        for k, v in expected.items():
            assert float(start[k]) == v, (sub, k)  # bit for bit
        assert start["memory"] == p["memory"]
        assert float(start["dt"]) == DT
        units = {v.name: v.unit for v in md.modelVariables}
        assert (units["ku1"], units["ku2"], units["kh"], units["rho"], units["dt"]) == \
            ("um/V", "um/V2", "um", "1/V", "s")


def test_fmu_uses_its_bundled_fonbw(work, fmpy_run):
    # Even when fonbw is importable in the host (e.g. an editable install), the
    # FMUs import the fonbw sources they carry: either from the extracted FMU
    # or from the digest-checked copy in the FMU cache folder (fonbw_fmu_common.
    # use_bundled_fonbw).  Either way every loaded module file must be byte for
    # byte the file in the FMU, and must not be this repository's file.
    _, rep = fmpy_run
    files = rep["fonbw_files"]
    assert "fonbw" in files and "fonbw.hysteresis" in files and "fonbw.plant" in files
    pkg = Path(files["fonbw"]).resolve().parent
    assert pkg != (ROOT / "fonbw").resolve()
    # (the user cache is used on purpose: it is content-addressed, and it spares
    # the numba compile on every test run with unchanged fonbw sources)
    cache = Path(os.environ.get("FONBW_FMU_CACHE") or Path(
        os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "fonbw-fmu")
    assert pkg.is_relative_to((work / "unzip").resolve()) or \
        pkg.is_relative_to(cache.resolve()), pkg
    bundled = work / "unzip" / "default" / "FonbwHysteresis" / "resources" / "fonbw"
    for mod, f in files.items():
        rel = Path(f).resolve().relative_to(pkg)
        assert Path(f).read_bytes() == (bundled / rel).read_bytes(), mod


def test_hysteresis_fmu_equals_library(fmpy_run, ref):
    arr, _ = fmpy_run
    y = arr["hyst"]
    assert y.shape == (N + 1,)
    assert y[0] == 0.0  # at rest before the first step
    assert _rel(y[1:], ref["y_def"]) <= REL_TOL
    assert np.ptp(ref["y_def"]) > 5.0  # a real loop, not a flat line (um)


@pytest.mark.parametrize("engine", ENGINES)
def test_memory_parameter_selects_engine(fmpy_run, ref, engine):
    arr, _ = fmpy_run
    assert _rel(arr["eng_" + engine], ref["eng_" + engine]) <= REL_TOL
    if engine in ("short", "oustaloup"):  # they differ from GL by % (docs), so the
        assert _rel(arr["eng_" + engine], ref["eng_exact"]) > 1e-4  # parameter took effect


def test_communication_step_multiple_of_dt(fmpy_run, ref):
    arr, _ = fmpy_run
    y = arr["hyst_zoh10"]  # h = 10 dt: 10 internal steps per doStep, input held
    assert _rel(y[1:], ref["y_zoh10"][9::10]) <= REL_TOL


def test_compensator_fmu_equals_library(fmpy_run, ref):
    arr, rep = fmpy_run
    assert "u_comp" in ref, "fonbw.compensate is not available"
    assert "comp_error" not in rep, rep.get("comp_error")
    u = arr["comp"]
    assert u[0] == 0.0
    assert _rel(u[1:], ref["u_comp"]) <= REL_TOL


def test_plant_fmu_equals_python_control(fmpy_run):
    arr, _ = fmpy_run
    _, _, _, h = _signals()
    # row k of fmpy's result is the output at t_k: C x_k (D = 0), the k-th
    # sample of control.forced_response of the c2d (ZOH) system
    assert _rel(arr["plant"], _plant_reference(h)) <= REL_TOL


def test_default_plant_is_the_library_mechanics(ref):
    import control

    d = json.loads((ROOT / "models" / "plant_default.json").read_text())
    g = control.ss(d["A"], d["B"], d["C"], d["D"])(2j * np.pi * np.array(FREQS))
    np.testing.assert_allclose(np.ravel(g), np.ravel(ref["mech_fr"]), rtol=1e-12)


def test_instances_with_different_parameters_stay_independent(fmpy_run, ref):
    arr, _ = fmpy_run
    ys = arr["indep"]
    # A: default FMU; B: same FMU, parameters set through fmi2SetReal;
    # C: another FMU file (same model identifier) built from another parameter set
    # (getReal right after doStep k: the library's y[k])
    for y, r in zip(ys, (ref["y_def"][:N_SHORT], ref["y_set"], ref["y_alt"])):
        assert _rel(y, r) <= REL_TOL
    assert _rel(ys[1], ys[0]) > 1e-3 and _rel(ys[2], ys[0]) > 1e-3


@pytest.mark.parametrize("case", ["hyst_fast", "hyst_exact", "comp", "plant"])
def test_state_rollback_replays_bit_for_bit(fmpy_run, case):
    arr, rep = fmpy_run
    assert "error" not in rep["state"][case], rep["state"][case]
    ya, yb, yc, yfresh = arr[f"state_{case}"]
    assert np.array_equal(ya, yb), "fmi2SetFMUstate did not restore the state"
    assert np.array_equal(ya, yc), "fmi2DeSerializeFMUstate into a new instance differs"
    # the restored memory matters: a fresh instance on the same inputs differs
    assert not np.allclose(ya, yfresh, rtol=1e-6, atol=0)


@pytest.mark.parametrize("i", range(len(BAD_PARAMS)), ids=[b[0] for b in BAD_PARAMS])
def test_bad_parameters_refused_with_log(fmpy_run, i):
    _, rep = fmpy_run
    e = rep["bad_params"][i]
    name = e["name"]
    # pythonfmu cannot return fmi2Error from fmi2ExitInitializationMode without
    # destroying the instance, so the refusal is an fmi2Error log line there ...
    assert e["exit_init_status"] == 0
    errors = [m for _, st, m in e["init_logs"] if st == 3]
    assert errors and any(name in m for m in errors), e["init_logs"]
    # ... and every doStep is refused with fmi2Discard and a log line
    assert e["step_status"] == 2
    assert any(st == 2 and "refused" in m and name in m for _, st, m in e["step_logs"]), e["step_logs"]


def test_bad_communication_step_refused_with_log(fmpy_run):
    _, rep = fmpy_run
    for b in rep["bad_steps"]:
        assert b["status"] == 2, b
        assert any(st == 2 and "not a whole multiple" in m for _, st, m in b["logs"]), b
    # the instance is unharmed: a valid step afterwards gives a fresh instance's number
    assert rep["after_bad_status"] == 0
    assert rep["after_bad_y"] == rep["fresh_3dt_y"]


def _plant_reference(h):
    import control

    d = json.loads((ROOT / "models" / "plant_default.json").read_text())
    sysd = control.c2d(control.ss(d["A"], d["B"], d["C"], d["D"]), DT, method="zoh")
    return control.forced_response(sysd, T=np.arange(len(h)) * DT, U=h).outputs


def test_hysteresis_and_plant_run_in_libcosim(cosim_run, ref):
    out, _ = cosim_run
    # override manipulator: the input set before step k is used in step k, and
    # the observer reads the output after it
    assert _rel(out["hyst"], ref["y_def"][:N_SHORT]) <= REL_TOL
    _, _, _, h = _signals()
    assert _rel(out["plant"], _plant_reference(h[:N_SHORT + 1])[1:]) <= REL_TOL


def test_compensator_chain_runs_in_libcosim(cosim_run, ref):
    out, rep = cosim_run
    assert "chain_error" not in rep, rep["chain_error"]
    assert "u_comp" in ref, "fonbw.compensate is not available"
    assert _rel(out["chain_comp"], ref["u_comp"][:N_SHORT]) <= REL_TOL
    # a connection carries the value after step k-1 into step k (0 before the first)
    assert _rel(out["chain_hyst2"], ref["y_chain"]) <= REL_TOL
    h_in = np.concatenate([[0.0], out["chain_hyst2"]])
    assert _rel(out["chain_plant2"], _plant_reference(h_in)[1:]) <= REL_TOL


def test_fixed_parameter_change_after_initialization_is_ignored_with_log(fmpy_run):
    _, rep = fmpy_run
    assert rep["kh_after"] == rep["kh_before"]  # the stepper and the variable agree
    assert any(st == 3 and "kh" in m and "fixed" in m for _, st, m in rep["set_fixed_logs"])


def test_plant_with_feedthrough_declares_and_applies_it(work, fmpy_run):
    import control
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    fmu = work / "ft" / "FonbwLinearPlant.fmu"
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    v = {x.name: x for x in md.modelVariables}
    assert (v["v"].causality, v["v"].unit, v["w"].causality, v["w"].unit) == \
        ("input", "V", "output", "um/V")
    assert [o.dependencies for o in md.outputs] == [[v["v"]]]
    assert [o.dependencies for o in md.initialUnknowns] == [[v["v"]]]
    _, rep = fmpy_run
    assert rep["ft_y0"] == 0.0
    assert rep["ft_y_set"] == 1.0  # D v, visible before any step
    sysd = control.c2d(control.ss(*(PLANT_FT[k] for k in "ABCD")), DT, method="zoh")
    x1 = float(sysd.B[0, 0]) * 2.0
    assert rep["ft_y_step"] == pytest.approx(0.5 * x1 + 1.0, rel=1e-14)


def test_compensator_reports_saturation(fmpy_run, ref):
    arr, rep = fmpy_run
    assert "sat_status" in ref, "fonbw.compensate is not available"
    np.testing.assert_array_equal(arr["sat_status"], ref["sat_status"])
    np.testing.assert_array_equal(arr["sat_u"], ref["sat_u"])
    st = ref["sat_status"]
    assert np.any(st != 0)  # the sequence does saturate
    # one warning log line per episode of non-ok samples
    episodes = int(np.sum((st[1:] != 0) & (st[:-1] == 0)) + (st[0] != 0))
    warnings = [m for _, lv, m in rep["sat_logs"] if lv == 1]
    assert len(warnings) == episodes, rep["sat_logs"]
