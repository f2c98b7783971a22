"""A plot of a model against measured records: what ``--plot`` writes.

Three panels per record: measured and model displacement y [µm] against
t [s], their difference (the error [µm]) and the loop y against u [V]. The
samples left out of the score (the burn-in of a record that does not start at
rest) are shaded. Drawn with matplotlib's Agg backend, so no display is needed.
"""
from __future__ import annotations

from .io import atomic_open

__all__ = ["fit_plot"]


def fit_plot(model, records, path, *, title="", burn_in=None, history=None, history_burn_in=0) -> str:
    """Write the fit plot of `model` on `records` as a PNG.

    Parameters
    ----------
    model : hysteresis model
        Anything with ``simulate(u, dt)``.
    records : list of fonbw.io.Record
        With u [V] and y [µm].
    path : str or PathLike
        Where to write the PNG (atomically).
    title : str
    burn_in : list of int, optional
        Samples at the start of each record left out of the score; with a
        non-zero burn-in the model output is shifted by the mean error after
        it (the sensor offset of a record that does not start at rest).
    history : fonbw.io.Record, optional
        The record before the (single) record: simulated first, not drawn.
    history_burn_in : int
        Burn-in of the history (:func:`fonbw.objective.score`).

    Returns
    -------
    str
        `path`.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .objective import stage_rest

    burn_in = burn_in or [0] * len(records)
    rest = stage_rest(model, [r.u for r in records] + ([history.u] if history is not None else []))
    fig, axes = plt.subplots(len(records), 3, figsize=(14, 3.6 * len(records)), squeeze=False,
                             gridspec_kw={"width_ratios": [2.2, 2.2, 1.4]})
    for row, rec, b in zip(axes, records, burn_in):
        _panels(row, model, rec, b, history, history_burn_in, rest)
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=100)
    plt.close(fig)
    return str(path)


def _panels(row, model, rec, b, history, hb, rest):
    """Time trace, error and loop of one record on three axes."""
    from .objective import score

    met = score(model, rec, b, history, hb, rest=rest)
    yhat, rms = met["yhat"], met["rms"]
    t = rec.t - rec.t[0]
    e = yhat - rec.y
    ax, ax_e, ax_l = row
    ax.plot(t, rec.y, lw=0.8, label="measured")
    ax.plot(t, yhat, lw=0.8, label="model")
    ax.set(xlabel="t [s]", ylabel="y [µm]", title=str(rec.path))
    ax.legend(loc="best", fontsize=8)
    ax_e.plot(t, e, lw=0.6, color="C3")
    ax_e.set(xlabel="t [s]", ylabel="model − measured [µm]", title=f"error: RMS {rms:.4g} µm after burn-in")
    ax_l.plot(rec.u[b:], rec.y[b:], lw=0.6, label="measured")
    ax_l.plot(rec.u[b:], yhat[b:], lw=0.6, label="model")
    ax_l.set(xlabel="u [V]", ylabel="y [µm]", title="loop")
    if b:
        for a in (ax, ax_e):
            a.axvspan(t[0], t[b], color="0.85", label="burn-in (not scored)")
