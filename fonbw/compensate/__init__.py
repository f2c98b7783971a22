"""Feedforward hysteresis compensation by the inverse multiplicative structure.

The paper's compensator (eqs. 16–17) gets the voltage from the desired
displacement H_d without inverting the model:

    u(t) = (H_d(t) − G(u, t)) / k_u1,
    G(u, t) = k_h ħ(t) + k_u2 u² + … + k_uN u^N .

G depends on the *current* u (through the polynomial and through ħ, which
eq. (11) ties to D^λ1 u at the same instant), so eq. (16) is implicit at every
step. With the model discretized as in :mod:`fonbw.hysteresis` it is exactly

    find u_k in [u_min, u_max] with H(u_k; history up to k−1) = H_d,k ,

a scalar root find on the model's own step function. Each step here evaluates
the model's compiled step with ``commit=False`` inside a safeguarded root
finder (secant from the previous voltage with the previous local slope;
Brent's method as soon as a sign change brackets the root; a bracket over the
whole voltage range as the fallback), then commits one step with the root.
Model and compensator therefore share their numerics (memory engine
included), and the model driven by the compensator's voltage reproduces H_d
to the solver tolerance.

The same per-step inversion serves CBW (eq. 21: u = (H_d − k_b D ĥ)/k_a,
implicit in ĥ for the same reason) and the model of Zhu et al. (eq. 22).

Zhu et al., eq. (22)
    As written, eq. (22) divides by (k1/τ) e^(−t/τ): the direct input term of
    eq. (20) decays with absolute time (τ ≈ 2e-5 s in Table 1), so after a
    few τ the division is by a number that underflows to zero and eq. (22)
    gives u → ∞. What actually carries u into the output after that is the
    Bouc-Wen state h (through A u̇ and δ u sgn u̇). Two honest readings:

    ``form="discrete"`` (default)
        the per-step inversion of the discrete model, x_k as a function of
        u_k with the mechanics included, as for every other kind: model ∘
        compensator = identity. Its one-step authority is small (the force
        reaches x_k through the mechanics' Γ, about dt²/(2 m0) for light
        damping), and it is greedy: one out-of-reach sample (an x0 offset at
        t = 0, say) can park u on a limit where the rate-independent h no
        longer moves. On the Zhu model identified from the virtual bench it
        does exactly that.
    ``form="eq22"``
        eq. (22) made implicit: the mechanics are inverted on H_d (backward
        differences for Ḣd, Ḧd) and the force balance
        (k1/τ)e^(−t_k/τ) u_k + ĥ_k(u_k) = m0 Ḧd + c0 Ḣd + k0 (H_d − x0)
        is solved per step for u_k. That is the compensator Table 4 compares.

Invertibility
    The per-step inverse exists and is stable when the model's step map
    u_k ↦ H_k has the sign of its quasi-static gain. For FONBW with k_h ρ < 0
    and λ1 > λ2 — the paper's Table 1 set, and what identification finds on
    the virtual bench — the one-step slope k_u1 + k_h ρ dt^(λ2−λ1) (small ħ)
    is negative at 10 kHz: a step in u first moves H the wrong way, the
    linearization has a right-half-plane zero, and the exact inverse is
    unstable. The solver then does what it can (chatters, saturates, or
    reports samples without a root) and says so in the status; it does not
    hide it. With the paper's Table 1 set the 5-Hz trajectory saturates at
    0 V from the second sample on. :func:`compensate` and
    :class:`Compensator` warn (RuntimeWarning) when the model is not
    invertible at their step (:func:`fonbw.invertibility.check_invertible`).
    Two ways out: identify under the constraint
    (``fonbw.identify(..., for_compensation=dt)``), or, for a trajectory
    known ahead, the non-causal stable inversion ``compensate(...,
    preview=True)`` (:mod:`fonbw.compensate.preview`), which gives a bounded,
    smooth voltage for any model; it starts the voltage ahead of the
    trajectory (``CompensationResult.u_lead``, drive with ``u_full``).

Explicit (one-step-delayed) variant
    ``explicit=True`` evaluates G with the previous voltage and the previous
    hysteretic state, u_k = (H_d,k − k_h ħ_(k−1) − Σ_(i≥2) k_ui u_(k−1)^i)/k_u1
    (CBW: u_k = (H_d,k − k_b D h_(k−1))/k_a), which is how a block diagram
    with a unit delay in the loop of Fig. 5 would run. It tracks less well;
    offered for comparison only. Not defined for Zhu2016 (see above).

Start
    A compensation runs from the model's recorded start: a model identified
    after a rest cycle (``meta["start"]``, :mod:`fonbw.compensate.rest`) is
    run through that cycle before t = 0 and its output is counted from the
    end of it, as a stage's sensor is zeroed at rest after a previous cycle.
    From its virgin state instead, an identified FONBW's descending branch
    stays above that zero at the lowest voltage, and the bottom of a
    trajectory that returns to 0 µm is out of reach (``history=()`` runs
    from the virgin state). The Zhu model's eq.-22 form is the exception: its
    force balance is written on H_d's derivatives from rest, so it warns and
    runs from rest. The same start is run wherever the model runs
    sample by sample or against a record: the hysteresis and compensator FMUs
    (pythonfmu and native), the closed loop's actuator
    (:func:`fonbw.compensate.rest.started_stepper`) and
    :func:`fonbw.objective.simulate_record` (``fonbw validate``).

Voltage limits default to the model's training input range (stored at
identification as ``u_range``), else the paper's amplifier range 0–120 V. A sample
whose H_d cannot be reached within the limits gets the limit nearer to the
solution and is reported as saturated; a sample whose equation has no root
the solver can find (a jump of the model's step map, e.g. the δ u sgn u̇ term
of eq. 20 at u̇ = 0) gets the voltage of smallest residual and is reported as
not converged.

Units: u [V], H_d and outputs [µm], dt and t [s].
"""
from .causal import (DEFAULT_LIMITS, DEFAULT_TOL, CompensationResult, Compensator, check_model, compensate,  # noqa: F401
                     compensate_file, compensator, default_limits)
from .preview import compensate_preview, small_signal_response  # noqa: F401
from .kernels import NOT_CONVERGED, OK, SAT_HIGH, SAT_LOW  # noqa: F401

__all__ = ["compensate", "compensate_preview", "compensator", "Compensator", "CompensationResult",
           "compensate_file", "default_limits", "small_signal_response", "DEFAULT_LIMITS",
           "DEFAULT_TOL", "OK", "SAT_LOW", "SAT_HIGH", "NOT_CONVERGED"]
