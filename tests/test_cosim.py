"""Closed-loop co-simulation: three masters, one loop.

* The reference master (library steppers, in this process) is checked against
  independent references: the model's batch simulation of the actuator input
  it applied, and python-control's closed loop (control.feedback +
  forced_response) for a linear plant without hysteresis.
* The fmpy master (FMUs through FMU2Slave, controller in the master) and the
  libcosim master (FMUs + the FonbwPID FMU, libcosim's fixed-step algorithm)
  run in fresh subprocesses, one per master (the FMUs' Python code must not
  mix with this process's imports), over the four modes with and without the
  plant's dynamics and creep; they must agree with the reference to 1e-9
  relative on rms_error and sample by sample on the trace.
* A faulty FMU (a communication step it refuses with fmi2Discard) stops the
  loop with a message naming the FMU and keeps the trace up to that step.

FMUs are built once for the module into a tmp dir.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import control as ct
import numpy as np
import pytest

import fonbw
from fonbw import loop
from fonbw.cli import main as fonbw_main
from fonbw.data import DEFAULT_MODEL
from fonbw.plant import mechanics

DT = 1e-4
T = 0.1                      # 1000 steps per run
PLANTS = ("none", "dynamics+creep")
REL = 1e-9
CASES = [dict(scenario="sine5", mode=m, plant=p, T=T) for p in PLANTS for m in loop.MODES]
TRACE_KEYS = ("t", "r", "u", "y", "e")

DRIVER = r'''
import json, os, sys
import numpy as np
from fonbw.loop import run_cosim
master, fmu_dir, cases_file, out = sys.argv[1:5]
cases = json.load(open(cases_file))
arrays, report = {}, []
keys = ("rms_error", "max_error", "rms_input", "steps", "error", "wall_s", "setup_s")
for i, kw in enumerate(cases):
    entry = {}
    # the reference in the same process: the same fonbw sources for both, even
    # while the shared tree is being edited
    for tag, m in (("ref", "reference"), ("run", master)):
        try:
            r = run_cosim(master=m, fmu_dir=fmu_dir, **kw)
        except Exception as e:
            entry[tag] = {"exception": f"{type(e).__name__}: {e}"}
            continue
        entry[tag] = {k: getattr(r, k) for k in keys}
        for k in ("t", "r", "u", "y", "e"):
            arrays[f"{i}_{tag}_{k}"] = getattr(r, k)
    report.append(entry)
np.savez(out + ".npz", **arrays)
with open(out + ".json", "w") as fh:
    json.dump(report, fh, indent=1)
# the results are on disk: leave without the interpreter's teardown, in which
# a master's still-loaded Python slaves once aborted the process (glibc
# "corrupted double-linked list", libcosim, a fresh-clone run; the same run
# alone passed). What is tested here is the co-simulation, not the unloading.
sys.stdout.flush()
sys.stderr.flush()
os._exit(0)
'''


@pytest.fixture(scope="module")
def fmu_dir(loop_fmus_dir):
    return loop_fmus_dir


def _drive(master, fmu_dir, cases, tag):
    work = Path(fmu_dir)
    cf = work / f"{tag}_cases.json"
    cf.write_text(json.dumps(cases))
    out = work / tag
    r = subprocess.run([sys.executable, "-c", DRIVER, master, str(fmu_dir), str(cf), str(out)],
                       capture_output=True, text=True, timeout=600, cwd=str(work))
    if r.returncode != 0:
        pytest.fail(f"{master} driver failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    arr = dict(np.load(str(out) + ".npz"))
    rep = json.loads(Path(str(out) + ".json").read_text())
    return [{tag: ({k: arr.get(f"{i}_{tag}_{k}") for k in TRACE_KEYS}, rep[i][tag])
             for tag in ("ref", "run")} for i in range(len(cases))]


FAULT_CASES = [
    # T not a whole multiple of dt: the final 0.5 dt step is refused by the FMUs
    dict(scenario="sine5", mode="ff+fb", plant="dynamics+creep", T=0.05 + 0.5 * DT),
]


@pytest.fixture(scope="module")
def fmpy_runs(fmu_dir):
    return _drive("fmpy", fmu_dir, CASES + FAULT_CASES, "fmpy")


@pytest.fixture(scope="module")
def libcosim_runs(fmu_dir):
    bad = [dict(scenario="sine5", mode="fb", plant="dynamics+creep", T=0.01,
                fmu_overrides={"hyst": {"dt": 2 * DT}})]
    return _drive("libcosim", fmu_dir, CASES + bad, "libcosim")


@pytest.fixture(scope="module")
def reference_runs():
    return [loop.run_cosim(master="reference", **kw) for kw in CASES]


def _assert_same(pair, what):
    (tr_ref, ref), (tr, rep) = pair["ref"], pair["run"]
    assert "exception" not in ref, ref
    assert "exception" not in rep, rep
    assert rep["error"] is None, rep["error"]
    assert rep["steps"] == ref["steps"] == int(round(T / DT))
    for key in ("rms_error", "max_error", "rms_input"):
        assert abs(rep[key] - ref[key]) <= REL * abs(ref[key]), (what, key, rep[key], ref[key])
    for key in TRACE_KEYS:
        a, b = np.asarray(tr[key]), tr_ref[key]
        assert a.shape == b.shape, (what, key)
        scale = max(float(np.max(np.abs(b))), 1e-300)
        assert float(np.max(np.abs(a - b))) <= REL * scale, (what, key)


@pytest.mark.parametrize("i", range(len(CASES)), ids=[f"{c['mode']}-{c['plant']}" for c in CASES])
def test_fmpy_master_agrees_with_reference(fmpy_runs, i):
    _assert_same(fmpy_runs[i], f"fmpy {CASES[i]}")


@pytest.mark.parametrize("i", range(len(CASES)), ids=[f"{c['mode']}-{c['plant']}" for c in CASES])
def test_libcosim_master_agrees_with_reference(libcosim_runs, i):
    _assert_same(libcosim_runs[i], f"libcosim {CASES[i]}")


@pytest.mark.parametrize("i", [i for i, c in enumerate(CASES) if c["plant"] == "none"],
                         ids=[c["mode"] for c in CASES if c["plant"] == "none"])
def test_actuator_in_the_loop_is_the_model(reference_runs, i):
    # Without a plant the measured output is the hysteresis block's: the
    # model's batch simulation of the voltage the loop applied, exactly.
    tr = reference_runs[i].trace
    model = fonbw.load_model(DEFAULT_MODEL)
    y = model.simulate(tr["u"], DT)
    assert np.max(np.abs(y - tr["y"])) <= 1e-12 * np.max(np.abs(y))


# A parameter set fonbw.compensate can invert sample by sample (its own tests'
# FONBW set): kh rho > 0, so the one-sample map u_k -> y_k increases.
INVERTIBLE = dict(ku=[0.15, -1e-4, -5e-8], kh=2.0, rho=0.02, sigma=0.8, n=1.5, lam1=0.95, lam2=0.85)


def test_feedforward_with_exact_model_tracks():
    # The compensator inverts the same model the actuator runs, no plant: the
    # chain reproduces H_d to the compensator's solver tolerance (the loop
    # feeds it the reference one step ahead, so the pipeline adds no latency).
    m = fonbw.FONBW(**INVERTIBLE)
    r = loop.run_cosim("sine5", "ff", "reference", T=0.5, models={"compensator": m})
    assert np.ptp(r.u) > 50.0  # V
    assert r.diagnostics["compensator"] == {"saturated_samples": 0, "unconverged_samples": 0}
    assert r.max_error <= 1e-4, r.max_error  # um, of a 10 um stroke
    # with dynamics and creep the feedforward leaves an error that feedback removes
    ff = loop.run_cosim("sine5", "ff", "reference", T=0.5, plant="dynamics+creep",
                         models={"compensator": m})
    both = loop.run_cosim("sine5", "ff+fb", "reference", T=0.5, plant="dynamics+creep",
                           models={"compensator": m})
    assert ff.rms_error > 0.03 and both.rms_error < 0.05 * ff.rms_error, (
        ff.rms_error, both.rms_error)


def _started(T=0.2):
    from fonbw.compensate.rest import rest_start_meta

    # a bipolar range: after a full cycle the descending branch of a smaller loop
    # ends above the zero at 0 V (Bouc-Wen has no return-point memory), so its
    # bottom needs a few volts below 0
    m = fonbw.FONBW(**INVERTIBLE)
    m.meta = {"u_range": [-20.0, 120.0], "start": rest_start_meta((-20.0, 120.0), T=T)}
    return m


def test_loop_runs_the_models_recorded_start():
    # A model identified behind a rest cycle: the loop's actuator and its
    # compensator both run that cycle and count from its end, so feedforward
    # with the exact model still tracks to the solver tolerance; an actuator
    # started from its virgin state instead misses the bottoms by far more.
    m = _started()
    same = loop.run_cosim("sine5", "ff", "reference", T=0.5, models={"compensator": m, "hysteresis": m})
    assert same.diagnostics["compensator"] == {"saturated_samples": 0, "unconverged_samples": 0}
    # 7e-4 um: the loop's first sample applies its initial 0 V before the
    # compensator's first voltage, and behind a cycle the fractional memory
    # still relaxes at 0 V (from the virgin state it does not: 2e-5 um)
    assert same.max_error <= 1e-3, same.max_error
    virgin = loop.run_cosim("sine5", "ff", "reference", T=0.5,
                            models={"compensator": m, "hysteresis": fonbw.FONBW(**INVERTIBLE)})
    assert virgin.max_error > 0.05, virgin.max_error
    # the actuator block is the model's batch run behind its start (an independent path)
    from fonbw.compensate.rest import start_history

    pre = start_history(m, DT)
    y = m.simulate(np.concatenate([pre, same.u]), DT)
    assert np.max(np.abs(y[pre.size:] - y[pre.size - 1] - same.y)) <= 1e-9


def test_fmu_masters_run_the_models_recorded_start(fmu_dir, tmp_path):
    # The FMUs take the start (rest_lo, rest_hi, rest_T) and the compensator's
    # limits as parameters the master sets from the model: fmpy with the
    # pythonfmu and the native FMUs, libcosim with the native ones, all equal
    # to the reference master's trace
    path = tmp_path / "started.json"
    _started().save(path)
    models = {"compensator": str(path), "hysteresis": str(path)}
    case = dict(scenario="sine5", mode="ff+fb", plant="dynamics+creep", T=T, models=models)
    runs = _drive("fmpy", fmu_dir, [case, {**case, "native": True}], "fmpy_started")
    runs += _drive("libcosim", fmu_dir, [{**case, "native": True}], "libcosim_started")
    for i, pair in enumerate(runs):
        _assert_same(pair, f"started model, run {i}")
    ref = loop.run_cosim(master="reference", **{**case, "models": {"compensator": _started(),
                                                                   "hysteresis": fonbw.FONBW(**INVERTIBLE)}})
    assert abs(ref.rms_error - runs[0]["ref"][1]["rms_error"]) > 1e-3  # the start changes the run


def test_feedforward_with_the_default_model_is_reported(reference_runs):
    # The shipped parameter set (models/fonbw_default.json, the paper's Table 1)
    # has no stable per-sample inverse at 10 kHz (kh rho < 0, lam1 > lam2: the
    # one-sample map u_k -> y_k decreases; documented in fonbw/compensate.py):
    # the compensator parks at 0 V. The loop must report that, and feedback
    # must still do its job around the idle feedforward.
    rr = {(c["mode"], c["plant"]): r for c, r in zip(CASES, reference_runs)}
    ff = rr[("ff", "none")]
    sat = ff.diagnostics["compensator"]["saturated_samples"]
    assert sat >= 0.99 * ff.steps, ff.diagnostics
    assert ff.rms_error > 0.5 * np.ptp(ff.r) / 2  # it really did not track
    for pl in PLANTS:
        both, fb = rr[("ff+fb", pl)], rr[("fb", pl)]
        assert abs(both.rms_error - fb.rms_error) <= 1e-3 * fb.rms_error
        assert both.rms_error < 0.5 * rr[("open", pl)].rms_error


def test_open_loop_input_is_scaled_reference(reference_runs):
    tr = reference_runs[CASES.index(dict(scenario="sine5", mode="open", plant="none", T=T))].trace
    k_lin = loop.linear_gain(fonbw.load_model(DEFAULT_MODEL), DT)
    np.testing.assert_array_equal(tr["u"], tr["r"] / k_lin)


def test_feedback_reduces_the_hysteresis_error(reference_runs):
    rms = {(c["mode"], c["plant"]): r.rms_error for c, r in zip(CASES, reference_runs)}
    for pl in PLANTS:
        assert rms[("fb", pl)] < 0.5 * rms[("open", pl)], rms


@pytest.mark.parametrize("scenario", ["step", "multi"])
def test_linear_loop_matches_python_control(scenario):
    # Known linear plant, no hysteresis, controller without limits: the
    # co-simulated loop is z^-1 K(z) P(z) closed by unit feedback (the
    # one-step alignment of the controller's inputs, fonbw.loop's docstring).
    P = ct.ss(0.15 * mechanics())
    spec = loop.controller_spec(0.5, 3000.0, 0.0, DT, None, None)
    r = loop.run_cosim(scenario, "fb", "reference", T=0.2, plant=P, hysteresis=False,
                        models={"controller": spec})
    tr = r.trace
    assert r.error is None and r.config["blocks"] == ["ctrl", "plant"]
    Pd = ct.c2d(ct.ss(P.A, P.B, P.C, P.D), DT)
    K = loop.LoopController(spec).pid.to_tf()
    z1 = ct.tf([1.0], [1.0, 0.0], DT)
    y = ct.forced_response(ct.feedback(z1 * K * Pd, 1), T=tr["t"], U=tr["r"]).outputs
    assert np.max(np.abs(y - tr["y"])) <= 1e-9 * np.max(np.abs(y))
    assert np.max(np.abs(tr["y"])) > 1.0


def test_designed_controller_has_margins():
    k = loop.linear_gain(fonbw.load_model(DEFAULT_MODEL), DT)
    for pl in ("none", "dynamics"):
        d = loop.design_controller(k, pl, DT)["design"]
        assert d["gain_margin"] >= 2.0 and d["phase_margin_deg"] >= 45.0, (pl, d)


def test_refused_step_stops_fmpy_loop_and_keeps_trace(fmpy_runs):
    tr, rep = fmpy_runs[len(CASES)]["run"]
    assert "exception" not in rep, rep
    n = int(round(0.05 / DT))
    assert rep["steps"] == n and tr["y"].shape == (n,)
    msg = rep["error"]
    assert msg and "fmi2Discard" in msg and "not a whole multiple" in msg and f"step {n}" in msg, msg
    # the kept trace is the normal run's (first 500 steps of the 1000-step run)
    full, _ = fmpy_runs[CASES.index(dict(scenario="sine5", mode="ff+fb", plant="dynamics+creep", T=T))]["ref"]
    np.testing.assert_allclose(tr["y"], full["y"][:n], rtol=0, atol=1e-9 * np.max(np.abs(tr["y"])))


def test_refused_step_stops_reference_loop_the_same_way():
    r = loop.run_cosim("sine5", "fb", "reference", T=0.01 + 0.5 * DT)
    assert r.steps == 100 and len(r.y) == 100
    assert "step 100" in r.error and "not a whole multiple" in r.error


def test_refused_step_stops_libcosim_loop(libcosim_runs):
    tr, rep = libcosim_runs[len(CASES)]["run"]
    assert "exception" not in rep, rep
    assert rep["steps"] == 0 and tr["y"].shape == (0,)
    assert "hyst" in rep["error"] and "step 0" in rep["error"], rep["error"]


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="mode"):
        loop.run_cosim("sine5", "bogus")
    with pytest.raises(ValueError, match="scenario"):
        loop.run_cosim("nope", "fb")
    with pytest.raises(ValueError, match="master"):
        loop.run_cosim("sine5", "fb", "simulink")
    with pytest.raises(ValueError, match="plant"):
        loop.run_cosim("sine5", "fb", plant="wobbly")


def test_cli_writes_json_and_csv(tmp_path, capsys):
    j, c = tmp_path / "r.json", tmp_path / "tr.csv"
    rc = fonbw_main(["cosim", "--scenario", "sine5", "--mode", "fb", "--T", "0.02",
                     "--json", str(j), "--csv", str(c)])
    assert rc == 0
    d = json.loads(j.read_text())
    assert d["steps"] == 200 and d["rms_error"] > 0
    rec = fonbw.read_record(c, need=("u", "y"))
    assert len(rec.t) == 200
    assert fonbw_main(["cosim", "--scenario", "sine5", "--mode", "fb", "--T", "-1"]) == 2
    assert "fonbw cosim:" in capsys.readouterr().err


def test_concurrent_unzips_share_one_complete_folder(loop_fmus_dir, tmp_path):
    import concurrent.futures
    import shutil

    from fonbw.loop.blocks import unzip

    fmu = tmp_path / "FonbwHysteresis.fmu"
    shutil.copy2(loop_fmus_dir / "FonbwHysteresis.fmu", fmu)
    with concurrent.futures.ProcessPoolExecutor(4) as ex:
        dirs = set(ex.map(unzip, [fmu] * 8))
    assert dirs == {fmu.with_suffix(".unzipped")}
    d = dirs.pop()
    assert (d / "modelDescription.xml").is_file() and (d / "binaries" / "linux64").is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["FonbwHysteresis.fmu", "FonbwHysteresis.unzipped"]


def test_linear_gain_runs_the_model_start_over_its_range():
    from fonbw.compensate.rest import rest_cycle, rest_start_meta

    m = fonbw.load_model(DEFAULT_MODEL)
    # no range, no start: the ramp 0 -> 120 V from the virgin state
    u = np.linspace(0.0, 120.0, int(round(1.0 / DT)))
    assert loop.linear_gain(m, DT) == pytest.approx(m.simulate(u, DT)[-1] / 120.0, rel=1e-12)
    # a bipolar stage behind its rest cycle: 0 -> 90 V after the cycle, by hand
    m.meta = {"u_range": [-90.0, 90.0], "start": rest_start_meta((-90.0, 90.0), T=0.1)}
    pre = rest_cycle((-90.0, 90.0), DT, T=0.1)
    u = np.linspace(0.0, 90.0, int(round(1.0 / DT)))
    y = m.simulate(np.concatenate([pre, u]), DT)[pre.size:]
    k = loop.linear_gain(m, DT)
    assert k == pytest.approx((y[-1] - y[0]) / 90.0, rel=1e-12)
    assert abs(k - m.simulate(u, DT)[-1] / 90.0) > 1e-3 * abs(k)
    # a range below 0 V: the ramp runs down from rest
    u = np.linspace(0.0, -90.0, int(round(1.0 / DT)))
    y = m.simulate(np.concatenate([pre, u]), DT)[pre.size:]
    assert loop.linear_gain(m, DT, u_range=(-90.0, 0.0)) == pytest.approx((y[-1] - y[0]) / -90.0, rel=1e-12)
    with pytest.raises(ValueError, match="low < high"):
        loop.linear_gain(m, DT, u_range=(1.0, 1.0))
