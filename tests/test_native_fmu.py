"""The native C FMUs: validation, agreement with the library, a C host with an
empty environment, fmpy and libcosim, and the win64 DLL under wine."""
from __future__ import annotations

import re
import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

import fonbw
from fonbw.data import DEFAULT_MODEL, DEFAULT_PLANT
from fonbw.fmu import native

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed: no linux64 binary")
HAVE_WIN = shutil.which("x86_64-w64-mingw32-gcc") is not None and shutil.which("wine") is not None
DT = 1e-4


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """The three native FMUs, built once, extracted beside themselves."""
    out = tmp_path_factory.mktemp("native")
    paths = native.build_native(out)
    d = {}
    for p in paths:
        kind = next(k for k, v in native.NATIVE_NAMES.items() if v == p.stem)
        ex = out / p.stem
        zipfile.ZipFile(p).extractall(ex)
        guid = re.search(r'guid="([^"]+)"', (ex / "modelDescription.xml").read_text()).group(1)
        d[kind] = {"fmu": p, "dir": ex, "guid": guid, "so": ex / "binaries/linux64" / (p.stem + ".so"),
                   "dll": ex / "binaries/win64" / (p.stem + ".dll")}
    return d


@pytest.fixture(scope="module")
def host(fmus, tmp_path_factory):
    """The C host of fonbw/fmu/csrc/fmu_host.c, compiled with gcc."""
    exe = tmp_path_factory.mktemp("host") / "fmu_host"
    subprocess.run(["gcc", "-std=c99", "-D_POSIX_C_SOURCE=200809L", "-O2", "-I",
                    str(fmus["hysteresis"]["dir"] / "sources"), "-o", str(exe),
                    str(native.NATIVE_DIR / "fmu_host.c"), "-ldl", "-lm"], check=True)
    return exe


def _run_fmpy(f, u, memory=None, params=None, h=DT):
    """Step the FMU with fmpy's FMU2Slave over the input u; returns the outputs."""
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(f["fmu"]))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s = FMU2Slave(guid=md.guid, unzipDirectory=str(f["dir"]),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="t")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    if memory:
        s.setString([vr["memory"]], [memory])
    for k, v in (params or {}).items():
        s.setReal([vr[k]], [v])
    s.exitInitializationMode()
    iv, ov = md.modelVariables[0].valueReference, md.modelVariables[1].valueReference
    y = np.empty(len(u))
    for k, uk in enumerate(u):
        s.setReal([iv], [float(uk)])
        s.doStep(k * h, h)
        y[k] = s.getReal([ov])[0]
    s.terminate()
    s.freeInstance()
    return y


def _model(**kw):
    m = fonbw.load_model(str(DEFAULT_MODEL))
    return fonbw.FONBW(**{**m.as_fonbw().params, **kw})


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def test_validate_and_layout(fmus):
    from fmpy.validation import validate_fmu

    for f in fmus.values():
        assert validate_fmu(str(f["fmu"])) == []  # includes the FMI 2.0 XSD
        md = (f["dir"] / "modelDescription.xml").read_text()
        assert "<SourceFiles>" in md and 'canSerializeFMUstate="true"' in md
        assert (f["dir"] / "sources" / "fmi2Functions.h").is_file() and f["so"].is_file()


@pytest.mark.slow
@pytest.mark.parametrize("memory", ["fast", "exact"])
def test_hysteresis_agrees(fmus, memory):
    from fonbw.signals import eq19_input

    _, u = eq19_input(1e4, 10.0)
    s = _model(memory=memory).stepper(DT)
    ref = np.array([s.step(x) for x in u])
    y = _run_fmpy(fmus["hysteresis"], u, memory)
    assert len(u) == 100_000 and _rel(y, ref) <= 1e-12


