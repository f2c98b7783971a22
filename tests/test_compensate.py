"""Tests of fonbw.compensate: the per-step inverse of eqs. (16)-(17), (21), (22).

References are independent of the compiled solver: the models' own
``simulate`` (model ∘ compensator = identity), a per-step root find written
here with scipy's brentq on the model stepper's ``peek``, and the closed forms
of the explicit (one-step-delayed) eqs. (16) and (21) evaluated with the
hysteretic state returned by ``simulate``.
"""
import importlib
import math

import numpy as np
import pytest
from scipy.optimize import brentq

import fonbw
from fonbw.io import read_record, write_csv
from fonbw.paper import TABLE1_FONBW
from fonbw.reproduce import format_table4, table4
from fonbw.signals import trajectory_5hz, trajectory_multi

C = importlib.import_module("fonbw.compensate")  # fonbw.compensate is the function

DT = 1e-4          # s, the paper's 10 kHz
T = 0.4            # s: two periods of the 5-Hz trajectory
t = np.arange(int(round(T / DT))) * DT
TRAJ = {"5hz": trajectory_5hz(t), "multi": trajectory_multi(t)}

WN, ZETA = 2 * np.pi * 1500.0, 0.7


def zhu(delta=0.0):
    return fonbw.Zhu2016(m0=1 / WN**2, c0=2 * ZETA / WN, k0=1.0, k1=0.1, x0=0.0, tau=2e-5,
                         A=0.17, beta=0.001, gamma=0.0005, delta=delta, n=1.0)


FONBW_P = dict(ku=[0.15, -1e-4, -5e-8], kh=2.0, rho=0.02, sigma=0.8, n=1.5, lam1=0.95, lam2=0.85)
MODELS = {
    "fonbw_fast": lambda: fonbw.FONBW(**FONBW_P, memory="fast"),
    "fonbw_exact": lambda: fonbw.FONBW(**FONBW_P, memory="exact"),
    "fonbw_oustaloup": lambda: fonbw.FONBW(**FONBW_P, memory="oustaloup"),
    "nbw": lambda: fonbw.NBW(ku=[0.15, 1e-4], kh=2.0, rho=0.02, sigma=0.8, n=1.5),
    "cbw": lambda: fonbw.CBW(ka=0.15, kb=0.05, D=50.0, A=1.0, beta=0.6, gamma=0.4, n=1.0),
    "zhu": lambda: zhu(),
}


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


@pytest.mark.parametrize("traj", list(TRAJ))
@pytest.mark.parametrize("name", list(MODELS))
def test_model_after_compensator_is_identity(name, traj):
    m = MODELS[name]()
    Hd = TRAJ[traj]
    res = C.compensate(m, Hd, DT)
    assert res.ok, res.summary()
    assert np.all(res.nfev >= 1) and res.nfev.max() <= 60
    # independent path: the model's own batch simulation of the voltage
    y = m.simulate(res.u, DT)
    assert _rel(y, Hd) <= 1e-9
    assert np.array_equal(y, res.y_model)
    assert np.all((res.u >= 0.0) & (res.u <= 120.0))
    assert np.array_equal(np.asarray(res, dtype=float), res.u)


@pytest.mark.parametrize("name", ["fonbw_fast", "cbw", "zhu"])
def test_root_equals_scipy_brentq_on_the_stepper(name):
    # second implementation: per step, brentq on peek() over the full range
    m = MODELS[name]()
    Hd = TRAJ["multi"][:600]
    res = C.compensate(m, Hd, DT)
    s = m.stepper(DT)
    u_ref = np.empty_like(Hd)
    for k, h in enumerate(Hd):
        u_ref[k] = brentq(lambda x: s.peek(x) - h, 0.0, 120.0, xtol=1e-14, rtol=1e-15)
        s.step(u_ref[k])
    assert np.max(np.abs(res.u - u_ref)) <= 1e-7


