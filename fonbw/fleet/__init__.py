"""Fleets of actuators and other sets of independent tasks on ``dask.distributed``.

* :func:`run_fleet` (``fonbw fleet DIR -o OUT``): identify every actuator of a
  folder (one sub-folder of records each) with the same options, one task per
  actuator, on an embedded ``LocalCluster`` or an existing cluster; write
  ``OUT/<actuator>.json``, ``OUT/fleet.csv`` and ``OUT/fleet.html``; skip the
  actuators whose model is up to date.
* :func:`identify_paths`: the identification ``fonbw identify`` and the fleet
  share (records read, burn-in, :func:`fonbw.identify.identify`, the model's
  JSON document with the digest of its records and options).
* :func:`map_tasks`: ``fn(item)`` for every item, ``(item, result)`` yielded
  as completed; the engine under the fleet, for harnesses and sweeps.

Results never depend on the number of workers or the order of completion:
each task carries everything it needs, its seed included.
"""
from __future__ import annotations

from .engine import connect, map_tasks, task_seed, worker_versions
from .fit import (FIT_OPTIONS, Fit, fit_options, identify_paths, model_bytes, model_document, read_fit,
                  records_digest, write_model)
from .run import FleetError, find_actuators, fit_actuator, run_fleet

__all__ = ["map_tasks", "connect", "task_seed", "worker_versions", "FIT_OPTIONS", "Fit", "fit_options",
           "identify_paths", "model_bytes", "model_document", "read_fit", "records_digest", "write_model",
           "FleetError", "find_actuators", "fit_actuator", "run_fleet"]
