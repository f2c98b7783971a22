"""Driver scripts of the FMU tests (tests/test_fmu.py), run with ``python -c``.

Each runs in a fresh subprocess with the test's work folder as working
directory and PYTHONPATH unset, so that only the FMU (or, for REFERENCE, the
fonbw sources bundled in it) can provide fonbw.  They read ``config.json`` and
``signals.npz`` from the work folder and write their results next to them.

* REFERENCE (argv: repository root, work folder, bundled resources folder):
  the library's batch results, ``reference.npz`` (and ``alt.json``, the
  second parameter set);
* FMPY_DRIVER (argv: work folder): every fmpy scenario, ``fmpy_out.npz`` and
  ``fmpy_report.json``;
* COSIM_DRIVER (argv: work folder): the libcosim runs, ``cosim_out.npz`` and
  ``cosim_report.json``.
"""

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
