"""Effects a limit beyond the training range hid: the first greedy step judged again on top of it.

A rail or a stroke limit that only the validation records reach
(:mod:`fonbw.gap.beyond`) can hold most of the validation gap. An effect the
training records do show then closes too small a share of that gap to be
material at the first greedy step, however much better it fits the
training records: an 8.9 σ amplifier beside a 10.6 σ stroke limit on a
Preisach core closed 0.18 of it with a training ΔBIC of −1.1e5
(blind-harness seed 64035) and was not named. When the first step named
nothing and the stage then names a limit, that step's candidates whose
first failed check was closing too little (and whose block did not refuse
its fit) are judged again, each with the limit cross-fitted on top of its
own refit as on the nominal. They are judged as a second effect after the
limit (:meth:`fonbw.gap.greedy.GreedySteps.check_candidate`): the share
each closes is still of the nominal's whole gap, but at a second step it is
material with half the first step's share, or with
:data:`~fonbw.gap.checks.LATE_SHARE` of what the limit leaves; the step
edges, the bootstrap and leave one record out are the greedy step's own.
The best passing one (:func:`fonbw.gap.selection.pick_best`) is named after
the limit. The training fits are the first step's (only the limit is
cross-fitted again, on each candidate). The other limit may be named so: a
rail beside a stroke limit is a pair the blind harness draws.
"""
from __future__ import annotations

import math

import numpy as np

from . import beyond as by
from .greedy import configuration
from .selection import pick_best

__all__ = ["judge_again"]


def judge_again(d, before, ctx):
    """Judge again, on top of the limit named beyond the training range, the
    candidates of the first greedy step of diagnosis `d` when it named no
    effect on the configuration `before`.

    Parameters
    ----------
    d : Diagnosis
        After :func:`fonbw.gap.beyond.beyond_training` named a limit
        (``d.beyond["effect"]``): ``d.current`` is `before` with its
        cross-fitted predictions.
    before : dict
        The configuration the limit was cross-fitted on.
    ctx : dict
        The stage's context (validation samples, folds, the judged samples,
        the configuration).

    Sets ``d.beyond["then"]`` (the effect named, or None) and, when one is
    named, ``d.current`` (its refit with the limit cross-fitted on top),
    ``d.beyond["params"]`` (the limit's parameters on that model; its
    ``gap_closed`` stays the stage's, on `before`) and a waterfall step; the
    candidates judged go to ``d.later_steps`` with ``beyond_training`` set
    to the limit's name.
    """
    step, limit = getattr(d, "open_step", None), d.beyond["effect"]
    # Only the first step, tried on the very configuration the limit sits
    # on: its shares are of the whole gap, which the limit held most of.
    # Judged after accepted effects, the limit's share of what they left
    # made a third block material for a remainder near the floor (a
    # resonance after a true delay and rail on a Prandtl-Ishlinskii core
    # closed 0.38 of what the two left, blind-harness seed 64023).
    if step is None or step["on"] is not before or d.accepted or d.max_effects < 2:
        return
    # the limit's own training fit is not judged again on top of it
    hidden = [r for r in step["results"] if d.lib[r["i"]].name != limit and r["checks"]["refused"] is None
              and r["checks"]["failed"] == "closes too little" and math.isfinite(r["mse"])]
    if not hidden:
        return
    under, ends = d.current, np.cumsum([len(r.y) for r in d.val_s])[:-1]
    results = []
    for r in hidden:
        name = d.lib[r["i"]].name
        cfg = configuration(r["fit"], r["eff"], before["idx"] + [r["i"]], r["mse"], r["pv"])
        # a limit the stage named with its refusal lifted (its rival passed
        # and closed less) is judged so on the candidate too
        t = by.limit_on(d, cfg, limit, ctx, lifted=d.beyond["overruled"] is not None)
        if t is None:
            d.say(f"on top of {limit} beyond the training range: +{name}: the stage would not name "
                  f"{limit} on it")
            continue
        pv = np.split(t["pred"], ends)
        # judged as a second effect, the limit the first
        ch = d.check_candidate(r["i"], 1, r["fit"], pv, t["mse"], r["eff"])
        results.append({**r, "pv": pv, "mse": t["mse"], "checks": ch, "limit": t})
        gc = ch["gap_closed_step"]
        d.say(f"on top of {limit} beyond the training range: +{name}: gap closed "
              f"{'–' if gc is None else f'{gc:.3f}'}, {'passes' if ch['passed'] else 'fails: ' + ch['failed']}")
    if not results:
        return
    best = pick_best(results, d.tie_margin)
    name = None if best is None else d.lib[best["i"]].name
    d.later_steps.append({"on_top_of": list(d.accepted) + [limit], "rms_validate": math.sqrt(under["mse"]),
                          "accepted": name, "beyond_training": limit, "candidates": d.entries(results)})
    for c in d.later_steps[-1]["candidates"]:
        c["accepted"] = c["effect"] == name
    if best is None:
        return
    # built on as a greedy step builds on what it accepts
    d.beyond["then"] = d.take(best, before["idx"])
    d.beyond["params"] = by.mean_params(best["limit"]["folds"])
