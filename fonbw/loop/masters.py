"""The three masters: who steps the blocks, and how.

``"reference"`` and ``"fmpy"`` differ only in what the blocks are
(:mod:`fonbw.loop.blocks`): library steppers, or FMUs through fmpy's FMI 2 API
with the controller as library code. One stepping loop, :func:`jacobi`, runs
both. ``"libcosim"`` hands the FMUs (the controller too, as the FonbwPID FMU)
to libcosim's own fixed-step algorithm, an independent implementation of the
same convention. The FMUs are the pythonfmu ones or, with ``native``, the C
ones of :mod:`fonbw.fmu.native` (FonbwPIDNative as libcosim's controller):
the masters take whatever :func:`fonbw.loop.fmus.build_fmus` built.

Every master returns a :class:`Stepped`.

Units: u [V], y, r [µm], t [s].
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

from .blocks import FmpyBlock, library_block, unzip
from .fmus import fmu_settings
from .spec import CosimError
from .wiring import IO

__all__ = ["Stepped", "jacobi", "run_master"]


class Stepped(NamedTuple):
    """What a master hands back: the trace (:meth:`fonbw.loop.wiring.Wiring.trace`),
    why it stopped early (or None), the stepping loop's wall and process CPU
    time [s], the setup time [s] (instantiation, initialization) and
    per-block diagnostics."""

    trace: dict
    error: str | None
    wall_s: float
    cpu_s: float
    setup_s: float
    diagnostics: dict


def jacobi(w, blocks, n, rest, dt):
    """Step `blocks` ({role: block}) over `n` steps of `dt` [s] and a final
    step of `rest` [s] if nonzero, Jacobi-coupled as `w` (a
    :class:`~fonbw.loop.wiring.Wiring`) connects them.

    Every block's inputs are set from the outputs after the previous step
    (or the exogenous sequences), then every block is stepped, then the
    outputs are read. A refused step stops the loop; the trace keeps the
    steps before it.

    Returns
    -------
    (trace, error, wall_s, cpu_s)
    """
    order = w.blocks
    pos = {b: j for j, b in enumerate(order)}
    ext = {key: arr.tolist() for key, arr in w.ext.items()}  # Python floats: cheaper per sample
    # per block: (block, [(exogenous sequence or None, position of the source block)])
    plan = [(blocks[b], [(ext[s[1]], -1) if s[0] == "ext" else (None, pos[s[1]])
                         for _, s in w.inputs(b)]) for b in order]
    blks = [blocks[b] for b in order]
    outs = [blk.get_output() for blk in blks]
    rec = [[] for _ in order]
    error = None
    k = -1
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n + (1 if rest else 0)):
        h = dt if k < n else rest
        t = k * dt
        # Jacobi: every block's inputs from the outputs after the previous step
        for blk, srcs in plan:
            blk.set_inputs([seq[k] if seq is not None else outs[sp] for seq, sp in srcs])
        for blk in blks:
            refused = blk.do_step(t, h)
            if refused is not None:
                error = f"co-simulation stopped at t={t!r} s (step {k}): {refused}"
                break
        if error:
            break
        for j, blk in enumerate(blks):
            v = blk.get_output()
            outs[j] = v
            rec[j].append(v)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    k_done = k if error else k + 1
    return w.trace(dict(zip(order, rec)), k_done), error, wall, cpu


def _fmpy_block(role, w, cfg):
    if role == "ctrl":  # the controller runs in the master as library code
        return library_block(role, cfg, cfg["dt"])
    fmu = Path(cfg["fmus"][role])
    return FmpyBlock(role, fmu, unzip(fmu), fmu_settings(role, cfg), [x for x, _ in w.inputs(role)],
                     IO[role][1])


def _run_blocks(make_block, w, cfg, n, rest, dt) -> Stepped:
    """Make the blocks (timed as setup), run :func:`jacobi`, close them."""
    blocks = {}
    t_setup = time.perf_counter()
    try:
        for b in w.blocks:
            blocks[b] = make_block(b)
        setup = time.perf_counter() - t_setup
        trace, error, wall, cpu = jacobi(w, blocks, n, rest, dt)
    finally:
        for blk in blocks.values():
            blk.close()
    diagnostics = {}
    comp = getattr(blocks.get("comp"), "stepper", None)
    if comp is not None:  # the library compensator: why a feedforward may fail
        diagnostics["compensator"] = {"saturated_samples": int(comp.n_saturated),
                                      "unconverged_samples": int(comp.n_not_converged)}
    return Stepped(trace, error, wall, cpu, setup, diagnostics)


def _run_reference(w, cfg, n, rest, dt) -> Stepped:
    return _run_blocks(lambda b: library_block(b, cfg, dt), w, cfg, n, rest, dt)


def _run_fmpy(w, cfg, n, rest, dt) -> Stepped:
    return _run_blocks(lambda b: _fmpy_block(b, w, cfg), w, cfg, n, rest, dt)


def _libcosim_setup(w, cfg, dt):
    """A libcosim execution with the loop's FMUs, parameters and connections;
    returns (execution, override manipulator, last-value observer,
    [(slave, reference, exogenous sequence)], [(block, slave, output reference)])."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave
    from libcosimpy._internal import get_last_error_message

    ex = CosimExecution.from_step_size(round(dt * 1e9))
    idx, vr = {}, {}
    for b in w.blocks:
        idx[b] = ex.add_local_slave(CosimLocalSlave(fmu_path=str(cfg["fmus"][b]), instance_name=b))
        if idx[b] < 0:
            raise CosimError(f"libcosim cannot load {cfg['fmus'][b]}: {get_last_error_message()}")
        vars_ = ex.slave_variables(idx[b])
        vr[b] = {v.name.decode(): v.reference for v in vars_}
        if b == "plant":  # any SISO plant FMU: its own variable names
            ins = [v.name.decode() for v in vars_ if v.causality == 0]   # INPUT
            outs = [v.name.decode() for v in vars_ if v.causality == 2]  # OUTPUT
            vr[b]["h"], vr[b]["x"] = vr[b][ins[0]], vr[b][outs[0]]
        for k, v in fmu_settings(b, cfg).items():
            ok = (ex.string_initial_value(idx[b], vr[b][k], v) if isinstance(v, str)
                  else ex.real_initial_value(idx[b], vr[b][k], float(v)))
            if not ok:
                raise CosimError(f"libcosim: cannot set parameter {k} of {b}: {get_last_error_message()}")
    man = CosimManipulator.create_override()
    ex.add_manipulator(man)
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    ext_in = []
    for b in w.blocks:
        for name, s in w.inputs(b):
            if s[0] == "out":
                src = s[1]
                rc = ex.connect_real_variables(idx[src], vr[src][IO[src][1]], idx[b], vr[b][name])
                if rc != 0:  # libcosimpy returns the C status here, not a bool
                    raise CosimError(f"libcosim: cannot connect {src} -> {b}.{name}: "
                                     f"{get_last_error_message()}")
            elif s[1] != "zero":
                ext_in.append((idx[b], vr[b][name], w.ext[s[1]]))
    outs = [(b, idx[b], vr[b][IO[b][1]]) for b in w.blocks]
    return ex, man, obs, ext_in, outs