@pytest.mark.slow
@pytest.mark.parametrize("memory,n", [("fast", 100_000), ("exact", 20_000)])
def test_compensator_agrees(fmus, memory, n):
    from fonbw.signals import eq19_input

    _, u = eq19_input(1e4, 10.0)
    m = _model(memory=memory)
    inv = _model(memory=memory, kh=-m.kh)  # one-step slope > 0: invertible
    for model, params in ((inv, {"kh": inv.kh}), (m, None)):
        hd = model.simulate(u[:n], DT)
        c = fonbw.compensator(model, DT)
        ref = np.array([c.step(x) for x in hd])
        got = _run_fmpy(fmus["compensator"], hd, memory, params)
        assert np.max(np.abs(got - ref)) <= 1e-12 * np.max(np.abs(ref))


def test_compensator_runs_the_recorded_rest_cycle(tmp_path):
    """A model identified after a rest cycle (meta "start"): the native
    compensator runs that cycle at initialization and counts its output from
    the end of it, as the library's compensator does; from rest it would not
    reach the bottom of the trajectory."""
    from fonbw.compensate.rest import rest_start_meta
    from fonbw.fmu.build import model_resource

    m0 = _model()
    m = _model(kh=-m0.kh)  # invertible
    m.meta = {"u_range": [-20.0, 100.0], "start": rest_start_meta((-20.0, 100.0), T=0.05)}
    fmu = native.build_native_one("compensator", model_resource(m, DT), tmp_path, platforms=["linux64"])
    ex = tmp_path / "x"
    zipfile.ZipFile(fmu).extractall(ex)
    f = {"fmu": fmu, "dir": ex}
    t = np.arange(3000) * DT
    hd = 4.0 * (1.0 - np.cos(2 * np.pi * 5.0 * t))  # from the rest zero up and back
    ref = fonbw.compensator(m, DT)
    u_ref = np.array([ref.step(x) for x in hd])
    from_rest = fonbw.compensator(m, DT, history=())
    u_rest = np.array([from_rest.step(x) for x in hd])
    got = _run_fmpy(f, hd)
    assert np.max(np.abs(got - u_ref)) <= 1e-11 * np.max(np.abs(u_ref))
    assert np.max(np.abs(u_rest - u_ref)) > 1.0  # the start matters: the test can tell
    # a cycle longer than REST_MAX_STEPS steps is refused at initialization, not run
    from fmpy.fmi1 import FMICallException  # raised by FMU2Slave on an fmi2Error

    with pytest.raises(FMICallException, match="fmi2ExitInitializationMode"):
        _run_fmpy(f, hd[:5], params={"rest_T": 1e5})  # 1e9 steps of 1e-4 s
    # the hysteresis FMU runs the same start: the model behind its cycle, counted from its end
    from fonbw.compensate.rest import started_stepper

    fmu_h = native.build_native_one("hysteresis", model_resource(m, DT), tmp_path / "h", platforms=["linux64"])
    zipfile.ZipFile(fmu_h).extractall(tmp_path / "hx")
    st = started_stepper(m, DT)
    y_ref = np.array([st.step(x) for x in u_ref])
    y = _run_fmpy({"fmu": fmu_h, "dir": tmp_path / "hx"}, u_ref)
    assert np.max(np.abs(y - y_ref)) <= 1e-11 * np.max(np.abs(y_ref))
    assert np.max(np.abs(y - hd)) <= 1e-9  # and the hysteresis inverts the compensator


def test_plant_agrees_with_control(fmus):
    import control

    from fonbw.fmu.build import plant_resource

    r = plant_resource(str(DEFAULT_PLANT))
    sysd = control.c2d(control.ss(*[np.array(r[k]) for k in "ABCD"]), DT)
    u = np.sin(np.arange(3000) * 0.01) * 10.0
    ref = control.forced_response(sysd, U=u).outputs
    y = _run_fmpy(fmus["plant"], u)
    assert _rel(y[:-1], ref[1:]) <= 1e-12  # output after step k: C x_(k+1)


