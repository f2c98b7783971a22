"""The paper's identification and verification study (Tables 1–3, Figs. 8–10)
and its feedforward compensation study (Table 4) recomputed on the virtual
bench (:mod:`fonbw.bench`).

FONBW, CBW and the Zhu et al. model are identified on the bench's eq.-19
record with :func:`fonbw.identify`, then validated on the sines
u = 60 − 60 cos(2πft) V at 1, 5, 10, 15 and 20 Hz (Table 3 metric: RMS error as
% of the measured range). Identification may run on a decimated copy of the
eq.-19 record (``fs_identify``): the models are continuous-time models
discretized at the record's step, so they are validated at the bench rate.
"""
from __future__ import annotations

import json
import math
import os
import time
import warnings

import numpy as np

from . import hysteresis as _hy
from .bench import Bench
from .compensate import DEFAULT_LIMITS, OK, check_model, compensate
from .paper import PAPER_TABLE2, PAPER_TABLE4, SINE_FREQS
from .signals import TRAJECTORIES, eq19_input, multi_input, sine_input
from .io import Record, atomic_open, decimate, input_range

__all__ = ["identify_models", "table1", "table2", "table3", "reproduce", "KIND_LABELS",
           "table4", "format_table4", "reproduce_table4", "table4_training", "table4_models",
           "TABLE4_KINDS"]

KIND_LABELS = {"fonbw": "FONBW", "cbw": "CBW", "zhu": "Zhu et al. (eq. 20)", "nbw": "asymmetric NBW"}

def identify_models(train, kinds=("fonbw", "cbw", "zhu"), *, seed=0, max_evals=3000, progress=False,
                    memory="fast"):
    """Identify each model kind on the training record(s); returns {kind: IdentifyResult}."""
    from .identify import identify

    out = {}
    for k in kinds:
        out[k] = identify(train, kind=k, seed=seed, max_evals=max_evals, progress=progress, memory=memory)
    return out


def rms_metrics(model, rec: Record) -> dict:
    """RMS error [µm], RMS as % of the measured range (Table 3), max |error| [µm]."""
    yhat = model.simulate(rec.u, rec.dt)
    e = yhat - rec.y
    rng = float(np.ptp(rec.y))
    rms = float(np.sqrt(np.mean(e**2)))
    return {"rms": rms, "rms_percent": 100.0 * rms / rng if rng > 0 else math.inf,
            "max_abs": float(np.max(np.abs(e))), "range": rng, "yhat": yhat}


def table1(results) -> list[dict]:
    """Identified parameters and training RMS per model (the paper's Table 1)."""
    rows = []
    for k, r in results.items():
        rows.append({"model": KIND_LABELS.get(k, k), "kind": k, "params": {p: float(v) for p, v in r.params.items()},
                     "rms_train": float(r.rms), "nfev": int(r.nfev), "wall_s": float(r.wall_time)})
    return rows


def table2(results) -> list[dict]:
    """Parameter counts and characteristics: the paper's literature rows plus the models fitted here."""
    rows = [{"model": m, "characteristic": c, "parameters": n, "source": "paper"} for m, c, n in PAPER_TABLE2]
    chars = {"fonbw": "asymmetric / rate-dependent", "cbw": "symmetric / rate-independent",
             "zhu": "asymmetric / rate-dependent", "nbw": "asymmetric"}
    for k, r in results.items():
        rows.append({"model": KIND_LABELS.get(k, k) + " (fitted here)", "characteristic": chars.get(k, ""),
                     "parameters": len(r.params), "source": "this run"})
    return rows


def table3(models, sines) -> dict:
    """RMS error as % of the measured range at each validation frequency.

    Returns ``{"freqs": [...], "rows": {kind: [%...]}, "rms_um": {kind: [...]}}``.
    """
    freqs = sorted(sines)
    rows, rms = {}, {}
    for k, m in models.items():
        met = [rms_metrics(m, sines[f]) for f in freqs]
        rows[k] = [x["rms_percent"] for x in met]
        rms[k] = [x["rms"] for x in met]
    return {"freqs": freqs, "rows": rows, "rms_um": rms}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


COLORS = {"fonbw": "tab:red", "cbw": "tab:blue", "zhu": "tab:green", "nbw": "tab:purple"}


