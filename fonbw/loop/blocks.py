"""The blocks of the loop behind one interface, whoever implements them.

A block is stepped like an FMI 2 co-simulation slave, so one stepping loop
(:func:`fonbw.loop.masters.jacobi`) drives library code and FMUs alike:

``set_inputs(values)``
    the inputs for the coming step, in the order of :data:`fonbw.loop.wiring.IO`;
``do_step(t, h)``
    advance from t to t + h [s]; returns None, or why the block refused the
    step (the loop stops there);
``get_output()``
    the output after the last step (before the first: the initial output);
``close()``
    free what the block holds.

:class:`LibraryBlock` wraps the library's own steppers (the reference master,
and the controller of the fmpy master); :class:`FmpyBlock` is one FMU
instance through fmpy's ``FMU2Slave``.

Units: u [V], y, r [µm], t, h [s].
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import control as ct

from .. import plant as _plant
from ..compensate import compensator
from ..compensate.rest import started_stepper
from .controller import LoopController
from .spec import CosimError
from .wiring import whole_multiple

__all__ = ["LibraryBlock", "library_block", "FmpyBlock", "unzip"]


class LibraryBlock:
    """A library stepper as a block: ``step(*inputs) -> output`` once per
    sample of `dt` [s].

    A communication step h other than dt must be a whole multiple of it (the
    FMUs' rule); the block then takes h/dt samples with the same inputs.

    Attributes
    ----------
    stepper : object
        The wrapped library object (its counters, e.g. the compensator's
        saturated samples, are read after the run).
    """

    def __init__(self, name, step, dt, stepper=None):
        self.name, self.dt, self.stepper = name, dt, stepper
        self._step = step
        self._in = ()
        self._out = 0.0

    def set_inputs(self, values) -> None:
        self._in = values

    def do_step(self, t, h):
        if h == self.dt:
            self._out = self._step(*self._in)
            return None
        ok, m = whole_multiple(h, self.dt)
        if not ok:
            return (f"block {self.name!r} refused the communication step {h!r} s: not a whole "
                    f"multiple of its step dt = {self.dt!r} s")
        for _ in range(m):
            self._out = self._step(*self._in)
        return None

    def get_output(self) -> float:
        return self._out

    def close(self) -> None:
        pass


def library_block(role, cfg, dt) -> LibraryBlock:
    """The library's stepper for `role` (``hyst``, ``comp``, ``ctrl``,
    ``plant``) from a run's configuration `cfg`, at step `dt` [s]."""
    if role == "hyst":
        st = started_stepper(cfg["truth"], dt)
        return LibraryBlock(role, st.step, dt, st)
    if role == "comp":
        c = compensator(cfg["model"], dt)
        return LibraryBlock(role, c.step, dt, c)
    if role == "ctrl":
        lc = LoopController(cfg["controller"])
        return LibraryBlock(role, lc.step, lc.dt, lc)
    ls = _plant.LinearStepper(ct.ss(*cfg["plant_mats"]), dt)

    def step(h):
        ls.step(h)
        return ls.output(h)

    return LibraryBlock(role, step, dt, ls)


