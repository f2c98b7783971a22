"""Build the fonbw FMUs: ``python build_fmu.py [--params MODEL.json] [--plant PLANT.json] [-o DIR]``.

A thin front door over the library's builder (:mod:`fonbw.fmu.build`, also
``fonbw build-fmu``), for a clone of the repository.
"""
import sys

from fonbw.fmu.build import main

if __name__ == "__main__":
    sys.exit(main())
