"""Where a compensation starts: the actuator's rest after a previous cycle.

A stage is zeroed at rest, after it has been driven: its state is then the
end of a descending branch, and the displacement at the bottom of every later
cycle comes back close to that zero. A Bouc-Wen-type model simulated "from
rest" starts instead from its virgin state (ħ = 0, no fractional memory):
after one cycle its descending branch does not return to the virgin level at
the lowest voltage (an identified FONBW of the virtual bench sits 0.69 µm
above it at 0 V), so a trajectory that comes back to 0 µm is out of reach
within the training voltage range, and the fit pays the same offset at every
low-voltage sample of its training records.

The remedy is one convention, used for identification and for compensation
alike: the model runs through a *rest cycle* (a slow raised-cosine sweep from
the rest voltage to the top of its range and back) before t = 0, and its
output is counted from the end of that cycle, as the stage's sensor is
zeroed there. :func:`with_rest_cycle` prepends the cycle to training records
(as a burn-in that is not scored, with a fitted zero per record);
:func:`start_history` gives the voltage the compensators run first for a
model that records the convention in ``meta["start"]``.

Units: u [V], dt and T [s].
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["REST_CYCLE_T", "rest_cycle", "start_history", "with_rest_cycle", "history_input",
           "rest_start_meta", "started_stepper", "StartedStepper", "REST_PARAMETERS", "rest_values",
           "start_from_values", "run_start", "REST_MAX_STEPS"]

#: Duration of the rest cycle [s]: slow enough to be quasi-static for the
#: rate-dependent models, short against the training records.
REST_CYCLE_T = 1.0


def rest_cycle(u_range, dt, T=REST_CYCLE_T) -> np.ndarray:
    """One raised-cosine cycle rest → top → rest [V], sampled at dt [s].

    The rest voltage is the point of ``u_range`` = (lo, hi) nearest to 0 V
    (0 V for a unipolar or a bipolar stage), the top is ``hi``; the last
    sample is the rest voltage, so the cycle ends on a descending branch.
    """
    lo, hi = (float(v) for v in u_range)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"u_range must be (lo, hi) with lo < hi [V], got {u_range!r}")
    dt, T = float(dt), float(T)
    if not (dt > 0.0 and T > 0.0):
        raise ValueError(f"dt and T must be positive [s], got dt={dt!r}, T={T!r}")
    if T / dt > REST_MAX_STEPS:
        # as the native FMU refuses it at initialization: a cycle, not a hang
        raise ValueError(f"a rest cycle of T = {T:g} s at dt = {dt:g} s is {T / dt:.3g} steps, more than "
                         f"the {REST_MAX_STEPS:.0e} a start may run")
    L = max(int(round(T / dt)), 8)
    u0 = min(max(0.0, lo), hi)
    return u0 + (hi - u0) * 0.5 * (1.0 - np.cos(2.0 * np.pi * np.arange(1, L + 1) / L))


#: The start as the FMUs' parameters (name, unit, description), values from :func:`rest_values`.
REST_PARAMETERS = (
    ("rest_lo", "V", "Rest cycle before t = 0: lower end of its range; the cycle runs from the point "
                     "of [rest_lo, rest_hi] nearest 0 V up to rest_hi and back"),
    ("rest_hi", "V", "Rest cycle before t = 0: upper end of its range (the top of the cycle)"),
    ("rest_T", "s", "Rest cycle before t = 0: its duration; outputs count from its end (the sensor "
                    "zeroed there). 0: start from rest, no cycle"),
)


def rest_values(model) -> tuple:
    """(rest_lo [V], rest_hi [V], rest_T [s]) of the start a model records
    (a model or its JSON dict); (0, 0, 0) for a start from rest."""
    meta = model if isinstance(model, dict) else (getattr(model, "meta", None) or {})
    st = meta.get("start") or {}
    if "rest_cycle" not in st:
        return (0.0, 0.0, 0.0)
    lo, hi = (float(v) for v in st["rest_cycle"])
    return (lo, hi, float(st.get("T", REST_CYCLE_T)))


def start_from_values(lo, hi, T):
    """The ``meta["start"]`` entry for :data:`REST_PARAMETERS` values (None for T = 0)."""
    return rest_start_meta((lo, hi), T) if T > 0 else None


def rest_start_meta(u_range, T=REST_CYCLE_T) -> dict:
    """The ``meta["start"]`` entry of a model identified after a rest cycle."""
    return {"rest_cycle": [float(u_range[0]), float(u_range[1])], "T": float(T)}


def start_history(model, dt) -> np.ndarray:
    """Voltage [V] a compensator runs before t = 0 for ``model``: its rest
    cycle when it was identified after one (``meta["start"]``), else none."""
    meta = getattr(model, "meta", None) or {}
    st = meta.get("start") or {}
    if "rest_cycle" not in st:
        return np.zeros(0)
    return rest_cycle(st["rest_cycle"], dt, st.get("T", REST_CYCLE_T))


#: Longest rest cycle a stepper or FMU runs at its start [steps] (a cycle, not a hang).
REST_MAX_STEPS = 1e8


def run_start(stepper, history) -> float:
    """Step `stepper` through the voltages `history` [V]; its output [µm] at
    the end (0 for none), the zero a started model counts from."""
    y0 = 0.0
    for u in history:
        y0 = stepper.step(u)
    return float(y0)


class StartedStepper:
    """A model's stepper that has run the model's recorded start.

    Same interface as :class:`fonbw.hysteresis.Stepper`; the outputs are
    counted from the model's output at the end of the start (a sensor zeroed
    there), and :meth:`reset` runs the start again. The hysteresis blocks of
    the closed loop and the hysteresis FMUs use it, so that a model and its
    compensator share one zero.
    """

    def __init__(self, stepper, history):
        self._st = stepper
        self.history = np.ascontiguousarray(history, dtype=float)
        self.reset()

    def reset(self) -> None:
        self._st.reset()
        self.zero = run_start(self._st, self.history)
        self._steps = 0

    def step(self, u: float) -> float:
        self._steps += 1
        return self._st.step(u) - self.zero

    def peek(self, u: float) -> float:
        return self._st.peek(u) - self.zero

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def state_variable(self) -> float:
        return self._st.state_variable

    def get_state(self) -> np.ndarray:
        return np.concatenate([[float(self._steps), self.zero], self._st.get_state()])

    def set_state(self, state) -> None:
        s = np.asarray(state, dtype=float)
        if s.ndim != 1 or len(s) < 3:
            raise ValueError("state must be a 1-D array from get_state()")
        self._st.set_state(s[2:])
        self._steps, self.zero = int(s[0]), float(s[1])


def started_stepper(model, dt):
    """``model``'s stepper at dt [s], started as the model records
    (:func:`start_history`): a :class:`StartedStepper` after a rest cycle,
    else the plain stepper (from rest)."""
    st = model.stepper(dt)
    pre = start_history(model, st.dt)
    return StartedStepper(st, pre) if pre.size else st


def history_input(model, dt, history):
    """The history a compensation runs first, as a float array [V].

    ``history=None``: the model's own start (:func:`start_history`); an
    array: that voltage; an empty sequence: from rest.
    """
    if history is None:
        return start_history(model, dt)
    h = np.ascontiguousarray(history, dtype=float)
    if h.ndim != 1 or not np.all(np.isfinite(h)):
        raise ValueError("history must be a 1-D array of finite voltages [V]")
    return h


def with_rest_cycle(records, u_range=None, T=REST_CYCLE_T):
    """Training records with a rest cycle in front, and their burn-ins.

    Parameters
    ----------
    records : list of Record
        Records that start at rest (the stage zeroed after a previous cycle).
    u_range : (float, float), optional
        Range of the cycle [V]; default the records' input range.
    T : float
        Duration of the cycle [s].

    Returns
    -------
    (list of Record, list of int)
        For :func:`fonbw.identify` with ``burn_in=``: the cycle's samples are
        not scored and each record gets its own zero (the fitted offset).
    """
    from ..io import Record, input_range

    if u_range is None:
        u_range = input_range(records)
    out, burn = [], []
    for r in records:
        pre = rest_cycle(u_range, r.dt, T)
        u = np.concatenate([pre, r.u])
        y = np.concatenate([np.full(pre.size, float(r.y[0])), r.y])
        out.append(Record(t=np.arange(u.size) * r.dt, u=u, y=y, dt=r.dt,
                          path=getattr(r, "path", "<memory>")))
        burn.append(pre.size)
    return out, burn
