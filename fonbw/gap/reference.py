"""A flexible reference hysteresis, linear in its weights, for the gap diagnosis.

The reference is a generalized Prandtl–Ishlinskii (PI) model: a bank of play
operators (Krasnosel'skii & Pokrovskii 1989) z_j on a threshold grid r_1 … r_m,
each entering through k + 1 columns, plus a polynomial in the input,

    y = Σ_j Σ_i c_ij B_i(z_j) + Σ_l a_l x^l,    x = (u - u_c) / u_h,

The play z_j is the boundary between the up and down relays on the Preisach
line α - β = 2 r_j, so B_i(z) = ∫ b_{i,k} (the integral of a Bernstein
polynomial of degree k = ``level`` in the relay centre, up to z) is that
line's output when its relay density is b_{i,k}. Weights c_ij ≥ 0 are
therefore a Preisach density ≥ 0 that is smooth along the lines and free
across them; k = 0 is the classical PI model (z_j itself). The polynomial
(free signs; l = 0 is the offset) carries the envelope. The grid is equally
spaced, r_j = j R / (2 (m + 1)), R the training records' input range: fixed by
the data, never searched.

Because y = Φ(u, dt; θ) c, the reference plugs into the variable-projection
fitter of the diagnosis like the nominal FONBW: :meth:`ReferenceHysteresis.columns`
gives Φ, :attr:`~ReferenceHysteresis.bounds` the bounds of c, and at most two
nonlinear parameters θ (:attr:`~ReferenceHysteresis.theta_bounds`) the rate
dependence:

``rate=None``
    rate independent, θ = ().
``rate="threshold"``
    thresholds widened by the input rate, r_j (1 + β |u'|_f), |u'|_f the
    absolute input rate [V/s] low-passed with time constant τ_f:
    θ = (β [s/V], τ_f [s]) (loops widening with frequency, as measured on
    PEAs; Ang et al., IEEE/ASME Trans. Mechatronics 12, 2007).
``rate="fractional"``
    one more column D^μ (u - u_0), the Grünwald–Letnikov derivative of
    :mod:`fonbw.fractional` (free sign): θ = (μ,). For small ħ FONBW's
    eq. (11) reduces to ħ ≈ ρ D^(λ1-λ2) u, a fractional linear term.
``rate="both"``
    both, θ = (β, μ), with τ_f fixed at ``rate_tau``: the only variant
    that reaches both truths below.
``rate="viscous"``
    "both" with an added width, r_j (1 + β |u'|_f) + γ |u'|_f:
    θ = (β, γ [s], μ). A play whose slider moves against viscous friction
    (a Bingham element: threshold plus overstress relaxing with a time
    constant γ) trails the input by r + γ |u'| while it flows, whatever its
    threshold; the multiplicative law widens the small thresholds hardly at
    all.

``memory=T`` cuts the fractional column's memory to the last T seconds
(the short-memory Grünwald–Letnikov sum). With the whole record as memory
and a small μ, D^μ of a step decays as t^-μ ≈ 1 − μ ln t: a logarithmic
creep, which the diagnosis attributes to its creep block, not to the loop's
rate dependence (:data:`fonbw.gap.form.REFERENCE_MEMORY`).

``relax=(τ_1, …)`` adds relaxation columns lag_τ(x) − x (a first-order lag
started at rest at the first sample), weights ≥ 0: a reversible part whose
stroke drops with frequency (a spring and a damper in series, beside the
hysteresis). Measured on two rate-dependent cores of the blind harness
(elasto-visco-plastic elements with τ 0.2–3 ms plus purely viscous ones
with τ 3–30 ms; seeds 21030 and 21003, noise 0.025 / 0.023 µm), train /
validation RMS [µm] of the diagnosis's reference::

    "both"                                  0.093 / 0.234   0.060 / 0.123
    "both", relax 2, 5, 10, 20, 50 ms       0.034 / 0.072   0.039 / 0.065
    "viscous", relax 2, 5, 10, 20, 50 ms    0.034 / 0.060   0.040 / 0.082

Neither case has an added effect. On "both" a lag block was named on each
(21030: creep, closing 0.85 of what the reference left; 21003: amplifier,
0.84). With the relaxations alone an amplifier still closed 0.67 on 21030
(the plays' viscous lag, which an input lag mimics); on "viscous" with the
relaxations it closed 0.01 and 0.13, and no lag was named. The diagnosis
still uses "both" without relaxations
(:data:`fonbw.gap.form.REFERENCE_RATE`, which says why).

Why this design (measured, 5 kHz, training on the eq.-19 input over 20 s,
validation on 5-period sines 60 - 60 cos(2πft) V; RMS [µm]; the reference
with 150 θ evaluations, FONBW by ``fonbw.identify(kind="fonbw", seed=0,
max_evals=1000)``)::

    truth (range)                   model                   train   1 Hz    5 Hz    20 Hz
    bench ideal, RD-PI (19.0 µm)    FONBW                   0.282   0.492   0.570   0.602
                                    m=24, k=0, descended    0.021   0.066   0.103   0.288
                                    m=16, k=2, descended    0.015   0.013   0.062   0.259
                                    + rate="threshold"      0.015   0.012   0.039   0.196
                                    + rate="fractional"     0.015   0.012   0.050   0.240
                                    + rate="both"           0.014   0.012   0.020   0.049
    FONBW Table 1 (15.5 µm)         FONBW                   0.0001  0.0003  0.003   0.012
                                    m=16, k=2               0.233   0.531   1.492   3.314
                                    + rate="fractional"     0.0001  0.0002  0.003   0.013
                                    + rate="both"           0.0001  0.0005  0.004   0.016
    Preisach, skewed density        FONBW                   0.362   0.825   0.874   0.934
    (test's, 19.8 µm)               m=24, k=0, descended    0.121   0.431   0.431   0.431
                                    m=24, k=1, descended    0.012   0.053   0.053   0.053
                                    m=16, k=2, descended    0.007   0.014   0.014   0.014

The bench's output polynomial of the PI sum and the Preisach truth's density
rising along the lines (loops wider at high voltage) are what k = 0 cannot
follow; k = 2 can (a Preisach relay grid could too, but needs m (m + 1) / 2
columns, 136 for m = 16 instead of 48, and the diagnosis filters and refits
every column thousands of times). A density concentrated in its relay
centres needs more than k = 2: the diagnosis uses k = 6
(:data:`fonbw.gap.form.REFERENCE_LEVEL`, measured there), and its joint
refits re-weigh the plays along a few leading directions
(:func:`fonbw.gap.cores.reduced_basis`). On its own truth FONBW is matched by
``rate="fractional"``, as it should be. The rate variants: "threshold" alone finds
the bench's rate law only partly from a training record below 1.5 Hz,
"fractional" alone finds FONBW's μ = λ1 - λ2 (0.334 for 0.3337); "both"
gets both. "threshold" alone on FONBW ran β to its bound and extrapolated
wildly (hence the bound of β at 1e-3 s/V and the clamp of the level
columns); the diagnosis should use "both". Building Φ (m = 16, k = 2, 52 columns) for 150 000 samples takes
about 45–75 ms on a shared 2-core machine (a third of it allocating the 62 MB
array), the bounded solve 0.1–0.5 s (BLAS with one thread: an
oversubscribed multi-threaded BLAS was 20 times slower).

Initial state (``initial=``), from the first sample u_0 of each record:

``"rest"``
    z_j = u_0: every play centred on its input, the demagnetized state; the
    first branch is a virgin curve, like FONBW from ħ = 0.
``"descended"``
    z_j = u_0 + r_j: at rest at the end of a descending branch, the state of
    a stage after a previous full cycle down to u_0 (the virtual bench's
    start). On the bench it lowers the training RMS from 0.080 to 0.021 µm
    (m = 24, k = 0).
``"ascended"``
    z_j = u_0 - r_j: at the end of an ascending branch that came from below
    every threshold, the state of a stage whose last move before the record
    was upward (or a Preisach operator started from negative saturation):
    relays with α < u_0 are up, all others down, so relays with β below the
    record's lowest input switch up on the first rise and never back. The
    first rise is then a virgin branch that no later rise repeats, which
    "rest" and "descended" both miss. On the tests' Preisach truth started
    that way (22 µm span) the reference fits 0.0095 µm from "ascended",
    0.062 from "rest" and 0.244 from "descended"; on a blind-harness Preisach
    core the diagnosis's reference went from 0.54 to 0.13 µm (seed 14003).
``"burn-in"``
    for records that start mid-drive: the first ``burn_in`` seconds of the
    record (default: the whole record) are run once before it, from rest, and
    discarded, i.e. the history before t = 0 is taken to be a periodic
    extension of the record. Exact for a record of whole periods of a
    periodic drive; every play whose band 2 r_j that stretch crosses forgets
    its rest state. Doubles the cost of Φ at the default.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ..fractional import apply_op, make_op
from .blas import single_thread
from .filters import first_order
from .lstsq import bounded_lstsq
from .plays import _combined_kernel, _filtered_rate, _level_columns, _play_kernel, play_bank

__all__ = ["ReferenceHysteresis", "ReferenceFit", "play_bank", "RATES", "INITIALS", "MU_MAX"]

RATES = (None, "threshold", "fractional", "both", "viscous")
INITIALS = ("rest", "descended", "ascended", "burn-in")

#: Highest order μ of the fractional column. Near 1 the column is the
#: drive's derivative, the first term of any lag of it: a delay d turns
#: H(u) into about H(u) − d H'(u) u'. Searched up to 0.98, the column took
#: the lags of rate-independent cores: over the 53rd–61st held-out runs
#: (360 scenarios; ``benchmarks/spent_rows.py orders``) μ went above 0.9 on
#: 29 of 57 Preisach and Prandtl–Ishlinskii cores with a delay, an
#: amplifier or a resonance injected, on 7 of 117 without one, once on 92
#: FONBW cores and never on 94 rate-dependent ones; delays of 2.3–6.7 σ
#: on five of them were named nothing. 0.9 lies just above the highest μ
#: any rate-dependent core took (0.89).
MU_MAX = 0.9

_MU = (0.02, MU_MAX)
_THETA = {
    None: ((), (), ()),
    "threshold": (("beta", "tau_f"), ((1e-7, 1e-3), (1e-4, 1.0)), (True, True)),
    "fractional": (("mu",), (_MU,), (False,)),
    "both": (("beta", "mu"), ((1e-7, 1e-3), _MU), (True, False)),
    "viscous": (("beta", "gamma", "mu"), ((1e-7, 1e-3), (1e-6, 1e-2), _MU), (True, True, False)),
}


# ---------------------------------------------------------------------------
# the reference


def _input(u) -> np.ndarray:
    u = np.ascontiguousarray(u, dtype=float)
    if u.ndim != 1 or u.size < 2 or not np.all(np.isfinite(u)):
        raise ValueError("u must be a 1-D array of at least 2 finite voltages [V]")
    return u


class ReferenceHysteresis:
    """Generalized Prandtl–Ishlinskii reference (module docstring).

    Parameters
    ----------
    n_plays : int
        Number of play operators m.
    degree : int
        Degree of the polynomial in x = (u - u_c) / u_h (powers 1 … degree).
    rate : {None, "threshold", "fractional", "both", "viscous"}
        Rate dependence and its nonlinear parameters θ.
    initial : {"rest", "descended", "ascended", "burn-in"}
        Play states at t = 0 of every record.
    burn_in : float, optional
        Seconds of the record's start run before it with ``initial="burn-in"``;
        None: the whole record.
    offset : bool
        Include a constant column (x^0).
    level : int
        Degree k of the density along each Preisach line α - β = 2 r_j, a
        Bernstein polynomial in the relay centre (k + 1 columns per play, all
        weights ≥ 0): 0 is the classical PI model (density constant along
        the lines); 1 or 2 let the loops widen towards one end of the range,
        which an output polynomial of a PI model or a real PEA shows.
    rate_tau : float
        Time constant [s] of the filtered input rate |u'|_f of "both" and
        "viscous".
    u_range : (float, float), optional
        Input range [V] that sizes the threshold grid and normalizes x; set
        from the training records by :meth:`fit` (or :meth:`with_range`).
    relax : sequence of float
        Time constants τ [s] of relaxation columns lag_τ(x) − x (weights ≥ 0).
    memory : float, optional
        Length [s] of the fractional column's memory (the short-memory
        Grünwald–Letnikov sum over that window); None: from the record's
        first sample.
    """

    def __init__(self, n_plays: int = 16, degree: int = 3, rate: str | None = None,
                 initial: str = "rest", burn_in: float | None = None, offset: bool = True,
                 level: int = 2, rate_tau: float = 0.01, u_range: tuple | None = None,
                 relax: tuple = (), memory: float | None = None):
        if int(n_plays) != n_plays or n_plays < 1:
            raise ValueError(f"n_plays must be a positive integer, got {n_plays!r}")
        if int(degree) != degree or degree < 0:
            raise ValueError(f"degree must be an integer ≥ 0, got {degree!r}")
        if rate not in RATES:
            raise ValueError(f"rate must be one of {RATES}, got {rate!r}")
        if initial not in INITIALS:
            raise ValueError(f"initial must be one of {INITIALS}, got {initial!r}")
        if burn_in is not None and not burn_in > 0:
            raise ValueError(f"burn_in must be a positive duration [s] or None, got {burn_in!r}")
        self.n_plays, self.degree, self.rate = int(n_plays), int(degree), rate
        self.initial, self.burn_in, self.offset, self.level = initial, burn_in, bool(offset), int(level)
        if not rate_tau > 0:
            raise ValueError(f"rate_tau must be a positive time constant [s], got {rate_tau!r}")
        self.rate_tau = float(rate_tau)
        relax = tuple(float(t) for t in relax)
        if not all(math.isfinite(t) and t > 0 for t in relax):
            raise ValueError(f"relax must be positive time constants [s], got {relax!r}")
        self.relax = relax
        if memory is not None and not (math.isfinite(memory) and memory > 0):
            raise ValueError(f"memory must be a positive duration [s] or None, got {memory!r}")
        self.memory = None if memory is None else float(memory)
        self.u_range = None
        if u_range is not None:
            lo, hi = (float(a) for a in u_range)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ValueError(f"u_range must be (low, high) with low < high [V], got {u_range!r}")
            self.u_range = (lo, hi)

    def __repr__(self):
        return (f"ReferenceHysteresis(n_plays={self.n_plays}, degree={self.degree}, rate={self.rate!r}, "
                f"initial={self.initial!r}, burn_in={self.burn_in!r}, offset={self.offset}, "
                f"level={self.level}, rate_tau={self.rate_tau!r}, u_range={self.u_range!r}, "
                f"relax={self.relax!r}, memory={self.memory!r})")

    def with_range(self, records_or_range) -> "ReferenceHysteresis":
        """A copy whose grid is sized on ``(low, high)`` [V] or on records' inputs."""
        if isinstance(records_or_range, tuple) and len(records_or_range) == 2 \
                and np.isscalar(records_or_range[0]):
            rng = records_or_range
        else:
            recs = _as_list(records_or_range)
            rng = (min(float(np.min(r.u)) for r in recs), max(float(np.max(r.u)) for r in recs))
        return ReferenceHysteresis(self.n_plays, self.degree, self.rate, self.initial, self.burn_in,
                                   self.offset, self.level, self.rate_tau, rng, self.relax, self.memory)

    # -- layout -------------------------------------------------------------

    def _range(self):
        if self.u_range is None:
            raise ValueError("the threshold grid is not sized yet: give u_range, or call fit / with_range")
        return self.u_range

    @property
    def thresholds(self) -> np.ndarray:
        """Play thresholds r_j [V]."""
        lo, hi = self._range()
        j = np.arange(1, self.n_plays + 1)
        return j * (hi - lo) / (2.0 * (self.n_plays + 1))

    @property
    def names(self) -> list:
        """Column names: plays (``play{j}``, or ``play{j}_hi``, ``play{j}_lo`` with
        ``level``), ``x^{i}``, then ``D^mu u`` with a fractional rate."""
        first = 0 if self.offset else 1
        m = range(self.n_plays)
        plays = [f"play{j}" + (f"_b{i}" if self.level else "") for i in range(self.level + 1) for j in m]
        frac = ["D^mu u"] if "mu" in self.theta_names else []
        relax = [f"relax{t:g}s" for t in self.relax]
        return plays + [f"x^{i}" for i in range(first, self.degree + 1)] + frac + relax

    @property
    def n_columns(self) -> int:
        return len(self.names)

    @property
    def n_play_columns(self) -> int:
        """Number of play columns (the first ones; weights ≥ 0)."""
        return self.n_plays * (self.level + 1)

    @property
    def bounds(self) -> tuple:
        """(lower, upper) bounds of the weights: 0 / +inf for plays and relaxations,
        ±inf for the rest."""
        p = self.n_columns
        lo = np.full(p, -np.inf)
        lo[: self.n_play_columns] = 0.0
        lo[p - len(self.relax):] = 0.0
        return lo, np.full(p, np.inf)

    @property
    def theta_names(self) -> tuple:
        return _THETA[self.rate][0]

    @property
    def theta_bounds(self) -> tuple:
        """Search box of θ, one (low, high) pair per parameter (natural units)."""
        return _THETA[self.rate][1]

    @property
    def theta_log(self) -> tuple:
        """Whether each θ is best searched in log scale."""
        return _THETA[self.rate][2]

    # -- regressors ---------------------------------------------------------

    def columns(self, u, dt: float, theta=(), keep=None, basis=None) -> np.ndarray:
        """Regressor matrix Φ, shape (n_samples, :attr:`n_columns`).

        Parameters
        ----------
        u : array_like
            Input [V] of one record, sampled at ``dt`` [s].
        dt : float
            Sampling period [s].
        theta : sequence of float
            Nonlinear parameters (:attr:`theta_names`); empty for ``rate=None``.
        keep : array_like of bool, optional
            Only these columns, in their order (the same numbers as those
            columns of the whole Φ, at a fraction of its memory traffic).
        basis : array_like, optional
            (n_kept, r) combinations of the (kept) columns: returns Φ B,
            shape (n_samples, r), summed as the play columns are made,
            without them in memory (equal to ``columns(...) @ basis`` up to
            the order of the sums).
        """
        u = _input(u)
        theta = tuple(float(t) for t in theta)
        if len(theta) != len(self.theta_names):
            raise ValueError(f"rate={self.rate!r} needs theta = {self.theta_names}, got {theta!r}")
        n = u.size
        if self.initial == "burn-in":
            nb = n if self.burn_in is None else min(n, max(1, int(round(self.burn_in / dt))))
            u = np.concatenate([u[:nb], u])
        r = self.thresholds
        if self.initial == "descended":
            z = u[0] + r
        elif self.initial == "ascended":
            z = u[0] - r
        else:
            z = np.full(r.size, u[0])
        lo, hi = self._range()
        m, q = self.n_plays, self.n_play_columns
        # where each column goes: all of them in order, or the kept ones packed
        col = np.arange(self.n_columns)
        if keep is not None:
            keep = np.asarray(keep, dtype=bool)
            if keep.shape != (self.n_columns,):
                raise ValueError(f"keep needs {self.n_columns} flags, got shape {keep.shape}")
            col = np.where(keep, np.cumsum(keep) - 1, -1)
        scale, add = self._scale(u, dt, theta)
        if basis is not None:
            return self._combined(u, dt, theta, z, scale, add, col, basis)[u.size - n:]
        out = np.empty((u.size, int(col.max()) + 1))
        if keep is None:
            pz = out[:, :m]  # the states, overwritten by the level columns
        else:
            pz = np.empty((u.size, m))
        _play_kernel(u, r, scale, add, z, pz)
        if self.level or keep is not None:
            _level_columns(pz, m, self.level, lo, hi - lo, col[:q], out)
        self._other_columns(u, dt, theta, col, out)
        return out[u.size - n:]

    def _other_columns(self, u, dt, theta, col, out):
        """The polynomial, fractional and relaxation columns, each to out[:, col[c]]
        (c counted over all columns; nowhere when negative)."""
        q = self.n_play_columns
        lo, hi = self._range()
        x = (u - 0.5 * (lo + hi)) / (0.5 * (hi - lo))
        first = 0 if self.offset else 1
        power = np.ones_like(x)
        for i in range(first, self.degree + 1):
            if i > 0:
                # products: numpy's x ** i calls pow per sample (25 ms for six
                # powers of 1.5e5 samples, as long as the play columns)
                power = power * x
            if col[q + i - first] >= 0:
                out[:, col[q + i - first]] = power
        if "mu" in self.theta_names and col[q + self.degree + 1 - first] >= 0:
            # measured from the first sample, so that a record starting away
            # from 0 V does not see a step at t = 0
            op = (make_op(theta[-1], dt, "fast") if self.memory is None
                  else make_op(theta[-1], dt, "short", L=max(1, round(self.memory / dt))))
            out[:, col[q + self.degree + 1 - first]] = apply_op(op, u - u[0])
        for j, tau in enumerate(self.relax):
            c = col[self.n_columns - len(self.relax) + j]
            if c >= 0:
                # lag − input: ≤ 0 on a rise, so a weight ≥ 0 takes stroke off fast moves
                out[:, c] = first_order(x, math.exp(-dt / tau)) - x

    def _combined(self, u, dt, theta, z, scale, add, col, basis):
        """Φ B with the play columns summed in the play kernel (:meth:`columns`)."""
        basis = np.asarray(basis, dtype=float)
        n_kept = int(col.max()) + 1
        if basis.ndim != 2 or basis.shape[0] != n_kept:
            raise ValueError(f"basis needs {n_kept} rows (one per kept column), got shape {basis.shape}")
        q = self.n_play_columns
        lo, hi = self._range()
        # the kept play columns come first among the kept ones: col[:q] numbers
        # them, and they are the basis's first rows
        n_plays = int(np.count_nonzero(col[:q] >= 0))
        out = np.empty((u.size, basis.shape[1]))
        # the kernel's block products go to scipy's OpenBLAS (numba's np.dot), a
        # thread pool beside numpy's: one thread, as in fonbw.gap.knee
        with single_thread():
            _combined_kernel(u, self.thresholds, scale, add, z, self.level, lo, hi - lo,
                             col[:q], np.ascontiguousarray(basis[:n_plays]), out)
        if n_kept > n_plays:
            # the few other columns, numbered from 0, times the basis's other rows
            rest = np.where(col[q:] >= 0, col[q:] - n_plays, -1)
            O = np.empty((n_kept - n_plays, u.size))  # written a contiguous row a column
            self._other_columns(u, dt, theta, np.concatenate([np.full(q, -1), rest]), O.T)
            out += O.T @ basis[n_plays:]
        return out

    def _scale(self, u, dt, theta):
        """Per-sample threshold factor and added width [V]: r_j s_k + a_k."""
        if self.rate == "threshold":
            return 1.0 + theta[0] * _filtered_rate(u, float(dt), theta[1]), np.zeros(u.size)
        if self.rate in ("both", "viscous"):
            f = _filtered_rate(u, float(dt), self.rate_tau)
            add = theta[1] * f if self.rate == "viscous" else np.zeros(u.size)
            return 1.0 + theta[0] * f, add
        return np.ones(u.size), np.zeros(u.size)

    def simulate(self, u, dt: float, weights, theta=()) -> np.ndarray:
        """Output y = Φ c [µm] for the input ``u`` [V] and weights ``c``."""
        return self.columns(u, dt, theta) @ np.asarray(weights, dtype=float)

    # -- fitting ------------------------------------------------------------

    def solve(self, Phi, y, n_free=0) -> tuple:
        """Bounded least squares of y ≈ Φ c; returns (c, residual sum of squares [µm²]).

        Φ holds this reference's columns, then `n_free` more columns whose
        weights are unbounded (another block's, solved beside the reference's):
        :func:`fonbw.gap.lstsq.bounded_lstsq` with this reference's
        :attr:`bounds`.
        """
        lo, hi = self.bounds
        return bounded_lstsq(Phi, y, np.r_[lo, np.full(n_free, -np.inf)], np.r_[hi, np.full(n_free, np.inf)])

    def _design(self, recs, theta):
        return np.concatenate([self.columns(r.u, r.dt, theta) for r in recs])

    def fit(self, records, *, seed=0, max_evals: int = 200, theta0=None) -> "ReferenceFit":
        """Fit the weights (and θ) to records by variable projection.

        Parameters
        ----------
        records : Record or list of Record
            Training records with ``u`` [V], ``y`` [µm], ``dt`` [s].
        seed : int
            Seed of the θ search (:func:`fonbw.de.jde_minimize`).
        max_evals : int
            Evaluations of the θ search (each builds Φ of every record and
            solves); unused with ``rate=None``.
        theta0 : sequence of float, optional
            A start placed in the search's initial population.

        Returns
        -------
        ReferenceFit
        """
        recs = _as_list(records)
        ref = self if self.u_range is not None else self.with_range(recs)
        y = np.concatenate([r.y for r in recs])
        t0 = time.perf_counter()
        nfev = 1
        if ref.rate is None:
            theta = ()
        else:
            from ..de import jde_minimize

            def cost(X):
                out = np.empty(len(X))
                for i, th in enumerate(X):
                    out[i] = ref.solve(ref._design(recs, th), y)[1]
                return out

            res = jde_minimize(cost, ref.theta_bounds, log_scale=ref.theta_log, seed=seed,
                               max_evals=int(max_evals), popsize=12, x0=theta0)
            theta, nfev = tuple(float(a) for a in res.x), res.nfev
        t1 = time.perf_counter()
        Phi = ref._design(recs, theta)
        t2 = time.perf_counter()
        c, _ = ref.solve(Phi, y)
        t3 = time.perf_counter()
        fit = ReferenceFit(ref, c, theta, nfev=nfev, wall_time=t3 - t0,
                           build_time=t2 - t1, solve_time=t3 - t2)
        fit.rms_records = [fit.rms(r) for r in recs]
        e = np.concatenate([fit.predict(r) - r.y for r in recs])
        fit.rms_train = float(np.sqrt(np.mean(e**2)))
        return fit


