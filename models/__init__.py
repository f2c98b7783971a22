"""Default parameter sets, installed with the library as ``fonbw.data``.

``DEFAULT_MODEL`` is the FONBW set the FMUs, the closed loop and the truth of
the blind harness start from; ``DEFAULT_PLANT`` the linear plant of the plant
FMU. Both are JSON files beside this module, so a wheel install carries them.
"""
from pathlib import Path

_HERE = Path(__file__).resolve().parent

#: FONBW parameter set (JSON, kind "fonbw").
DEFAULT_MODEL = _HERE / "fonbw_default.json"
#: Linear plant of the plant FMU (JSON, kind "linear_plant").
DEFAULT_PLANT = _HERE / "plant_default.json"
