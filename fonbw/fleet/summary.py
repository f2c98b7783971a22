"""The fleet's summary: ``fleet.csv`` and ``fleet.html`` with parameter spread and outliers.

An actuator is an outlier in a quantity (a model parameter or the training
RMS) when its robust z-score, 0.6745 (x − median) / MAD over the fleet's
identified actuators, exceeds 3.5 in magnitude (Iglewicz & Hoaglin). A
parameter that is positive on every actuator and spans more than a decade is
compared in log10, since the search explores it on a log scale and its spread
is multiplicative. Both files are rewritten only when their content changes,
so a re-run that identifies nothing touches no file.
"""
from __future__ import annotations

import io
import os
import tempfile

import numpy as np

__all__ = ["flat_params", "robust_z", "outliers", "summary_rows", "csv_text", "write_if_changed",
           "write_summary", "Z_LIMIT"]

#: |robust z| above which a quantity is flagged.
Z_LIMIT = 3.5


def flat_params(params: dict) -> dict:
    """Model parameters with list-valued ones spread out (``ku`` → ``ku1, ku2, …``)."""
    out = {}
    for k, v in params.items():
        if isinstance(v, (list, tuple)):
            out.update({f"{k}{i}": float(x) for i, x in enumerate(v, 1)})
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[k] = float(v)
    return out


def robust_z(x) -> np.ndarray:
    """Robust z-scores 0.6745 (x − median) / MAD of a 1-D array.

    With MAD = 0 (over half the values equal) the mean absolute deviation
    scaled by 1.2533 stands in; with that also 0 every score is 0.
    """
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return x
    med = np.median(x)
    mad = np.median(np.abs(x - med))
    if mad > 0:
        return 0.6745 * (x - med) / mad
    mean_ad = np.mean(np.abs(x - med))
    return (x - med) / (1.2533 * mean_ad) if mean_ad > 0 else np.zeros_like(x)


def _scaled(v: np.ndarray) -> tuple[np.ndarray, bool]:
    """`v` in log10 when positive everywhere and spanning more than a decade."""
    if v.size and np.all(v > 0) and v.max() / v.min() > 10:
        return np.log10(v), True
    return v, False


def outliers(rows) -> dict:
    """``{actuator: {quantity: z}}`` for every |robust z| > :data:`Z_LIMIT`.

    Quantities: each parameter (log10 where :func:`_scaled` says so) and
    ``training_rms_um``, over the rows with status ``ok``.
    """
    ok = [r for r in rows if r["status"] == "ok"]
    if len(ok) < 3:  # a median and MAD of fewer say nothing about spread
        return {}
    names = [k for k in ok[0]["params"] if all(k in r["params"] for r in ok)]
    flags = {}
    for q in names + ["training_rms_um"]:
        v = np.array([r["params"][q] if q in r["params"] else r["rms"] for r in ok])
        z = robust_z(_scaled(v)[0])
        for r, zi in zip(ok, z):
            if abs(zi) > Z_LIMIT:
                flags.setdefault(r["actuator"], {})[q] = float(zi)
    return flags


def summary_rows(results) -> list:
    """One row per actuator from ``{actuator: document or failure text}`` (sorted by name)."""
    rows = []
    for name in sorted(results):
        d = results[name]
        if isinstance(d, dict):
            fit = d["fit"]
            rows.append({"actuator": name, "kind": d["kind"], "params": flat_params(d["params"]),
                         "rms": float(fit["training_rms_um"]), "records": len(fit["records"]),
                         "status": "ok", "warnings": list(fit.get("warnings", []))})
        else:
            rows.append({"actuator": name, "kind": "", "params": {}, "rms": float("nan"), "records": 0,
                         "status": f"failed: {d}", "warnings": []})
    return rows


def _param_names(rows) -> list:
    names = []
    for r in rows:
        names += [k for k in r["params"] if k not in names]
    return names


def csv_text(rows, flags) -> str:
    """``fleet.csv``: actuator, kind, each parameter, training RMS [µm], records, status, outliers."""
    import csv

    names = _param_names(rows)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["actuator", "kind", *names, "training_rms_um", "records", "status", "outliers"])
    for r in rows:
        vals = [repr(r["params"][k]) if k in r["params"] else "" for k in names]
        rms = repr(r["rms"]) if r["status"] == "ok" else ""
        out = " ".join(f"{q}(z={z:+.1f})" for q, z in sorted(flags.get(r["actuator"], {}).items()))
        w.writerow([r["actuator"], r["kind"], *vals, rms, r["records"], r["status"], out])
    return buf.getvalue()


