"""The closed loop's vocabulary and defaults: modes, masters, plants, the
communication step, the controller's limits and crossover, and the error a
run reports.

Units: [s], [V], [Hz].
"""
from __future__ import annotations

from ..paper import U_RANGE

__all__ = ["MODES", "MASTERS", "PLANTS", "DT", "U_LIMITS", "NO_LIMIT", "BANDWIDTH_HZ",
           "CONVENTION", "CosimError"]

#: Loop structures: uncompensated, feedforward, feedback, both.
MODES = ("open", "ff", "fb", "ff+fb")
#: Who steps the blocks: library code in Python, fmpy's FMI 2 API, libcosim.
MASTERS = ("reference", "fmpy", "libcosim")
#: Linear dynamics after the actuator (:func:`fonbw.loop.plant_system`).
PLANTS = ("none", "dynamics", "creep", "dynamics+creep")
#: Communication step = sample time of every block [s] (10 kHz).
DT = 1e-4
#: Output limits of the controller [V] (the amplifier's 0-120 V range).
U_LIMITS = U_RANGE
#: Stand-in for "no limit" in the controller's limits (FMU parameters must be finite).
NO_LIMIT = 1e300
#: Default crossover of the feedback loop [Hz] (see :func:`fonbw.loop.design_controller`).
BANDWIDTH_HZ = 100.0
#: The coupling every master uses, as recorded in a run's configuration.
CONVENTION = ("Jacobi, one-step delay per connection, no direct feedthrough; "
              "reference fed d steps ahead to a block d connections upstream "
              "of the measured output; controller sees r_{k-1}, y_{k-1}")


class CosimError(ValueError):
    """The co-simulation could not run: bad or refused FMU, missing dependency,
    a run stopped by a block (a ValueError, so the CLI reports it in one line)."""
