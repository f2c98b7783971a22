"""Build the FMI 2.0 co-simulation FMUs of a model.

Writes FonbwHysteresis.fmu (u [V] -> y [µm]), FonbwCompensator.fmu
(y_ref [µm] -> u [V]) and FonbwLinearPlant.fmu into DIR, each checked by
fmpy's validator. Works from any directory: everything it needs is installed
with the library.
"""
from __future__ import annotations


def add_arguments(p) -> None:
    from ..fmu.build import add_arguments as builder_arguments

    builder_arguments(p)


def run(ns) -> None:
    from ..fmu.build import run as build_run

    build_run(ns)
