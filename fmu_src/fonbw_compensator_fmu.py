"""FMU script: inverse (compensator) of the FONBW hysteresis, y_ref [um] -> u [V].

A thin pythonfmu wrapper over fonbw.compensator(model, dt) (eqs. 16-17); see
fonbw_fmu_common.py for the sampling convention, the FMU state and why nothing
here raises.  Own module name: FMUs in one process share sys.modules.
"""
from fonbw_fmu_common import FonbwModelSlave


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
        self._default_experiment()

    def _build(self):
        import fonbw  # bundled copy
        return fonbw.compensator(self._fonbw_model(), self.dt, limits=(self.u_min, self.u_max))
