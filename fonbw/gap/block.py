"""The base class of the diagnosis's candidate effect blocks: what each block
declares (its parameters, the form it takes in the joint refit, the checks
that judge it) and the defaults. The blocks are in :mod:`fonbw.gap.effects`
and, the two that act at the top of the range, :mod:`fonbw.gap.limits`.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["Effect"]


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
    """

    name = "none"
    names: tuple = ()
    lin_names: tuple = ()
    units: dict = {}
    input_side = False
    filtered_columns = True
    output_nonlinear = False
    #: An operator on the output (:meth:`output_op`, a resonance): an output
    #: limit acts ahead of it (:mod:`fonbw.gap.prelimit`).
    output_linear = False
    compressive = False
    c_min = -math.inf
    lin_nonneg = False
    lag = False
    edges_left_most: float | None = None
    edges_who = ""
    transport_delay = False
    range_limit = False
    overruled_by: str | None = None
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

    def lag_s(self, th) -> float | None:
        """The lag [s] parameters `th` put on a slow sine (the phase over ω as
        ω → 0) for a lag block; None for a block that is none."""
        return None

    def refusal_waived_beside(self, accepted) -> bool:
        """Whether :meth:`refuses` is waived at a later greedy step beside the
        effect blocks `accepted` before it, when this block's fit alone on the
        nominal passed it: where its refused parameter trades with one of
        theirs (:func:`fonbw.gap.greedy._refused`). By default a refusal
        judges what the block is and holds at every step."""
        return False

    def refuses(self, params) -> str | None:
        """Why fitted `params` (:meth:`describe`) are not this block's effect
        but something it imitates, in words; None when they are its own.

        A candidate refused this way fails its checks, however much it closes
        (:meth:`identified` only ranks it behind a competing block), unless
        its :attr:`overruled_by` block passes beside it and closes less.
        """
        return None

    def lin_names_on(self, core: str) -> tuple:
        """The linear parameters the block has on the nominal `core`
        ("fonbw" or "reference"): all of :attr:`lin_names` unless a block says otherwise."""
        return self.lin_names

    def describe(self, th, lin, core: str = "fonbw") -> dict:
        """Parameters by name (nonlinear then linear, those of the nominal `core`) as plain floats."""
        d = {k: float(v) for k, v in zip(self.names, th)}
        d.update({k: float(v) for k, v in zip(self.lin_names_on(core), lin)})
        return d
