"""Localize the residual of a model: where, when and under which conditions it is large.

The residual r = y − ŷ of the nominal model on each validation record is
split against

* frequency — Welch power spectral density against the estimated noise floor;
* time — RMS in consecutive windows;
* input rate |du/dt|, amplitude u, loop branch (ascending, descending, hold)
  and the time since the last reversal of the input — RMS per bin.

For every binned feature the *correlation ratio* η² (the share of the
residual's variance that the bin means explain) says how strongly the
residual is organised by that feature. The noise floor σ² is the level of the
residual spectrum in the upper part of the band, where a model of a
piezo stage driven by the paper's inputs has no error left but white
sensor noise (its median is robust to the few bins a step edge leaves there).
:func:`where` places a correction of one model by another (the hysteresis
form's) on the loop by the same features.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import welch

__all__ = ["noise_floor", "localize", "tones", "reversal_age", "branch", "where", "TONE_SHARE", "TONE_PREDICTED"]


def _psd(r, dt, nperseg=256):
    nper = int(min(nperseg, max(16, len(r) // 4)))
    f, p = welch(r, fs=1.0 / dt, nperseg=nper, detrend="constant")
    return f, p


def noise_floor(residuals, dt, band=(0.3, 0.48), nperseg=256):
    """White-noise variance σ² [µm²] from the residual spectrum's upper band.

    Parameters
    ----------
    residuals : sequence of 1-D arrays
        Residuals [µm] of one or more records.
    dt : float
        Sampling period [s].
    band : (lo, hi)
        The band as fractions of the sampling frequency.

    Returns
    -------
    float
        σ² = (median over time segments of the band-averaged one-sided PSD)
        × fs/2; white noise has a flat one-sided PSD 2σ²/fs. The median over
        segments ignores the few segments where a step edge or a model
        transient leaves broadband error.
    """
    from scipy.signal import spectrogram

    fs = 1.0 / dt
    levels = []
    for r in residuals:
        r = np.asarray(r, dtype=float)
        if r.size < nperseg:
            continue
        f, _, S = spectrogram(r, fs=fs, nperseg=nperseg, noverlap=0, detrend="linear", scaling="density")
        sel = (f >= band[0] * fs) & (f <= band[1] * fs)
        if sel.any():
            levels.append(S[sel].mean(axis=0))
    if not levels:
        raise ValueError(f"noise_floor: records too short (need ≥ {nperseg} samples) for a spectrum")
    return float(np.median(np.concatenate(levels)) * fs / 2.0)


def branch(u, tol=None):
    """+1 ascending, −1 descending, 0 hold, per sample (sign of du, hold below `tol`)."""
    u = np.asarray(u, dtype=float)
    du = np.diff(u, prepend=u[0])
    if tol is None:
        tol = 1e-6 * max(np.ptp(u), 1e-12)
    s = np.where(du > tol, 1, np.where(du < -tol, -1, 0))
    # a hold keeps no branch; a sample between two moves in one direction keeps it
    return s


def reversal_age(u, dt):
    """Time since the last reversal of the input direction [s] (holds do not reset it)."""
    s = branch(u)
    age = np.empty(len(s))
    last_dir = 0
    t_rev = 0.0
    for k, sk in enumerate(s):
        if sk != 0 and sk != last_dir:
            if last_dir != 0:
                t_rev = k * dt
            last_dir = sk
        age[k] = k * dt - t_rev
    return age


def _binned(feature, r, edges):
    idx = np.clip(np.searchsorted(edges, feature, side="right") - 1, 0, len(edges) - 2)
    rows = []
    total = float(np.sum((r - r.mean()) ** 2))
    between = 0.0
    for b in range(len(edges) - 1):
        m = idx == b
        n = int(m.sum())
        if n == 0:
            rows.append({"lo": float(edges[b]), "hi": float(edges[b + 1]), "n": 0, "mean": None, "rms": None})
            continue
        mu = float(r[m].mean())
        between += n * (mu - r.mean()) ** 2
        rows.append({"lo": float(edges[b]), "hi": float(edges[b + 1]), "n": n, "mean": mu,
                     "rms": float(np.sqrt(np.mean(r[m] ** 2)))})
    eta2 = float(between / total) if total > 0 else 0.0
    return {"bins": rows, "eta2": eta2}


def localize(records, predictions, dt, sigma2, n_time_bins=20, n_bins=8):
    """Localization of the residual of `predictions` on `records`.

    Parameters
    ----------
    records : list of Record
        Validation records (u [V], y [µm]).
    predictions : list of ndarray
        Model outputs [µm], one per record.
    dt : float
        Sampling period [s].
    sigma2 : float
        Noise floor σ² [µm²] (:func:`noise_floor`).

    Returns
    -------
    dict
        ``records``: per record its name, gap (RMS residual [µm], as % of the
        output range, and the excess over noise sqrt(max(MSE − σ², 0)) [µm]),
        the residual spectrum against the floor (excess bands where the PSD is
        above 4× the floor), RMS versus time; ``features``: pooled binned
        RMS and η² versus input rate, amplitude, branch and time since
        reversal; ``dominant``: the feature with the largest η².
    """
    fs = 1.0 / dt
    floor_psd = 2.0 * sigma2 / fs
    out = []
    R, RATE, AMP, BR, AGE = [], [], [], [], []
    for rec, yhat in zip(records, predictions):
        r = rec.y - yhat
        out.append(_record_summary(rec, r, dt, sigma2, floor_psd, n_time_bins))
        R.append(r)
        RATE.append(np.abs(np.gradient(rec.u, dt)))
        AMP.append(rec.u)
        BR.append(branch(rec.u))
        AGE.append(reversal_age(rec.u, dt))
    feats = _features(np.concatenate(R), np.concatenate(RATE), np.concatenate(AMP),
                      np.concatenate(BR), np.concatenate(AGE), dt, n_bins)
    dom = max(feats, key=lambda k: feats[k]["eta2"])
    return {"records": out, "features": feats, "dominant": dom, "noise_floor": float(sigma2)}


#: A narrow line in what a model leaves is reported when it holds at least
#: this share of the excess left (Σ n_i max(MSE_i − σ², 0)) ...
TONE_SHARE = 0.1
#: ... and the model's own output carries less than this share of the line's
#: power in the same bins: a misfit of what the model makes (a harmonic of a
#: drive that the hysteresis bends) comes with it, a disturbance added to the
#: output (mains pickup) does not. Bins within two of a drive's fundamental
#: hold the model's own line, so no line is named there.
TONE_PREDICTED = 0.1


def tones(records, predictions, dt, sigma2, resolution=1.0, most=3):
    """Narrow lines in the residual of `predictions` that the model's own output lacks.

    Parameters
    ----------
    records, predictions
        Validation records (scored part) and a model's outputs [µm] on them.
    dt : float
        Sampling period [s].
    sigma2 : float
        Noise floor σ² [µm²], taken off every bin (white noise: 2σ²dt one-sided).
    resolution : float
        Welch bin width [Hz] (records shorter than two bins' windows are left out).
    most : int
        Largest number of lines looked at, strongest first.

    Returns
    -------
    list of dict
        ``hz`` (the line's frequency [Hz]) and ``share`` (of the excess left,
        pooled over the records) of each line that holds at least
        :data:`TONE_SHARE` and whose bins the model's output fills to less
        than :data:`TONE_PREDICTED` of it; strongest first.
    """
    fs = 1.0 / dt
    nper = int(round(fs / resolution))
    total, E, P, f = 0.0, 0.0, 0.0, None
    for rec, yhat in zip(records, predictions):
        r = np.asarray(rec.y, dtype=float) - yhat
        n = r.size
        total += n * max(float(np.mean(r * r)) - sigma2, 0.0)
        if n < 2 * nper:
            continue
        f, pr = welch(r, fs=fs, nperseg=nper, detrend="constant")
        _, pp = welch(np.asarray(yhat, dtype=float), fs=fs, nperseg=nper, detrend="constant")
        df = f[1] - f[0]
        # energies per bin [µm² × samples], comparable with the pooled excess
        E = E + n * np.maximum(pr - 2.0 * sigma2 * dt, 0.0) * df
        P = P + n * pp * df
    if f is None or not total > 0:
        return []
    out, left = [], np.array(E, dtype=float)
    left[0] = 0.0  # the mean is an offset, not a line
    for _ in range(most):
        k = int(np.argmax(left))
        lo, hi = max(1, k - 2), min(left.size, k + 3)   # a Hann window's main lobe
        line = float(np.sum(E[lo:hi]))
        if line < TONE_SHARE * total:
            break
        if float(np.sum(P[lo:hi])) < TONE_PREDICTED * line:
            out.append({"hz": float(f[k]), "share": line / total})
        left[lo:hi] = 0.0
    return out


def _excess_bands(f, p, floor_psd):
    """[lo, hi, peak/floor] of each run of frequency bins whose PSD is above 4× the floor."""
    above = p > 4.0 * floor_psd
    bands = []
    k = 0
    while k < len(f):
        if above[k]:
            j = k
            while j + 1 < len(f) and above[j + 1]:
                j += 1
            bands.append([float(f[k]), float(f[j]), float(np.max(p[k:j + 1]) / floor_psd)])
            k = j + 1
        else:
            k += 1
    return bands


def _record_summary(rec, r, dt, sigma2, floor_psd, n_time_bins):
    """Gap, residual spectrum and RMS versus time of one record's residual `r` [µm]."""
    mse = float(np.mean(r ** 2))
    f, p = _psd(r, dt)
    bands = _excess_bands(f, p, floor_psd)
    # a few hundred points are plenty for the report
    step = max(1, len(f) // 200)
    nb_t = min(n_time_bins, max(1, len(r) // 50))
    chunks = np.array_split(r, nb_t)
    t_rms = [float(np.sqrt(np.mean(c ** 2))) for c in chunks]
    rng = float(np.ptp(rec.y)) or 1.0
    return {
        "name": str(rec.path),
        "n": int(len(r)),
        "rms": float(np.sqrt(mse)),
        "rms_pct_range": float(100.0 * np.sqrt(mse) / rng),
        "excess_rms": float(np.sqrt(max(mse - sigma2, 0.0))),
        "spectrum": {"f": f[::step].tolist(), "psd": p[::step].tolist(), "floor": floor_psd,
                     "excess_bands": bands[:20]},
        "time": {"t": [float((i + 0.5) * len(r) * dt / nb_t) for i in range(nb_t)], "rms": t_rms},
    }


def _features(r, rate, amp, br, age, dt, n_bins):
    """Pooled binned residual and η² versus input rate [V/s], amplitude [V],
    branch and time since reversal [s]."""
    qs = np.linspace(0, 1, n_bins + 1)
    feats = {}
    e = np.unique(np.quantile(rate, qs))
    feats["input_rate"] = _binned(rate, r, e if len(e) > 2 else np.array([rate.min(), rate.max() + 1e-12]))
    feats["input_rate"]["unit"] = "V/s"
    e = np.linspace(amp.min(), amp.max() + 1e-9, n_bins + 1)
    feats["amplitude"] = _binned(amp, r, e)
    feats["amplitude"]["unit"] = "V"
    feats["branch"] = _binned(br.astype(float), r, np.array([-1.5, -0.5, 0.5, 1.5]))
    feats["branch"]["labels"] = ["descending", "hold", "ascending"]
    amax = max(float(age.max()), 10 * dt)
    e = np.concatenate([[0.0], np.geomspace(dt, amax, n_bins)])
    e[-1] = amax + 1e-12
    feats["time_since_reversal"] = _binned(age, r, e)
    feats["time_since_reversal"]["unit"] = "s"
    return feats


def where(records, p0, p1, dt, n_bins=8):
    """Where on the loop the form's correction δ = p1 − p0 [µm] concentrates.

    Returns ``dominant`` (the localization feature with the largest η² of δ:
    input_rate, amplitude, branch, time_since_reversal), ``eta2`` per
    feature, the shares of Σδ² in the ``top`` and ``bottom`` fifth of the
    input range, in ``minor_loops`` (branches spanning under half the range)
    and ``rms_um`` (RMS of δ).
    """
    delta = np.concatenate([b - a for a, b in zip(p0, p1)])
    u = np.concatenate([r.u for r in records])
    rate = np.concatenate([np.abs(np.gradient(r.u, dt)) for r in records])
    br = np.concatenate([branch(r.u) for r in records])
    age = np.concatenate([reversal_age(r.u, dt) for r in records])
    feats = _features(delta, rate, u, br, age, dt, n_bins)
    eta = {k: float(v["eta2"]) for k, v in feats.items()}
    e2 = delta * delta
    tot = float(e2.sum()) or 1.0
    lo, hi = float(u.min()), float(u.max())
    span = hi - lo or 1.0
    minor = np.concatenate([_minor(r.u, span) for r in records])
    return {"dominant": max(eta, key=eta.get), "eta2": eta,
            "top": float(e2[u >= hi - 0.2 * span].sum() / tot),
            "bottom": float(e2[u <= lo + 0.2 * span].sum() / tot),
            "minor_loops": float(e2[minor].sum() / tot), "rms_um": float(np.sqrt(np.mean(e2)))}


def _minor(u, span):
    """Samples on branches that span less than half the input range `span` [V]."""
    br = branch(u)
    moving = np.flatnonzero(br != 0)
    out = np.zeros(len(u), dtype=bool)
    if moving.size == 0:
        return out
    # branch boundaries: where the moving direction changes
    s = br[moving]
    cuts = moving[np.flatnonzero(np.diff(s) != 0) + 1]
    edges = np.r_[0, cuts, len(u)]
    for a, b in zip(edges[:-1], edges[1:]):
        out[a:b] = np.ptp(u[a:b]) < 0.5 * span
    return out
