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


REFERENCE = r'''
import json, sys
import numpy as np
root, work, bundle = sys.argv[1], sys.argv[2], sys.argv[3]
# fonbw as bundled in the FMU (byte-identical to this repository's fonbw/ at
# build time), imported the way the FMU imports it, but without any FMU code
sys.path.insert(0, bundle)
from fonbw_fmu_common import use_bundled_fonbw
use_bundled_fonbw(bundle)
import fonbw
assert not fonbw.__file__.startswith(root + "/fonbw/"), fonbw.__file__
cfg = json.load(open(work + "/config.json"))
sig = np.load(work + "/signals.npz")
N, dt = cfg["N"], cfg["DT"]
u, y_ref = sig["u"][:N], sig["y_ref"][:N]
base = fonbw.load_model(root + "/models/fonbw_default.json")
p = dict(base.params)
alt = fonbw.FONBW(**{**p, **cfg["ALT_PARAMS"]})
alt.save(work + "/alt.json")
out = {
    "y_def": base.simulate(u, dt),
    "y_set": fonbw.FONBW(**{**p, **cfg["SET_PARAMS"]}).simulate(u[:cfg["N_SHORT"]], dt),
    "y_alt": alt.simulate(u[:cfg["N_SHORT"]], dt),
    **{"eng_" + e: fonbw.FONBW(**{**p, "memory": e}).simulate(u[:cfg["N_SHORT"]], dt)
       for e in cfg["ENGINES"]},
    # communication step 10 dt: the FMU holds u over 10 internal steps
    "y_zoh10": base.simulate(np.repeat(u[:cfg["N_SHORT"]:10], 10), dt),
}
import fonbw.plant
out["mech_fr"] = fonbw.plant.mechanics()(2j * np.pi * np.array(cfg["FREQS"]))
try:
    out["u_comp"] = np.asarray(fonbw.compensate(base, y_ref, dt), dtype=float)
    sat = fonbw.compensate(base, np.array(cfg["Y_SAT"]), dt)
    out["sat_u"], out["sat_status"] = sat.u, sat.status.astype(float)
    ns = cfg["N_SHORT"]
    out["y_chain"] = base.simulate(np.concatenate([[0.0], out["u_comp"][:ns - 1]]), dt)
except Exception as e:  # compensator not available: reported by its test
    print("compensate:", type(e).__name__, e)
np.savez(work + "/reference.npz", **out)
'''

