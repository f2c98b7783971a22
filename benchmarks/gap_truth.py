"""Truth simulator for the blind test of the gap diagnosis.

Used by ``benchmarks/blind_gap.py`` and ``tests/test_gap.py``; it uses the
library's public API only. Written apart from :mod:`fonbw.gap.effects` on
purpose: every effect here has other equations or another discretization
than the candidate block the diagnosis may use to explain it, so the blind
test is not rigged. The equations are in :mod:`gap_effects_truth`, the
hysteresis cores in :mod:`gap_cores`.

=============  =========================================  ===========================================
effect         truth (here)                               candidate block (fonbw.gap.effects)
=============  =========================================  ===========================================
creep          logarithmic creep, γ per decade: 12 modes   4 fixed modes 0.01…10 s, implicit Euler,
               τ = 1 ms … 100 s, Tustin, on the output     gains solved
dynamics       two modes: 0.96 at (f_res, ζ) and 0.04 at    one mode, ζ ≤ 0.5, python-control c2d (FOH)
               (3.3 f_res, 0.1), scipy lsim
amplifier      internal pole at 4 f_c, then the load's RC  one RC stage whose rate is clipped
               with a current (slew) limit, exact ODE      per sample (implicit step)
               solution, 16 sub-steps per sample
delay          continuous transport delay of the input,    input delay, linear interpolation
               monotone cubic (PCHIP) interpolation
drift          A (1 − e^(−t/τ_th)) + integrated random     (t/10 s), (t/10 s)² shared by records
               walk per record
saturation     smooth stroke limit (tanh knee) on the      slope change c over a softplus corner
               displacement                                of width w at the knee, on the model's
                                                           own output, c solved (Gauss-Newton)
clip           the amplifier's rail: the voltage after     none yet (JSON name ``clip``). Not the
               the amplifier is clipped at a rail below    saturation block: the rail acts before
               the drive's peak (lower rail −30 V), with   the hysteresis, so the core's memory
               a softplus knee of 0.2–1.5 V; a material    turns at the rail and the descending
               share of the samples is clipped             branch starts from the clipped voltage
hum            50 Hz + 150 Hz mains pickup, random phase   none: outside the library
=============  =========================================  ===========================================

The hysteresis is a truth core of :mod:`gap_cores` (families fonbw,
preisach, pi, rate) drawn per scenario; without a family,
:func:`draw_scenario` keeps the library's FONBW
(:data:`fonbw.data.DEFAULT_MODEL` perturbed a few per cent), the draw of the
fixed-seed tests. Sensor noise is white Gaussian with a 16-bit ADC over
±40 µm. Magnitudes are set by bisection on each effect's strength so that
the RMS change it makes on the validation records equals a target multiple
of the noise standard deviation.

A record may start mid-drive: its drive is simulated from rest through every
stateful block (core, creep, dynamics, amplifier, drift) and the record keeps
the samples from its start on (:func:`gap_cores.mid_drive_record`).
"""
from __future__ import annotations

import math

import numpy as np

from fonbw import FONBW, load_model
from fonbw import signals as _sig
from fonbw.data import DEFAULT_MODEL
from fonbw.io import Record

import gap_cores
from gap_effects_truth import (LEGACY_POOL, POOL, TRUTH_EFFECTS, _amplifier_ode, clipped_share,  # noqa: F401
                               input_side, output_side, strength, strength_params)

__all__ = ["TRUTH_EFFECTS", "KINDS", "Truth", "default_experiments", "draw_scenario", "scenario_kind",
           "scenario_family", "magnitude", "calibrate", "records_with"]

FS = 5000.0
KINDS = ("null", "single", "pair", "outside", "below")
KIND_P = (0.15, 0.45, 0.2, 0.1, 0.1)  # probabilities of KINDS
# a record that starts mid-drive starts within this share of its drive
MID_START = (0.15, 0.45)


def default_experiments(fs=FS, scale=1.0):
    """Training and validation inputs shaped like the paper's experiments.

    Training: eq. (19) (8 s), steps with holds (40, 100, 60 V, 1 s each),
    multi-tone 1/5/10/20 Hz (2 s). Validation: 1 Hz and 20 Hz sines
    (60 − 60 cos), multi-tone 2/7/15/25 Hz, steps 80 and 20 V. `scale`
    stretches every duration.

    Returns
    -------
    (list of (name, u)), (list of (name, u))
    """
    s = float(scale)
    train = [
        ("eq19", _sig.eq19_input(fs, 8.0 * s)[1]),
        ("steps", _sig.step_hold_input((40.0, 100.0, 60.0), hold=1.0 * s, fs=fs)[1]),
        ("multi", _sig.multi_input((1.0, 5.0, 10.0, 20.0), fs=fs, T=2.0 * s, weights=(1.0, 0.7, 0.5, 0.5))[1]),
    ]
    val = [
        ("sine01", _sig.sine_input(1.0, fs, periods=None, T=2.0 * s)[1]),
        ("sine20", _sig.sine_input(20.0, fs, periods=None, T=0.5 * s)[1]),
        ("multi_v", _sig.multi_input((2.0, 7.0, 15.0, 25.0), fs=fs, T=2.0 * s)[1]),
        ("steps_v", _sig.step_hold_input((80.0, 20.0), hold=1.0 * s, fs=fs)[1]),
    ]
    return train, val