def plot_fig8(train: Record, models, path):
    """Identification: (a) input, (b) outputs, (c) model errors, (d) loops."""
    plt = _plt()
    fig, ax = plt.subplots(2, 2, figsize=(11, 7))
    t = train.t - train.t[0]
    ax[0, 0].plot(t, train.u, "k", lw=0.8)
    ax[0, 0].set(xlabel="t [s]", ylabel="u [V]", title="(a) input, eq. (19)")
    ax[0, 1].plot(t, train.y, "k", lw=1.5, label="bench")
    ax[1, 1].plot(train.u, train.y, "k", lw=1.5, label="bench")
    for k, m in models.items():
        y = m.simulate(train.u, train.dt)
        ax[0, 1].plot(t, y, color=COLORS.get(k), lw=0.8, label=KIND_LABELS.get(k, k))
        ax[1, 0].plot(t, y - train.y, color=COLORS.get(k), lw=0.6, label=KIND_LABELS.get(k, k))
        ax[1, 1].plot(train.u, y, color=COLORS.get(k), lw=0.6)
    ax[0, 1].set(xlabel="t [s]", ylabel="y [µm]", title="(b) outputs")
    ax[1, 0].set(xlabel="t [s]", ylabel="error [µm]", title="(c) model errors")
    ax[1, 1].set(xlabel="u [V]", ylabel="y [µm]", title="(d) loops")
    ax[0, 1].legend(fontsize=8)
    ax[1, 0].legend(fontsize=8)
    fig.suptitle("Fig. 8: identification on the virtual bench")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_fig9_10(sines, models, path9, path10, freqs=(1, 5, 10, 20)):
    """Fig. 9: loops at several frequencies; Fig. 10: the model errors there."""
    plt = _plt()
    f9, a9 = plt.subplots(2, 2, figsize=(10, 8))
    f10, a10 = plt.subplots(2, 2, figsize=(10, 7))
    for i, f in enumerate(freqs):
        rec = sines[f]
        t = rec.t - rec.t[0]
        ax9, ax10 = a9.ravel()[i], a10.ravel()[i]
        ax9.plot(rec.u, rec.y, "k", lw=1.5, label="bench")
        for k, m in models.items():
            y = m.simulate(rec.u, rec.dt)
            ax9.plot(rec.u, y, color=COLORS.get(k), lw=0.8, label=KIND_LABELS.get(k, k))
            ax10.plot(t, y - rec.y, color=COLORS.get(k), lw=0.7, label=KIND_LABELS.get(k, k))
        ax9.set(xlabel="u [V]", ylabel="y [µm]", title=f"f = {f} Hz")
        ax10.set(xlabel="t [s]", ylabel="error [µm]", title=f"f = {f} Hz")
    a9[0, 0].legend(fontsize=8)
    a10[0, 0].legend(fontsize=8)
    f9.suptitle("Fig. 9: validation loops, bench vs identified models")
    f10.suptitle("Fig. 10: validation errors")
    for f, p in ((f9, path9), (f10, path10)):
        f.tight_layout()
        f.savefig(p, dpi=100)
        plt.close(f)


def ordering_statement(t3) -> str:
    """An honest sentence on which model wins where."""
    rows, freqs = t3["rows"], t3["freqs"]
    parts = []
    for i, f in enumerate(freqs):
        order = sorted(rows, key=lambda k: rows[k][i])
        parts.append(f"{f:g} Hz: " + " < ".join(KIND_LABELS.get(k, k) for k in order))
    msg = "Validation RMS (% of range), best first — " + "; ".join(parts) + "."
    if "fonbw" in rows and "cbw" in rows:
        beats = all(a < b for a, b in zip(rows["fonbw"], rows["cbw"]))
        gap = [b - a for a, b in zip(rows["fonbw"], rows["cbw"])]
        widening = gap[-1] > gap[0]
        msg += (" FONBW beats CBW at every frequency" if beats else " FONBW does NOT beat CBW at every frequency")
        msg += (", by a margin that widens with frequency " if widening else ", but the margin does not widen with frequency ")
        msg += f"({gap[0]:.2f} → {gap[-1]:.2f} percentage points)."
    return msg


