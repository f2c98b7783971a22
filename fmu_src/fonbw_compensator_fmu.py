"""FMU script: inverse (compensator) of the FONBW hysteresis, y_ref [um] -> u [V].

A thin pythonfmu wrapper over fonbw.compensator(model, dt) (eqs. 16-17); see
fonbw_fmu_common.py for the sampling convention, the FMU state and why nothing
here raises.  Own module name: FMUs in one process share sys.modules.
"""
from fonbw_fmu_common import FonbwModelSlave
from pythonfmu import Fmi2Causality, Fmi2Variability, Integer
from pythonfmu.enums import Fmi2Initial, Fmi2Status

# fonbw.compensate per-sample status codes (OK, SAT_LOW, SAT_HIGH, NOT_CONVERGED)
_STATUS = {1: "saturated at u_min", 2: "saturated at u_max", 3: "not converged"}


class FonbwCompensator(FonbwModelSlave):
    description = ("Feedforward hysteresis compensator built on the inverse of the "
                   "fractional-order normalized Bouc-Wen model (FONBW): desired displacement "
                   "y_ref [um] in, actuator voltage u [V] out, fixed internal step dt")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._io(("y_ref", "um", "Desired actuator displacement, held constant over each "
                                 "communication step"),
                 ("u", "V", "Compensating actuator voltage at the end of the step"))
        res = self._register_fonbw_parameters()
        lo, hi = res.get("limits", (0.0, 120.0))
        self._parameter("u_min", lo, "V", "Lower voltage limit of the compensator (amplifier "
                                          "range); unreachable targets saturate here")
        self._parameter("u_max", hi, "V", "Upper voltage limit of the compensator (amplifier "
                                          "range); unreachable targets saturate here")
        self.register_variable(Integer(
            "status", description="Compensator status of the last internal step: 0 ok, "
            "1 saturated at u_min, 2 saturated at u_max (y_ref unreachable within the "
            "limits), 3 solver not converged", causality=Fmi2Causality.output,
            variability=Fmi2Variability.discrete, initial=Fmi2Initial.calculated,
            getter=lambda: 0 if self._stepper is None else int(self._stepper.status)))
        self._bad_before = False  # throttles the saturation warning to episode starts
        self._default_experiment()

    def do_step(self, current_time: float, step_size: float) -> bool:
        s = self._stepper
        n0 = (s.n_saturated + s.n_not_converged) if s is not None else 0
        ok = super().do_step(current_time, step_size)
        s = self._stepper
        if ok and s is not None:
            bad = s.n_saturated + s.n_not_converged > n0
            if bad and not self._bad_before:
                self.log(f"{self.instance_name}: at t={current_time!r} y_ref={self._x_in!r} um: "
                         f"{_STATUS.get(int(s.status), 'saturated or not converged')} "
                         f"(u = {self._x_out!r} V); further samples of this episode are "
                         f"not logged, see the status output", Fmi2Status.warning)
            self._bad_before = bad
        return ok

    def _build(self):
        import fonbw  # bundled copy
        return fonbw.compensator(self._fonbw_model(), self.dt, limits=(self.u_min, self.u_max))