def _records(truth, drives, effects=None):
    """The measured records of `truth` on `drives` (``{"train": items, "validate": items}``),
    indexed as the noise and the drift's walk are drawn: training i, validation 50 + i;
    with `effects` instead of the truth's own when given."""
    out = {}
    for key, off in (("train", 0), ("validate", 50)):
        out[key] = []
        for i, item in enumerate(drives[key]):
            name, h, u = split_drive(item)
            out[key].append(truth.record(u, name, off + i, history=h, effects=effects))
    return out


def records_with(sc, effects):
    """Scenario `sc`'s records ({"train", "validate"}) had its truth carried
    `effects` instead ({}: the core alone): the same drives, noise and ADC.
    `effects` as the truth holds them (``sc["truth"].effects``: parameters
    by effect name, without the calibration's ``share``)."""
    return _records(sc["truth"], {"train": sc["train_drives"], "validate": sc["validate_drives"]}, effects)


def split_drive(item):
    """``(name, history, u_record)`` of an input item ``(name, u)`` or ``(name, u_full, start)``."""
    if len(item) == 2:
        return item[0], None, np.asarray(item[1], dtype=float)
    name, u_full, start = item
    if not start:
        return name, None, np.asarray(u_full, dtype=float)
    h, u = gap_cores.mid_drive_record(u_full, start)
    return name, h, u


class Truth:
    """A "real" actuator: a hysteresis core plus the chosen effects.

    Parameters
    ----------
    hyst : gap_cores.Core or FONBW
        Anything with ``simulate(u, dt)`` from rest.
    effects : dict
        ``{name: params}`` with name in :data:`TRUTH_EFFECTS` (see
        :mod:`gap_effects_truth` for the parameters of each).
    noise_std : float
        Sensor noise [µm].
    fs : float
        Sampling frequency [Hz].
    seed : int
        Seed of the noise, drift random walk and hum phases.
    """

    def __init__(self, hyst, effects=None, noise_std=0.02, fs=FS, seed=0):
        self.hyst = hyst
        self.effects = dict(effects or {})
        for k in self.effects:
            if k not in TRUTH_EFFECTS:
                raise ValueError(f"unknown truth effect {k!r}")
        self.noise_std = float(noise_std)
        self.fs = float(fs)
        self.dt = 1.0 / self.fs
        self.seed = seed

    @property
    def core(self):
        """The hysteresis core (the same object as ``hyst``)."""
        return self.hyst

    def output(self, u, rec_index=0, effects=None, history=None):
        """Noiseless displacement [µm] for the command u [V].

        Parameters
        ----------
        u : array_like
            The record's command [V].
        rec_index : int
            Index of the record (seeds its drift walk and hum phases).
        effects : dict, optional
            Effects to apply instead of the truth's own.
        history : array_like, optional
            Command [V] of the drive before the record: the whole drive is
            simulated from rest through every block and the record's samples
            are cut out after, so blocks with state (core, creep, dynamics,
            amplifier, drift) enter the record where the history left them.

        Returns
        -------
        ndarray
            One value per sample of u.
        """
        eff = self.effects if effects is None else effects
        u = np.asarray(u, dtype=float)
        n0 = 0
        if history is not None and len(history):
            n0 = len(history)
            u = np.concatenate([np.asarray(history, dtype=float), u])
        rng = np.random.default_rng([self.seed, rec_index, 7])
        v = input_side(u, eff, self.dt)
        y = self.hyst.simulate(v, self.dt)
        y = output_side(y, eff, self.dt, rng)
        return y[n0:] if n0 else y

    def record(self, u, name, rec_index, history=None, effects=None):
        """A measured record: noise and 16-bit ADC over ±40 µm added (see :meth:`output`)."""
        u = np.asarray(u, dtype=float)
        y = self.output(u, rec_index, effects=effects, history=history)
        rng = np.random.default_rng([self.seed, rec_index, 11])
        y = y + rng.normal(0.0, self.noise_std, y.size)
        q = 80.0 / 2 ** 16
        y = -40.0 + np.round((y + 40.0) / q) * q
        return Record.from_arrays(u=u, y=y, dt=self.dt, path=f"<truth:{name}>")


