"""Candidate effect blocks for the sim-to-real gap diagnosis.

Each block is a cheap wrapper around the nominal hysteresis model H (FONBW,
eqs. 9-11) with few parameters. The attribution step (:mod:`fonbw.gap.attribute`)
adds a block to the nominal model and refits everything jointly. To keep that
refit cheap every block is written in one of four forms, which compose:

* **input side** — ``transform_input(u, dt, th)`` changes the voltage before
  the hysteresis (amplifier, delay); the hysteresis is simulated again;
* **linear output operator** — ``output_op(Y, dt, th)`` filters signals along
  their last axis (dynamics). A linear time-invariant operator L
  commutes with the linear part of the model,
  L(Σ ku_i u^i + kh ħ) = Σ ku_i L(u^i) + kh L(ħ), so the linear parameters ku
  and kh are still solved by least squares (variable projection, as in
  :mod:`fonbw.identify`);
* **additive regressors** — ``columns(ctx, th)`` adds signals whose gains are
  solved linearly (creep: first-order modes driven by the reference output of
  the model; drift: powers of time, not input-driven);
* **output nonlinearity** — ``shape(z, th)`` bends the model's own output z
  (saturation: y = z + c f(z) above a knee); its gain c and the linear
  parameters inside z are solved together by Gauss-Newton
  (:meth:`fonbw.gap.attribute.Fitter.fit_linear`).

Nonlinear parameters (``names``) are searched; linear ones (``lin_names``)
are solved. Units: u [V], y [µm], t [s], frequencies [Hz].
"""
from __future__ import annotations

import copy
import functools
import math

import control as ct
import numba as nb
import numpy as np
from scipy.signal import lfilter

from .. import plant as _plant
from . import edges, knee
from .blas import single_thread
from .filters import first_order

__all__ = ["Effect", "Creep", "Dynamics", "Amplifier", "Delay", "Drift", "Saturation", "Clip",
           "library", "EFFECTS"]

#: Names of the library's effect blocks, in the order they are tried.
EFFECTS = ("creep", "dynamics", "amplifier", "delay", "drift", "saturation", "clip")


