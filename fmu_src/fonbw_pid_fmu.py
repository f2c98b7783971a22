"""FMU script: discrete PID with feedforward input, for closed-loop co-simulation.

u = sat(u_ff + PID(r - y)) with the library's controller
(fonbw.loop.LoopController around fonbw.pid.PIDStepper: derivative filter,
anti-windup that sees the saturation of the sum).  Built by
fonbw.fmu.build.build_pid_fmu (this is the controller block of the libcosim
master; the fmpy and reference masters run the same library class in the
master process).

Sampling convention (as the other fonbw FMUs, fonbw_fmu_common.py):
doStep(t, h) holds r, y, u_ff over (t, t+h], advances m = h/dt controller
samples with them, and the output at t+h is the last controller output.  So
the output does not react to inputs set at a communication point
(dependencies="", a one-sample computational delay, as a real DAQ loop has)
and closing a loop through this FMU is never algebraic.

Own module name: FMUs in one process share sys.modules.
"""
from pathlib import Path

from fonbw_fmu_common import PID_RESOURCE, FonbwSlaveBase, UReal, read_json
from pythonfmu import Fmi2Causality, Fmi2Variability


class _ControllerStepper:
    """The stepper interface FonbwSlaveBase drives (step/reset/get_state/
    set_state), with the two extra inputs read from the slave."""

    def __init__(self, slave, ctrl):
        self._slave = slave
        self._ctrl = ctrl

    def step(self, r):
        s = self._slave
        return self._ctrl.step(r, s._y_meas, s._u_ff)

    def reset(self):
        self._ctrl.reset()

    def get_state(self):
        return self._ctrl.get_state()

    def set_state(self, arr):
        self._ctrl.set_state(arr)


class FonbwPID(FonbwSlaveBase):
    description = ("Discrete PID controller with derivative filter, output limits and "
                   "anti-windup (fonbw.plant.PIDStepper), plus a feedforward input added "
                   "before the limits: u = sat(u_ff + PID(r - y)); fixed sample time dt")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        spec = read_json(Path(self.resources) / PID_RESOURCE)
        self._y_meas = 0.0
        self._u_ff = 0.0
        self._io(("r", "um", "Reference displacement, held over each communication step"),
                 ("u", "V", "Actuator voltage command sat(u_ff + PID(r - y)) at the end of "
                            "the step"))

        def set_y(v):
            self._y_meas = float(v)

        def set_uff(v):
            self._u_ff = float(v)

        self.register_variable(UReal(
            "y", unit="um", description="Measured displacement, held over each "
            "communication step", causality=Fmi2Causality.input,
            variability=Fmi2Variability.continuous, getter=lambda: self._y_meas, setter=set_y))
        self.register_variable(UReal(
            "u_ff", unit="V", description="Feedforward voltage added to the PID output "
            "before the limits (0: feedback only)", causality=Fmi2Causality.input,
            variability=Fmi2Variability.continuous, getter=lambda: self._u_ff, setter=set_uff))
        for name, unit, desc in (
                ("kp", "V/um", "Proportional gain"),
                ("ki", "V/(um.s)", "Integral gain"),
                ("kd", "V.s/um", "Derivative gain"),
                ("Tf", "s", "Derivative filter time constant"),
                ("Tt", "s", "Tracking time constant of the back-calculation anti-windup"),
                ("u_min", "V", "Lower output limit (use -1e300 for none)"),
                ("u_max", "V", "Upper output limit (use 1e300 for none)")):
            self._parameter(name, float(spec[name]), unit, desc)
        self._parameter("dt", float(spec["dt"]), "s",
                        "Controller sample time; every communication step must be a whole "
                        "multiple of it")
        self._string_parameter("integrator", spec["integrator"],
                               "Discretization of the integral: forward, backward or tustin")
        self._string_parameter("anti_windup", spec["anti_windup"],
                               "Anti-windup: back-calculation, clamping or none")
        self._default_experiment()

    def _build(self):
        from fonbw.loop.controller import LoopController  # bundled copy
        ctrl = LoopController(dict(kp=self.kp, ki=self.ki, kd=self.kd, Tf=self.Tf, Tt=self.Tt,
                                   u_min=self.u_min, u_max=self.u_max, dt=self.dt,
                                   integrator=self.integrator, anti_windup=self.anti_windup))
        return _ControllerStepper(self, ctrl)
