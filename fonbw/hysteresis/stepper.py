"""Per-sample steppers of the hysteresis models (FMUs, closed loops).

A stepper holds a model's packed parameter and state blocks and calls the
model's compiled step function on them, one sample per call; the numbers are
those of the model's batch ``simulate``.
"""
from __future__ import annotations

import numpy as np

from .. import fractional as fr
from .kernels import FONBW_S0


class Stepper:
    """One sample at a time: ``y_k = s.step(u_k)``.

    ``peek(u)`` returns the output the next step would give for ``u`` without
    advancing; ``get_state()``/``set_state()`` copy the whole state (fractional
    memory included) as one float64 array, so a rollback replays bit for bit.
    The numbers are those of the model's ``simulate``: both run the same
    compiled step function.
    """

    def __init__(self, model, dt):
        self.model = model
        self.dt = dt
        self._kernel = model._step
        self.reset()

    def reset(self) -> None:
        """Back to rest at t = 0."""
        self.P, ss = self.model._pack(self.dt)
        self.S = np.zeros(ss)
        self._steps = 0

    def step(self, u: float) -> float:
        """Advance one step with input u [V]; returns the output [µm]."""
        y = self._kernel(float(u), True, self.P, self.S)
        self._steps += 1
        return y

    def peek(self, u: float) -> float:
        """Output for input u [V] at the next step, without advancing."""
        return self._kernel(float(u), False, self.P, self.S)

    @property
    def steps(self) -> int:
        return self._steps

    @property
    def state_variable(self) -> float:
        """Hysteretic state (ħ or h) after the last committed step."""
        return float(self.S[2])

    def get_state(self) -> np.ndarray:
        return np.concatenate([[float(self._steps), len(self.P)], self.P, self.S])

    def set_state(self, state) -> None:
        s = np.asarray(state, dtype=float)
        if s.ndim != 1 or len(s) < 2:
            raise ValueError("state must be a 1-D array from get_state()")
        npar = int(s[1])
        P = s[2:2 + npar]
        if len(P) != npar or not self._compatible(P):
            raise ValueError("state does not belong to this stepper (model, engine or step differ)")
        self._steps = int(s[0])
        self.P = P.copy()
        self.S = s[2 + npar:].copy()

    def _compatible(self, P):
        return len(P) == len(self.P) and np.array_equal(P, self.P)


class _FONBWStepper(Stepper):
    """FONBW stepper; the exact engine's window grows with the run."""

    def reset(self):
        self.ops = self.model._ops(self.dt)
        super().reset()

    def step(self, u):
        if any(op.growable and self._count(i) >= op.window for i, op in enumerate(self.ops)):
            self._grow()
        return super().step(u)

    def _offsets(self):
        sz = [fr.state_size(op) for op in self.ops]
        return [FONBW_S0, FONBW_S0 + sz[0]], sz

    def _count(self, i):
        q = self._offsets()[0][i]
        return int(self.S[q + 1])

    def _grow(self):
        (q1, q2), (s1, s2) = self._offsets()
        blocks = [self.S[q1:q1 + s1], self.S[q2:q2 + s2]]
        new_ops, new_blocks = [], []
        for op, blk in zip(self.ops, blocks):
            if op.growable and int(blk[1]) >= op.window:
                W = op.window
                new = op.grown(2 * W)
                pos = int(blk[0])
                vals = blk[3 + pos:3 + pos + W]  # newest first (lag 1 … W)
                nbuf = np.zeros(2 * new.window)
                nbuf[:W] = vals
                nbuf[new.window:new.window + W] = vals
                blk = np.concatenate([[0, blk[1], blk[2]], nbuf, blk[3 + 2 * W:]])
                op = new
            new_ops.append(op)
            new_blocks.append(blk)
        self.ops = tuple(new_ops)
        self.P, _ = self.model._pack(self.dt, ops=self.ops)
        self.S = np.concatenate([self.S[:FONBW_S0], *new_blocks])

    def set_state(self, state):
        s = np.asarray(state, dtype=float)
        npar = int(s[1]) if len(s) > 1 else -1
        if any(op.growable for op in self.ops) and npar > 0:
            # the exact window may have grown: rebuild the operators to match
            N = len(self.model.ku)
            P = s[2:2 + npar]
            W1 = int(P[5 + N + 2])
            o2 = 5 + N + fr._sizes(P, 5 + N)[3]
            W2 = int(P[o2 + 2])
            ops = tuple(op.grown(W) if op.growable and W != op.window else op for op, W in zip(self.ops, (W1, W2)))
            self.ops = ops
            self.P, _ = self.model._pack(self.dt, ops=ops)
        super().set_state(state)