class Effect:
    """Base block: identity everywhere.

    Attributes
    ----------
    name : str
    names : tuple of str
        Nonlinear (searched) parameters.
    bounds : list of (lo, hi)
    log_scale : list of bool
    units : dict
        Units of every parameter, nonlinear and linear.
    grid : ndarray, shape (G, len(names))
        Starting points tried with the nominal model fixed, before the joint refit.
    lin_names : tuple of str
        Names of the additive regressors' gains (solved linearly).
    input_side : bool
        True when ``transform_input`` is not the identity.
    filtered_columns : bool
        Whether later output operators act on this block's additive regressors
        (creep acts before the mechanics; drift does not). An output
        nonlinearity acts after everything and is never filtered.
    output_nonlinear : bool
        True for a static nonlinearity on the model's own output,
        y = z + c·f(z) with z everything else the model puts out: its
        regressor ``f(z)`` depends on the linear parameters, which the
        fitter then solves by Gauss-Newton (:meth:`shape` gives f and f',
        ``residual`` the residual with both in one pass).
    compressive : bool
        For an output nonlinearity: its gain c is bounded above by 0 (it may
        only lower the output's slope).
    c_min : float
        For an output nonlinearity: the least gain c (−∞: unbounded).
    lin_nonneg : bool
        The gains of ``lin_names`` are bounded below by 0.
    lag : bool
        The block slows a step of the command (a delay, a lag, a resonance):
        the share of a step it lets through within the step's own sample is
        checked against the records' step edges (:mod:`fonbw.gap.edges`).
    search_seeds : int
        Seeds the block's refit on the FONBW nominal runs from (search and
        polish each; the best training fit at the full rate is kept).
    edges_left_most : float or None
        The block is a lag that the step edges show whole: its fit may leave
        at most this share of the nominal's misfit there
        (:meth:`fonbw.gap.edges.StepEdges.left`; a transport delay is judged
        so only where the edges show it under a sample,
        :func:`fonbw.gap.greedy._edges_left_most`). None: not judged so.
    edges_who : str
        What does so, for the refusal's message.
    transport_delay : bool
        The block is a transport delay: when the step edges refuse its fit,
        it is searched again over the delays they accept (it then has a
        method ``within(lo, hi)`` giving the block so bounded), and where
        they hold a dead time it may be judged within the training rates.
    range_limit : bool
        The block acts only where the drive or the displacement reaches the
        top of its range (a rail, a stroke limit): between two such blocks
        that pass, the validation records decide
        (:func:`fonbw.gap.selection.pick_best`).
    overruled_by : str or None
        The block whose passing at the same greedy step, closing less, shows
        that what :meth:`refuses` took for something imitated is in the
        records: the refused block is then checked without its refusal
        (:meth:`fonbw.gap.greedy.GreedySteps._overrule`). None: no block can.
    refuses_at_every_step : bool
        :meth:`refuses` judges what the block is, not a parameter that trades
        with an accepted effect's: it holds at a later greedy step even when
        the block's fit alone on the nominal passed it
        (:func:`fonbw.gap.greedy._refused`).
    """

    name = "none"
    names: tuple = ()
    lin_names: tuple = ()
    units: dict = {}
    input_side = False
    filtered_columns = True
    output_nonlinear = False
    compressive = False
    c_min = -math.inf
    lin_nonneg = False
    lag = False
    edges_left_most: float | None = None
    edges_who = ""
    transport_delay = False
    range_limit = False
    overruled_by: str | None = None
    refuses_at_every_step = False
    search_seeds = 1
    #: How far above 1 the pooled leave-one-record-out ratio may lie
    #: (:func:`fonbw.gap.checks.loro`) for the block to pass; below zero, the
    #: share of their error by which the held-out records must fit better (strictly).
    loro_slack = 0.0

    def __init__(self):
        self.bounds = []
        self.log_scale = []
        self.grid = np.zeros((1, 0))

    def transform_input(self, u, dt, th):
        return u

    def output_op(self, Y, dt, th):
        return Y

    def columns(self, ctx, th):
        return None

    def identified(self, th) -> bool:
        """Whether parameters `th` describe this block's own effect.

        False where the block degenerates into another one (a resonance
        that cannot ring is a lag); the attribution then prefers a tied
        candidate that is identified, or one that fits the training
        records better (between two limits, one that closes more of the
        validation gap: :func:`fonbw.gap.selection.pick_best`).
        """
        return True

    def refuses(self, params) -> str | None:
        """Why fitted `params` (:meth:`describe`) are not this block's effect
        but something it imitates, in words; None when they are its own.

        A candidate refused this way fails its checks, however much it closes
        (:meth:`identified` only ranks it behind a competing block), unless
        its :attr:`overruled_by` block passes beside it and closes less.
        """
        return None

    def describe(self, th, lin) -> dict:
        """Parameters by name (nonlinear then linear) as plain floats."""
        d = {k: float(v) for k, v in zip(self.names, th)}
        d.update({k: float(v) for k, v in zip(self.lin_names, lin)})
        return d


#: Time constants [s] of the creep block's modes (those the records cover).
CREEP_TAUS = (0.1, 1.0, 10.0)


class Creep(Effect):
    """Creep: first-order modes driven by the model output.

    y = H + Σ_j g_j (LP_τj(H_ref) − H_ref), LP_τ(s) = 1/(τ s + 1), with fixed
    time constants τ_j of 0.1, 1 and 10 s (those the records cover) and gains
    g_j [-] solved linearly. Creep is the slow part of a step response. A
    10-ms mode, there before, closed up to 0.89 of what the reference left
    on rate-dependent cores with no effect (their viscous elements lag by
    3-30 ms) and named creep on 11 of the 80 scenarios of the fifteenth and
    sixteenth held-out runs that had none; without it creep is named on one
    of them, and every true creep of those runs is still found. The
    seventeenth run then lost a 43 σ creep beside an amplifier on a
    rate-dependent core that the mode had found. Faster lags belong to the
    amplifier and delay blocks or to the form. H_ref is the nominal model's
    output (the modes are small, so driving them by the nominal rather than the refitted output
    changes the fit by second-order terms only). The static gain is unchanged:
    the g_j are the fractions of a step that arrive late, with time constant τ_j.
    A fraction is not negative (``lin_nonneg``): creep moves on in the
    direction of the step. A negative g_j would be a lead, a high-pass boost
    that takes up a nominal's wrong rate dependence (a 10-ms mode at −0.11
    corrected a reference on a 20-Hz sine beyond the training rates).
    """

    name = "creep"
    lin_nonneg = True

    def __init__(self, dt, t_max):
        super().__init__()
        taus = [tau for tau in CREEP_TAUS if tau <= 2.0 * t_max and tau >= 20 * dt]
        self.taus = tuple(taus or [max(20 * dt, t_max / 4)])
        self.lin_names = tuple(f"g_{tau:g}s" for tau in self.taus)
        self.units = {k: "1" for k in self.lin_names}

    def columns(self, ctx, th):
        h = ctx["y_ref"]
        return np.column_stack([first_order(h, math.exp(-ctx["dt"] / tau)) - h for tau in self.taus])