def reproduce(out_dir, *, seed=0, quick=False, bench=None, progress=False, max_evals=None, fs_identify=None,
              kinds=("fonbw", "cbw", "zhu")) -> dict:
    """Tables 1–3 and Figs. 8–10 on the virtual bench; writes PNGs, tables.json and tables.md.

    Parameters
    ----------
    out_dir : path
    seed : int
        Bench noise and optimizer seed.
    quick : bool
        Small budgets (smoke runs, the demo's reduced mode).
    bench : Bench, optional
        Defaults to ``Bench(seed)`` (creep, amplifier and mechanics on).
    max_evals : int, optional
        DE evaluations per model (default 3000, quick 600).
    fs_identify : float, optional
        Sampling rate used for identification (default 5 kHz, quick 2 kHz).
    """
    os.makedirs(out_dir, exist_ok=True)
    bench = bench or Bench(seed=seed)
    max_evals = max_evals or (600 if quick else 3000)
    fs_identify = fs_identify or (2000.0 if quick else 5000.0)
    q = max(1, int(round(bench.fs / fs_identify)))
    t0 = time.perf_counter()
    train_full = bench.record(eq19_input(bench.fs)[1], "eq19")
    train = decimate(train_full, q)
    sines = {f: bench.record(sine_input(f, bench.fs, periods=3 if quick else 5)[1], f"sine_{f:g}hz") for f in SINE_FREQS}
    results = identify_models(train, kinds, seed=seed, max_evals=max_evals, progress=progress)
    models = {k: r.model for k, r in results.items()}
    t1 = table1(results)
    t2 = table2(results)
    t3 = table3(models, sines)
    figs = {
        "fig8": os.path.join(out_dir, "fig8_identification.png"),
        "fig9": os.path.join(out_dir, "fig9_validation_loops.png"),
        "fig10": os.path.join(out_dir, "fig10_validation_errors.png"),
    }
    plot_fig8(train_full, models, figs["fig8"])
    plot_fig9_10(sines, models, figs["fig9"], figs["fig10"])
    for k, m in models.items():
        m.save(os.path.join(out_dir, f"model_{k}.json"))
    res = {"bench": bench.config(), "identification": {"fs": bench.fs / q, "samples": int(train.n),
                                                         "max_evals": max_evals, "seed": seed},
           "table1": t1, "table2": t2, "table3": {k: v for k, v in t3.items()},
           "ordering": ordering_statement(t3), "figures": figs, "wall_s": time.perf_counter() - t0}
    with atomic_open(os.path.join(out_dir, "tables.json"), "w", encoding="utf-8") as fh:
        json.dump(res, fh, indent=2)
    with atomic_open(os.path.join(out_dir, "tables.md"), "w", encoding="utf-8") as fh:
        fh.write(tables_markdown(res))
    res["models"] = models
    res["results"] = results
    return res


def tables_markdown(res) -> str:
    """Tables 1–3 as Markdown."""
    lines = ["### Table 1 — identified parameters (training RMS on the eq.-19 record)", ""]
    for row in res["table1"]:
        ps = ", ".join(f"{k} = {v:.5g}" for k, v in row["params"].items())
        lines.append(f"- **{row['model']}** (RMS {row['rms_train']:.3f} µm, {row['nfev']} evaluations, "
                     f"{row['wall_s']:.1f} s): {ps}")
    lines += ["", "### Table 2 — parameter counts", "", "| model | characteristic | parameters | source |",
              "|---|---|---|---|"]
    for r in res["table2"]:
        lines.append(f"| {r['model']} | {r['characteristic']} | {r['parameters']} | {r['source']} |")
    t3 = res["table3"]
    lines += ["", "### Table 3 — validation RMS error, % of the measured range", "",
              "| model | " + " | ".join(f"{f:g} Hz" for f in t3["freqs"]) + " |",
              "|---|" + "---|" * len(t3["freqs"])]
    for k, vals in t3["rows"].items():
        lines.append(f"| {KIND_LABELS.get(k, k)} | " + " | ".join(f"{v:.2f} %" for v in vals) + " |")
    lines += ["", res["ordering"], ""]
    return "\n".join(lines)


# ---------------------------------------------------------------------------
# Table 4: feedforward compensation on the bench

def _rms(x):
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else math.nan


def _table4_specs(models, limits, explicit):
    """name -> (model, keyword options of :func:`fonbw.compensate`)."""
    specs = {}
    for name, spec in models.items():
        m, opts = spec if isinstance(spec, tuple) else (spec, {})
        check_model(m)
        # Table 4 compares the paper's compensators: eq. (22) for the Zhu model
        form = "eq22" if isinstance(m, _hy.Zhu2016) else "discrete"
        specs[name] = (m, {"limits": limits, "explicit": explicit, "form": form, **opts})
    return specs


def _slope_min(m, dt):
    """Smallest one-step slope [µm/V] of m at dt (None for the Zhu model)."""
    if isinstance(m, _hy.Zhu2016):
        return None
    from .invertibility import check_invertible
    return check_invertible(m, dt)[1]


