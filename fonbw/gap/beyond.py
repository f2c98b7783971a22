"""Limits that only the validation records reach: a rail or a stroke limit beyond the training range.

A rail above every training command, or a stroke limit above every training
displacement, leaves the training records as they would be without it. No
fit on them can see it, so the greedy steps, which fit on the training
records and judge on the validation records, cannot name it. A validation
record that drives past the training range shows it, as a gap on its
samples out there and on the branches that turn from them.

This stage, run on the diagnosis's final configuration, fits the two limit
blocks to the validation records with everything else held, and keeps the
fit honest by cross-fitting: the scored samples fall into alternate blocks
of :data:`FOLD_S` seconds, each block's parameters are chosen on one fold
(a grid, the stroke limit's slope factor by least squares) and scored on the
other, and the other way round. What a limit closes is counted only on
samples it was not chosen on, so a block that bends a loop's extrapolated
top to suit one fold pays for it on the other.

Measured before it was added, on 56 scenarios of the blind harness's held-out
seeds 45000-47039 (the two blocks cross-fitted on top of each diagnosis's
final model; ``BENCHMARKS.md``, "A limit only the validation records reach"):
of the 39 with no limit injected, none had the rail close more than 0.42 of
what the model left (47018, a Preisach null) or a stroke limit that was not a
bend; the rails the training records did not reach closed 0.97 and 0.84 of it
(46013, 47008) and one beside an amplifier 0.66 (45022), the stroke limits
0.97 on a FONBW core (47032) and 0.59 beside a rail (45005); three rails
closed 0.34-0.48 and stay unnamed. A stroke limit on a Preisach core was
named a rail (46016, 0.63). The least drop of the MSE is the later greedy
steps' own (:data:`~fonbw.gap.checks.LATE_DROP`); none of the 56 needed it.
"""
from __future__ import annotations

import math

import numpy as np

from . import checks

__all__ = ["FOLD_S", "SHARE", "folds", "cross_fit", "pick", "beyond_training"]

#: Length [s] of the alternate blocks of the two folds: 10 periods of the
#: harness's 20-Hz validation sine, half a period of its 1-Hz one.
FOLD_S = 0.5
#: Share of what the final model leaves (validation MSE above σ²) a limit
#: must close, cross-fitted, to be named.
SHARE = 0.5
#: Fewest samples beyond the training range each fold must hold for a limit
#: to be chosen on it.
MIN_SAMPLES = 10