@pytest.mark.parametrize("name", ["fonbw_fast", "fonbw_exact", "cbw", "zhu"])
def test_stepper_equals_batch_bit_for_bit(name):
    m = MODELS[name]()
    Hd = TRAJ["5hz"][:1500] * (1.8 if name == "cbw" else 1.0)  # cbw: some saturation too
    res = C.compensate(m, Hd, DT)
    c = C.compensator(m, DT)
    u = np.array([c.step(h) for h in Hd])  # exact engine: the window grows past 1024
    assert np.array_equal(u, res.u)
    assert c.n_saturated == np.count_nonzero(res.saturated)
    assert c.steps == len(Hd)


def test_state_rollback_replays_bit_for_bit():
    m = MODELS["fonbw_fast"]()
    Hd = TRAJ["multi"]
    c = C.compensator(m, DT)
    for h in Hd[:500]:
        c.step(h)
    state = c.get_state()
    a = [c.step(h) for h in Hd[500:800]]
    c.set_state(state)
    b = [c.step(h) for h in Hd[500:800]]
    assert a == b
    c2 = C.compensator(m, DT)  # a new instance takes the state too
    c2.set_state(state)
    assert [c2.step(h) for h in Hd[500:800]] == a
    c.reset()
    assert c.steps == 0 and [c.step(h) for h in Hd[:5]] == list(C.compensate(m, Hd[:5], DT).u)
    with pytest.raises(ValueError, match="state"):
        c.set_state(np.zeros(3))


def test_saturation_is_honoured_and_reported():
    m = MODELS["nbw"]()
    Hd = 3.0 * TRAJ["5hz"]  # 30 µm peak: beyond 120 V
    lo, hi = 0.0, 100.0
    res = C.compensate(m, Hd, DT, limits=(lo, hi))
    assert np.all((res.u >= lo) & (res.u <= hi))
    sat = res.saturated_samples
    assert sat.size > 0 and np.all(res.u[res.status == C.SAT_HIGH] == hi)
    # out of reach indeed: even u_max falls short there
    assert np.all(res.y_model[res.status == C.SAT_HIGH] < Hd[res.status == C.SAT_HIGH])
    # everything else is solved
    ok = res.status == C.OK
    assert np.all(np.abs(res.residual[ok]) <= res.tol)
    assert np.array_equal(np.flatnonzero(~ok), sat)
    assert f"{sat.size} saturated at u_max" in res.summary()
    # negative targets: the lower limit
    Hd2 = -TRAJ["5hz"]
    res2 = C.compensate(m, Hd2, DT, limits=(lo, hi))
    assert np.all(res2.u == lo)
    assert np.array_equal(res2.status == C.SAT_LOW, Hd2 < -res2.tol)


def test_unconverged_samples_are_reported():
    # δ u sgn(u̇) of eq. (20) makes the step map jump at u_k = u_(k−1): a target
    # inside the jump has no root; it must be reported, never passed off as solved
    m = zhu(delta=0.05)
    res = C.compensate(m, TRAJ["multi"], DT)
    bad = res.unconverged_samples
    assert bad.size > 0
    assert np.all(np.abs(res.residual[bad]) > res.tol)
    good = res.status == C.OK
    assert np.all(np.abs(res.residual[good]) <= res.tol)
    assert "not converged" in res.summary()
    # the residual left is the jump, small against the stroke
    assert np.max(np.abs(res.residual)) < 1e-3