class Drift(Effect):
    """Slow thermal drift, not input-driven: d(t) = d1 (t/T0) + d2 (t/T0)², T0 = 10 s.

    t is the time since the start of each record (every record starts from
    rest); d1, d2 [µm] are shared by all records and solved linearly.
    """

    name = "drift"
    lin_names = ("d1_um", "d2_um")
    units = {"d1_um": "µm per 10 s", "d2_um": "µm per (10 s)²"}
    filtered_columns = False
    T0 = 10.0
    # Not input-driven: a held-out record's drift is predicted wholly by the
    # law fitted on the others, so the check has teeth here that it lacks for
    # a block a held-out record may not excite. 18 injected drifts came out
    # at pooled ratios of 0.01-0.41 (the 0.41 a 3.2-sigma drift beside an
    # amplifier, seed 41023); the drifts named for a start-up transient on a
    # null and for mains hum, neither shared by the records, at 0.93 and 0.98
    # (45026, 45031)
    loro_slack = -0.25

    def columns(self, ctx, th):
        s = ctx["t"] / self.T0
        return np.column_stack([s, s * s])


class Dynamics(Effect):
    """Second-order mechanical resonance on the output (:func:`fonbw.plant.mechanics`).

    G(s) = ωn²/(s² + 2ζωn s + ωn²), ωn = 2π f_res, ζ ≤ 0.5, unit DC gain, discretized
    by python-control with a first-order hold once per parameter pair. The
    hold keeps a direct feedthrough, so a fast resonance tends to the
    identity; a zero-order hold would add a whole sample of delay at any
    f_res, which on records with steps costs more than the resonance gains.
    f_res may exceed the Nyquist frequency (up to 1000 fs/2): that is how
    the block switches itself off.
    """

    name = "dynamics"
    names = ("f_res", "zeta")
    units = {"f_res": "Hz", "zeta": "1"}
    lag = True
    edges_left_most = edges.MODE_LEFT
    edges_who = "a mode of the stage"

    def __init__(self, dt):
        super().__init__()
        fn = 0.5 / dt
        self.f_nyq = fn
        # a resonance: ζ ≤ 0.5, a mode that peaks (by 15 % at ζ = 0.5). Near
        # ζ = 0.7 a second-order mode is a flat low-pass whose only trace at
        # the records' 1-25 Hz is a lag, which is what the amplifier and
        # delay blocks describe; allowing it let this block take their cases
        self.bounds = [(fn / 100.0, 1000.0 * fn), (0.02, 0.5)]
        self.log_scale = [True, True]
        f = np.r_[np.geomspace(fn / 100.0, 5.0 * fn, 12), 1000.0 * fn]
        z = np.array([0.05, 0.15, 0.3, 0.45])
        self.grid = np.array([(a, b) for a in f for b in z])

    def identified(self, th):
        # a mode at or above the Nyquist frequency cannot be seen ringing in
        # the samples, and one at the damping bound does not ring: both are
        # only a lag, which the delay and amplifier blocks describe
        return bool(th[0] < self.f_nyq and th[1] < 0.98 * self.bounds[1][1])

    @staticmethod
    @functools.lru_cache(maxsize=4096)
    def _coeffs(f, zeta, dt):
        # one BLAS thread: a 4 x 4 matrix exponential does not split its
        # work (the same numbers), and waking a second thread on a busy
        # machine cost 100 times the exponential itself (fonbw.gap.blas)
        with single_thread():
            sysd = ct.c2d(_plant.mechanics(f, zeta), dt, method="foh")
        num = np.atleast_1d(np.squeeze(sysd.num[0][0]))
        den = np.atleast_1d(np.squeeze(sysd.den[0][0]))
        # lfilter reads coefficients of z^0, z^-1, ...: align the degrees
        num = np.concatenate([np.zeros(len(den) - len(num)), num])
        return num, den

    def output_op(self, Y, dt, th):
        num, den = self._coeffs(float(th[0]), float(th[1]), float(dt))
        Y = np.asarray(Y, dtype=float)
        # at rest at the first value (the model's rest state), so the filter
        # does not see a step at t = 0
        y0 = Y[..., :1]
        out = lfilter(num, den, Y - y0, axis=-1)
        return out + y0