def _table4_row(mname, tname, pname, yp, Hd, res, slope=None):
    """One row of :func:`table4`: output `yp` [µm] of plant `pname` driven by
    the compensation `res` of `Hd` [µm]."""
    e = yp - Hd
    ok = res.status == OK
    return {"compensator": mname, "trajectory": tname, "plant": pname,
            "slope_min": slope,
            "rms_du": _rms(np.diff(res.u)),
            "max_model_error": float(np.max(np.abs(res.residual))) if len(Hd) else 0.0,
            "rms_error": _rms(e), "max_error": float(np.max(np.abs(e))),
            "rms_error_solved": _rms(e[ok]),
            "rms_input": _rms(res.u),
            "saturated": int(np.count_nonzero(res.saturated)),
            "not_converged": int(res.unconverged_samples.size),
            "samples": int(len(Hd))}


def table4(bench, models, dt=None, out_dir=None, *, T=2.0, limits=DEFAULT_LIMITS,
           explicit=False, ideal=True, trajectories=None, preview=False) -> list[dict]:
    """Reproduce Table 4: feedforward tracking of the two trajectories on a bench.

    Each model's compensator (:func:`fonbw.compensate`, from rest) turns H_d into a
    voltage, the bench runs it (from rest, measured output: sensor, noise and
    ADC included), and the error is measured − desired over the whole record.

    Parameters
    ----------
    bench : fonbw.bench.Bench
        The plant. Anything with ``run(u) -> y`` [µm] and ``dt`` [s] works.
    models : mapping of str to model or (model, dict)
        Compensator name (e.g. "FONBW", "CBW", "Zhu") -> identified model,
        optionally with keyword options of :func:`fonbw.compensate` for it (e.g.
        ``(zhu_model, {"form": "discrete"})``). A Zhu2016 model compensates
        in the form of eq. (22) unless told otherwise (``form="eq22"``, the
        compensator the paper compares; the per-step inversion of its
        discrete mechanics is greedy and can lock on a voltage limit).
    dt : float, optional
        Step [s]; must equal ``bench.dt`` (default).
    out_dir : path, optional
        Where to write ``table4.csv`` and one PNG per trajectory (tracking
        and error of every compensator).
    T : float
        Duration of each trajectory [s].
    limits, explicit, preview
        Passed to :func:`fonbw.compensate` (``limits=None``: each model's
        training range; ``preview``: the non-causal stable inversion, not for
        the Zhu model).
    ideal : bool
        Also run each compensator on its own model as the plant (rows with
        ``plant="model"``): tracks to the solver tolerance unless saturated.
    trajectories : mapping, optional
        name -> function of t [s] giving H_d [µm]; default
        :data:`fonbw.signals.TRAJECTORIES`.

    Returns
    -------
    list of dict
        One row per (compensator, trajectory[, plant]) with ``compensator``,
        ``trajectory``, ``plant`` ("bench" or "model"), ``slope_min`` (the
        model's smallest one-step slope u_k → H_k at dt [µm/V], None for
        Zhu), ``rms_du`` (RMS sample-to-sample change of u [V]),
        ``max_model_error`` (max |model ∘ compensator − H_d| [µm]), ``rms_error`` [µm],
        ``max_error`` [µm], ``rms_error_solved`` [µm] (over the samples whose
        equation was solved, i.e. neither saturated nor unconverged),
        ``rms_input`` [V], ``saturated`` and ``not_converged`` (sample
        counts), ``samples``.
    """
    dt, T = _table4_checks(bench, models, dt, T)
    specs = _table4_specs(models, limits, explicit)
    if preview:
        for m, opts in specs.values():
            if not isinstance(m, _hy.Zhu2016):
                opts["preview"] = True
    slopes = {name: _slope_min(m, dt) for name, (m, _) in specs.items()}
    trajs = dict(TRAJECTORIES if trajectories is None else trajectories)
    t = np.arange(int(round(T / dt))) * dt
    rows, traces = [], {}
    for tname, fn in trajs.items():
        Hd = np.asarray(fn(t), dtype=float)
        for mname, (m, opts) in specs.items():
            with warnings.catch_warnings():
                # non-invertible models are the point of the slope column
                warnings.simplefilter("ignore", RuntimeWarning)
                res = compensate(m, Hd, dt, **opts)
            # the preview's pre-actuation drives the bench before t = 0
            y = np.asarray(bench.run(res.u_full), dtype=float)[res.u_lead.size:]
            traces[tname, mname] = (Hd, y)
            plants = [("bench", y)] + ([("model", res.y_model)] if ideal else [])
            rows += [_table4_row(mname, tname, pname, yp, Hd, res, slopes[mname])
                     for pname, yp in plants]
    if out_dir is not None:
        _write_table4(out_dir, rows, traces, t, list(trajs), list(specs))
    return rows


