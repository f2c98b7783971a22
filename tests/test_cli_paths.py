"""Where the command line writes, and the inputs it refuses before any work:
outputs that would replace an input (named relatively or through a link),
unusable output paths, a drive that never moves, every candidate diverging,
bad provenance fields, parameter names and true/false values in a model
file (and one with a byte-order mark, which loads), a model that diverges
on the input, a diagnosis budget too small to search, a record whose
output never moves in strict JSON, and a held-out check that cannot run or
is cut short by Ctrl-C once the model is written, or whose fit diverges on
its record; a trajectory without its
column and plant files that are not one (each named in the refusal)."""
import json
import re

import numpy as np
import pytest

import fonbw
from fonbw.cli.main import main
from fonbw.io import write_csv
from fonbw.paper import TABLE1_FONBW

from cli_process import run


@pytest.fixture(scope="module")
def d(tmp_path_factory):
    d = tmp_path_factory.mktemp("paths")
    m = fonbw.FONBW(**TABLE1_FONBW)
    m.save(d / "model.json")
    t = np.arange(800) * 1e-3
    for i, f in enumerate((1.0, 2.0)):
        u = 60 - 60 * np.cos(2 * np.pi * f * t)
        write_csv(d / f"r{i}.csv", {"t": t, "u": u, "y": m.simulate(u, 1e-3)})
    write_csv(d / "input.csv", {"t": t, "u": 60 - 60 * np.cos(2 * np.pi * t)})
    return d


@pytest.mark.parametrize("args, victim", [
    (["simulate", "{d}/model.json", "{d}/input.csv", "-o", "{d}/input.csv"], "input.csv"),
    (["simulate", "{d}/model.json", "{d}/input.csv", "-o", "{d}/model.json"], "model.json"),
    (["identify", "{d}/r0.csv", "{d}/r1.csv", "-o", "{d}/r1.csv", "--max-evals", "60"], "r1.csv"),
    (["validate", "{d}/model.json", "{d}/r0.csv", "--plot", "{d}/r0.csv"], "r0.csv"),
    (["diagnose", "--train", "{d}/r0.csv", "--validate", "{d}/r1.csv", "--json", "{d}/r1.csv"], "r1.csv"),
    (["diagnose", "--train", "{d}/r0.csv", "--validate", "{d}/r1.csv", "--json", "{d}/g.json",
      "--html", "{d}/g.json"], None),
])
def test_an_output_that_names_an_input_is_refused_and_the_input_kept(d, args, victim):
    before = {p.name: p.read_bytes() for p in d.iterdir()}
    r = run(*[a.format(d=d) for a in args])
    assert r.returncode == 2 and "Traceback" not in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert "is also" in r.stderr and "write the output elsewhere" in r.stderr
    # nothing replaced, nothing added (the refusal comes before any work)
    assert {p.name: p.read_bytes() for p in d.iterdir()} == before
    assert victim is None or victim in r.stderr


def test_an_unusable_output_path_is_refused_up_front(d, monkeypatch, capsys):
    sim = ["simulate", str(d / "model.json"), str(d / "input.csv"), "-o"]
    assert main(sim + [str(d)]) == 2
    assert f"{d}: is a directory; give a file name for the output" in capsys.readouterr().err
    assert main(sim + [""]) == 2
    assert "the output path is empty" in capsys.readouterr().err
    assert main(sim + [str(d / "input.csv" / "o.csv")]) == 2
    assert f"{d / 'input.csv'} is a file, not a folder" in capsys.readouterr().err
    assert main(sim + [str(d / "no" / "o.csv")]) == 2
    assert f"output directory {d / 'no'} does not exist" in capsys.readouterr().err

    import tempfile

    def refused(*a, **k):
        raise PermissionError(1, "Operation not permitted")

    # a folder the user may not write in (root ignores permission bits, so the refusal is simulated)
    monkeypatch.setattr(tempfile, "NamedTemporaryFile", refused)
    assert main(sim + [str(d / "o.csv")]) == 2
    assert f"{d / 'o.csv'}: cannot write in {d}: Operation not permitted" in capsys.readouterr().err
    assert not (d / "o.csv").exists()