class FmpyBlock:
    """One FMU instance stepped through fmpy's FMU2Slave, with preallocated
    ctypes buffers (the per-step calls are fmi2SetReal/DoStep/GetReal).

    Parameters
    ----------
    role : str
        Instance name and block role.
    fmu, unzip_dir : path
        The FMU and its extraction folder (:func:`unzip`).
    params : dict
        Parameter values set during initialization (name -> float or str).
    in_names, out_name
        The FMU variables the loop connects (a plant FMU uses its own first
        input and output instead).
    """

    def __init__(self, role, fmu, unzip_dir, params, in_names, out_name):
        from fmpy import read_model_description

        md = read_model_description(str(fmu))
        self.name, self.identifier = role, md.coSimulation.modelIdentifier
        self.logs = []  # (status, message) from the FMU's logger
        vr = {v.name: v for v in md.modelVariables}
        if role == "plant":  # any SISO plant FMU: its own variable names
            in_names = [v.name for v in md.modelVariables if v.causality == "input"][:1]
            out_name = [v.name for v in md.modelVariables if v.causality == "output"][0]
        for nm in list(in_names) + [out_name]:
            if nm not in vr:
                raise CosimError(f"{fmu}: no variable {nm!r} (has {', '.join(vr)})")
        kus = [n for n in vr if n.startswith("ku") and n[2:].isdigit()]
        if role in ("hyst", "comp"):
            want = [k for k in params if k.startswith("ku")]
            if len(want) != len(kus):
                raise CosimError(f"{fmu} has {len(kus)} polynomial coefficients, the model {len(want)}")
        self._instantiate(md, unzip_dir)
        try:
            self._initialize(fmu, vr, params)
        except Exception:
            self.close()  # not yet known to the caller: free it here
            raise
        self._buffers(vr, in_names, out_name)

    def _instantiate(self, md, unzip_dir):
        from fmpy.fmi1 import calloc, free
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

        def log(env, inst, status, cat, msg):
            self.logs.append((int(status), msg.decode(errors="replace") if msg else ""))

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(log)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._cb = cb  # keep the callbacks alive as long as the instance
        s = FMU2Slave(guid=md.guid, unzipDirectory=str(unzip_dir), modelIdentifier=self.identifier,
                      instanceName=self.name)
        s.instantiate(callbacks=cb, loggingOn=True)
        self.slave = s

    def _initialize(self, fmu, vr, params):
        s = self.slave
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        for k, v in params.items():
            if k not in vr:
                raise CosimError(f"{fmu}: no parameter {k!r}")
            if isinstance(v, str):
                s.setString([vr[k].valueReference], [v])
            else:
                s.setReal([vr[k].valueReference], [float(v)])
        s.exitInitializationMode()

    def _buffers(self, vr, in_names, out_name):
        from fmpy.fmi1 import FMICallException
        from fmpy.fmi2 import fmi2Real, fmi2ValueReference

        n = len(in_names)
        self._ivr = (fmi2ValueReference * n)(*[vr[x].valueReference for x in in_names])
        self._ival = (fmi2Real * n)()
        self._ovr = (fmi2ValueReference * 1)(vr[out_name].valueReference)
        self._oval = (fmi2Real * 1)()
        self._n = n
        # the fmi2 functions themselves: the loop calls them every step
        s = self.slave
        self._set, self._get, self._do, self._c = s.fmi2SetReal, s.fmi2GetReal, s.fmi2DoStep, s.component
        self._call_error = FMICallException

    def set_inputs(self, values) -> None:
        self._ival[:] = values
        self._set(self._c, self._ivr, self._n, self._ival)

    def do_step(self, t, h):
        try:
            self._do(self._c, t, h, 1)
        except self._call_error as e:
            msgs = "; ".join(m for _, m in self.logs) or "no log message"
            label = {2: "fmi2Discard", 3: "fmi2Error", 4: "fmi2Fatal"}.get(e.status, str(e.status))
            return (f"FMU {self.identifier} (instance {self.name!r}) returned {label} from "
                    f"fmi2DoStep: {msgs}")
        return None

    def get_output(self) -> float:
        self._get(self._c, self._ovr, 1, self._oval)
        return self._oval[0]

    def close(self) -> None:
        try:
            self.slave.terminate()
        except Exception:  # a failed instance may refuse terminate; free it anyway
            pass
        self.slave.freeInstance()


def unzip(fmu: Path) -> Path:
    """Extract `fmu` once next to it and reuse the folder while the FMU is
    unchanged (numba's cache then lives there across runs).

    Several processes may share the folder (two runs of the loop, a demo and a
    test): each extracts into a temporary folder beside it and renames that
    into place, so no process ever sees, or deletes, a half-extracted copy.
    """
    from fmpy import extract

    d = fmu.with_suffix(".unzipped")
    key = f"{fmu.stat().st_mtime_ns}-{fmu.stat().st_size}"
    if _stamped(d, key):
        return d
    tmp = Path(tempfile.mkdtemp(dir=fmu.parent, prefix=d.name + "."))
    extract(str(fmu), str(tmp))
    (tmp / ".fonbw-stamp").write_text(key)
    if d.exists():
        if _stamped(d, key):  # another process finished first
            shutil.rmtree(tmp, ignore_errors=True)
            return d
        stale = Path(tempfile.mkdtemp(dir=fmu.parent, prefix=d.name + ".stale."))
        os.replace(d, stale / "old")  # a copy of an older build of the FMU
        shutil.rmtree(stale, ignore_errors=True)
    try:
        os.rename(tmp, d)
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        if not _stamped(d, key):
            raise
    return d


def _stamped(d: Path, key: str) -> bool:
    stamp = d / ".fonbw-stamp"
    try:
        return stamp.read_text() == key
    except OSError:
        return False
