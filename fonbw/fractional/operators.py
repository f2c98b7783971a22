"""One fractional derivative as a compiled-kernel operator.

:class:`FracOp` describes D^λ at a fixed step for one engine and
:func:`make_op` builds it; :func:`pack` and :func:`state_size` lay it out as
the flat parameter and state blocks that the kernels of
:mod:`fonbw.fractional.kernels` read (layout below).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from .weights import ENGINES, FAST_K, FAST_M, SHORT_L, _check_lam, gl_weights, oustaloup_ss, tail_modes

#: Operator kinds of the compiled kernels.
KIND_GL = 0
KIND_OUSTALOUP = 1


@dataclasses.dataclass
class FracOp:
    """Compiled-kernel description of one fractional derivative D^λ at step dt.

    Attributes
    ----------
    kind : int
        ``KIND_GL`` (window of exact weights plus optional geometric modes)
        or ``KIND_OUSTALOUP``.
    a : float
        Coefficient of the current sample in (*).
    w : ndarray
        Scaled weights ``dt^-λ w_j`` for lags j = 1..W (index j-1).
    c, r : ndarray
        Scaled tail modes (``fast``); empty otherwise.
    A, B, C : ndarray
        Oustaloup state space (empty for GL).
    engine : str
    lam : float
    growable : bool
        True for the exact engine in a stepper: the window grows with the run.
    """

    kind: int
    a: float
    w: np.ndarray
    c: np.ndarray
    r: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    engine: str
    lam: float
    dt: float
    growable: bool = False

    @property
    def window(self) -> int:
        return len(self.w)

    @property
    def nz(self) -> int:
        return len(self.r) if self.kind == KIND_GL else len(self.B)

    def grown(self, window: int) -> "FracOp":
        """The same exact-engine operator with a longer window."""
        w = gl_weights(self.lam, window + 1)[1:] * self.dt ** (-self.lam)
        return dataclasses.replace(self, w=w)


_EMPTY = np.zeros(0)
_EMPTY2 = np.zeros((0, 0))


def make_op(lam: float, dt: float, memory: str = "fast", *, n_steps: int | None = None,
            K: int = FAST_K, M: int = FAST_M, L: int = SHORT_L) -> FracOp:
    """Build the operator of D^λ for an engine.

    Parameters
    ----------
    lam : float
        Order, 0 < λ ≤ 1.
    dt : float
        Fixed step [s].
    memory : {"fast", "exact", "short", "oustaloup"}
    n_steps : int, optional
        Known run length (batch): sizes the exact engine's window. Without it
        the exact window starts small and grows (steppers).
    K, M : int
        Fast engine: exact lags and geometric modes.
    L : int
        Short engine: window length.
    """
    lam = _check_lam(lam)
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"step dt must be a positive finite number of seconds, got {dt!r}")
    if memory not in ENGINES:
        raise ValueError(f"unknown memory engine {memory!r}; choose one of {', '.join(ENGINES)}")
    scale = dt ** (-lam)
    if lam == 1.0:
        # Backward difference: exact for every engine.
        return FracOp(KIND_GL, scale, np.array([-scale]), _EMPTY, _EMPTY, _EMPTY2, _EMPTY, _EMPTY,
                      memory, lam, dt)
    if memory == "oustaloup":
        A, B, C, D = oustaloup_ss(lam, dt)
        return FracOp(KIND_OUSTALOUP, D, _EMPTY, _EMPTY, _EMPTY, A, B, C, memory, lam, dt)
    if memory == "exact":
        W = int(n_steps) if n_steps else 1024
        w = gl_weights(lam, W + 1)[1:] * scale
        return FracOp(KIND_GL, scale, w, _EMPTY, _EMPTY, _EMPTY2, _EMPTY, _EMPTY, memory, lam, dt,
                      growable=n_steps is None)
    if memory == "short":
        w = gl_weights(lam, L + 1)[1:] * scale
        return FracOp(KIND_GL, scale, w, _EMPTY, _EMPTY, _EMPTY2, _EMPTY, _EMPTY, memory, lam, dt)
    c, r = tail_modes(lam, K, M)
    w = gl_weights(lam, K + 1)[1:] * scale
    return FracOp(KIND_GL, scale, w, c * scale, r, _EMPTY2, _EMPTY, _EMPTY, memory, lam, dt)


# ---------------------------------------------------------------------------
# Packed layout of an operator for the kernels of fonbw.fractional.kernels.
#
# An operator is packed into a flat float64 parameter block and a flat state
# block so that a whole model travels to numba as two arrays (cheap dispatch
# per FMU step) and batch, population and per-step code all run the same
# function.
#
# parameter block: [kind, a, W, M, m, w(W), c(M), r(M), A(m*m), B(m), C(m)]
# state block:     [pos, count, hz, buf(2*max(W,1)), z(nz), tmp(m)]
#   nz = M (GL) or m (Oustaloup); tmp (scratch) only for Oustaloup;
#   hz = the modes' part of the history (Σ c_i z_i, or C·z), refreshed by
#   every push, so a history evaluation (several per step in the
#   compensator) only sums the exact window.
#
# The kernels address both blocks through integer offsets (a descriptor
# tuple of plain numbers, :func:`op_desc`), never through array views: a
# tuple of two dozen views pays a reference-count round trip per view each
# time it crosses a call, about 150 ns a model step — more than all the
# arithmetic of the fast engine.

def pack(op: FracOp) -> np.ndarray:
    """Flat parameter block of an operator (see the layout above)."""
    m = len(op.B) if op.kind == KIND_OUSTALOUP else 0
    M = len(op.r)
    head = np.array([op.kind, op.a, op.window, M, m], dtype=float)
    return np.concatenate([head, op.w, op.c, op.r, op.A.ravel() if m else [], op.B if m else [],
                           op.C if m else []])


def state_size(op: FracOp) -> int:
    """Length of an operator's state block (layout above)."""
    extra = op.nz if op.kind == KIND_GL else 2 * op.nz
    return 3 + 2 * max(op.window, 1) + extra
