"""The three masters: who steps the blocks, and how.

``"reference"`` and ``"fmpy"`` differ only in what the blocks are
(:mod:`fonbw.loop.blocks`): library steppers, or FMUs through fmpy's FMI 2 API
with the controller as library code. One stepping loop, :func:`jacobi`, runs
both. ``"libcosim"`` hands the FMUs (the controller too, as the FonbwPID FMU)
to libcosim's own fixed-step algorithm, an independent implementation of the
same convention. The FMUs are the pythonfmu ones or, with ``native``, the C
ones of :mod:`fonbw.fmu.native` (FonbwPIDNative as libcosim's controller):
the masters take whatever :func:`fonbw.loop.fmus.build_fmus` built. The
libcosim run is one call into libcosim with no Python per step: the
exogenous inputs are played by FonbwSignalNative FMUs, the outputs recorded
by its time-series observer, and its execution has no worker thread
(:mod:`fonbw.loop.lc_threads`; the thread hand-off per step was most of its
cost at 10 kHz).

Every master returns a :class:`Stepped`.

Units: u [V], y, r [µm], t [s].
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import NamedTuple

from . import lc_threads
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


def _signal_fmu():
    """The native signal FMU (built once into the per-user cache), or None
    where this platform has no C compiler."""
    from ..fmu import native
    from ..fmu.build import cache_dir

    return native.cached_signal(cache_dir() / "native")


def _add_slave(ex, fmu, name):
    from libcosimpy.CosimSlave import CosimLocalSlave
    from libcosimpy._internal import get_last_error_message

    i = ex.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name=name))
    if i < 0:
        raise CosimError(f"libcosim cannot load {fmu}: {get_last_error_message()}")
    return i


def _init(ex, i, ref, v, what):
    from libcosimpy._internal import get_last_error_message

    ok = ex.string_initial_value(i, ref, v) if isinstance(v, str) else ex.real_initial_value(i, ref, float(v))
    if not ok:
        raise CosimError(f"libcosim: cannot set {what}: {get_last_error_message()}")


def _connect(ex, src, out, dst, inp, what):
    from libcosimpy._internal import get_last_error_message

    if ex.connect_real_variables(src, out, dst, inp) != 0:  # libcosimpy returns the C status here
        raise CosimError(f"libcosim: cannot connect {what}: {get_last_error_message()}")


def _libcosim_setup(w, cfg, dt, signal, table_dir):
    """A libcosim execution with the loop's FMUs, parameters and connections,
    and a time-series observer of every block's output.

    Each exogenous input is fed by an instance of the signal FMU `signal`
    (its samples written to a file in `table_dir`), connected like any
    output: after k steps it gives sample k, which is what the block reads
    in step k. Without `signal` (None) the inputs are listed for an override
    manipulator instead. The execution is created with no worker thread
    where possible (:func:`fonbw.loop.lc_threads.single_thread`). Returns
    (execution, observer, manipulator or None, [(slave, reference,
    exogenous sequence)] for the manipulator, [(block, slave, output
    reference)], the thread report of ``single_thread``)."""
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver

    with lc_threads.single_thread() as threads:  # the pool is made with the execution
        ex = CosimExecution.from_step_size(round(dt * 1e9))
    idx, vr = {}, {}
    for b in w.blocks:
        idx[b] = _add_slave(ex, cfg["fmus"][b], b)
        vars_ = ex.slave_variables(idx[b])
        vr[b] = {v.name.decode(): v.reference for v in vars_}
        if b == "plant":  # any SISO plant FMU: its own variable names
            ins = [v.name.decode() for v in vars_ if v.causality == 0]   # INPUT
            outs = [v.name.decode() for v in vars_ if v.causality == 2]  # OUTPUT
            vr[b]["h"], vr[b]["x"] = vr[b][ins[0]], vr[b][outs[0]]
        for k, v in fmu_settings(b, cfg).items():
            _init(ex, idx[b], vr[b][k], v, f"parameter {k} of {b}")
    man = None if signal else CosimManipulator.create_override()
    if man is not None:
        ex.add_manipulator(man)
    obs = CosimObserver.create_time_series()
    ex.add_observer(obs)
    ext_in = []
    for b in w.blocks:
        for name, s in w.inputs(b):
            if s[0] == "out":
                _connect(ex, idx[s[1]], vr[s[1]][IO[s[1]][1]], idx[b], vr[b][name], f"{s[1]} -> {b}.{name}")
            elif s[1] != "zero" and signal:
                table = Path(table_dir) / f"{s[1]}.txt"
                table.write_text("\n".join(map(repr, w.ext[s[1]].tolist())) + "\n", encoding="ascii")
                j = _add_slave(ex, signal, f"signal_{s[1]}")
                sv = {v.name.decode(): v.reference for v in ex.slave_variables(j)}
                _init(ex, j, sv["dt"], dt, f"dt of the signal {s[1]}")
                _init(ex, j, sv["file"], str(table), f"file of the signal {s[1]}")
                _connect(ex, j, sv["y"], idx[b], vr[b][name], f"signal {s[1]} -> {b}.{name}")
            elif s[1] != "zero":
                ext_in.append((idx[b], vr[b][name], w.ext[s[1]]))
    outs = [(b, idx[b], vr[b][IO[b][1]]) for b in w.blocks]
    for _, i, ref in outs:
        obs.start_time_series(i, ref, CosimVariableType.REAL)
    return ex, obs, man, ext_in, outs, threads


def _samples(obs, outs, n):
    """{block: outputs after steps 1..k} from the observer, k <= n the steps done."""
    rec = {}
    for b, i, ref in outs:
        try:
            _, steps, vals = obs.time_series_real_samples(i, ref, from_step=1, sample_count=max(n, 1))
        except AssertionError:  # nothing recorded: the run stopped before its first step
            steps, vals = [], []
        if list(steps) != list(range(1, len(steps) + 1)):
            raise CosimError(f"libcosim recorded {b} at steps {steps[:5]}..., not 1, 2, ...")
        rec[b] = list(vals)
    return rec


def _step_libcosim(ex, man, ext_in, n):
    """Step `ex` n times: first one step (libcosim initializes the slaves
    inside it: timed as setup), then the rest in one call, or, with a
    manipulator, one step at a time with the exogenous inputs set before
    each. Returns (setup share [s], wall_s, cpu_s, ok)."""
    t_init = time.perf_counter()
    ok = n == 0 or _one_step(ex, man, ext_in, 0)
    t0, c0 = time.perf_counter(), time.process_time()
    if ok and n > 1:
        if man is None:
            ok = ex.step(n - 1)
        else:
            for k in range(1, n):
                if not _one_step(ex, man, ext_in, k):
                    ok = False
                    break
    return t0 - t_init, time.perf_counter() - t0, time.process_time() - c0, ok


def _one_step(ex, man, ext_in, k):
    if man is not None:
        for i, ref, arr in ext_in:
            man.slave_real_values(i, [ref], [float(arr[k])])
    return ex.step(1)


def _run_libcosim(w, cfg, n, rest, dt) -> Stepped:
    if rest:
        raise ValueError(f"the libcosim master needs T to be a whole multiple of dt = {dt!r} s "
                         f"(its fixed-step algorithm takes no shorter final step)")
    ns = round(dt * 1e9)
    if abs(ns * 1e-9 - dt) > 1e-12 * dt:
        raise ValueError(f"dt = {dt!r} s is not a whole number of nanoseconds (libcosim's time unit)")
    lc_threads.prepare()  # before libcosimpy loads libcosimc
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy._internal import get_last_error_message

    log_output_level(CosimLogLevel.ERROR)
    t_setup = time.perf_counter()
    signal = _signal_fmu()
    with tempfile.TemporaryDirectory(prefix="fonbw_lc_") as tables:
        ex, obs, man, ext_in, outs, threads = _libcosim_setup(w, cfg, dt, signal, tables)
        setup = time.perf_counter() - t_setup
        init, wall, cpu, ok = _step_libcosim(ex, man, ext_in, n)
        rec = _samples(obs, outs, n)
        k_done = min(len(v) for v in rec.values()) if rec else 0
        error = None if ok else (f"co-simulation stopped at t={k_done * dt!r} s (step {k_done}): "
                                 f"libcosim step failed: {get_last_error_message()}")
        del ex
    diagnostics = {"libcosim": {"worker_threads": threads["workers"], "stepping": threads["note"],
                                "exogenous": "signal FMUs" if signal else "override manipulator, per step"}}
    return Stepped(w.trace(rec, k_done), error, wall, cpu, setup + init, diagnostics)


_MASTERS = {"reference": _run_reference, "fmpy": _run_fmpy, "libcosim": _run_libcosim}


def run_master(master, w, cfg, n, rest, dt) -> Stepped:
    """Run the loop `w` with configuration `cfg` ({"model", "truth",
    "controller", "dt", "plant_mats", "fmus", "overrides"}) under `master`."""
    return _MASTERS[master](w, cfg, n, rest, dt)
