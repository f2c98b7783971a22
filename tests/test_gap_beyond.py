"""Tests of the limits cross-fitted beyond the training range (fonbw.gap.beyond):
the folds and the cross-fit against hand-computed values, and a rail that only
the validation records reach, diagnosed on the separate truth simulator."""
import numpy as np
import pytest

import gap_truth as tr
from fonbw.gap import diagnose
from fonbw.gap.beyond import FOLD_S, SHARE, cross_fit, folds, pick
from fonbw.gap.checks import LATE_DROP
from fonbw.io import Record

FAST = dict(budget=500, global_evals=160, refit_evals=45)


def test_folds_alternate_half_seconds_from_each_record_start():
    a = Record.from_arrays(u=np.zeros(12), y=np.zeros(12), dt=0.1)
    b = Record.from_arrays(u=np.zeros(7), y=np.zeros(7), dt=0.1)
    f = folds([a, b], block_s=0.5)
    # 0.0-0.4 s, 0.5-0.9 s, 1.0-1.1 s; the second record starts over
    assert f.tolist() == [0] * 5 + [1] * 5 + [0] * 2 + [0] * 5 + [1] * 2


def test_cross_fit_scores_each_fold_by_the_other_folds_choice():
    y = np.array([1.0, 2.0, 3.0, 10.0, 20.0, 30.0])
    fold = np.array([0, 0, 0, 1, 1, 1])

    def mean_of(mask):
        m = float(y[mask].mean())
        return {"m": m}, np.full(y.shape, m)
    pred, chosen = cross_fit(y, fold, mean_of)
    # fold 0 is predicted by fold 1's mean (20), fold 1 by fold 0's (2)
    assert pred.tolist() == [20.0, 20.0, 20.0, 2.0, 2.0, 2.0]
    assert chosen == [{"m": 2.0}, {"m": 20.0}]


def test_pick_names_the_best_unrefused_limit_that_closes_half_and_one_noise_variance():
    s2 = 1e-4
    # what the model leaves: 5 σ² above the floor of a 6 σ² MSE
    mse = 6 * s2

    def t(share, refused=None):
        return {"gap_closed": share, "mse": mse - share * 5 * s2, "refused": refused}
    assert pick({"clip": t(0.6), "saturation": t(0.9, "a bend")}, mse, s2) == "clip"
    assert pick({"clip": t(0.6), "saturation": t(0.7)}, mse, s2) == "saturation"
    assert pick({"clip": t(0.45)}, mse, s2) is None                     # under half of what is left
    # of 1.5 σ² left, 0.6 is 0.9 σ²: under one noise variance of MSE; 0.7 is 1.05 σ²
    assert pick({"clip": {"gap_closed": 0.6, "mse": 1.6 * s2, "refused": None}}, 2.5 * s2, s2) is None
    assert pick({"clip": {"gap_closed": 0.7, "mse": 1.45 * s2, "refused": None}}, 2.5 * s2, s2) == "clip"
    assert pick({"saturation": t(0.9, "a bend")}, mse, s2) is None


@pytest.fixture(scope="module")
def rail_beyond_training():
    # training commands stop at 114.8 V, the validation sines reach 120 V: a
    # rail at 117 V is not in the training records at all
    sc = tr.draw_scenario(13, "null", scale=0.5)
    truth = sc["truth"]
    tr_in, va_in = tr.default_experiments(scale=0.5)
    rail = {"hi": 117.0, "lo": -30.0, "knee": 0.3}
    assert tr.magnitude(truth, tr_in, "clip", rail) < 1e-4
    truth.effects = {"clip": rail}
    train = [truth.record(u, n, i) for i, (n, u) in enumerate(tr_in)]
    val = [truth.record(u, n, 50 + i) for i, (n, u) in enumerate(va_in)]
    return rail, diagnose(train, val, seed=2, **FAST).to_dict()


def test_a_rail_only_the_validation_records_reach_is_named_beyond_training(rail_beyond_training):
    rail, res = rail_beyond_training
    v, b = res["verdict"], res["verdict"]["beyond_training"]
    assert b["effect"] == "clip" and v["effects"][-1] == "clip"
    # the training-fitted clip cannot see it: its level stays above every training command
    first = next(c for c in res["candidates"] if c["effect"] == "clip")
    assert not first["accepted"]
    assert b["params"]["level"] == pytest.approx(rail["hi"], abs=1.0)
    assert b["gap_closed"] >= SHARE and b["tried"]["clip"]["gap_closed"] == b["gap_closed"]
    # the waterfall's last step before the floor is the limit, at the verdict's MSE
    st = v["waterfall"][-2]
    assert st["step"] == "+clip beyond training"
    assert st["gap_closed_cum"] == pytest.approx(v["gap_closed"], abs=1e-12)
    assert f"alternate {FOLD_S:g}-s blocks" in v["message"]
    s2 = res["nominal"]["noise_floor"] ** 2
    before = v["waterfall"][-3]["rms_validate"] ** 2
    assert before - st["rms_validate"] ** 2 >= LATE_DROP * s2