def magnitude(truth, inputs, name, params):
    """RMS change [in noise std] that effect `name` alone makes on `inputs`.

    `inputs` items are ``(name, u)`` or ``(name, u_full, start)`` (a record
    that starts mid-drive; measured on the record's samples only).
    """
    num = 0.0
    n = 0
    for i, item in enumerate(inputs):
        _, h, u = split_drive(item)
        a = truth.output(u, 100 + i, effects={}, history=h)
        b = truth.output(u, 100 + i, effects={name: params}, history=h)
        num += float(np.sum((a - b) ** 2))
        n += u.size
    return math.sqrt(num / n) / truth.noise_std


def calibrate(truth, inputs, name, target, rng):
    """Effect parameters whose magnitude on `inputs` is `target` noise stds (bisection).

    Returns
    -------
    params : dict
        For clip, with the share of the records' command samples above the
        rail (``share``).
    magnitude : float
        Reached magnitude [noise stds]; below target when even the strongest
        setting does not reach it.
    """
    drives = [split_drive(item) for item in inputs]
    # the top of the stroke the records dwell at: FONBW answers an instant
    # step with a one-sample spike (the GL derivative of the step), which a
    # plain max would take for the stroke
    y_top = np.quantile(np.concatenate([truth.output(u, effects={}, history=h) for _, h, u in drives]), 0.999)
    rp = strength_params(name, rng, y_top, [u for _, _, u in drives])
    lo, hi = 0.0, 1.0
    m_hi = magnitude(truth, inputs, name, strength(name, hi, rp))
    if m_hi >= target:
        for _ in range(14):
            mid = 0.5 * (lo + hi)
            if magnitude(truth, inputs, name, strength(name, mid, rp)) < target:
                lo = mid
            else:
                hi = mid
    p = strength(name, hi, rp)
    if name == "clip":
        p["share"] = clipped_share(p, [u for _, _, u in drives])
    return p, magnitude(truth, inputs, name, p)


def scenario_kind(seed):
    """The kind :func:`draw_scenario` draws for `seed` (cheap: no simulation)."""
    return str(np.random.default_rng([seed, 2026]).choice(KINDS, p=KIND_P))


def scenario_family(seed, families=gap_cores.FAMILIES):
    """The core family of scenario `seed`: uniform over `families` (cheap)."""
    families = tuple(families)
    return str(families[int(np.random.default_rng([seed, 2027]).integers(len(families)))])


def _legacy_fonbw(rng):
    """The library's FONBW a few per cent off :data:`fonbw.data.DEFAULT_MODEL` (the draw of the fixed-seed tests)."""
    pr = load_model(DEFAULT_MODEL).params
    ku = np.asarray(pr["ku"]) * (1 + 0.03 * rng.standard_normal(3))
    return FONBW(ku, pr["kh"] * (1 + 0.03 * rng.standard_normal()), pr["rho"], pr["sigma"],
                 pr["n"], min(1.0, pr["lam1"] + 0.03 * rng.standard_normal()),
                 min(1.0, pr["lam2"] + 0.03 * rng.standard_normal()))


def _mid_drive_layout(seed, share, tr_in, va_in):
    """Which records start mid-drive, and where: ``{"train": (i, start) or None, "validate": ...}``.

    With probability `share` one validation record, one training record or
    one of each (a third each) starts within :data:`MID_START` of its drive.
    Drawn from its own stream so the rest of the scenario does not move.
    """
    rng = np.random.default_rng([seed, 2026, 2])
    out = {"train": None, "validate": None}
    if not share or rng.random() >= share:
        return out
    which = ("train", "validate", "both")[int(rng.integers(3))]
    for key, ins in (("train", tr_in), ("validate", va_in)):
        i = int(rng.integers(len(ins)))
        start = int(rng.uniform(*MID_START) * ins[i][1].size)
        if which in (key, "both"):
            out[key] = (i, start)
    return out


def _targets(kind, rng, pool):
    """Effect names and target magnitudes [noise stds] of a scenario of `kind`."""
    if kind == "null":
        return [], []
    if kind == "single":
        return [str(rng.choice(pool))], [10 ** rng.uniform(math.log10(2), 2)]
    if kind == "pair":
        names = [str(n) for n in rng.choice(pool, 2, replace=False)]
        return names, list(10 ** rng.uniform(math.log10(3), math.log10(60), 2))
    if kind == "outside":
        return ["hum"], [10 ** rng.uniform(math.log10(3), math.log10(50))]
    return [str(rng.choice(pool))], [10 ** rng.uniform(-1, math.log10(0.4))]


