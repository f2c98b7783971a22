"""Report of a gap diagnosis: JSON and a self-contained HTML page.

``write_html(result, path)`` draws the localization plots (residual spectrum
against the noise floor, RMS versus time, binned RMS versus input rate,
amplitude, branch and time since reversal), the ranking table of the
candidates (and of each later greedy step's, with the check each one
failed), the hysteresis form with the loop-shape residual (FONBW's and
the reference's residual versus the input; needs the result object) and a
waterfall nominal → form → +effect … → noise floor (the form after the
effects when it was found on top of them; a step where an accepted
amplifier takes a pole of its own), all from the result alone (a :class:`fonbw.gap.DiagnosisResult` or its ``to_dict()``); the
PNGs are embedded as base64, so the page is one file.
"""
from __future__ import annotations

import base64
import html
import io
import json
import math

from ..io import atomic_open, jsonable
from .checks import flag_text
from .edges import summary_text
from .selection import form_text, on_top_of_text, outcome_text

__all__ = ["write_json", "write_html"]


def write_json(result, path):
    """Write the diagnosis result (a DiagnosisResult or its dict) as strict
    JSON, atomically: a figure that is not a finite number (a candidate that
    diverged on the validation records, a bootstrap with nothing to resample)
    is null, which every JSON reader takes, where -Infinity and NaN are not
    JSON."""
    if hasattr(result, "to_dict"):
        result = result.to_dict()
    with atomic_open(path, "w", encoding="utf-8") as fh:
        json.dump(jsonable(result, strict=True), fh, indent=1, ensure_ascii=False, allow_nan=False)
        fh.write("\n")


