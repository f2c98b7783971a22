"""Closed-loop co-simulation of the PEA: compensator, hysteresis, plant, controller.

Three masters run the same fixed-step loop and give the same numbers (to
round-off; tests/test_cosim.py checks it sample by sample):

* ``"reference"`` — pure Python on the library's own steppers
  (``FONBW.stepper``, ``fonbw.compensator``, :class:`fonbw.plant.LinearStepper`,
  :class:`LoopController`);
* ``"fmpy"`` — the FMUs of :mod:`fonbw.fmu.build` (FonbwCompensator,
  FonbwHysteresis, FonbwLinearPlant) through fmpy's FMI 2 API (``FMU2Slave``:
  instantiate, setupExperiment, enter/exitInitializationMode, setReal,
  doStep, getReal); the controller runs in the master as library code;
* ``"libcosim"`` — the same FMUs plus the controller FMU FonbwPID in libcosim
  (Open Simulation Platform, through libcosimpy), an independent master.

The first two share one stepping loop over blocks with one interface
(:mod:`fonbw.loop.blocks`, :func:`fonbw.loop.masters.jacobi`); libcosim
steps with its own algorithm.

Loop (``mode``)::

    open :  r/k_lin ------------------------------> hyst -> [plant] -> y
    ff   :  r -> comp ----------------------------> hyst -> [plant] -> y
    fb   :  r, y -> ctrl -------------------------> hyst -> [plant] -> y
    ff+fb:  r -> comp -> u_ff; r, y, u_ff -> ctrl -> hyst -> [plant] -> y

``hyst`` is the "true" actuator (a FONBW model), ``comp`` the eq. (16)-(17)
inverse of the identified model, ``plant`` optional linear dynamics
(mechanics, creep; :func:`plant_system`), ``ctrl`` a PI(D) with output limits,
anti-windup and the feedforward added before the limits (:class:`LoopController`).
``k_lin`` is the model's mean slope (:func:`linear_gain`).

Convention (stated once, used by all three masters; it is libcosim's fixed-step
algorithm): **Jacobi**, every connection carries the value an output had after
the previous communication step, every block is stepped once per
communication step, and no output depends on an input set at the same
communication point (all FMUs declare ``dependencies=""``; the controller
has the one-sample computational delay of a real DAQ loop). So each
connection is a one-step delay and no loop is algebraic. Exogenous inputs
(reference, open-loop voltage) are set before the step they belong to.

Alignment: a block that is ``d`` connections upstream of the measured output
gets the reference ``d`` steps ahead (a known trajectory, fed with preview,
so the pipeline latency is not counted as tracking error: in ``ff`` without a
plant, the measured output after step k is exactly the library chain
``H(C(r_0..r_k))``). The controller compares the reference with the
measurement of the same sample: at step k it gets ``r_{k-1}`` and the output
after step k-1. The error of sample k is ``e_k = r_k - y_k``, ``y_k`` the
measured output after step k (``t_{k+1}``).

Limits: the libcosim master needs T to be a whole multiple of dt (no shorter
final step); the FMU masters load the FMUs into the calling process, so the
FMUs use that process's ``fonbw`` if it is already imported (see
fmu_src/README.md; the FMUs' own bundled copy is tested by tests/test_fmu.py).
Speed (BENCHMARKS.md, "Closed loop"): fmpy runs the 10 kHz loop faster than
real time; libcosim is about 7x slower, as it steps the Python slaves on
worker threads that must share the GIL.

Modules: :mod:`~fonbw.loop.spec` (names and defaults),
:mod:`~fonbw.loop.controller` (plant, gain, controller design),
:mod:`~fonbw.loop.wiring` (connections, steps, trace),
:mod:`~fonbw.loop.blocks` (the block interface), :mod:`~fonbw.loop.fmus`
(building and parametrizing the FMUs), :mod:`~fonbw.loop.masters`,
:mod:`~fonbw.loop.run` (:func:`run_cosim`, :class:`CosimResult`),
:mod:`~fonbw.loop.study` (feedforward / feedback study).

Units: u [V], y, r [µm], t [s].
"""
from ..signals import SCENARIOS, trajectory
from .controller import (LoopController, controller_spec, design_controller, linear_gain, loop_plant,
                         plant_system)
from .fmus import build_fmus
from .run import CosimResult, run_cosim
from .spec import BANDWIDTH_HZ, DT, MASTERS, MODES, NO_LIMIT, PLANTS, U_LIMITS, CosimError
from .study import default_truth, ff_fb_study, study_table

__all__ = [
    "MODES", "MASTERS", "PLANTS", "DT", "U_LIMITS", "NO_LIMIT", "BANDWIDTH_HZ", "CosimError",
    "SCENARIOS", "trajectory",
    "plant_system", "linear_gain", "controller_spec", "loop_plant", "design_controller",
    "LoopController", "build_fmus", "run_cosim", "CosimResult",
    "default_truth", "ff_fb_study", "study_table",
]