def _run_libcosim(w, cfg, n, rest, dt) -> Stepped:
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy._internal import get_last_error_message

    if rest:
        raise ValueError(f"the libcosim master needs T to be a whole multiple of dt = {dt!r} s "
                         f"(its fixed-step algorithm takes no shorter final step)")
    ns = round(dt * 1e9)
    if abs(ns * 1e-9 - dt) > 1e-12 * dt:
        raise ValueError(f"dt = {dt!r} s is not a whole number of nanoseconds (libcosim's time unit)")
    log_output_level(CosimLogLevel.ERROR)
    t_setup = time.perf_counter()
    ex, man, obs, ext_in, outs = _libcosim_setup(w, cfg, dt)
    setup = time.perf_counter() - t_setup
    rec = {b: [] for b in w.blocks}
    error = None
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n):
        if k == 1:
            # libcosim initializes the slaves inside the first step: count that
            # step as setup, so wall_s is the stepping alone as for fmpy
            t1 = time.perf_counter()
            setup += t1 - t0
            t0, c0 = t1, time.process_time()
        for i, ref, arr in ext_in:
            man.slave_real_values(i, [ref], [float(arr[k])])
        if not ex.step(1):
            error = (f"co-simulation stopped at t={k * dt!r} s (step {k}): libcosim step failed: "
                     f"{get_last_error_message()}")
            break
        for b, i, ref in outs:
            rec[b].append(obs.last_real_values(i, [ref])[0])
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    k_done = k if error else n
    del ex
    return Stepped(w.trace(rec, k_done), error, wall, cpu, setup, {})


_MASTERS = {"reference": _run_reference, "fmpy": _run_fmpy, "libcosim": _run_libcosim}


def run_master(master, w, cfg, n, rest, dt) -> Stepped:
    """Run the loop `w` with configuration `cfg` ({"model", "truth",
    "controller", "dt", "plant_mats", "fmus", "overrides"}) under `master`."""
    return _MASTERS[master](w, cfg, n, rest, dt)
