"""``fonbw demo``: the whole workflow on the virtual bench, one report.

1. the bench's experiments (eq. 19, sines, multi-tone, step-and-hold) as CSV;
2. FONBW, CBW and Zhu identified on the eq.-19 record (Tables 1–3, Figs. 8–10);
3. the three feedforward compensators on the paper's two trajectories (Table 4);
4. the FMUs built (:mod:`fonbw.fmu.build`) with the identified FONBW parameters;
5. the closed loop run by the fmpy master: feedforward, feedback, both;
6. the sim-to-real gap between the identified model and the bench diagnosed
   (the bench has creep and mechanics the model lacks);
7. ``report.md`` and a self-contained ``report.html``.

Every stage is timed; a stage that fails is reported as failed in the report
(with the error) instead of aborting the rest.
"""
from __future__ import annotations

import os
import sys
import time
import traceback

import numpy as np

from .report import Section, md_table, write_html, write_markdown

__all__ = ["run_demo"]


class _Stages:
    """Runs named stages with a progress bar and keeps their timings and errors."""

    def __init__(self, names, progress=True):
        from tqdm.auto import tqdm

        self.bar = tqdm(total=len(names), desc="fonbw demo", unit="stage", disable=not progress, file=sys.stderr)
        self.times, self.errors = {}, {}

    def run(self, name, fn, *a, **kw):
        self.bar.set_postfix_str(name)
        t0 = time.perf_counter()
        try:
            return fn(*a, **kw)
        except KeyboardInterrupt:
            raise
        except Exception as exc:  # reported in the report, the demo goes on
            self.errors[name] = f"{type(exc).__name__}: {exc}"
            self.errors[name + " (traceback)"] = traceback.format_exc(limit=6)
            return None
        finally:
            self.times[name] = time.perf_counter() - t0
            self.bar.update(1)

    def close(self):
        self.bar.close()


def _budgets(quick):
    if quick:
        return dict(max_evals=300, fs_identify=1000.0, T_traj=1.0, cosim_T=0.5, gap_budget=300, gap_refit=30,
                    gap_T=(6.0, 2.0))
    return dict(max_evals=1500, fs_identify=2000.0, T_traj=2.0, cosim_T=2.0, gap_budget=800, gap_refit=80,
                gap_T=(20.0, 5.0))


def _stage_data(bench, out):
    return bench.write_experiments(os.path.join(out, "data"))


def _stage_identify(bench, out, seed, b, progress):
    from .reproduce import reproduce

    return reproduce(os.path.join(out, "identify"), seed=seed, bench=bench, max_evals=b["max_evals"],
                     fs_identify=b["fs_identify"], progress=progress, quick=b["T_traj"] < 2)


def _stage_compensate(bench, out, seed, b):
    """Table 4 with the compensators' own models: FONBW, CBW, NBW and Zhu
    identified on the same records behind a rest cycle, all but Zhu invertible
    at the bench's step (:func:`fonbw.reproduce.table4_models`; the FONBW
    warm-started from the NBW). The FONBW goes on to the FMUs and the closed
    loop."""
    from .reproduce import table4, table4_models, table4_training

    T19, Tm = (5.0, 2.0) if b["T_traj"] < 2 else (10.0, 4.0)
    recs = table4_training(seed, fs=b["fs_identify"], T_eq19=T19, T_multi=Tm)
    named, fits = table4_models(bench.dt, seed=seed, max_evals=b["max_evals"], records=recs)
    d = os.path.join(out, "compensate")
    rows = table4(bench, named, out_dir=d, T=b["T_traj"])
    for r in rows:
        r["rms_train"] = fits.get(r["compensator"])
    for name, m in named.items():
        m.save(os.path.join(d, f"model_{name.lower()}.json"))
    return rows, sorted(os.path.join(d, f) for f in os.listdir(d) if f.endswith(".png")), named["FONBW"]


def _stage_fmus(model, out):
    from .fmu.build import run_builder

    d = os.path.join(out, "fmus")
    os.makedirs(d, exist_ok=True)
    params = os.path.join(d, "fonbw_identified.json")
    model.save(params)
    run_builder(["--params", params, "-o", d])
    return sorted(os.path.join(d, f) for f in os.listdir(d) if f.endswith(".fmu"))


