"""How the blocks of the loop are connected and sampled: stepping order, the
source of every input, the exogenous input sequences with their preview, the
communication steps, and the trace a run records.

Units: u [V], y, r [µm], t [s].
"""
from __future__ import annotations

import math

import numpy as np

from ..signals import trajectory
from .spec import MODES

__all__ = ["Wiring", "IO", "steps", "whole_multiple"]

#: block -> (input names, output name); the names are the FMUs' variables.
IO = {"comp": (("y_ref",), "u"), "ctrl": (("r", "y", "u_ff"), "u"),
      "hyst": (("u",), "y"), "plant": (("h",), "x")}


def steps(T, dt):
    """Communication steps for a run of `T` [s] at step `dt` [s]: n_full
    steps of dt, plus the length [s] of a final shorter one if T is not a
    whole multiple of dt (0.0 if it is; the blocks then refuse it)."""
    n = int(math.floor(T / dt + 1e-9))
    rest = T - n * dt
    return n, (rest if rest > 1e-9 * dt else 0.0)


def whole_multiple(h, dt):
    """(is the step `h` [s] a whole multiple of `dt` [s], that multiple)."""
    m = h / dt
    k = round(m)
    return k >= 1 and abs(m - k) <= 1e-6, int(k)


def _chain(mode, has_plant, hysteresis):
    """The blocks in stepping order (each one feeds the next)."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    act = "hyst" if hysteresis else None
    blocks = {"open": [], "ff": ["comp"], "fb": ["ctrl"], "ff+fb": ["comp", "ctrl"]}[mode]
    blocks = blocks + ([act] if act else []) + (["plant"] if has_plant else [])
    if mode == "open" and not act:
        raise ValueError("mode 'open' needs the hysteresis block")
    if mode in ("ff", "ff+fb") and not act:
        raise ValueError(f"mode {mode!r} needs the hysteresis block (the compensator inverts it)")
    if not blocks or blocks[-1] in ("comp", "ctrl"):
        raise ValueError("the loop needs an actuator or a plant block")
    return blocks


class Wiring:
    """Blocks in stepping order, where each input comes from, the exogenous
    input sequences, and the measured output (see :mod:`fonbw.loop`).

    Parameters
    ----------
    mode : str
        One of :data:`MODES`.
    scenario : str
        Trajectory name (:data:`fonbw.signals.SCENARIOS`).
    n : int
        Samples of every input sequence (one per communication step).
    dt : float
        Communication step [s].
    has_plant, hysteresis : bool
        Whether the plant block and the actuator block are in the loop.
    k_lin : float
        Mean actuator gain [µm/V]; the open loop applies r / k_lin.

    Attributes
    ----------
    blocks : list of str
        Roles in stepping order (``comp``, ``ctrl``, ``hyst``, ``plant``).
    measured, actuator, drive : str
        The block whose output is y; the block the voltage goes to; the
        block (or ``"u_open"``) that drives it.
    src : dict
        (block, input) -> ("out", block) | ("ext", sequence key).
    preview : dict
        block -> connections between it and the measured output.
    t, r : ndarray
        Sample times [s] and the reference [µm].
    ext : dict
        Exogenous input sequences, aligned with the steps.
    """

    def __init__(self, mode, scenario, n, dt, has_plant, hysteresis, k_lin):
        blocks = _chain(mode, has_plant, hysteresis)
        act = "hyst" if hysteresis else None
        self.blocks = blocks
        self.measured = blocks[-1]
        # who drives the actuator (or the plant when there is no actuator)
        drive = "ctrl" if mode in ("fb", "ff+fb") else ("comp" if mode == "ff" else None)
        target = act or "plant"
        self.src = {(target, IO[target][0][0]): ("ext", "u_open") if drive is None else ("out", drive)}
        if act and has_plant:
            self.src[("plant", "h")] = ("out", act)
        if "ctrl" in blocks:
            self.src[("ctrl", "r")] = ("ext", "r_ctrl")
            self.src[("ctrl", "y")] = ("out", self.measured)
            self.src[("ctrl", "u_ff")] = ("out", "comp") if "comp" in blocks else ("ext", "zero")
        if "comp" in blocks:
            self.src[("comp", "y_ref")] = ("ext", "r_comp")
        # a chain: block j is len - 1 - j connections upstream of the measured output
        self.preview = {b: len(blocks) - 1 - j for j, b in enumerate(blocks)}
        k = np.arange(n)
        self.t = k * dt
        self.r = trajectory(scenario, self.t)
        self.ext = {"zero": np.zeros(n)}
        if "comp" in blocks:
            self.ext["r_comp"] = trajectory(scenario, (k + self.preview["comp"]) * dt)
        if "ctrl" in blocks:
            # the controller compares r_{k-1} with the output after step k-1
            self.ext["r_ctrl"] = trajectory(scenario, (k - 1) * dt)
        if drive is None:
            self.ext["u_open"] = trajectory(scenario, (k + self.preview[target]) * dt) / k_lin
        self.drive = "u_open" if drive is None else drive
        self.actuator = target

    def inputs(self, block):
        """[(input name, source)] of `block`, in the order of its FMU inputs."""
        return [(name, self.src[(block, name)]) for name in IO[block][0]]

    def trace(self, outputs, k_done):
        """The recorded run cut at `k_done` completed steps: t [s], r [µm],
        out_<block> (each block's output after each step), u [V] (the
        actuator's, or the plant's, input), y [µm] (the measured output) and
        e = r - y [µm]. `outputs` maps block -> its outputs, at least k_done."""
        out = {"t": self.t[:k_done].copy(), "r": np.asarray(self.r[:k_done], dtype=float).copy()}
        for b in self.blocks:
            out["out_" + b] = np.asarray(outputs[b][:k_done], dtype=float).copy()
        if self.drive == "u_open":
            out["u"] = self.ext["u_open"][:k_done].copy()
        else:
            # a connection is a one-step delay: the drive's previous output
            src = out["out_" + self.drive]
            out["u"] = np.concatenate([[0.0], src[:-1]]) if k_done else np.zeros(0)
        out["y"] = out["out_" + self.measured].copy()
        out["e"] = out["r"] - out["y"]
        return out
