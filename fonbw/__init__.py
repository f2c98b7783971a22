"""fonbw — fractional-order normalized Bouc-Wen hysteresis of piezoelectric actuators.

Equation numbers refer to Kang et al., "A Fractional-Order Normalized Bouc-Wen
Model for Piezoelectric Hysteresis Nonlinearity" (the paper in shared/paper).
"""
__version__ = "0.1.0"