class Delay(Effect):
    """Transport delay [s] of the command, up to 25 samples, before the hysteresis.

    v(t) = u(t − d), with u linear between samples (linear interpolation for
    fractional samples) and at rest at u_0 before the record. On the input
    side, not the output: for whole samples the two are the same (the model
    is time invariant and starts at rest at u_0), but a fractional delay of
    an instant step is a two-sample ramp of the command, which FONBW's
    fractional derivative answers with another spike than a delayed output.
    """

    name = "delay"
    names = ("delay",)
    units = {"delay": "s"}
    input_side = True
    lag = True
    transport_delay = True
    edges_left_most = edges.LEFT
    edges_who = "a delay of the drive under a sample"

    def __init__(self, dt):
        super().__init__()
        self.bounds = [(0.0, 25.0 * dt)]
        self.log_scale = [False]
        self.grid = dt * np.array([[d] for d in (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0,
                                                 12.0, 16.0, 24.0)])

    @staticmethod
    def shift(Y, d):
        """`Y` (along its last axis) delayed by `d` samples, linear interpolation, at rest at Y[..., 0]."""
        Y = np.asarray(Y, dtype=float)
        m = int(math.floor(d))
        f = d - m
        n = Y.shape[-1]
        pad = np.repeat(Y[..., :1], m + 1, axis=-1)
        Z = np.concatenate([pad, Y], axis=-1)  # Z[k + m + 1] = Y[k]
        a = Z[..., 1:n + 1]            # Y[k − m]
        b = Z[..., 0:n]                # Y[k − m − 1]
        return (1.0 - f) * a + f * b

    def transform_input(self, u, dt, th):
        return self.shift(u, float(th[0]) / dt)

    def within(self, lo, hi):
        """This block searched only over delays from `lo` to `hi` [s] (within its
        bounds): the grid points there and both ends; None when its bounds hold
        no such delay (a dead time longer than its longest delay)."""
        b_lo, b_hi = self.bounds[0]
        lo, hi = max(float(lo), b_lo), min(float(hi), b_hi)
        if not lo < hi:
            return None
        out = copy.copy(self)
        d = self.grid[:, 0]
        out.bounds = [(lo, hi)]
        out.grid = np.unique(np.r_[lo, d[(d > lo) & (d < hi)], hi])[:, None]
        return out


@nb.njit(cache=True)
def _amp_kernel(u, a, smax, out):  # pragma: no cover - compiled
    # RC output stage with a current limit: the voltage moves towards the
    # command by the implicit first-order step, at most smax per sample.
    v = u[0]
    for k in range(u.shape[0]):
        d = (1.0 - a) * (u[k] - v)
        if d > smax:
            d = smax
        elif d < -smax:
            d = -smax
        v = v + d
        out[k] = v