def test_explicit_variant_is_eq16_and_eq21_in_closed_form():
    Hd = TRAJ["5hz"][:2000]
    m = MODELS["fonbw_fast"]()
    res = C.compensate(m, Hd, DT, explicit=True)
    _, hb = m.simulate(res.u, DT, return_state=True)
    k1, k2, k3 = m.ku
    up = np.concatenate([[0.0], res.u[:-1]])
    hp = np.concatenate([[0.0], hb[:-1]])
    u_ref = np.clip((Hd - m.kh * hp - k2 * up**2 - k3 * up**3) / k1, 0.0, 120.0)
    assert np.max(np.abs(res.u - u_ref)) <= 1e-9
    cb = MODELS["cbw"]()
    res = C.compensate(cb, Hd, DT, explicit=True)
    _, h = cb.simulate(res.u, DT, return_state=True)
    hp = np.concatenate([[0.0], h[:-1]])
    u_ref = np.clip((Hd - cb.kb * cb.D * hp) / cb.ka, 0.0, 120.0)
    assert np.max(np.abs(res.u - u_ref)) <= 1e-9
    # the delayed form does not invert the model: the implicit one does
    assert _rel(cb.simulate(res.u, DT), Hd) > 1e-4
    c = C.compensator(cb, DT, explicit=True)
    assert np.array_equal([c.step(h) for h in Hd], res.u)


def test_refusals():
    m = MODELS["nbw"]()
    with pytest.raises(ValueError, match="limits"):
        C.compensate(m, TRAJ["5hz"], DT, limits=(120.0, 0.0))
    with pytest.raises(ValueError, match="not finite at sample 3"):
        C.compensate(m, [0.0, 1.0, 2.0, math.nan], DT)
    with pytest.raises(ValueError, match="1-D"):
        C.compensate(m, np.zeros((2, 3)), DT)
    with pytest.raises(ValueError, match="dt"):
        C.compensate(m, TRAJ["5hz"], 0.0)
    with pytest.raises(ValueError, match="tol"):
        C.compensate(m, TRAJ["5hz"], DT, tol=-1.0)
    with pytest.raises(ValueError, match="max_iter"):
        C.compensator(m, DT, max_iter=0)
    with pytest.raises(ValueError, match="Zhu2016"):
        C.compensate(zhu(), TRAJ["5hz"], DT, explicit=True)
    with pytest.raises(ValueError, match="cannot compensate"):
        C.compensate(object(), TRAJ["5hz"], DT)
    with pytest.raises(ValueError, match="not finite"):
        C.compensator(m, DT).step(math.inf)
    assert len(C.compensate(m, [], DT).u) == 0


def test_public_names_and_file_helper(tmp_path):
    m = MODELS["fonbw_fast"]()
    assert fonbw.compensator is C.compensator
    assert np.array_equal(fonbw.compensate(m, TRAJ["5hz"][:50], DT).u,
                          C.compensate(m, TRAJ["5hz"][:50], DT).u)
    mp, tp, op = tmp_path / "m.json", tmp_path / "traj.csv", tmp_path / "u.csv"
    m.save(mp)
    write_csv(tp, {"t": t[:800], "Hd": TRAJ["multi"][:800]})
    res = C.compensate_file(mp, tp, op)
    out = read_record(op, need=("u", "Hd"))
    dt = read_record(tp, need=("Hd",)).dt  # the median step of the file's t column
    ref = C.compensate(m, TRAJ["multi"][:800], dt)
    assert np.array_equal(out.u, ref.u) and res.ok and abs(dt - DT) < 1e-15
    bad = tmp_path / "bad.csv"
    write_csv(bad, {"t": t[:10], "u": t[:10]})
    with pytest.raises(ValueError, match="bad.csv: row 1: missing column.*Hd"):
        C.compensate_file(mp, bad, op)


