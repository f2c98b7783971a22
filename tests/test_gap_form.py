"""Hysteresis form in the gap diagnosis, the reference core, and record starts."""
import numpy as np
import pytest

from fonbw.io import Record
from fonbw.start import StartState, start_state


def _rec(u, y=None, dt=2e-4):
    u = np.asarray(u, float)
    return Record.from_arrays(u=u, y=u.copy() if y is None else y, dt=dt)


def test_start_at_rest_held_input():
    u = np.r_[np.zeros(20), np.sin(np.linspace(0, 6 * np.pi, 500))]
    s = start_state(_rec(u))
    assert isinstance(s, StartState) and s.at_rest and s.burn_in == 0


def test_start_mid_drive_burn_in_hand_computed():
    # u = sin(phase) from phase 0: the maximum 1 is approached first, the
    # minimum -1 later; "close" is within 5 % of the 2 V range (0.1 V).
    n = 2000
    ph = np.linspace(0, 8 * np.pi, n)
    u = np.sin(ph)
    s = start_state(_rec(u))
    first_low = int(np.flatnonzero(u <= -1 + 0.1)[0])
    assert not s.at_rest and s.burn_in == first_low + 1
    # by hand: sin(ph) <= -0.9 first at ph = pi + asin(0.9)
    assert abs(ph[s.burn_in - 1] - (np.pi + np.arcsin(0.9))) < 8 * np.pi / n * 1.5


def test_start_burn_in_capped():
    # a ramp reaches its maximum only at the end: burn-in capped at 40 %
    u = np.linspace(0, 1, 1000)
    s = start_state(_rec(u))
    assert not s.at_rest and s.burn_in == 400 and "capped" in s.reason


def test_start_held_input_but_moving_output_is_not_at_rest():
    u = np.r_[np.zeros(20), np.sin(np.linspace(0, 6 * np.pi, 500))]
    y = u.copy()
    y[:20] = np.linspace(0.5, 0.0, 20)      # output still relaxing: not at rest
    s = start_state(_rec(u, y))
    assert not s.at_rest and s.burn_in > 20
    assert s.to_dict()["burn_in"] == s.burn_in