class Amplifier(Effect):
    """Amplifier with a capacitive load: bandwidth f_c and slew limit, before the hysteresis.

    v_k = v_{k−1} + clip((1 − a)(u_k − v_{k−1}), ± S dt), a = e^(−2π f_c dt):
    the first-order pole 1/(2π R C) of :func:`fonbw.plant.amplifier` (implicit
    step) whose rate is capped at the slew rate S = I_max / C [V/s].
    """

    name = "amplifier"
    names = ("f_c", "slew")
    units = {"f_c": "Hz", "slew": "V/s"}
    input_side = True
    lag = True
    edges_left_most = edges.LEFT
    edges_who = "the drive's own amplifier"
    # The global search sees decimated records, where the slew limit hardly
    # shows, so the valley the full-rate polish ends in depends on the
    # search's draw: on a FONBW core with an amplifier (blind harness, seed
    # 24007) four seeds gave training RMS 0.041, 0.032, 0.037, 0.028 µm and
    # validation gap closed 0.23, 0.90, 0.87, 0.93 (a resonance, 0.85, was
    # named at the first), and the coarse fit could not rank them. Two seeds
    # for every block cost 1.5 times the time on FONBW cores (a stroke
    # limit, 30 s of records: 53 s → 86 s) and changed no other verdict of
    # 20 scenarios but to rename a lag; the delay's one parameter ends in
    # the same fit from either seed on the tests' amplifier case.
    search_seeds = 2

    def __init__(self, dt, U):
        super().__init__()
        fn = 0.5 / dt
        # the upper corner (f_c = fs, a full-range step in a tenth of a
        # sample) is the block switched off
        self.bounds = [(fn / 500.0, 2.0 * fn), (U / 0.1, 10.0 * U / dt)]
        self.log_scale = [True, True]
        # the slew limit binds only at step edges, which the decimated
        # global search cannot see: the full-rate grid must resolve it
        f = np.geomspace(fn / 500.0, 2.0 * fn, 10)
        s = np.geomspace(U / 0.1, 10.0 * U / dt, 8)
        self.grid = np.array([(a, b) for a in f for b in s])

    def transform_input(self, u, dt, th):
        a = math.exp(-2.0 * math.pi * float(th[0]) * dt)
        out = np.empty_like(u)
        _amp_kernel(np.ascontiguousarray(u, dtype=float), a, float(th[1]) * dt, out)
        return out