FMPY_DRIVER = r'''
import importlib.util, json, sys, traceback
import numpy as np
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.simulation import instantiate_fmu
from fmpy.fmi1 import FMICallException

work = sys.argv[1]
cfg = json.load(open(work + "/config.json"))
sig = np.load(work + "/signals.npz")
N, NS, DT = cfg["N"], cfg["N_SHORT"], cfg["DT"]
rep = {"fonbw_importable_before": importlib.util.find_spec("fonbw") is not None}
arr = {}

def unzip(name, sub="default"):
    fmu = f"{work}/{sub}/{name}.fmu"
    d = extract(fmu, f"{work}/unzip/{sub}/{name}")
    return d, read_model_description(fmu)

logs = []
def logger(env, inst, status, cat, msg):
    logs.append((inst.decode() if inst else "", int(status), msg.decode(errors="replace")))

def new(d, md, name, params=None):
    s = instantiate_fmu(d, md, "CoSimulation", debug_logging=True, logger=logger)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    for k, v in (params or {}).items():
        if isinstance(v, str):
            s.setString([vr[k]], [v])
        else:
            s.setReal([vr[k]], [v])
    s.exitInitializationMode()
    return s, vr

def status_of(f, *a):
    try:
        f(*a)
        return 0
    except FMICallException as e:
        return int(e.status)

H = unzip("FonbwHysteresis"); C = unzip("FonbwCompensator"); P = unzip("FonbwLinearPlant")
A = unzip("FonbwHysteresis", "alt")
t = sig["t"]

def sim(fmu, inname, x, outname, stop=N * DT, step=DT):
    inp = np.array(list(zip(t, x)), dtype=[("time", float), (inname, float)])
    r = simulate_fmu(fmu[0], stop_time=stop, output_interval=step, input=inp, output=[outname])
    return np.asarray(r[outname], dtype=float)

# 1. batch runs under fmpy's own master, 2 s at 10 kHz
arr["hyst"] = sim(H, "u", sig["u"], "y")
arr["hyst_zoh10"] = sim(H, "u", sig["u"], "y", stop=NS * DT, step=10 * DT)
try:
    arr["comp"] = sim(C, "y_ref", sig["y_ref"], "u")
except Exception as e:
    rep["comp_error"] = f"{type(e).__name__}: {e}"
arr["plant"] = sim(P, "h", sig["h"], "x")
rep["fonbw_files"] = {k: getattr(m, "__file__", None) for k, m in sys.modules.items()
                      if k == "fonbw" or k.startswith("fonbw.")}

# 2. three instances in one process, stepped interleaved
inst = [new(*H, "A"), new(*H, "B", cfg["SET_PARAMS"]), new(*A, "C")]
ys = np.zeros((3, NS))
for k in range(NS):
    for s, vr in inst:
        s.setReal([vr["u"]], [sig["u"][k]])
    for s, vr in inst:
        s.doStep(k * DT, DT)
    for i, (s, vr) in enumerate(inst):
        ys[i, k] = s.getReal([vr["y"]])[0]
arr["indep"] = ys
for s, vr in inst:
    s.terminate(); s.freeInstance()

# 2b. the memory parameter selects the library's engine
for eng in cfg["ENGINES"]:
    s, vr = new(*H, "eng_" + eng, {"memory": eng})
    out = np.zeros(NS)
    for k in range(NS):
        s.setReal([vr["u"]], [sig["u"][k]])
        s.doStep(k * DT, DT)
        out[k] = s.getReal([vr["y"]])[0]
    arr["eng_" + eng] = out
    s.terminate(); s.freeInstance()

# 3. state: save -> run -> restore -> run; serialize -> new instance -> run
def run(s, vr, iname, oname, x, k0, n):
    out = []
    for k in range(k0, k0 + n):
        s.setReal([vr[iname]], [x[k]])
        s.doStep(k * DT, DT)
        out.append(s.getReal([vr[oname]])[0])
    return np.array(out)

cases = {"hyst_fast": (H, "u", "y", sig["u"], {"memory": "fast"}),
         "hyst_exact": (H, "u", "y", sig["u"], {"memory": "exact"}),
         "comp": (C, "y_ref", "u", sig["y_ref"], {}),
         "plant": (P, "h", "x", sig["h"], {})}
rep["state"] = {}
for name, (F, i, o, x, par) in cases.items():
    try:
        s, vr = new(*F, name, par)
        run(s, vr, i, o, x, 0, 300)
        st = s.getFMUstate()
        blob = s.serializeFMUstate(st)
        ya = run(s, vr, i, o, x, 300, 500)
        s.setFMUstate(st)
        yb = run(s, vr, i, o, x, 300, 500)
        s.freeFMUstate(st)
        s2, vr2 = new(*F, name + "2", par)
        st2 = s2.deSerializeFMUstate(blob)
        s2.setFMUstate(st2)
        yc = run(s2, vr2, i, o, x, 300, 500)
        s3, vr3 = new(*F, name + "3", par)
        yfresh = run(s3, vr3, i, o, x, 300, 500)
        arr[f"state_{name}"] = np.vstack([ya, yb, yc, yfresh])
        rep["state"][name] = {"bytes": len(blob)}
        for q in (s, s2, s3):
            q.terminate(); q.freeInstance()
    except Exception as e:
        rep["state"][name] = {"error": f"{type(e).__name__}: {e}"}

# 4. refused parameters: status of exitInitializationMode and of doStep, log lines
rep["bad_params"] = []
for name, value in cfg["BAD_PARAMS"]:
    logs.clear()
    entry = {"name": name}
    s = instantiate_fmu(H[0], H[1], "CoSimulation", debug_logging=True, logger=logger)
    vr = {v.name: v.valueReference for v in H[1].modelVariables}
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    if isinstance(value, str):
        s.setString([vr[name]], [value])
    else:
        s.setReal([vr[name]], [value])
    entry["exit_init_status"] = status_of(s.exitInitializationMode)
    entry["init_logs"] = list(logs)
    logs.clear()
    entry["step_status"] = status_of(s.doStep, 0.0, DT)
    entry["step_logs"] = list(logs)
    s.terminate(); s.freeInstance()
    rep["bad_params"].append(entry)

# 5. refused communication steps, then a valid step still works
logs.clear()
s, vr = new(*H, "step")
s.setReal([vr["u"]], [sig["u"][0]])
rep["bad_steps"] = []
for h in (1.5 * DT, 0.5 * DT, 0.0):
    logs.clear()
    rep["bad_steps"].append({"h": h, "status": status_of(s.doStep, 0.0, h), "logs": list(logs)})
rep["after_bad_status"] = status_of(s.doStep, 0.0, 3 * DT)
rep["after_bad_y"] = s.getReal([vr["y"]])[0]
logs.clear()
kh0 = s.getReal([vr["kh"]])[0]
rep["set_fixed_status"] = status_of(s.setReal, [vr["kh"]], [2 * kh0])
rep["set_fixed_logs"] = list(logs)
rep["kh_after"], rep["kh_before"] = s.getReal([vr["kh"]])[0], kh0
s2, vr2 = new(*H, "step2")
s2.setReal([vr2["u"]], [sig["u"][0]])
s2.doStep(0.0, 3 * DT)
rep["fresh_3dt_y"] = s2.getReal([vr2["y"]])[0]

# 6. a plant with direct feedthrough (D != 0), custom names and units
F = unzip("FonbwLinearPlant", "ft")
s, vr = new(*F, "ft")
rep["ft_y0"] = s.getReal([vr["w"]])[0]
s.setReal([vr["v"]], [2.0])
rep["ft_y_set"] = s.getReal([vr["w"]])[0]      # before any step: D v
s.doStep(0.0, DT)
rep["ft_y_step"] = s.getReal([vr["w"]])[0]     # C x_1 + D v
s.terminate(); s.freeInstance()

# 7. compensator with unreachable targets: status output and warning log lines
s, vr = new(*C, "sat")
logs.clear()
cs = []
for k, yr in enumerate(cfg["Y_SAT"]):
    s.setReal([vr["y_ref"]], [yr])
    s.doStep(k * DT, DT)
    cs.append((s.getReal([vr["u"]])[0], s.getInteger([vr["status"]])[0]))
arr["sat_u"], arr["sat_status"] = np.array(cs).T
rep["sat_logs"] = list(logs)
s.terminate(); s.freeInstance()

np.savez(work + "/fmpy_out.npz", **arr)
json.dump(rep, open(work + "/fmpy_report.json", "w"), indent=1)
print("driver done")
'''

