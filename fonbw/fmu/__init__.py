"""FMI 2.0 co-simulation FMUs of the library: building them (:mod:`.build`).

Numerics never import this package; it imports the numerics.
"""