class Saturation(Effect):
    """Stroke saturation: the displacement is compressed above a knee y_k [µm].

    y = z + c w softplus((z − y_k)/w), softplus(x) = ln(1 + e^x), where z is
    the output of the rest of the model: the slope changes by the factor
    1 + c (c < 0 for a limit; c = −1 is a hard stop) over a corner of width
    w [µm] around the knee. c is linear, the knee and w are searched.

    The block acts on the model's *own* output z (``output_nonlinear``), not
    on the nominal model's: a nominal fitted to clipped records has its peaks
    in the wrong place, and a knee placed against those peaks mends one test
    signal while spoiling the others. The fitter solves the linear
    parameters and c jointly by Gauss-Newton, started from the regressor
    driven by the nominal output (``columns``). Far above the knee the block
    is a straight segment, which extrapolates sanely to displacements the
    training records did not reach (a polynomial bends back); a sharp corner
    (w → 0) cannot follow a limit that sets in gradually. A knee at the top
    of the training range with a narrow corner switches the block off.
    """

    name = "saturation"
    names = ("knee", "width")
    lin_names = ("c",)
    units = {"knee": "µm", "width": "µm", "c": "1"}
    output_nonlinear = True
    range_limit = True
    #: c ≤ 0: a stroke limit only lowers the slope. A top that steepens is no
    #: limit but loop shape (a Prandtl–Ishlinskii envelope bending up), which
    #: a free sign would credit to this block.
    compressive = True
    #: c ≥ −1: a stop flattens the displacement and never turns it back.
    #: Unbounded, the fits on 160 blind-harness scenarios (seeds
    #: 32000-35039) reached c = −4.1 with corners 0.01-0.08 µm wide, a hook
    #: at the top of the training loops (gap closed down to −10 on
    #: validation). Bounded, a rate-dependent core's stroke limit (seed
    #: 35000) was named, no longer a rail; the other 21 scenarios rerun kept
    #: their verdicts (BENCHMARKS.md).
    c_min = -1.0
    #: Least drop of the slope above the knee (−c) for a stroke limit. A stop
    #: (a mechanical end, a flexure run out of travel) flattens the
    #: displacement; a top that only bends is loop shape, the hysteresis
    #: form's, which the reference nominal's envelope follows only in part.
    #: Measured on the accepted saturations of 160 blind-harness scenarios
    #: (seeds 29000-29039, 30000-31039, 32000-32039), alone on the nominal,
    #: with c unbounded below: the nine injected ones dropped the slope by
    #: 0.78-1.42 (c ≥ −1 caps the drop at 1), the ten where none was
    #: material (the Preisach and Prandtl-Ishlinskii cores' envelopes) by
    #: 0.04-0.57.
    min_drop = 2.0 / 3.0
    #: A rail that passes shows a flat top in the records, which an envelope
    #: that only bends does not make: the rail turns the core's memory at its
    #: level. Measured on the first-step candidates of the blind harness's
    #: 32nd-43rd held-out runs whose saturation closed at least 0.2 with a
    #: drop under two thirds: on the 17 Preisach and Prandtl–Ishlinskii cores
    #: with neither a stroke limit nor a material rail, the clip closed −12.7
    #: to 0.00 and failed; on 7 rails it passed and closed more (0.65-1.00
    #: against 0.32-0.69); on stroke limits it passed five times and the
    #: saturation closed more twice (41009: 0.94 against 0.89, drop 56 %;
    #: 43027: 0.91 against 0.79, drop 46 %; the other three, 35005, 37003 and
    #: 42010, barely reached the training records, under 1.1 σ there).
    overruled_by = "clip"
    #: Corner widths the knee's grid tries, as shares of the displacement span.
    width_shares = (0.003, 0.02, 0.08)

    def __init__(self, y_lo, y_hi):
        super().__init__()
        span = max(y_hi - y_lo, 1e-9)
        self.bounds = [(y_lo + 0.3 * span, y_hi), (1e-3 * span, 0.2 * span)]
        self.log_scale = [False, True]
        knees = np.linspace(y_lo + 0.35 * span, y_hi - 0.02 * span, 10)
        widths = span * np.array(self.width_shares)
        self.grid = np.array([(k, w) for k in knees for w in widths])

    @staticmethod
    def shape(z, th):
        """f(z) = w softplus((z − y_k)/w) [µm] and its slope f'(z) [-]."""
        return knee.softplus(z, th[0], th[1])

    @staticmethod
    def residual(B, b, y, th, r, f, df):
        """y − (z + c f(z)), z = B b[:-1], c = b[-1], into `r`, with f(z) and
        f'(z) into `f` and `df` (contiguous, like `y`); returns its sum of squares."""
        return knee.residual(B, b, y, th[0], th[1], r, f, df)

    def columns(self, ctx, th):
        return self.shape(ctx["y_ref"], th)[0][:, None]

    def refuses(self, params):
        drop = -params["c"]
        if drop < self.min_drop:
            return (f"the slope above the knee drops by {drop:.0%}, less than a stroke limit's "
                    f"{self.min_drop:.0%}: a bend of the loop")
        return None