def _stage_cosim(model, out, b):
    from .loop import ff_fb_study

    d = os.path.join(out, "cosim")
    rows = ff_fb_study(out_dir=d, master="fmpy", trajectories=("sine5",), plants=("dynamics+creep",),
                       modes=("ff", "fb", "ff+fb"), T=b["cosim_T"], model=model)
    return rows, sorted(os.path.join(d, f) for f in os.listdir(d) if f.endswith(".png"))


def _stage_gap(bench, model, out, seed, b, progress):
    from .signals import eq19_input, multi_input, sine_input, step_hold_input
    from .gap import diagnose, write_html as gap_html, write_json as gap_json
    from .io import decimate

    q = max(1, int(round(bench.fs / 5000.0)))  # 5 kHz, the rate the diagnosis is tuned and timed at
    Tt, Tv = b["gap_T"]
    train = [decimate(bench.record(eq19_input(bench.fs, Tt)[1], "eq19"), q),
             decimate(bench.record(step_hold_input(hold=Tv, fs=bench.fs)[1], "step_hold"), q)]
    val = [decimate(bench.record(sine_input(f, bench.fs, periods=max(3, int(f * Tv / 2)))[1], f"sine_{f:g}hz"), q)
           for f in (1.0, 10.0, 20.0)]
    val.append(decimate(bench.record(multi_input(fs=bench.fs, T=Tv)[1], "multi"), q))
    res = diagnose(train, val, model=None, seed=seed, progress=progress, budget=b["gap_budget"],
                   refit_evals=b["gap_refit"])
    d = os.path.join(out, "gap")
    os.makedirs(d, exist_ok=True)
    gap_html(res, os.path.join(d, "gap_report.html"))
    gap_json(res, os.path.join(d, "gap.json"))
    return res