COSIM_DRIVER = r'''
import json, sys
import numpy as np
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimSlave import CosimLocalSlave
from libcosimpy.CosimManipulator import CosimManipulator
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimLogging import log_output_level, CosimLogLevel

work = sys.argv[1]
cfg = json.load(open(work + "/config.json"))
sig = np.load(work + "/signals.npz")
NS, DT = cfg["N_SHORT"], cfg["DT"]
log_output_level(CosimLogLevel.WARNING)
FILES = {"hyst": "FonbwHysteresis", "comp": "FonbwCompensator", "plant": "FonbwLinearPlant"}
OUT = {"hyst": "y", "comp": "u", "plant": "x"}

def execution(slaves):
    ex = CosimExecution.from_step_size(round(DT * 1e9))  # nanoseconds
    idx = {n: ex.add_local_slave(CosimLocalSlave(fmu_path=f"{work}/default/{FILES[n.rstrip('2')]}.fmu",
                                                  instance_name=n)) for n in slaves}
    vr = {n: {v.name.decode(): v.reference for v in ex.slave_variables(i)} for n, i in idx.items()}
    man = CosimManipulator.create_override(); ex.add_manipulator(man)
    obs = CosimObserver.create_last_value(); ex.add_observer(obs)
    return ex, idx, vr, man, obs

def run(ex, idx, vr, man, obs, overrides):
    out = {n: np.zeros(NS) for n in idx}
    for k in range(NS):
        for n, (var, x) in overrides.items():
            man.slave_real_values(idx[n], [vr[n][var]], [x[k]])
        if not ex.step(1):
            raise RuntimeError(f"libcosim step {k} failed")
        for n in idx:
            out[n][k] = obs.last_real_values(idx[n], [vr[n][OUT[n.rstrip('2')]]])[0]
    return out

res, rep = {}, {}
# 1. hysteresis and plant, inputs from the override manipulator
ex = execution(["hyst", "plant"])
out = run(*ex, {"hyst": ("u", sig["u"]), "plant": ("h", sig["h"])})
res.update({"hyst": out["hyst"], "plant": out["plant"]})
del ex
# 2. open chain compensator -> hysteresis -> plant through libcosim connections
try:
    ex, idx, vr, man, obs = execution(["comp", "hyst2", "plant2"])
    ex.connect_real_variables(idx["comp"], vr["comp"]["u"], idx["hyst2"], vr["hyst2"]["u"])
    ex.connect_real_variables(idx["hyst2"], vr["hyst2"]["y"], idx["plant2"], vr["plant2"]["h"])
    out = run(ex, idx, vr, man, obs, {"comp": ("y_ref", sig["y_ref"])})
    res.update({"chain_" + k: v for k, v in out.items()})
except Exception as e:
    rep["chain_error"] = f"{type(e).__name__}: {e}"
np.savez(work + "/cosim_out.npz", **res)
json.dump(rep, open(work + "/cosim_report.json", "w"))
print("cosim done")
'''


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