class Clip(Effect):
    """The amplifier's upper rail: the voltage is limited smoothly at a level [V] before the hysteresis.

    v = L + ((u − L) − sqrt((u − L)² + k²)) / 2, the hyperbolic smooth
    minimum of the command u and the rail L with a knee of width k [V]: v
    follows u well below the rail (v − u ≈ −k²/(4 (L − u))), is L − k/2 at
    u = L and tends to L above it. On the input side, so the core's memory
    turns at the rail: a descending branch starts from the clipped voltage,
    which an output saturation cannot express. A level above every command
    switches the block off. Drives never go below 0 V, so only the upper
    rail is modelled.
    """

    name = "clip"
    names = ("level", "knee")
    units = {"level": "V", "knee": "V"}
    input_side = True
    range_limit = True
    # A rail acts only where a command reaches it, and a held-out record is
    # scored only over the displacements the other records span, so the check
    # sees little of what the rail does: true clips of 0.34-0.97 gap closed
    # came out at pooled ratios of 1.001-1.009 (held-out seeds 26011, 26026,
    # 28015, 28039), the clips that were not there at 1.109 and 1.248
    # (27018, 28032)
    loro_slack = 0.02
    #: Knee widths the grid tries, as shares of the largest training command U.
    knee_shares = (0.003, 0.015)
    #: Widest knee of a rail, as a share of U. An amplifier's output stage
    #: leaves its rail within a few volts of a 100-V swing; a knee spread
    #: wider compresses the whole top of the drive, which is the loop's own
    #: bend or a stroke limit's. On 199 spent blind-harness scenarios (seeds
    #: 45000-49039) the rails accepted with a knee wider than 2.5 % of U were
    #: injected in one case of eight (45005, a rail the training records did
    #: not reach); the other seven named a rail for a stroke limit (47000,
    #: 48002, 46027, 49000, 49038) or for nothing (a Preisach null, 49005;
    #: a 0.4 σ drift, 46005). The 16 other rails accepted where one was
    #: injected had knees of 0.11-1.75 V (BENCHMARKS.md, "A rail is sharp").
    knee_max_share = 0.025
    # a knee refit wide beside an accepted stroke limit is that limit's bend
    # again, above every command (held-out seed 51020: 126.2 V, 5.74 V, where
    # alone on the nominal it was a sharp 113.7 V rail); the three rails
    # accepted so at a later step of the 35th-41st runs were none injected
    refuses_at_every_step = True
    #: Nearest a rail may sit to the largest training command, as a share
    #: of U, to be judged on the training records. Closer, they barely
    #: reach it, and its level follows how their top bends, which a stroke
    #: limit or the loop's own envelope bends too: the stage beyond the
    #: training range (:mod:`fonbw.gap.beyond`) then fits it and a stroke
    #: limit on the validation records, which drive past it (a validation
    #: set that does not is no judge, and the rail is not named). On the
    #: rows of 518 spent blind-harness scenarios (seeds 45000-57039) a rail
    #: passed a greedy step within 0.5 % of U under the training top, or
    #: above it, in 18: 6 with a rail injected, 10 with a stroke limit, 2
    #: with neither; lower down in 55: 41, 13 and 1 (BENCHMARKS.md, "A rail
    #: at the top of the training commands").
    top_share = 0.005

    def __init__(self, U):
        super().__init__()
        self.U = float(U)
        self.bounds = [(0.4 * U, 1.1 * U), (1e-3 * U, 0.05 * U)]
        self.log_scale = [False, True]
        levels = np.r_[np.linspace(0.6 * U, 1.0 * U, 11), 1.1 * U]
        self.grid = np.array([(a, b) for a in levels for b in (k * U for k in self.knee_shares)])

    def identified(self, th):
        # a rail above every command the records reach is no rail
        return bool(th[0] < self.U)

    def refuses(self, params):
        most = self.knee_max_share * self.U
        if params["knee"] > most:
            return (f"its knee spreads over {params['knee']:.3g} V, more than a rail's {most:.3g} V: "
                    f"the top of the drive bends, not a rail")
        level = params["level"]
        if level >= (1.0 - self.top_share) * self.U:
            where = ("above every training command" if level >= self.U else
                     f"within {self.top_share:.1%} under the largest training command")
            return (f"it sits at {level:.4g} V, {where} ({self.U:.4g} V), so the training records do not "
                    f"show its flat top: the validation records judge it beside a stroke limit, beyond "
                    f"the training range")
        return None

    def transform_input(self, u, dt, th):
        L, k = float(th[0]), float(th[1])
        d = np.asarray(u, dtype=float) - L
        return L + 0.5 * (d - np.sqrt(d * d + k * k))


def library(dt, U, t_max, names=EFFECTS, y_range=(0.0, 1.0)):
    """The candidate blocks for records with step `dt` [s], max |u| `U` [V], longest
    record `t_max` [s] and measured displacements within `y_range` [µm].

    Parameters are in physical units, so the same blocks act on records
    decimated for the global search (the blocks read the records' own step).
    """
    make = {
        "creep": lambda: Creep(dt, t_max),
        "dynamics": lambda: Dynamics(dt),
        "amplifier": lambda: Amplifier(dt, U),
        "delay": lambda: Delay(dt),
        "drift": lambda: Drift(),
        "saturation": lambda: Saturation(*y_range),
        "clip": lambda: Clip(U),
    }
    out = []
    for n in names:
        if n not in make:
            raise ValueError(f"unknown effect {n!r}; choose from {', '.join(EFFECTS)}")
        out.append(make[n]())
    return out