def _png(fig):
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _figures(result):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    loc = result["localization"]
    sigma = result["nominal"]["noise_floor"]
    figs = {}
    fig, ax = plt.subplots(1, 2, figsize=(11, 3.6))
    for rec in loc["records"]:
        sp = rec["spectrum"]
        ax[0].loglog(sp["f"][1:], sp["psd"][1:], lw=1, label=rec["name"])
        ax[1].plot(rec["time"]["t"], rec["time"]["rms"], marker=".", lw=1, label=rec["name"])
    if loc["records"]:
        ax[0].axhline(loc["records"][0]["spectrum"]["floor"], color="k", ls="--", label="noise floor")
    ax[0].set_xlabel("frequency [Hz]")
    ax[0].set_ylabel("residual PSD [µm²/Hz]")
    ax[0].legend(fontsize=7)
    ax[1].axhline(sigma, color="k", ls="--", label="noise σ")
    ax[1].set_xlabel("time [s]")
    ax[1].set_ylabel("residual RMS [µm]")
    ax[1].legend(fontsize=7)
    figs["spectrum_time"] = _png(fig)

    feats = loc["features"]
    fig, axs = plt.subplots(1, len(feats), figsize=(3.2 * len(feats), 3.2))
    for ax, (name, ft) in zip(axs, feats.items()):
        bins = [b for b in ft["bins"] if b["n"]]
        if "labels" in ft:
            lab = {-1.0: "desc.", 0.0: "hold", 1.0: "asc."}
            x = [lab.get(round(0.5 * (b["lo"] + b["hi"])), "?") for b in bins]
            ax.bar(x, [b["rms"] for b in bins], color="C0", alpha=0.7)
        else:
            x = [0.5 * (b["lo"] + b["hi"]) for b in bins]
            ax.plot(x, [b["rms"] for b in bins], "o-", label="RMS")
            ax.plot(x, [b["mean"] for b in bins], "s--", label="mean")
            if name == "time_since_reversal":
                ax.set_xscale("symlog", linthresh=1e-3)
            ax.legend(fontsize=7)
        ax.axhline(sigma, color="k", ls=":", lw=1)
        ax.set_title(f"{name} (η²={ft['eta2']:.2f})", fontsize=9)
        ax.set_xlabel(ft.get("unit", ""))
    axs[0].set_ylabel("residual [µm]")
    figs["features"] = _png(fig)

    steps = result["verdict"]["steps"]
    fig, ax = plt.subplots(figsize=(max(4, 1.6 * len(steps)), 3.2))
    vals = [s["rms_validate"] for s in steps]
    for i, (s, v) in enumerate(zip(steps, vals)):
        if i == 0 or i == len(steps) - 1:
            ax.bar(i, v, color="C7" if i == 0 else "k", alpha=0.7)
        else:
            ax.bar(i, vals[i - 1] - v, bottom=v, color="C2")
        ax.text(i, v, f"{v:.3g}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(range(len(steps)), [s["label"] for s in steps], fontsize=8)
    ax.set_ylabel("validation RMS [µm]")
    ax.set_title("waterfall: what each step leaves, down to the noise floor", fontsize=9)
    figs["waterfall"] = _png(fig)
    loops = getattr(result, "loops", None)
    if loops:
        figs["loops"] = _loop_figure(plt, loops)
    return figs


def _loop_figure(plt, loops):
    """Residual [µm] versus input [V] of the FONBW nominal and of the reference:
    loop-shape error shows as a loop-shaped residual that the reference removes."""
    fig, ax = plt.subplots(1, 2, figsize=(11, 3.6), sharey=True)
    for u, r0, r1 in zip(loops["u"], loops["fonbw"], loops["reference"]):
        step = max(1, len(u) // 4000)
        ax[0].plot(u[::step], r0[::step], lw=0.6)
        ax[1].plot(u[::step], r1[::step], lw=0.6)
    ax[0].set_title("FONBW residual versus input", fontsize=9)
    ax[1].set_title("reference hysteresis residual versus input", fontsize=9)
    for a in ax:
        a.set_xlabel("u [V]")
    ax[0].set_ylabel("residual [µm]")
    return _png(fig)


_CANDIDATE_HEAD = ("<tr><th>effect</th><th>gap closed</th><th>val. RMS [µm]</th><th>ΔBIC</th><th>own ΔBIC</th>"
                   "<th>bootstrap p10</th><th>held-out MSE ratio</th><th>accepted</th><th>parameters</th></tr>")


def _num(x, spec):
    """`x` formatted by `spec`, or a dash for a figure not computed (None) or
    not finite (a check that did not run, a refit that diverged)."""
    return "–" if x is None or not math.isfinite(x) else format(x, spec)


def _candidate_row(c):
    """A candidate's table row, with what became of it (:func:`~fonbw.gap.selection.outcome_text`)."""
    esc = html.escape
    ch = c.get("checks", {})
    bs = ch.get("bootstrap") or {}
    lo = (ch.get("loro") or {}).get("ratios")
    params = ", ".join(f"{k}={val:.4g}" for k, val in c["params"].items())
    w = ch.get("within_training_rates")
    within = "" if w is None else f" ({_num(w['gap_closed'], '.3f')} within the training rates)"
    return (f"<tr><td>{esc(c['effect'])}</td><td>{_num(c['gap_closed'], '.3f')}{within}</td>"
            f"<td>{_num(c['rms_validate'], '.4g')}</td>"
            f"<td>{_num(ch.get('delta_bic'), '.4g')}</td><td>{_num(ch.get('own_bic'), '.4g')}</td>"
            f"<td>{_num(bs.get('p10'), '.3f')}</td>"
            f"<td>{esc(', '.join(_num(q, '.2f') for q in lo)) if lo else '–'}</td>"
            f"<td>{esc(outcome_text(c))}</td><td>{esc(params)}</td></tr>")


def _beyond_cell(r):
    """The remaining-gap table's note on samples beyond the training range ('' when none)."""
    b = r.get("beyond_input_range")
    if not b or b["gap"] <= 0:  # as the verdict's message: nothing of the gap out there, nothing to say
        return ""
    return f" ({100 * b['gap']:.0f} % of its gap on the {100 * b['samples']:.0f} % of samples out of range)"


def _step_outcome(st):
    """What a later greedy step (an entry of ``later_steps``) added, in words."""
    if st.get("own_pole"):
        return f"the amplifier takes a pole of its own at {st['own_pole']['params']['f_pole']:.4g} Hz"
    return "+" + st["accepted"] if st["accepted"] else "nothing added"


def write_html(result, path):
    """Write a self-contained HTML report of a :func:`fonbw.gap.diagnose` result."""
    figs = _figures(result)
    v = result["verdict"]
    nom = result["nominal"]
    esc = html.escape
    rows = [_candidate_row(c) for c in result["candidates"]]
    later = "".join(
        f"<h3>On top of {esc(on_top_of_text(st))} (val. RMS {st['rms_validate']:.4g} µm): "
        f"{esc(_step_outcome(st))}</h3>"
        f"<table>{_CANDIDATE_HEAD}{''.join(_candidate_row(c) for c in st['candidates'])}</table>"
        for st in v.get("later_steps", []))
    recs = "".join(
        f"<tr><td>{esc(r['name'])}</td><td>{r['rms']:.4g}</td><td>{r['rms_pct_range']:.3g}</td>"
        f"<td>{r['excess_rms']:.4g}</td><td>{esc('; '.join(f'{a:.0f}–{b:.0f} Hz (×{m:.0f})' for a, b, m in r['spectrum']['excess_bands'][:5]))}</td></tr>"
        for r in result["localization"]["records"])
    fo = v.get("form") or {}
    form_txt = form_text(fo)
    wf = "".join(f"<tr><td>{esc(w['step'])}</td><td>{w['rms_validate']:.4g}</td><td>{w['gap_closed_cum']:.3f}</td></tr>"
                 for w in v.get("waterfall", []))
    st = v.get("start") or {}
    loop_img = f'<img src="{figs["loops"]}" alt="loop-shape residual">' if "loops" in figs else ""
    left = "".join(
        f"<tr><td>{esc(r['record'])}</td><td>{100 * r['share']:.1f}</td><td>{r['rms']:.4g}</td>"
        f"<td>{esc('; '.join(flag_text(f) for f in r['outside']) or 'no')}{_beyond_cell(r)}</td></tr>"
        for r in v.get("remaining", []))
    cov = "".join(f"<li>{esc(c['record'])}: {esc(c['condition'])} {c['validate']:.4g} (training up to {c['train']:.4g})</li>"
                  for c in v.get("coverage", [])) or "<li>none</li>"
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>fonbw gap diagnosis</title>
<style>body{{font-family:sans-serif;max-width:1150px;margin:1em auto}} table{{border-collapse:collapse}}
td,th{{border:1px solid #bbb;padding:3px 6px;font-size:13px}} img{{max-width:100%}}</style></head><body>
<h1>Sim-to-real gap diagnosis</h1>
<p><b>Verdict:</b> {esc(v.get('message', ''))}. Accepted effects: {esc(', '.join(v['effects']) or 'none')};
gap closed {v['gap_closed']:.3f}; unexplained: {v['unexplained']}; at noise floor: {v['at_noise_floor']}.</p>
<p>Nominal FONBW: validation RMS {nom['rms_validate']:.4g} µm, training RMS {nom['rms_train']:.4g} µm,
noise floor σ = {nom['noise_floor']:.4g} µm.</p>
<h2>Localization</h2>
<table><tr><th>record</th><th>RMS [µm]</th><th>% of range</th><th>excess over noise [µm]</th><th>bands above 4× floor</th></tr>{recs}</table>
<p>Dominant feature: {esc(result['localization']['dominant'])}.</p>
<img src="{figs['spectrum_time']}" alt="residual spectrum and RMS versus time">
<img src="{figs['features']}" alt="residual versus rate, amplitude, branch, time since reversal">
<h2>Candidates (each refit jointly with the nominal model)</h2>
<table>{_CANDIDATE_HEAD}{''.join(rows)}</table>
<h2>Later greedy steps (each candidate refit jointly with the effects accepted before it)</h2>
{later or "<p>none</p>"}
<h2>Hysteresis form</h2><p>{esc(form_txt)}.</p>{loop_img}
<h2>Waterfall</h2><img src="{figs['waterfall']}" alt="waterfall">
<table><tr><th>step</th><th>val. RMS [µm]</th><th>gap closed (cumulative)</th></tr>{wf}</table>
<h2>Record starts</h2><p>{esc(st.get('message', ''))}</p>
<h2>Step edges</h2><p>{esc(summary_text(v.get('step_edges')))}.</p>
<h2>Where the gap left lies</h2>
<table><tr><th>validation record</th><th>share of the gap left [%]</th><th>RMS [µm]</th>
<th>beyond the training records</th></tr>{left}</table>
<h2>Validation conditions not covered by training</h2><ul>{cov}</ul>
</body></html>
"""
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write(page)