def write_if_changed(path, data: bytes) -> bool:
    """Write `data` to `path` atomically unless the file already holds exactly it.

    Returns
    -------
    bool
        True when the file was written.
    """
    from ..io import atomic_open

    try:
        with open(path, "rb") as fh:
            if fh.read() == data:
                return False
    except OSError:
        pass
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return True


def _spread_png(rows, flags, path) -> None:
    """Box and strip plot of every parameter and the RMS over the fleet, outliers in red."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r["status"] == "ok"]
    qs = [k for k in _param_names(ok) if all(k in r["params"] for r in ok)] + ["training_rms_um"]
    ncol = min(5, len(qs))
    nrow = -(-len(qs) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(2.2 * ncol, 3.0 * nrow), squeeze=False)
    jitter = np.random.default_rng(0).uniform(-0.12, 0.12, len(ok))  # fixed: the same figure every run
    for ax, q in zip(axes.flat, qs):
        v = np.array([r["params"][q] if q != "training_rms_um" else r["rms"] for r in ok])
        s, log = _scaled(v)
        ax.boxplot(s, widths=0.5, showfliers=False)
        red = np.array([q in flags.get(r["actuator"], {}) for r in ok], dtype=bool)
        ax.scatter(1 + jitter[~red], s[~red], s=12, color="tab:blue", alpha=0.7)
        ax.scatter(1 + jitter[red], s[red], s=18, color="tab:red")
        ax.set_title(("log10 " if log else "") + (q if q != "training_rms_um" else "RMS [µm]"), fontsize=9)
        ax.set_xticks([])
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(qs):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=90, metadata={"Software": None})
    plt.close(fig)


def _sections(rows, flags, options):
    from ..report import Section, md_table

    ok = [r for r in rows if r["status"] == "ok"]
    names = _param_names(ok)
    table = md_table(["actuator", "status", "RMS [µm]", "records", *names],
                     [[r["actuator"], r["status"], r["rms"] if r["status"] == "ok" else "",
                       r["records"], *[r["params"].get(k, "") for k in names]] for r in rows])
    rms = np.array([r["rms"] for r in ok])
    zr = dict(zip([r["actuator"] for r in ok], robust_z(rms) if len(ok) >= 3 else np.zeros(len(ok))))
    quality = md_table(["actuator", "RMS [µm]", "robust z", "notes of the search"],
                       [[r["actuator"], r["rms"], float(zr[r["actuator"]]), "; ".join(r["warnings"]) or "-"]
                        for r in ok])
    flagged = [f"- **{a}**: " + ", ".join(f"{q} (z = {z:+.2f})" for q, z in sorted(f.items()))
               for a, f in sorted(flags.items())]
    opts = ", ".join(f"{k}={v}" for k, v in options.items() if v is not None)
    return [
        Section("Actuators", f"{len(ok)} of {len(rows)} actuators identified; options: {opts}.", table),
        Section("Parameter spread", "Each parameter and the training RMS over the fleet (box: quartiles, "
                "whiskers: 1.5 IQR; points: actuators, red: outliers; log10 where a positive parameter "
                "spans more than a decade).", ""),
        Section("Fit quality", "Training RMS per actuator, its robust z-score against the fleet, and what "
                "the search reported (parameters at a bound or poorly determined).", quality),
        Section("Outliers", f"Actuators with a parameter or RMS whose robust z-score exceeds {Z_LIMIT} "
                "(median/MAD of the fleet).", "\n".join(flagged) if flagged else "None."),
    ]


def write_summary(out_dir, results, options) -> list:
    """Write ``fleet.csv`` and ``fleet.html`` in `out_dir` (each only if it changed).

    Parameters
    ----------
    out_dir : path-like
    results : dict
        ``{actuator: model document}`` or ``{actuator: failure text}``.
    options : dict
        The fit options, shown in the report.

    Returns
    -------
    list of str
        Paths actually written.
    """
    from ..report import write_html

    rows = summary_rows(results)
    flags = outliers(rows)
    written = []
    csv_path = os.path.join(out_dir, "fleet.csv")
    if write_if_changed(csv_path, csv_text(rows, flags).encode("utf-8")):
        written.append(csv_path)
    secs = _sections(rows, flags, options)
    with tempfile.TemporaryDirectory() as tmp:
        if any(r["status"] == "ok" for r in rows):
            png = os.path.join(tmp, "spread.png")
            _spread_png(rows, flags, png)
            secs[1].figures.append((png, "Parameter spread over the fleet"))
        html_tmp = os.path.join(tmp, "fleet.html")
        write_html(html_tmp, f"Fleet of {len(rows)} actuators", secs)
        with open(html_tmp, "rb") as fh:
            data = fh.read()
    html_path = os.path.join(out_dir, "fleet.html")
    if write_if_changed(html_path, data):
        written.append(html_path)
    return written