def _core_params(core):
    if isinstance(core, gap_cores.Core):
        return core.family, core.params
    p = core.params
    return "fonbw", {k: (list(map(float, np.atleast_1d(v))) if k == "ku" else v) for k, v in p.items()}


def fixed_case(seed, effects, scale=1.0, kind="null", family=None):
    """A fixed case for tests: scenario `seed`'s truth (core of `family`, as in
    :func:`draw_scenario`) with `effects` instead of the drawn ones, on the
    default experiments; returns (truth, training records, validation records)."""
    truth = draw_scenario(seed, kind, scale=scale, family=family)["truth"]
    truth.effects = effects
    tr_in, va_in = default_experiments(scale=scale)
    recs = _records(truth, {"train": tr_in, "validate": va_in})
    return truth, recs["train"], recs["validate"]


def draw_scenario(seed, kind=None, scale=1.0, fs=FS, family=None, core=None, mid_drive=0.0, pool=None):
    """A random blind scenario.

    Parameters
    ----------
    seed : int
    kind : {"null", "single", "pair", "outside", "below"}, optional
        Drawn (15/45/20/10/10 %) when None.
    scale : float
        Stretches every record's duration.
    fs : float
        Sampling frequency [Hz].
    family : str, optional
        Core family of :data:`gap_cores.FAMILIES`, drawn with
        :func:`gap_cores.draw_core` from the seed. None (and no `core`)
        keeps the FONBW draw and effect pool of the fixed-seed tests.
    core : gap_cores.Core, optional
        Use this core (the rest of the scenario is drawn as without it).
    mid_drive : float
        Probability that a training and/or validation record starts mid-drive.
    pool : sequence of str, optional
        Effects single, pair and below scenarios draw from; default
        :data:`gap_effects_truth.POOL` with a family, the pool without clip
        without one.

    Returns
    -------
    dict
        ``kind``, ``family``, ``core_params``, ``truth`` (Truth), ``injected``
        {name: {"params", "magnitude", "magnitude_train"}} (magnitudes on the
        validation and the training drives), ``train``, ``validate`` (lists of
        Record), ``train_drives``, ``validate_drives`` (lists of
        ``(name, u_full, start)``: the drive each record is cut from),
        ``starts_at_rest``, ``mid_drive`` and ``noise_std``.
    """
    rng = np.random.default_rng([seed, 2026])
    if kind is None:
        kind = rng.choice(KINDS, p=KIND_P)
    hyst = _legacy_fonbw(rng)  # always drawn: the rest of the stream stays that of the fixed-seed tests
    if core is not None:
        hyst = core
    elif family is not None:
        hyst = gap_cores.draw_core(family, np.random.default_rng([seed, 2026, 1]))
    if pool is None:
        pool = LEGACY_POOL if family is None else POOL
    noise = float(10 ** rng.uniform(-2, math.log10(0.03)))
    truth = Truth(hyst, {}, noise, fs, seed=int(rng.integers(1 << 30)))
    tr_in, va_in = default_experiments(fs, scale)
    layout = _mid_drive_layout(seed, mid_drive, tr_in, va_in)
    drives = {}
    for key, ins in (("train", tr_in), ("validate", va_in)):
        cut = layout[key]
        drives[key] = [(n, u, cut[1] if cut and cut[0] == i else 0) for i, (n, u) in enumerate(ins)]
    injected = {}
    for n, m in zip(*_targets(kind, rng, pool)):
        p, got = calibrate(truth, drives["validate"], n, m, rng)
        injected[n] = {"params": p, "magnitude": got}
    truth.effects = {n: {k: x for k, x in v["params"].items() if k != "share"} for n, v in injected.items()}
    # what the diagnosis can learn of each effect: magnitudes are calibrated on
    # the validation drives, which reach 120 V where training stops near 115 V,
    # so a knee or rail near the top can leave the training records untouched
    for n, v in injected.items():
        v["magnitude_train"] = magnitude(truth, drives["train"], n, truth.effects[n])
    recs = _records(truth, drives)
    fam, params = _core_params(hyst)
    return {"kind": str(kind), "family": fam, "core_params": params, "truth": truth, "injected": injected,
            "train": recs["train"], "validate": recs["validate"], "train_drives": drives["train"],
            "validate_drives": drives["validate"], "noise_std": noise,
            "starts_at_rest": layout["train"] is None and layout["validate"] is None,
            "mid_drive": {k: (list(v) if v else None) for k, v in layout.items()}}