def test_an_input_named_relatively_or_through_a_link_is_still_an_input(d, monkeypatch, capsys):
    monkeypatch.chdir(d)
    (d / "link.csv").symlink_to(d / "input.csv")
    before = (d / "input.csv").read_bytes()
    for out in ("input.csv", "./input.csv", str(d / "link.csv")):
        assert main(["simulate", "model.json", "link.csv", "-o", out]) == 2
        assert "is also link.csv" in capsys.readouterr().err
    assert main(["compensate", "model.json", "input.csv", "-o", "model.json"]) == 2
    assert "model.json: is also model.json" in capsys.readouterr().err
    assert (d / "input.csv").read_bytes() == before
    (d / "link.csv").unlink()


def test_a_drive_that_never_moves_is_refused(d, tmp_path):
    t = np.arange(400) * 1e-3
    write_csv(tmp_path / "hold.csv", {"t": t, "u": np.full(t.size, 50.0), "y": 5.0 + 0.01 * np.sin(t)})
    r = run("identify", tmp_path / "hold.csv", "--model", "nbw", "--max-evals", "60", "-o", tmp_path / "m.json")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{tmp_path / 'hold.csv'}: the input u is constant (50 V) in every record" in r.stderr
    assert not (tmp_path / "m.json").exists()


def test_a_held_out_fit_that_cannot_run_is_said_and_the_model_kept(d, tmp_path, capsys):
    # beside a moving record, a record of the stage at rest fits (the two together), but not alone
    t = np.arange(800) * 1e-3
    write_csv(tmp_path / "hold.csv", {"t": t, "u": np.zeros(t.size), "y": np.zeros(t.size)})
    out = tmp_path / "m.json"
    code = main(["identify", str(d / "r0.csv"), str(tmp_path / "hold.csv"), "-o", str(out), "--model", "nbw",
                 "--max-evals", "60", "-q"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert f"warning: {d / 'r0.csv'} not held out: the other record(s) cannot be fitted alone" in cap.err
    assert f"held out {tmp_path / 'hold.csv'}: RMS" in cap.out
    assert fonbw.load_model(out).kind == "nbw"


def test_every_candidate_diverging_is_bad_input_naming_the_records(d, tmp_path, monkeypatch, capsys):
    from fonbw import hysteresis as hyst

    monkeypatch.setattr(hyst, "simulate_population",
                        lambda kind, theta, u, dt, memory="fast", N=3: np.full((theta.shape[0], u.size), np.nan))
    code = main(["identify", str(d / "r0.csv"), "-o", str(tmp_path / "m.json"), "--model", "nbw",
                 "--max-evals", "60", "-q"])
    err = capsys.readouterr().err
    assert code == 2 and f"fonbw identify: error: {d / 'r0.csv'}: identify('nbw'): every candidate diverged" in err
    assert not (tmp_path / "m.json").exists()


@pytest.mark.parametrize("meta, field", [
    ({"start": "rest_cycle"}, "field 'start': expected an object"),
    ({"start": ["rest_cycle"]}, "field 'start': expected an object"),
    ({"start": {"rest_cycle": [0, 120], "T": 1e12}}, "field 'start.T'"),
    ({"start": {"rest_cycle": [0, 120], "T": 61.0}}, "field 'start.T'"),
    ({"start": {}}, "field 'start': expected the keys rest_cycle"),
    ({"start": {"T": 1.0}}, "field 'start': expected the keys rest_cycle"),
    ({"start": {"rest-cycle": [0, 120]}}, "field 'start': expected the keys rest_cycle"),
    ({"start": {"rest_cycle": [0, 120], "T": -1.0}}, "field 'start.T'"),
    ({"start": {"rest_cycle": [0, 120], "T": "1"}}, "field 'start.T'"),
    ({"start": {"rest_cycle": [0]}}, "field 'start.rest_cycle'"),
    ({"start": {"rest_cycle": ["a", 120]}}, "field 'start.rest_cycle'"),
    ({"u_range": 5}, "field 'u_range'"),
    ({"u_range": [120, 0]}, "field 'u_range'"),
    ({"u_range": [0, float("nan")]}, "field 'u_range'"),
    ({"invertibility": 3}, "field 'invertibility'"),
])
def test_bad_provenance_fields_of_a_model_file_are_named(d, tmp_path, meta, field):
    doc = {**json.loads((d / "model.json").read_text()), **meta}
    with pytest.raises(ValueError, match="^bad.json: " + field.replace("(", r"\(")):
        fonbw.hysteresis.model_from_dict(doc, source="bad.json")
    (tmp_path / "m.json").write_text(json.dumps(doc))
    write_csv(tmp_path / "traj.csv", {"t": np.arange(50) * 1e-3, "Hd": np.linspace(0, 5, 50)})
    r = run("compensate", tmp_path / "m.json", tmp_path / "traj.csv", "-o", tmp_path / "u.csv")
    assert r.returncode == 2 and "Traceback" not in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert f"{tmp_path / 'm.json'}: {field}" in r.stderr
    assert not (tmp_path / "u.csv").exists()


def test_good_provenance_fields_still_load(d):
    doc = {**json.loads((d / "model.json").read_text()), "u_range": [0, 115], "start": None,
           "invertibility": {"dt": 1e-4}}
    m = fonbw.hysteresis.model_from_dict({**doc, "start": {"rest_cycle": [0, 120], "T": 1}}, source="ok.json")
    assert m.meta["start"] == {"rest_cycle": [0.0, 120.0], "T": 1.0} and m.meta["u_range"] == [0.0, 115.0]
    # null stands for absent and round-trips as it was
    assert fonbw.hysteresis.model_from_dict(doc, source="ok.json").to_dict()["start"] is None
    # numbers made in code (numpy scalars) are numbers too
    m = fonbw.hysteresis.model_from_dict({**doc, "u_range": [np.float32(0), np.float64(115)],
                                          "start": {"rest_cycle": (np.int64(0), 120.0), "T": np.float32(1)}})
    assert m.meta["u_range"] == [0.0, 115.0] and m.meta["start"] == {"rest_cycle": [0.0, 120.0], "T": 1.0}


def test_a_rest_cycle_longer_than_a_start_may_run_is_refused():
    from fonbw.compensate.rest import REST_MAX_STEPS, rest_cycle

    assert rest_cycle((0, 120), 1e-3, 1.0).size == 1000
    with pytest.raises(ValueError, match="more than the 1e\\+08 a start may run"):
        rest_cycle((0, 120), 1e-6, 1.01 * REST_MAX_STEPS * 1e-6)


def test_validate_json_stays_strict_when_the_output_never_moves(d, tmp_path):
    t = np.arange(400) * 1e-3
    write_csv(tmp_path / "still.csv", {"t": t, "u": np.zeros(t.size), "y": np.zeros(t.size)})
    r = run("validate", d / "model.json", tmp_path / "still.csv", "--json", "--keep-offset")
    assert r.returncode == 0, r.stderr

    def no_constants(name):
        raise AssertionError(f"{name} in the JSON")

    res = json.loads(r.stdout, parse_constant=no_constants)
    assert res["rms_percent"] is None and res["range"] == 0.0 and np.isfinite(res["rms"])


def test_ctrl_c_after_the_model_is_written_says_so(d, tmp_path, monkeypatch, capsys):
    import fonbw.cli.identify as cli_identify

    def interrupted(recs, kw):
        # what the held-out fit's search says when cut before its first population
        raise KeyboardInterrupt("interrupted before the search had a best candidate")

    monkeypatch.setattr(cli_identify, "_holdout", interrupted)
    out = tmp_path / "m.json"
    code = main(["identify", str(d / "r0.csv"), str(d / "r1.csv"), "-o", str(out), "--model", "nbw",
                 "--max-evals", "60", "-q"])
    err = capsys.readouterr().err
    assert code == 130
    assert err.rstrip().endswith(f"fonbw identify: interrupted; {out} was written; the held-out check or the "
                                 "plot was cut short")
    assert fonbw.load_model(out).kind == "nbw"


def test_a_held_out_fit_that_diverges_on_its_record_is_said_so(d, tmp_path, monkeypatch, capsys):
    import dataclasses
    import importlib

    ident = importlib.import_module("fonbw.identify")  # the module: the package's name is the function
    real = ident.identify

    def wild_when_held_out(records, *args, **kw):
        res = real(records, *args, **kw)
        if len(records) > 1:
            return res
        # fitted on the other record alone: a model that runs away on the held-out one
        wild = dict(fonbw.FONBW(**TABLE1_FONBW).to_dict()["params"], rho=1e300)
        return dataclasses.replace(res, model=fonbw.FONBW(**wild))

    monkeypatch.setattr(ident, "identify", wild_when_held_out)
    out = tmp_path / "m.json"
    code = main(["identify", str(d / "r0.csv"), str(d / "r1.csv"), "-o", str(out), "--max-evals", "60"])
    cap = capsys.readouterr()
    assert code == 0 and fonbw.load_model(out).kind == "fonbw"
    for rec in ("r0.csv", "r1.csv"):
        assert re.search(rf"warning: held out {re.escape(str(d / rec))}: the model fitted on the other 1 record\(s\) "
                         r"diverges on it \(its output passes 1e\+09 µm or is not finite from sample 1, "
                         r"t = 0.001 s\): no RMS", cap.err), cap.err
    assert "held out" not in cap.out and "RuntimeWarning" not in cap.err and "RMS inf" not in cap.out + cap.err


def test_parameter_errors_of_a_model_file_speak_of_its_fields():
    load = fonbw.hysteresis.model_from_dict
    with pytest.raises(ValueError, match=r"^m.json: field 'params': missing parameter\(s\) kh, rho, sigma, n$"):
        load({"kind": "nbw", "params": {"ku": 1.0}}, source="m.json")
    nbw = {"ku": 1.0, "kh": 1.0, "rho": 1.0, "sigma": 0.5, "n": 1.0}
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) lam1 \(a nbw model takes ku, kh, rho, sigma, n\)"):
        load({"kind": "nbw", "params": {**nbw, "lam1": 0.9}}, source="m.json")
    with pytest.raises(ValueError, match="parameter ku must be a number or a non-empty list of numbers, got"):
        load({"kind": "nbw", "params": {**nbw, "ku": ["a"]}}, source="m.json")
    assert load({"kind": "nbw", "params": nbw}).kind == "nbw"
    # JSON's true is no number, though Python's bool is an int
    with pytest.raises(ValueError, match=r"^m.json: field 'params.n': expected a number, got true$"):
        load({"kind": "nbw", "params": {**nbw, "n": True}}, source="m.json")
    with pytest.raises(ValueError, match=r"^m.json: field 'params.ku': expected a number, got \[1.0, false\]$"):
        load({"kind": "nbw", "params": {**nbw, "ku": [1.0, False]}}, source="m.json")


def test_a_model_file_with_a_byte_order_mark_loads(d, tmp_path):
    text = (d / "model.json").read_text(encoding="utf-8")
    (tmp_path / "bom.json").write_text(text, encoding="utf-8-sig")
    assert (tmp_path / "bom.json").read_bytes()[:3] == b"\xef\xbb\xbf"
    assert fonbw.load_model(tmp_path / "bom.json").to_dict() == fonbw.load_model(d / "model.json").to_dict()


def test_a_model_that_diverges_on_the_input_is_refused_and_nothing_written(d, tmp_path, capsys):
    m = json.loads((d / "model.json").read_text(encoding="utf-8"))
    m["params"]["rho"] = 1e300
    (tmp_path / "wild.json").write_text(json.dumps(m), encoding="utf-8")
    out = tmp_path / "y.csv"
    assert main(["simulate", str(tmp_path / "wild.json"), str(d / "input.csv"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert re.search(rf"wild.json: the model's output on {re.escape(str(d / 'input.csv'))} reaches -\d\.\d\de\+\d+ µm "
                     r"at sample 1 \(t = 0.001 s\): it diverges on this input", err)
    assert "RuntimeWarning" not in err and not out.exists()
    assert main(["validate", str(tmp_path / "wild.json"), str(d / "r0.csv"), "--json"]) == 2
    cap = capsys.readouterr()
    assert "output on" in cap.err and " at sample 1 " in cap.err and "RuntimeWarning" not in cap.err
    assert cap.out == ""
    # run after a history it diverges on, the history is named, with its sample
    rec = np.loadtxt(d / "r1.csv", delimiter=",", skiprows=1)
    write_csv(tmp_path / "next.csv", {"t": rec[:, 0] + 0.8, "u": rec[:, 1], "y": rec[:, 2]})
    assert main(["validate", str(tmp_path / "wild.json"), str(tmp_path / "next.csv"),
                 "--history", str(d / "r0.csv")]) == 2
    err = capsys.readouterr().err
    assert re.search(rf"wild.json: the model's output on {re.escape(str(d / 'r0.csv'))} reaches -\d\.\d\de\+\d+ µm "
                     r"at sample 1 \(t = 0.001 s\): it diverges on this input", err), err
    # compensate says once, in its own words, what numpy warns of at every operation
    write_csv(tmp_path / "hd.csv", {"t": rec[:, 0], "Hd": rec[:, 2]})
    assert main(["compensate", str(tmp_path / "wild.json"), str(tmp_path / "hd.csv"), "-o",
                 str(tmp_path / "u.csv")]) == 2
    lines = capsys.readouterr().err.splitlines()
    fp = [ln for ln in lines if "encountered in" in ln]
    assert len(fp) == 1 and fp[0].startswith(
        "fonbw compensate: warning: the model's arithmetic overflowed or gave values that are not numbers on this "
        "trajectory (numpy: overflow encountered in ")
    assert re.search(r"×\d+", fp[0]) and len(lines) == len(set(lines))
    assert any("fonbw compensate --preview" in ln for ln in lines)
    assert lines[-1].startswith("fonbw compensate: error: ") and "cannot track the trajectory" in lines[-1]


def test_a_trajectory_without_its_column_is_told_how_to_map_it(d, tmp_path, capsys):
    rec = np.loadtxt(d / "r1.csv", delimiter=",", skiprows=1)
    write_csv(tmp_path / "traj.csv", {"t": rec[:, 0], "z": rec[:, 2]})
    assert main(["compensate", str(d / "model.json"), str(tmp_path / "traj.csv"), "-o",
                 str(tmp_path / "u.csv")]) == 2
    assert capsys.readouterr().err.strip().endswith(
        "missing column(s) 'Hd'; header has 't', 'z'; map them with --columns Hd=COL (COL a header name "
        "or a 1-based position)")
    # mapped as told, the column is read (this model cannot track it causally: exit 2 after writing)
    main(["compensate", str(d / "model.json"), str(tmp_path / "traj.csv"), "-o", str(tmp_path / "u.csv"),
          "--columns", "Hd=z"])
    assert capsys.readouterr().out.startswith(f"wrote {tmp_path / 'u.csv'}: 800 samples")


def test_a_plant_file_is_read_or_refused_by_name(tmp_path, capsys):
    from fonbw.fmu.build import BuildError, plant_resource

    plant = {"kind": "linear_plant", "A": [[-100.0]], "B": [[100.0]], "C": [[0.5]], "D": [[0.5]], "sys_dt": None}
    p = tmp_path / "p.json"
    p.write_text(json.dumps(plant), encoding="utf-8-sig")
    res = plant_resource(p)
    # no input or output named: the plant FMU's own names; the BOM read past
    assert res["A"] == [[-100.0]] and res["input"]["name"] == "x" and res["output"]["name"] == "y"
    bad = [([1, 2], "expected a JSON object (kind linear_plant), got list"),
           ({**plant, "A": [[1.0, 2.0]]}, "fields A, B, C, D, sys_dt: not a state-space system ("),
           ({**plant, "input": "v"}, "field 'input': expected an object with a \"name\""),
           ({**plant, "output": {"unit": "um"}}, "field 'output': expected an object with a \"name\""),
           ({**plant, "output": {"name": "w", "unit": 5}}, "field 'output': expected an object with a \"name\""),
           ({**plant, "dt": True}, "field 'dt': expected a positive number of seconds, got true"),
           ({**plant, "dt": "1e-4"}, "field 'dt': expected a positive number of seconds, got \"1e-4\""),
           ({**plant, "description": 3}, "field 'description': expected text, got 3"),
           ({**plant, "B": [[1.0, 2.0]], "D": [[0.0, 0.0]]}, "fields A, B, C, D, sys_dt: not a state-space "
                                                            "system (2 input(s) and 1 output(s); the plant FMU "
                                                            "is single-input single-output)")]
    for doc, why in bad:
        p.write_text(json.dumps(doc), encoding="utf-8")
        with pytest.raises(BuildError) as exc:
            plant_resource(p)
        assert str(exc.value).startswith(f"{p}: {why}"), str(exc.value)
    out = tmp_path / "fmus"
    p.write_text("[1, 2]", encoding="utf-8")
    assert main(["build-fmu", "--plant", str(p), "--only", "plant", "-o", str(out)]) == 2
    assert capsys.readouterr().err == f"fonbw build-fmu: error: {p}: expected a JSON object (kind linear_plant), " \
                                      "got list\n"
    assert not out.exists()


def test_a_column_given_to_two_quantities_is_refused():
    from fonbw.reader import parse_columns

    assert parse_columns("t=1,u=2,y=3") == {"t": 1, "u": 2, "y": 3}
    with pytest.raises(ValueError, match="^--columns: u=1 is the column already given to t$"):
        parse_columns("t=1,u=1,y=3")
    with pytest.raises(ValueError, match="^--columns: y=volts is the column already given to u$"):
        parse_columns("t=time,u=volts,y=volts")
    with pytest.raises(ValueError, match="^--columns: u is given twice$"):
        parse_columns("t=1,u=2,U=3")


def test_a_loop_whose_stage_diverges_stops_with_strict_outputs(d, tmp_path, capsys):
    m = json.loads((d / "model.json").read_text(encoding="utf-8"))
    m["params"]["rho"] = 1e300
    (tmp_path / "wild.json").write_text(json.dumps(m), encoding="utf-8")
    js, csv = tmp_path / "c.json", tmp_path / "c.csv"
    assert main(["cosim", "--scenario", "sine5", "--mode", "open", "--T", "0.01", "--truth",
                 str(tmp_path / "wild.json"), "--json", str(js), "--csv", str(csv)]) == 2
    assert "the stage output is not finite or beyond any stage from t = 0.0001 s (step 1)" in capsys.readouterr().err

    def refuse(c):
        raise AssertionError(f"not strict JSON: {c}")

    out = json.loads(js.read_text(encoding="utf-8"), parse_constant=refuse)
    # the RMS of an error that overflows when squared is null, the reason is the file's too
    assert out["rms_error"] is None and out["error"].startswith("the stage output is not finite")
    assert csv.read_text().count("\n") == 101


def test_wild_outputs_and_strict_json_by_hand():
    from fonbw.cli.records import CLIError, finite_output, first_wild
    from fonbw.io import jsonable

    y = np.array([0.0, 1.0, 2e9, np.nan])
    assert first_wild(y) == 2 and first_wild(y[:2]) is None and first_wild(np.array([np.inf])) == 0
    with pytest.raises(CLIError, match=r"^m.json: the model's output on r.csv is not finite at sample 1 \(t = 0.5 s\)"):
        finite_output(np.array([0.0, np.nan]), "m.json", "r.csv", np.array([0.0, 0.5]))
    got = jsonable({"a": (np.float32("nan"), np.int64(3)), "b": [np.bool_(True), -np.inf, 2.5]}, strict=True)
    assert got == {"a": [None, 3], "b": [True, None, 2.5]}
    assert type(got["a"][1]) is int and type(got["b"][0]) is bool
    loose = jsonable({"x": np.float64("inf")})
    assert loose == {"x": float("inf")} and type(loose["x"]) is float


def test_a_diagnosis_budget_too_small_to_search_is_refused_up_front(d, tmp_path, capsys):
    out = tmp_path / "g.json"
    args = ["diagnose", "--train", str(d / "r0.csv"), "--validate", str(d / "r1.csv"), "--json", str(out)]
    assert main(args + ["--budget", "30"]) == 2
    err = capsys.readouterr().err
    # 18 evaluations, a fifth of them the polish, hold no population of 16
    assert "a budget of 30 evaluations leaves each candidate's global search 18 evaluations" in err
    assert "give at least 31 (default 1000)" in err and not out.exists()
    from fonbw.gap.attribute import Diagnosis
    with pytest.raises(ValueError, match="global_evals=18 leaves each candidate.s global search 18 evaluations, "
                       "less than one population of 16 and its polish; give at least 19$"):
        Diagnosis([], [], budget=80, global_evals=18)