def _as_list(records):
    recs = [records] if hasattr(records, "u") else list(records)
    if not recs or any(getattr(r, "u", None) is None for r in recs):
        raise ValueError("need at least one record with an input u [V]")
    return recs


@dataclasses.dataclass
class ReferenceFit:
    """A fitted reference hysteresis.

    Attributes
    ----------
    reference : ReferenceHysteresis
        The configuration, its grid sized on the training inputs.
    weights : ndarray
        Linear weights c (order of ``reference.names``): plays [µm/V],
        polynomial [µm].
    theta : tuple
        Nonlinear parameters (``reference.theta_names``).
    nfev : int
        Evaluations (Φ built and solved) of the θ search.
    wall_time, build_time, solve_time : float
        Whole fit, one build of the training Φ, one bounded solve [s].
    rms_train : float
        RMS error over all training samples [µm].
    rms_records : list of float
        RMS error per training record [µm].
    """

    reference: ReferenceHysteresis
    weights: np.ndarray
    theta: tuple
    nfev: int = 1
    wall_time: float = 0.0
    build_time: float = 0.0
    solve_time: float = 0.0
    rms_train: float = float("nan")
    rms_records: list = dataclasses.field(default_factory=list)

    def simulate(self, u, dt: float) -> np.ndarray:
        """Output [µm] for the input ``u`` [V] at step ``dt`` [s]."""
        return self.reference.simulate(u, dt, self.weights, self.theta)

    def predict(self, record) -> np.ndarray:
        """Output [µm] on a record's input."""
        return self.simulate(record.u, record.dt)

    def rms(self, record) -> float:
        """RMS error [µm] on a record (training or validation)."""
        return float(np.sqrt(np.mean((self.predict(record) - record.y) ** 2)))
