"""Small linear filters shared by the effect blocks and the reference hysteresis."""
from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

__all__ = ["first_order"]


def first_order(x, a):
    """y_k = a y_{k-1} + (1 − a) x_k along the last axis, starting at rest at x_0.

    ``a = exp(−dt/τ)`` for a time constant τ [s]. The backward (implicit) form
    keeps a step's first sample from being delayed, which a delay candidate
    would otherwise have to share.
    """
    x = np.asarray(x, dtype=float)
    zi_shape = x.shape[:-1] + (1,)
    zi = (a * x[..., :1]).reshape(zi_shape)
    y, _ = lfilter([1.0 - a], [1.0, -a], x, axis=-1, zi=zi)
    return y