def test_table4_on_an_ideal_bench_and_the_plots(tmp_path):
    from fonbw.bench import Bench

    bench = Bench.ideal(seed=0)
    models = {"NBW": MODELS["nbw"](), "CBW": MODELS["cbw"](), "Zhu": zhu()}  # Zhu: eq. (22) form by default
    rows = table4(bench, models, out_dir=tmp_path, T=0.2)
    assert len(rows) == 3 * 2 * 2
    for r in rows:
        assert r["samples"] == 2000 and r["saturated"] == 0 and r["not_converged"] == 0
        if r["plant"] == "model" and r["compensator"] != "Zhu":
            # compensator and plant from the same model
            assert r["rms_error"] <= 1e-9 and r["rms_error_solved"] == r["rms_error"]
        else:  # the bench is not a Bouc-Wen model: a real, finite error
            assert 1e-3 < r["rms_error"] < 5.0
        assert 10.0 < r["rms_input"] < 120.0
    # the RMS input is the voltage of the compensator, independent of the plant
    u = C.compensate(models["CBW"], trajectory_5hz(np.arange(2000) * DT), DT).u
    row = next(r for r in rows if r["compensator"] == "CBW" and r["trajectory"] == "5-Hz")
    assert row["rms_input"] == pytest.approx(np.sqrt(np.mean(u**2)), rel=1e-12)
    uz = C.compensate(zhu(), trajectory_5hz(np.arange(2000) * DT), DT, form="eq22").u
    row = next(r for r in rows if r["compensator"] == "Zhu" and r["trajectory"] == "5-Hz")
    assert row["rms_input"] == pytest.approx(np.sqrt(np.mean(uz**2)), rel=1e-12)
    for f in ("table4.csv", "table4_5_hz.png", "table4_multi_freq.png"):
        assert (tmp_path / f).stat().st_size > 0
    assert "paper" in format_table4(rows)
    with pytest.raises(ValueError, match="differs"):
        table4(bench, models, dt=2 * DT)


def test_zhu_eq22_form_solves_the_force_balance():
    # eq. (22) made implicit: (k1/τ)e^(−t/τ)u + ĥ(u) = m0 Ḧd + c0 Ḣd + k0 (Hd − x0),
    # checked with the h that the model's own simulate returns
    m = zhu()
    Hd = TRAJ["multi"][:2000]
    res = C.compensate(m, Hd, DT, form="eq22")
    assert res.ok, res.summary()
    _, h = m.simulate(res.u, DT, return_state=True)
    k = np.arange(len(Hd))
    force = m.k1 / m.tau * np.exp(-k * DT / m.tau) * res.u + h
    h1 = np.r_[Hd[0], Hd[:-1]]
    h2 = np.r_[Hd[0], Hd[0], Hd[:-2]]
    target = m.m0 * (Hd - 2 * h1 + h2) / DT**2 + m.c0 * (Hd - h1) / DT + m.k0 * (Hd - m.x0)
    assert np.max(np.abs(force - target)) <= 1e-9
    # the mechanics are inverted on Hd, not on the discrete model: close, not exact
    assert 1e-9 < _rel(res.y_model, Hd) < 2e-2
    c = C.compensator(m, DT, form="eq22")
    u = [c.step(x) for x in Hd]
    assert np.array_equal(u, res.u)
    with pytest.raises(ValueError, match="eq22"):
        C.compensate(MODELS["cbw"](), Hd, DT, form="eq22")
    with pytest.raises(ValueError, match="form"):
        C.compensate(m, Hd, DT, form="continuous")


def test_paper_table1_fonbw_is_not_invertible_and_says_so():
    # Table 1: k_h ρ < 0 with λ1 > λ2, so at 10 kHz one step of u moves H the
    # wrong way (right-half-plane zero); the exact inverse cannot track within
    # 0-120 V and every such sample must be reported, not passed off as solved
    m = fonbw.FONBW(**TABLE1_FONBW)
    s = m.stepper(DT)
    s.step(0.0)
    assert s.peek(1.0) < s.peek(0.0)  # the one-step map decreases in u
    res = C.compensate(m, TRAJ["5hz"], DT)
    assert not res.ok
    bad = res.status != C.OK
    assert np.count_nonzero(bad) > 0.9 * len(res.u)
    assert np.all(np.abs(res.residual[bad]) > res.tol)
    assert np.all(np.abs(res.residual[~bad]) <= res.tol)


