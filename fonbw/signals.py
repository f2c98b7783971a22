"""Input signals and desired trajectories, each defined once.

Inputs u(t) [V] of the bench's experiments (the paper's eq. (19), sines,
multi-tone, steps with holds, a bipolar drive) return ``(t [s], u [V])``;
trajectories H_d(t) [µm] of the compensation and closed-loop scenarios take
times [s] and return displacements [µm].
"""
from __future__ import annotations

import math

import numpy as np

from .paper import FS, U_RANGE

__all__ = ["eq19_input", "sine_input", "multi_input", "step_hold_input", "bipolar_input",
           "trajectory_5hz", "trajectory_multi", "TRAJECTORIES", "SCENARIOS", "trajectory", "EQ19_T"]

#: Default duration of the eq. (19) record [s]; its envelope 120 e^(-0.13 t) V
#: has fallen to 8.9 V (7 %) by then.
EQ19_T = 20.0


def _n_samples(T, fs):
    if not (math.isfinite(T) and T > 0):
        raise ValueError(f"duration must be positive [s], got {T!r}")
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be positive [Hz], got {fs!r}")
    return int(round(T * fs))


def eq19_input(fs: float = FS, T: float = EQ19_T):
    """Identification input of eq. (19), u = 60 e^(-0.13t) [cos(3πt e^(-0.09t) - 3.15) + 1] V.

    It starts at 0.003 V, peaks near 120 V at 1.5 Hz and decays; the
    instantaneous frequency falls to zero at t = 1/0.09 = 11.1 s, after which
    the phase runs backwards. The default 20 s keeps the part whose envelope
    is above 7 % of the start (8.9 V).
    """
    n = _n_samples(T, fs)
    t = np.arange(n) / fs
    return t, 60.0 * np.exp(-0.13 * t) * (np.cos(3 * np.pi * t * np.exp(-0.09 * t) - 3.15) + 1.0)


def sine_input(f: float, fs: float = FS, periods: float | None = 5, T: float | None = None,
               amplitude: float = 60.0, offset: float = 60.0):
    """Validation input u = offset - amplitude cos(2πft) V (paper: 60 - 60 cos).

    Give either `periods` (default 5) or the duration `T` [s].
    """
    if not (math.isfinite(f) and f > 0):
        raise ValueError(f"f must be a positive frequency [Hz], got {f!r}")
    if T is None:
        if periods is None or not periods > 0:
            raise ValueError("give a positive number of periods or a duration T")
        T = periods / f
    n = _n_samples(T, fs)
    t = np.arange(n) / fs
    return t, offset - amplitude * np.cos(2 * np.pi * f * t)


def multi_input(freqs=(1.0, 5.0, 10.0, 20.0), fs: float = FS, T: float = 5.0,
                weights=None, u_max: float = U_RANGE[1]):
    """Multi-tone input u = u_max/2 (1 - Σ a_i cos(2π f_i t) / Σ a_i), within [0, u_max] V.

    Starts at 0 V (all cosines at 1); default weights a_i = 1 / i so the low
    frequencies carry the stroke.
    """
    freqs = np.asarray(freqs, dtype=float)
    if freqs.ndim != 1 or freqs.size == 0 or np.any(freqs <= 0):
        raise ValueError("freqs must be positive frequencies [Hz]")
    a = 1.0 / np.arange(1, freqs.size + 1) if weights is None else np.asarray(weights, dtype=float)
    if a.shape != freqs.shape or np.any(a < 0) or a.sum() <= 0:
        raise ValueError("weights must be non-negative, one per frequency, not all zero")
    n = _n_samples(T, fs)
    t = np.arange(n) / fs
    s = (a[:, None] * np.cos(2 * np.pi * freqs[:, None] * t[None, :])).sum(axis=0) / a.sum()
    return t, 0.5 * u_max * (1.0 - s)


def step_hold_input(levels=(60.0,), hold: float = 10.0, fs: float = FS, rest: float = 0.1):
    """Steps to each level in turn, held `hold` s, after `rest` s at 0 V (creep tests)."""
    levels = np.atleast_1d(np.asarray(levels, dtype=float))
    n0 = int(round(rest * fs))
    nh = _n_samples(hold, fs)
    u = np.concatenate([np.zeros(n0)] + [np.full(nh, L) for L in levels])
    return np.arange(u.size) / fs, u


def bipolar_input(fs: float = FS, T: float = 6.0, f: float = 1.0, amplitude: float = 150.0):
    """Bipolar drive u = amplitude sin(2πft) [V] (±150 V by default), starting at 0 V."""
    n = _n_samples(T, fs)
    t = np.arange(n) / fs
    return t, amplitude * np.sin(2 * np.pi * f * t)


def trajectory_5hz(t):
    """Single-frequency trajectory of Sec. IV-D: H_d = 5 − 5 cos(10πt) µm."""
    t = np.asarray(t, dtype=float)
    return 5.0 - 5.0 * np.cos(10.0 * np.pi * t)


def trajectory_multi(t):
    """Multi-frequency trajectory of Sec. IV-D:
    H_d = 4 − cos 2πt − cos 6πt − cos 10πt − cos 20πt µm."""
    t = np.asarray(t, dtype=float)
    return (4.0 - np.cos(2 * np.pi * t) - np.cos(6 * np.pi * t) - np.cos(10 * np.pi * t)
            - np.cos(20 * np.pi * t))


#: The two desired trajectories of Table 4, by the paper's names.
TRAJECTORIES = {"5-Hz": trajectory_5hz, "Multi-freq.": trajectory_multi}


def _sine(f):
    return lambda t: 5.0 - 5.0 * np.cos(2 * np.pi * f * t)


def _step(t):
    return np.where(t >= 0.01, 10.0, 0.0)


#: Closed-loop scenarios: name -> (H_d(t) [µm], default duration [s], description).
SCENARIOS = {
    "sine1": (_sine(1.0), 2.0, "H_d = 5 - 5 cos(2π t) µm"),
    "sine5": (trajectory_5hz, 1.0, "H_d = 5 - 5 cos(10π t) µm (paper, Table 4)"),
    "sine10": (_sine(10.0), 1.0, "H_d = 5 - 5 cos(20π t) µm"),
    "sine20": (_sine(20.0), 0.5, "H_d = 5 - 5 cos(40π t) µm"),
    "multi": (trajectory_multi, 2.0, "H_d = 4 - cos 2πt - cos 6πt - cos 10πt - cos 20πt µm (paper, Table 4)"),
    "step": (_step, 0.5, "H_d = 10 µm from t = 0.01 s"),
}


def trajectory(scenario, t) -> np.ndarray:
    """Desired displacement H_d [µm] of a scenario at times `t` [s] (H_d(0) for t < 0)."""
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; choose one of {', '.join(SCENARIOS)}")
    t = np.maximum(np.asarray(t, dtype=float), 0.0)
    return np.asarray(SCENARIOS[scenario][0](t), dtype=float) + 0.0 * t