def folds(records, block_s=FOLD_S):
    """Fold (0 or 1) of every sample of `records`, concatenated: alternate
    blocks of `block_s` seconds, counted from each record's first sample."""
    return np.concatenate([((np.arange(len(r.y)) * r.dt) // block_s).astype(int) % 2 for r in records])


def cross_fit(y, fold, choose):
    """Cross-fitted predictions of a block whose parameters are chosen per fold.

    Parameters
    ----------
    y : ndarray
        Measured output [µm], all scored samples.
    fold : ndarray of int
        Fold (0, 1) of each sample (:func:`folds`).
    choose : callable
        ``choose(mask) -> (params, pred)``: the block's parameters chosen on the
        samples where `mask` is True, and its prediction [µm] of every sample.

    Returns
    -------
    (ndarray, list)
        The prediction of each sample by the parameters chosen on the other
        fold, and those parameters (fold 0's choice first).
    """
    out = np.empty_like(y, dtype=float)
    chosen = []
    for f in (0, 1):
        params, pred = choose(fold == f)
        other = fold != f
        out[other] = pred[other]
        chosen.append(params)
    return out, chosen


def _rail(d, ctx):
    """The rail's cross-fit: ten levels from just under the training's largest
    command (3 % of it) to the validation's, each with a sharp and a soft knee."""
    clip = next(e for e in d.lib if e.name == "clip")
    att, cur = d.att, d.current
    levels = np.linspace(ctx["u_train"] - 0.03 * clip.U, float(ctx["u"].max()), 10)
    preds = {}
    for level in levels:
        for width in (0.003 * clip.U, 0.015 * clip.U):
            fit = {**cur["fit"], "th": list(cur["fit"]["th"]) + [np.array([level, width])]}
            p = d.cut_va(att["fitter"].predict(d.val, fit, list(cur["eff"]) + [clip], att["yref_va"]))
            preds[(float(level), float(width))] = np.concatenate(p)
    y = ctx["y"]

    def choose(mask):
        best = min(preds, key=lambda k: float(np.sum((y[mask] - preds[k][mask]) ** 2)))
        return {"level": best[0], "knee": best[1]}, preds[best]
    return cross_fit(y, ctx["fold"], choose), None


def _stroke_limit(d, ctx):
    """The stroke limit's cross-fit on the model's own output: 25 knees from the
    median of the validation prediction to its top, three corner widths, the
    slope factor c in [−1, 0] by least squares on the fold."""
    sat = next(e for e in d.lib if e.name == "saturation")
    z, y = ctx["z"], ctx["y"]
    span = max(float(np.ptp(z)), 1e-12)
    shapes = {(float(k), float(w)): sat.shape(z, (k, w))[0]
              for k in np.linspace(float(np.median(z)), float(z.max()), 25)
              for w in span * np.array([0.003, 0.02, 0.08])}
    r = y - z

    def choose(mask):
        best = None
        for key, f in shapes.items():
            fm, rm = f[mask], r[mask]
            den = float(fm @ fm)
            c = 0.0 if den <= 0.0 else min(max(float(fm @ rm) / den, sat.c_min), 0.0)
            sse = float(np.sum((rm - c * fm) ** 2))
            if best is None or sse < best[0]:
                best = (sse, key, c)
        _, (k, w), c = best
        return {"knee": k, "width": w, "c": c}, z + c * shapes[(k, w)]
    out = cross_fit(y, ctx["fold"], choose)
    # the block's own rule on each fold's fit: a top that only bends is loop shape
    refused = next((sat.refuses(p) for p in out[1] if sat.refuses(p) is not None), None)
    return out, refused


def beyond_training(d):
    """Cross-fit a rail and a stroke limit the training records did not reach on
    top of diagnosis `d`'s final configuration; name the better one when it
    closes :data:`SHARE` of what is left and :data:`~fonbw.gap.checks.LATE_DROP`
    noise variances of MSE.

    Sets ``d.beyond`` (None when no validation record goes past the training
    range, else ``effect`` (the limit named, or None), ``gap_closed`` (its share
    of what the model left), ``gap_closed_all`` (of the excess the effects are
    attributed on), ``params`` and ``tried`` (each block's share, fold
    parameters and refusal)) and, when a limit is named, ``d.current``'s
    validation predictions and MSE (cross-fitted) and a waterfall step.
    """
    d.beyond = None
    cur, sigma2 = d.current, d.sigma2
    left = cur["mse"] - sigma2
    # credited only for what the model leaves above the floor, as a greedy step
    if d.at_floor or cur["mse"] <= (1.0 + d.floor_tol) * sigma2 or len(d.accepted) >= d.max_effects:
        return
    y = np.concatenate([r.y for r in d.val_s])
    u = np.concatenate([r.u for r in d.val_s])
    z = np.concatenate(cur["pred"])
    ctx = {"y": y, "u": u, "z": z, "fold": folds(d.val_s),
           "u_train": max(float(r.u.max()) for r in d.train),
           "y_train": max(float(r.y.max()) for r in d.train)}
    span = ctx["u_train"] - min(float(r.u.min()) for r in d.train)
    blocks = {}
    if "clip" not in d.accepted and u.max() > ctx["u_train"] + checks.AMPLITUDE_TOL * span:
        blocks["clip"] = (_rail, u > ctx["u_train"])
    if "saturation" not in d.accepted and z.max() > ctx["y_train"]:
        blocks["saturation"] = (_stroke_limit, z > ctx["y_train"])
    blocks = {k: v for k, v in blocks.items()
              if all(np.count_nonzero(v[1] & (ctx["fold"] == f)) >= MIN_SAMPLES for f in (0, 1))}
    if not blocks:
        return
    n = len(y)
    tried = {}
    for name, (fn, _) in blocks.items():
        (pred, chosen), refused = fn(d, ctx)
        mse = float(np.sum((y - pred) ** 2)) / n
        tried[name] = {"gap_closed": (cur["mse"] - mse) / left, "mse": mse, "folds": chosen,
                       "refused": refused, "pred": pred}
    name = pick(tried, cur["mse"], sigma2)
    d.beyond = {"effect": name, "gap_closed": None, "gap_closed_all": None, "params": None, "fold_s": FOLD_S,
                "tried": {k: {kk: t[kk] for kk in ("gap_closed", "folds", "refused")} for k, t in tried.items()}}
    d.say("beyond the training range: " + ", ".join(
        f"{k} closes {t['gap_closed']:.3g} of what is left" + (f" ({t['refused']})" if t["refused"] else "")
        for k, t in tried.items()) + (f"; {name} named" if name else "; none named"))
    if name is None:
        return
    t, ex = tried[name], d.att["excess"]
    d.beyond.update(gap_closed=t["gap_closed"], gap_closed_all=(cur["mse"] - t["mse"]) / ex if ex > 0 else None,
                    params=_mean_params(t["folds"]))
    ends = np.cumsum([len(r.y) for r in d.val_s])[:-1]
    d.current = {**cur, "pred": np.split(t["pred"], ends), "mse": t["mse"]}
    d.steps.append({"label": f"+{name} beyond training", "rms_validate": math.sqrt(t["mse"])})


def pick(tried, mse, sigma2):
    """The limit named among the cross-fitted `tried` blocks (name → ``gap_closed``,
    ``mse``, ``refused``) on top of a model of validation MSE `mse` [µm²], or None:
    of those not refused, the one closing most, when that is at least
    :data:`SHARE` of what is left and :data:`~fonbw.gap.checks.LATE_DROP`
    noise variances `sigma2` of MSE."""
    ok = [k for k, t in tried.items() if t["refused"] is None]
    if not ok:
        return None
    best = max(ok, key=lambda k: tried[k]["gap_closed"])
    t = tried[best]
    return best if t["gap_closed"] >= SHARE and mse - t["mse"] >= checks.LATE_DROP * sigma2 else None


def _mean_params(chosen):
    """One set of parameters from the two folds' choices: their means."""
    return {k: float(np.mean([c[k] for c in chosen])) for k in chosen[0]}