def _gap_figures(res, d):
    """Waterfall and candidate bar chart as PNG files for the main report."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cands = res.get("candidates", [])
    paths = []
    if cands:
        fig, ax = plt.subplots(figsize=(7, 3.5))
        names = [c["effect"] for c in cands]
        vals = [c["gap_closed"] for c in cands]
        ax.barh(names, vals, color=["tab:green" if c.get("accepted") else "tab:gray" for c in cands])
        ax.axvline(0, color="k", lw=0.8)
        ax.set(xlabel="gap closed on validation (1 = down to the noise floor)",
               title="candidate effects (green: accepted)")
        fig.tight_layout()
        p = os.path.join(d, "gap_candidates.png")
        fig.savefig(p, dpi=100)
        plt.close(fig)
        paths.append(p)
    return paths


def _fmt_rows(rows, keys):
    return [[r.get(k, "") for k in keys] for r in rows]


def run_demo(out_dir="demo-out", *, seed=0, quick=False, progress=True) -> dict:
    """Run the whole workflow on the virtual bench and write the report.

    Returns a dict with the results of each stage, the timings and the errors.
    """
    from .bench import Bench

    t0 = time.perf_counter()
    os.makedirs(out_dir, exist_ok=True)
    b = _budgets(quick)
    bench = Bench(seed=seed)
    st = _Stages(["data", "identify", "compensate", "fmus", "cosim", "gap", "report"], progress)
    data = st.run("data", _stage_data, bench, out_dir)
    rep = st.run("identify", _stage_identify, bench, out_dir, seed, b, False)
    models = rep["models"] if rep else None
    comp = st.run("compensate", _stage_compensate, bench, out_dir, seed, b)
    # the FMUs and the loop wrap the compensation model (invertible at the loop's step, behind
    # the rest cycle), else the identification stage's FONBW
    m_comp = comp[2] if comp else (models["fonbw"] if models else None)
    fmus = st.run("fmus", _stage_fmus, m_comp, out_dir) if m_comp is not None else None
    cos = st.run("cosim", _stage_cosim, m_comp, out_dir, b) if m_comp is not None else None
    gap = st.run("gap", _stage_gap, bench, models["fonbw"] if models else None, out_dir, seed, b, False)
    res = {"data": data, "reproduce": rep, "compensate": comp, "fmus": fmus, "cosim": cos, "gap": gap}
    st.run("report", _write_report, out_dir, bench, res, st, b, seed, quick)
    st.close()
    res["times"] = st.times
    res["errors"] = {k: v for k, v in st.errors.items() if "traceback" not in k}
    res["wall_s"] = time.perf_counter() - t0
    return res


def _bench_sections(out_dir, bench, res):
    secs = []
    cfg = bench.config()
    secs.append(Section(
        "Virtual bench",
        "The 'real' actuator every number below is measured on: not built from the FONBW equations.",
        md_table(["setting", "value"], [[k, v] for k, v in cfg.items() if k != "params"])
        + "\n\nRecords written: " + ", ".join(f"`{os.path.relpath(p, out_dir)}`" for p in (res["data"] or []))))
    return secs


def _reproduce_sections(res):
    secs = []
    rep = res["reproduce"]
    if rep:
        t1 = rep["table1"]
        body = md_table(["model", "training RMS [µm]", "parameters", "evaluations", "time [s]"],
                        [[r["model"], r["rms_train"], len(r["params"]), r["nfev"], r["wall_s"]] for r in t1])
        body += "\n\n" + "\n".join(f"- **{r['model']}**: " + ", ".join(f"{k} = {v:.4g}" for k, v in r["params"].items())
                                   for r in t1)
        secs.append(Section("Table 1 — identification", "Parameters identified by jDE on the eq.-19 record "
                            f"(at {rep['identification']['fs']:g} Hz, {rep['identification']['max_evals']} evaluations "
                            "per model) and their training RMS error.", body, [(rep["figures"]["fig8"],
                            "Fig. 8: input, outputs, errors and loops of the identification record.")]))
        secs.append(Section("Table 2 — parameter counts", "How many parameters each model needs (paper's literature "
                            "rows and the models fitted here).",
                            md_table(["model", "characteristic", "parameters", "source"],
                                     _fmt_rows(rep["table2"], ["model", "characteristic", "parameters", "source"]))))
        t3 = rep["table3"]
        from .reproduce import KIND_LABELS

        body = md_table(["model"] + [f"{f:g} Hz" for f in t3["freqs"]],
                        [[KIND_LABELS.get(k, k)] + [f"{v:.2f} %" for v in vals] for k, vals in t3["rows"].items()])
        secs.append(Section("Table 3 — validation", "RMS error as % of the measured range on the sines "
                            "u = 60 − 60 cos(2πft) V.", body + "\n\n" + rep["ordering"],
                            [(rep["figures"]["fig9"], "Fig. 9: validation loops, bench (black) vs models."),
                             (rep["figures"]["fig10"], "Fig. 10: validation errors.")]))
    return secs


def _compensate_sections(res):
    secs = []
    comp = res["compensate"]
    if comp:
        rows, figs = comp[:2]
        keys = [k for k in ("compensator", "trajectory", "plant", "rms_error", "rms_input", "max_error", "saturated",
                            "rms_train") if k in rows[0]]
        secs.append(Section("Table 4 — feedforward compensation", "Each model's inverse multiplicative "
                            "compensator (eq. 16) drives the bench along the paper's two trajectories. Every "
                            "model is identified for it on the same records (eq. 19 and a multi-tone), "
                            "behind a rest cycle, all but Zhu invertible at the bench's step. "
                            "plant = model rows are the ideal case (compensator and plant the same model).",
                            md_table(keys, _fmt_rows(rows, keys)),
                            [(p, "Tracking and error: " + os.path.basename(p)) for p in figs]))
    return secs


def _fmu_sections(out_dir, res):
    secs = []
    if res["fmus"]:
        secs.append(Section("FMUs", "FMI 2.0 co-simulation FMUs built by fonbw build-fmu with the identified FONBW "
                            "parameters (validated by fmpy during the build).",
                            "\n".join(f"- `{os.path.relpath(p, out_dir)}` ({os.path.getsize(p) / 1e3:.0f} kB)"
                                      for p in res["fmus"])))
    return secs


def _cosim_sections(res):
    secs = []
    cos = res["cosim"]
    if cos:
        rows, figs = cos
        keys = [k for k in ("trajectory", "plant", "mode", "rms_error_um", "max_error_um", "rms_input_V",
                            "rel_rms_error") if k in rows[0]]
        secs.append(Section("Closed loop in fmpy", "The compensator, hysteresis, plant (mechanics + creep) and "
                            "PI controller FMUs in a 10 kHz loop run by the fmpy master: feedforward, feedback, both.",
                            md_table(keys, _fmt_rows(rows, keys)), [(p, os.path.basename(p)) for p in figs]))
    return secs


def _gap_sections(out_dir, bench, res):
    from .gap.selection import form_text, outcome_text

    secs = []
    gap = res["gap"]
    if gap:
        d = os.path.join(out_dir, "gap")
        nom = gap["nominal"]
        v = gap["verdict"]
        body = (f"Nominal validation RMS {nom['rms_validate']:.4g} µm, noise floor {nom['noise_floor']:.4g} µm.\n\n"
                + md_table(["effect", "gap closed", "named"],
                           [[c["effect"], _gc(c), outcome_text(c)] for c in gap["candidates"]])
                + f"\n\n**Verdict**: {v.get('message', '')}. Hysteresis form: "
                + form_text(v.get("form"))
                + f"; unmodelled effects {', '.join(v['effects']) or 'none'}; gap closed by both {v['gap_closed']:.3g}; "
                + ("unexplained part remains." if v.get("unexplained") else "explained.")
                + "\n\n" + md_table(["step", "validation RMS [µm]", "gap closed (cumulative)"],
                                     [[w["step"], w["rms_validate"], w["gap_closed_cum"]]
                                      for w in v.get("waterfall", [])])
                + _later_steps_text(v.get("later_steps", []))
                + f"\n\nThe bench's own settings: creep = {bench.creep}, dynamics = {bench.dynamics}, "
                f"amplifier = {bench.amplifier} (the diagnosis was not told).\n\nFull diagnosis: `gap/gap_report.html`.")
        secs.append(Section("Sim-to-real gap", "Where the identified FONBW model misses the bench, how much "
                            "of it is the hysteresis form (what no FONBW reaches but a reference hysteresis "
                            "does), which unmodelled effect causes the rest and how far adding it closes the "
                            "gap.", body,
                            [(p, "Gap closed per candidate effect.") for p in _gap_figures(gap, d)]))
    return secs


def _gc(c):
    """A candidate's gap closed for a table ("–" where its fit diverges on validation)."""
    return "–" if c["gap_closed"] is None else c["gap_closed"]