def _table4_checks(bench, models, dt, T):
    """The step [s] (the bench's) and duration [s] of :func:`table4`, checked."""
    bdt = float(getattr(bench, "dt"))
    dt = bdt if dt is None else _hy._dt(dt)
    if abs(dt - bdt) > 1e-12 * bdt:
        raise ValueError(f"dt = {dt!r} s differs from the bench's sampling step {bdt!r} s")
    if not models:
        raise ValueError("models must name at least one model to compensate with")
    T = float(T)
    if not (math.isfinite(T) and T > 0):
        raise ValueError(f"T must be a positive duration [s], got {T!r}")
    return dt, T


def _write_table4(out_dir, rows, traces, t, tnames, mnames):
    import csv

    os.makedirs(out_dir, exist_ok=True)
    keys = list(rows[0])
    with atomic_open(os.path.join(out_dir, "table4.csv"), "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for tname in tnames:
        fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
        Hd = traces[tname, mnames[0]][0]
        # desired on top; measured traces thin and translucent, so a
        # chattering compensator does not hide the others
        a1.plot(t, Hd, "k--", lw=1.2, label="desired", zorder=10)
        for m in mnames:
            y = traces[tname, m][1]
            a1.plot(t, y, lw=0.7, alpha=0.8, label=f"{m}-based")
            a2.plot(t, y - Hd, lw=0.7, alpha=0.8, label=f"{m}: RMS {_rms(y - Hd):.3f} µm")
        a1.set_ylabel("displacement [µm]")
        a1.set_title(f"Feedforward compensation on the bench, {tname} trajectory")
        a1.legend(loc="upper right", fontsize=8)
        a2.set_ylabel("tracking error [µm]")
        a2.set_xlabel("t [s]")
        a2.legend(loc="upper right", fontsize=8)
        fig.tight_layout()
        slug = "".join(ch if ch.isalnum() else "_" for ch in tname.lower()).strip("_")
        path = os.path.join(out_dir, f"table4_{slug}.png")
        with atomic_open(path, "wb") as fh:
            fig.savefig(fh, format="png", dpi=110)
        plt.close(fig)


def format_table4(rows, paper=True) -> str:
    """Plain-text Table 4 (bench rows; with the paper's numbers beside them): RMS
    tracking error, RMS input, saturated and rootless samples, the smallest
    one-step slope, RMS step change of u, max |model ∘ compensator − H_d| and,
    when the models were identified here, their training RMS."""
    ref = {(c, tr): (e, u) for c, tr, e, u in PAPER_TABLE4}
    lines = [f"{'compensator':<12} {'trajectory':<12} {'RMS error':>10} {'RMS input':>10} "
             f"{'saturated':>9} {'no root':>7} {'slope_min':>10} {'RMS du':>8} {'model∘comp':>10} "
             f"{'fit RMS':>9}" + ("   paper: error, input" if paper else "")]
    for r in rows:
        if r["plant"] != "bench":
            continue
        sl = r.get("slope_min")
        line = (f"{r['compensator']:<12} {r['trajectory']:<12} {r['rms_error']:>7.3f} µm "
                f"{r['rms_input']:>8.2f} V {r['saturated']:>9d} {r['not_converged']:>7d} "
                f"{('%.3g' % sl) if sl is not None else '-':>10} {r.get('rms_du', math.nan):>6.3f} V "
                f"{r.get('max_model_error', math.nan):>7.2g} µm "
                f"{('%6.3f µm' % r['rms_train']) if r.get('rms_train') is not None else '-':>9}")
        if paper and (r["compensator"], r["trajectory"]) in ref:
            e, u = ref[r["compensator"], r["trajectory"]]
            line += f"   {e:.2f} µm, {u:.2f} V"
        lines.append(line)
    return "\n".join(lines)


def table4_training(seed=0, fs=5000.0, T_eq19=10.0, T_multi=4.0, *, creep=True, extra=()):
    """The pooled training records every Table 4 model is identified on: the
    eq.-19 sweep and a multi-tone record (1, 5, 10, 20 Hz) from the default
    bench's truth sampled at ``fs`` [Hz] (identification cost scales with the
    samples; the models are continuous-time and used at the bench's rate).

    ``creep=False`` switches the bench's creep off; ``extra`` holds
    (name, input [V] at ``fs``) pairs recorded after the two on the same
    bench (its noise stream goes on), for studies of the training set."""
    b = Bench(seed=seed, fs=fs, creep=creep)
    return [b.record(eq19_input(fs, T=T_eq19)[1], "eq19"),
            b.record(multi_input(fs=fs, T=T_multi)[1], "multi")] + [b.record(u, name) for name, u in extra]


#: Table 4's compensators and the model kinds behind them.
TABLE4_KINDS = (("FONBW", "fonbw"), ("CBW", "cbw"), ("NBW", "nbw"), ("Zhu", "zhu"))


def reproduce_table4(out_dir=None, *, seed=0, max_evals=3000, T=2.0, models=None,
                     workers=None, progress=False, for_compensation=True, records=None,
                     kinds=TABLE4_KINDS, preview=False) -> list[dict]:
    """Table 4 end to end on the default virtual bench.

    Identifies every model of ``kinds`` (FONBW, CBW, asymmetric NBW, Zhu) on
    the same pooled records (:func:`table4_training` unless ``records``),
    same seed and budget, unless ``models`` is given, then runs
    :func:`table4` at the bench's step. The records are scored after a rest
    cycle (:func:`fonbw.compensate.rest.with_rest_cycle`: the bench is zeroed
    at rest after a previous cycle, a model simulated from its virgin state
    is not), and the models record that start (``meta["start"]``), which the
    compensators then run first. With ``for_compensation`` (default) FONBW,
    NBW and CBW are identified invertible at the bench's step
    (``identify(..., for_compensation=bench.dt)``), so the causal
    compensator has a root at every sample. With ``out_dir`` also writes the
    identified models as ``model_<name>.json`` (with ``u_range``, the start
    and the invertibility record). Rows then carry ``rms_train``, the
    model's fit [µm] on the scored training samples.
    """
    bench = Bench(seed=seed)
    fits = {}
    if models is None:
        models, fits = table4_models(bench.dt, seed=seed, max_evals=max_evals, workers=workers,
                                     progress=progress, for_compensation=for_compensation,
                                     records=records, kinds=kinds)
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
        for name, m in models.items():
            m.save(os.path.join(out_dir, f"model_{name.lower()}.json"))
    rows = table4(bench, models, bench.dt, out_dir, T=T, limits=None, preview=preview)
    for r in rows:
        r["rms_train"] = fits.get(r["compensator"])
    return rows


def table4_models(dt, *, seed=0, max_evals=3000, workers=None, progress=False,
                  for_compensation=True, records=None, kinds=TABLE4_KINDS, bounds=None):
    """Table 4's models, every kind identified on the same records after a rest
    cycle (and, with ``for_compensation``, invertible at ``dt`` [s] except Zhu).
    ``bounds`` maps a kind to its search-bound overrides
    (:func:`fonbw.identify.identify`'s ``bounds``), e.g. ``{"fonbw": {"lam2": (1, 1)}}``.

    Returns ``({name: model}, {name: training RMS [µm]})``.
    """
    from .compensate.rest import rest_start_meta, with_rest_cycle
    from .identify import identify

    recs = table4_training(seed) if records is None else records
    lo, hi = input_range(recs)
    cycled, burn = with_rest_cycle(recs, (lo, hi))
    models, fits = {}, {}
    # the NBW first: it warm-starts the FONBW (the FONBW with λ1 = λ2 = 1), so
    # that the richer model never ends worse on the records than the one it contains
    order = sorted(kinds, key=lambda nk: nk[1] != "nbw")
    nbw = None
    for name, kind in order:
        fc = dt if (for_compensation and kind != "zhu") else None
        res = identify(cycled, kind, seed=seed, max_evals=max_evals, workers=workers,
                       progress=progress, for_compensation=fc, burn_in=burn,
                       x0=nbw if kind == "fonbw" else None, bounds=(bounds or {}).get(kind))
        if kind == "nbw":
            nbw = res.model
        m = res.model
        m.meta = {**(getattr(m, "meta", None) or {}), "u_range": [lo, hi],
                  "start": rest_start_meta((lo, hi))}
        models[name], fits[name] = m, float(res.rms)
    return {n: models[n] for n, _ in kinds}, {n: fits[n] for n, _ in kinds}
