"""The pythonfmu slave scripts of the fonbw FMUs, installed as ``fonbw.fmu.slaves``.

They are data for the builder (:mod:`fonbw.fmu.build` hands each script to
pythonfmu), not modules to import: each FMU imports its script and
``fonbw_fmu_common`` as top-level modules from its own resources folder.
"""
from pathlib import Path

#: Folder holding the slave scripts.
SLAVES_DIR = Path(__file__).resolve().parent