def _later_steps_text(steps):
    """The later greedy steps as a table: why a further effect was or was not named."""
    from .gap.selection import on_top_of_text, outcome_text

    rows = [[on_top_of_text(st), c["effect"], _gc(c), outcome_text(c)]
            for st in steps for c in st["candidates"]]
    if not rows:
        return ""
    return ("\n\nLater steps, each candidate refit on top of the effects named before it, or its first-step "
            "refit judged with a limit named beyond the training range on top (gap closed: "
            "the share it adds of the gap the nominal they are attributed on leaves, as above):\n\n"
            + md_table(["on top of", "effect", "gap closed", "named"], rows))


def _run_sections(st, seed, quick):
    secs = []
    tm = st.times
    body = md_table(["stage", "wall time [s]"], [[k, v] for k, v in tm.items()])
    errs = {k: v for k, v in st.errors.items() if "traceback" not in k}
    if errs:
        body += "\n\n**Failed stages**\n\n" + "\n".join(f"- {k}: {v}" for k, v in errs.items())
    secs.append(Section("Run", f"Timings of this run (seed {seed}, {'quick' if quick else 'full'} budgets).", body))
    return secs


def _write_report(out_dir, bench, res, st, b, seed, quick):
    secs = (_bench_sections(out_dir, bench, res) + _reproduce_sections(res) + _compensate_sections(res)
            + _fmu_sections(out_dir, res) + _cosim_sections(res) + _gap_sections(out_dir, bench, res)
            + _run_sections(st, seed, quick))
    title = "fonbw demo — FONBW hysteresis on the virtual bench"
    intro = ("This report walks the whole workflow of `fonbw` on its built-in virtual piezo bench: "
             "identification, validation, compensation, FMUs, closed loop and gap diagnosis.")
    write_markdown(os.path.join(out_dir, "report.md"), title, secs, intro)
    write_html(os.path.join(out_dir, "report.html"), title, secs, intro)
