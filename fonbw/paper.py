"""The paper's published numbers, each written once.

Everything here is quoted from the paper (Kang et al., the FONBW model): the
identified parameter set of its Table 1, the literature counts of Table 2, the
compensation results of Table 4, and the setup those numbers belong to (the
10 kHz sampling, the validation frequencies, the amplifier's 0-120 V range).
Code that reproduces a table or needs "the paper's" default reads it from here.
"""
from __future__ import annotations

__all__ = ["FS", "SINE_FREQS", "U_RANGE", "TABLE1_FONBW", "PAPER_TABLE2", "PAPER_TABLE4", "table1_model"]

#: Sampling frequency of the paper's setup [Hz].
FS = 10_000.0

#: Validation frequencies of the paper's Table 3 [Hz].
SINE_FREQS = (1.0, 5.0, 10.0, 15.0, 20.0)

#: Voltage range of the paper's amplifier [V]: the unipolar default of the bench,
#: its inputs and the closed loop's controller.
U_RANGE = (0.0, 120.0)

#: FONBW parameters identified in the paper's Table 1 (u in V, displacement in µm).
TABLE1_FONBW = dict(ku=[0.1811, -1.4037e-4, -7.7154e-8], kh=-3.2719e4, rho=6.4808e-7,
                    sigma=1.3039e5, n=2.0006, lam1=0.9557, lam2=0.6220)

#: The paper's Table 2: (model, kind of hysteresis it describes, number of parameters).
PAPER_TABLE2 = [
    ("Wang et al.", "asymmetric", 6), ("Zhu et al. (2012)", "asymmetric", 7), ("Habineza et al.", "asymmetric", 8),
    ("Li et al.", "asymmetric / rate-dependent", 22), ("Zhu et al. (2016), eq. (20)", "asymmetric / rate-dependent", 11),
    ("FONBW (proposed)", "asymmetric / rate-dependent", 9),
]

#: The paper's Table 4: (compensator, trajectory, RMS error [µm], RMS input [V]).
PAPER_TABLE4 = (
    ("FONBW", "5-Hz", 0.22, 41.09), ("FONBW", "Multi-freq.", 0.16, 24.54),
    ("CBW", "5-Hz", 0.33, 43.15), ("CBW", "Multi-freq.", 0.36, 29.32),
    ("Zhu", "5-Hz", 0.27, 44.66), ("Zhu", "Multi-freq.", 0.26, 30.45),
)


def table1_model(memory: str = "fast"):
    """The paper's Table 1 FONBW as a :class:`fonbw.FONBW` with the given memory engine."""
    from .hysteresis import FONBW
    return FONBW(**TABLE1_FONBW, memory=memory)