def test_sources_alone_build_the_same_binary(fmus, host, tmp_path):
    """What another tool does with sources/: compile the files the model
    description lists, nothing else; the result steps like the shipped
    binary, bit for bit."""
    for kind in ("hysteresis", "compensator"):
        f = fmus[kind]
        md = (f["dir"] / "modelDescription.xml").read_text()
        listed = re.findall(r'<File name="([^"]+)"', md)
        assert set(listed) == set(native.C_SOURCES)  # the split sources, all of them
        so = tmp_path / f"{kind}.so"
        subprocess.run(["gcc", "-std=c99", "-O3", "-ffp-contract=off", "-shared", "-fPIC", "-I",
                        str(f["dir"] / "sources"), "-o", str(so),
                        *[str(f["dir"] / "sources" / x) for x in listed], "-lm"], check=True)
        runs = [subprocess.run([str(host), "run", str(lib), f["guid"], "", "2000"], capture_output=True,
                               text=True, timeout=120) for lib in (so, f["so"])]
        assert runs[0].returncode == runs[1].returncode == 0, runs[0].stderr
        assert len(runs[0].stdout.split()) == 2000 and runs[0].stdout == runs[1].stdout


def test_signal_fmu_plays_its_table(tmp_path):
    """FonbwSignalNative: y = sample k after k internal steps, read back bit
    for bit from the text table, the last sample held past the end; a
    missing table is refused at initialization."""
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave
    from fmpy.validation import validate_fmu

    fmu = native.build_signal(tmp_path, DT, ["linux64"])
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    with zipfile.ZipFile(fmu) as z:
        listed = re.findall(r'<File name="([^"]+)"', z.read("modelDescription.xml").decode())
        assert listed == list(native.C_SOURCES) and "sources/fonbw_table.c" in z.namelist()
    rng = np.random.default_rng(7)
    x = rng.standard_normal(300) * 10.0 ** rng.integers(-12, 12, 300)
    table = tmp_path / "x.txt"
    table.write_text("\n".join(map(repr, x.tolist())) + "\n")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    d = tmp_path / "signal"
    zipfile.ZipFile(fmu).extractall(d)

    def start(path):
        s = FMU2Slave(guid=md.guid, unzipDirectory=str(d), modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="s")
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        s.setString([vr["file"]], [str(path)])
        s.enterInitializationMode()
        s.exitInitializationMode()
        return s

    s = start(table)
    assert s.getString([vr["file"]]) == [str(table).encode()]
    # a reset forgets the table and the file; initialized again it plays from the start
    s.reset()
    assert s.getString([vr["file"]]) == [b""]
    s.setupExperiment(startTime=0.0)
    s.setString([vr["file"]], [str(table)])
    s.enterInitializationMode()
    s.exitInitializationMode()
    got = [s.getReal([vr["y"]])[0]]
    t = 0.0
    for h in [DT] * 200 + [2 * DT] * 60:  # a step of 2 dt advances two samples
        s.doStep(t, h)
        t += h
        got.append(s.getReal([vr["y"]])[0])
    s.terminate()
    s.freeInstance()
    want = np.concatenate([x[:201], x[202:300:2], np.full(11, x[-1])])
    assert np.array_equal(np.array(got), want)
    with pytest.raises(Exception):
        start(tmp_path / "missing.txt")
    # CRLF, blank and whitespace-only lines are skipped, not read as 0
    crlf = tmp_path / "crlf.txt"
    crlf.write_bytes(b"1.5\r\n\r\n  \t\r\n-2.25  \r\n   \n")
    s = start(crlf)
    got = [s.getReal([vr["y"]])[0]]
    s.doStep(0.0, DT)
    got.append(s.getReal([vr["y"]])[0])
    with pytest.raises(Exception):  # the model description offers no FMU state
        s.getFMUstate()
    s.terminate()
    s.freeInstance()
    assert got == [1.5, -2.25]
    bad = tmp_path / "bad.txt"
    bad.write_text("1\n2 3\n")
    with pytest.raises(Exception):
        start(bad)


def test_step_not_multiple_discards(fmus):
    with pytest.raises(Exception, match="2"):  # fmi2Discard raises in fmpy
        _run_fmpy(fmus["hysteresis"], [1.0], h=1.5 * DT)


