"""FMU script: linear time-invariant plant (python-control state space), SISO.

Output convention: y(t) = C x(t) + D u(t) read live from the stepper, so the
output at t+h is the exact zero-order-hold response at the end of the step
(fmpy's result then equals control.forced_response of the c2d system sample
for sample) and a plant with D != 0 declares its direct feedthrough.

The matrices ride in resources/fonbw_plant.json (written by build_fmu.py from a
control.StateSpace); the stepping is fonbw.plant.LinearStepper.  Input and
output names, units and descriptions come from that file too.  Own module
name: FMUs in one process share sys.modules.
"""
import math
from pathlib import Path

from fonbw_fmu_common import FonbwSlaveBase, PLANT_RESOURCE, read_json


class FonbwLinearPlant(FonbwSlaveBase):
    description = ("Linear time-invariant plant x' = Ax + Bu, y = Cx + Du (or its discrete "
                   "counterpart) from a python-control state-space system, stepped with a "
                   "fixed internal step dt by fonbw.plant.LinearStepper")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        spec = read_json(Path(self.resources) / PLANT_RESOURCE)
        self._spec = spec
        i, o = spec["input"], spec["output"]
        self._io((i["name"], i.get("unit"), i.get("description", "Plant input")),
                 (o["name"], o.get("unit"), o.get("description", "Plant output")))
        self._parameter("dt", float(spec.get("dt") or spec.get("sys_dt") or 1e-4), "s",
                        "Internal fixed step; a continuous-time plant is discretized with it "
                        "(zero-order hold); every communication step must be a whole "
                        "multiple of it")
        self._default_experiment()
        # y = C x + D u: a nonzero D is a direct feedthrough at communication points
        self._feedthrough = any(float(d) != 0.0 for row in spec["D"] for d in row)

    def _output(self) -> float:
        # Exact zero-order-hold output at the communication point: C x(t) + D u(t)
        # with the state after the last step and the input as currently set.
        s = self._stepper
        return 0.0 if s is None else s.output(self._x_in)

    def _check_parameters(self):
        sys_dt = self._spec.get("sys_dt")
        if sys_dt and not math.isclose(self.dt, sys_dt, rel_tol=1e-12):
            return [f"dt = {self.dt!r} s differs from the sampling time {sys_dt!r} s "
                    f"of the discrete-time plant"]
        return []

    def _build(self):
        import control
        import numpy as np
        from fonbw.plant import LinearStepper  # bundled copy
        s = self._spec
        mats = [np.array(s[k], dtype=float).reshape(s["shape"][k]) for k in "ABCD"]
        sys = control.ss(*mats, s["sys_dt"]) if s.get("sys_dt") else control.ss(*mats)
        return LinearStepper(sys, self.dt)
