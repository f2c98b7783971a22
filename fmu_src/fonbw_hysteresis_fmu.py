"""FMU script: FONBW hysteresis of a piezo actuator, u [V] -> y [um].

A thin pythonfmu wrapper over fonbw.FONBW(...).stepper(dt); see
fonbw_fmu_common.py for the sampling convention, the FMU state and why nothing
here raises.  The module name is unique among the fonbw FMUs on purpose: all
FMUs loaded into one process share one Python interpreter and sys.modules.
"""
from fonbw_fmu_common import FonbwModelSlave


class FonbwHysteresis(FonbwModelSlave):
    description = ("Rate-dependent asymmetric hysteresis of a piezoelectric actuator: "
                   "fractional-order normalized Bouc-Wen model (FONBW), input voltage u [V], "
                   "output displacement y [um], fixed internal step dt")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._io(("u", "V", "Actuator input voltage, held constant over each communication step"),
                 ("y", "um", "Actuator displacement y = g(u) + kh*h at the end of the step"))
        self._register_fonbw_parameters()
        self._default_experiment()

    def _build(self):
        from fonbw.compensate.rest import started_stepper  # bundled copy
        return started_stepper(self._fonbw_model(), self.dt)