@pytest.mark.parametrize("pair", [("hysteresis", "plant"), ("compensator", "hysteresis")])
def test_c_host_empty_environment(fmus, host, pair):
    a, b = fmus[pair[0]], fmus[pair[1]]
    r = subprocess.run(["env", "-i", str(host), "check", str(a["so"]), a["guid"], "", str(b["so"]), b["guid"], "",
                        "3000"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr
    assert "invalid parameters: kh = nan is not finite" in r.stderr


def test_fmpy_and_libcosim_chain(fmus):
    """Open-loop chain hysteresis -> plant in libcosim against the library."""
    pytest.importorskip("libcosimpy")
    import control
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    from fonbw.fmu.build import plant_resource
    from fonbw.plant import LinearStepper
    from fonbw.signals import eq19_input

    n = 2000
    _, u = eq19_input(1e4, 10.0)
    u = u[:n]
    r = plant_resource(str(DEFAULT_PLANT))
    y = _model().simulate(u, DT)
    x_ref = LinearStepper(control.ss(*[np.array(r[k]) for k in "ABCD"]), DT).simulate(np.append(y, 0.0))[1:]
    ex = CosimExecution.from_step_size(round(DT * 1e9))
    h = ex.add_local_slave(CosimLocalSlave(fmu_path=str(fmus["hysteresis"]["fmu"]), instance_name="h"))
    p = ex.add_local_slave(CosimLocalSlave(fmu_path=str(fmus["plant"]["fmu"]), instance_name="p"))
    assert ex.connect_real_variables(h, 1, p, 0) == 0  # C status
    man, obs = CosimManipulator.create_override(), CosimObserver.create_last_value()
    ex.add_manipulator(man)
    ex.add_observer(obs)
    hy, px = [], []
    for k in range(n):
        man.slave_real_values(h, [0], [float(u[k])])
        assert ex.step(1)
        hy.append(obs.last_real_values(h, [1])[0])
        px.append(obs.last_real_values(p, [1])[0])
    assert _rel(np.array(hy), y) <= 1e-12
    # the plant sees h's output one communication step late (Jacobi-style connection)
    x_lag = LinearStepper(control.ss(*[np.array(r[k]) for k in "ABCD"]), DT).simulate(np.append(0.0, y))[1:]
    assert min(_rel(np.array(px), x_ref), _rel(np.array(px), x_lag[:n])) <= 1e-12


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_WIN, reason="x86_64-w64-mingw32-gcc or wine not installed: win64 not tested")
def test_win64_dll_under_wine(fmus, host, tmp_path):
    exe = tmp_path / "fmu_host.exe"
    f = fmus["hysteresis"]
    subprocess.run(["x86_64-w64-mingw32-gcc", "-std=c99", "-O2", "-I", str(f["dir"] / "sources"), "-o", str(exe),
                    str(native.NATIVE_DIR / "fmu_host.c"), "-lm"], check=True)
    args = ["run", None, f["guid"], "", "3000"]
    win = subprocess.run(["wine", str(exe), *(args[:1] + [str(f["dll"])] + args[2:])], capture_output=True,
                         text=True, timeout=300, env={"WINEDEBUG": "-all", "PATH": "/usr/bin:/bin",
                                                      "HOME": str(Path.home())})
    lin = subprocess.run([str(host), *(args[:1] + [str(f["so"])] + args[2:])], capture_output=True, text=True)
    assert win.returncode == 0, win.stderr[-2000:]
    a, b = np.array(win.stdout.split(), float), np.array(lin.stdout.split(), float)
    assert len(a) == len(b) == 3000 and _rel(a, b) <= 1e-12
    # two instances + another FMU in one process, rollback, a bad parameter: under wine too
    g = fmus["plant"]
    chk = subprocess.run(["wine", str(exe), "check", str(f["dll"]), f["guid"], "", str(g["dll"]), g["guid"], "",
                          "3000"], capture_output=True, text=True, timeout=300,
                         env={"WINEDEBUG": "-all", "PATH": "/usr/bin:/bin", "HOME": str(Path.home())})
    assert chk.returncode == 0 and chk.stdout.strip() == "ok", chk.stderr[-2000:]
    assert "invalid parameters: kh = nan is not finite" in chk.stderr