def test_preview_file_starts_ahead_of_the_trajectory(tmp_path):
    # the pre-actuation rows come first, before the trajectory's first time,
    # with status -1; the model driven by the whole u column reproduces y_model
    m = fonbw.FONBW(**TABLE1_FONBW)
    m.meta = {"u_range": [-100.0, 200.0]}
    mp, tp, op = tmp_path / "m.json", tmp_path / "traj.csv", tmp_path / "u.csv"
    m.save(mp)
    write_csv(tp, {"t": t[:1000], "Hd": TRAJ["5hz"][:1000]})
    res = C.compensate_file(mp, tp, op, preview=True)
    out = read_record(op, need=("u", "Hd"))
    k = res.u_lead.size
    assert k > 0 and len(out.u) == k + 1000
    assert np.all(out.t[:k] < t[0]) and np.allclose(out.t[k:], t[:1000], atol=1e-12)
    import csv
    with open(op) as fh:
        rows = list(csv.DictReader(fh))
    status = np.array([float(r["status"]) for r in rows])
    y_col = np.array([float(r["y_model"]) for r in rows])
    assert np.all(status[:k] == -1) and np.all(status[k:] == C.OK)
    y = m.simulate(out.u, DT)
    assert np.max(np.abs(y - y_col)) <= 1e-9
    assert np.max(np.abs(y[k:] - TRAJ["5hz"][:1000])) <= 1e-8


def test_zhu_model_with_a_start_is_compensated_from_it():
    from fonbw.compensate.rest import rest_start_meta
    from fonbw.objective import simulate_record

    m = zhu()
    m.meta = {"u_range": [0.0, 120.0], "start": rest_start_meta((0.0, 120.0), T=0.05)}
    Hd = TRAJ["5hz"][:1500]
    res = C.compensate(m, Hd, DT)
    # the mechanics still settle from the cycle on the first samples, below 0 V's reach
    ok = res.status == C.OK
    assert np.count_nonzero(~ok) <= 2 and ok[10:].all(), res.summary()
    # independent path: validate's run of the model behind its cycle, zeroed at its end
    y = simulate_record(m, res.u, DT)
    assert np.max(np.abs(y - Hd)[ok]) <= 1e-9 * np.max(np.abs(Hd))
    # the per-step compensator runs the same start
    c = C.compensator(m, DT)
    assert np.array_equal(np.array([c.step(h) for h in Hd]), res.u)
    # from rest instead the voltage differs (the cycle leaves the model elsewhere)
    assert np.max(np.abs(C.compensate(m, Hd, DT, history=()).u - res.u)) > 1e-3
    with pytest.warns(RuntimeWarning, match="eq.-22 form runs from rest"):
        C.compensate(m, Hd, DT, form="eq22")


def test_table4_training_records_with_extra_inputs_and_without_creep():
    from fonbw.bench import Bench
    from fonbw.reproduce import table4_training
    from fonbw.signals import eq19_input, multi_input

    fs, T = 2000.0, 0.5
    u = np.linspace(0.0, 100.0, 600)
    base = table4_training(0, fs=fs, T_eq19=T, T_multi=T)
    more = table4_training(0, fs=fs, T_eq19=T, T_multi=T, extra=[("ramp", u)])
    # the extra record comes after the two, from the same bench and noise stream
    assert [r.n for r in more] == [1000, 1000, 600]
    for a, b in zip(base, more):
        np.testing.assert_array_equal(a.y, b.y)
    b = Bench(seed=0, fs=fs)
    for name, x in (("eq19", eq19_input(fs, T=T)[1]), ("multi", multi_input(fs=fs, T=T)[1]), ("ramp", u)):
        rec = b.record(x, name)
    np.testing.assert_array_equal(more[2].y, rec.y)
    # without its creep the bench's slow rise after the eq.-19 record's first peak is gone
    flat = table4_training(0, fs=fs, T_eq19=T, T_multi=T, creep=False)
    ref = Bench(seed=0, fs=fs, creep=False).record(eq19_input(fs, T=T)[1], "eq19")
    np.testing.assert_array_equal(flat[0].y, ref.y)
    assert np.max(np.abs(flat[0].y - base[0].y)) > 0.02
