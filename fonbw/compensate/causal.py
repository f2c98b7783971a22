"""The causal compensator: the per-step inverse of a model (eqs. 16-17, 21, 22).

See :mod:`fonbw.compensate` for the method, the forms of eq. (22), invertibility
and the explicit variant. Units: u [V], H_d and outputs [µm], dt and t [s].
"""
from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

from .. import hysteresis as _hy
from ..io import as_signal
from ..paper import U_RANGE
from .rest import run_start
from .kernels import (NOT_CONVERGED, OK, SAT_HIGH, SAT_LOW, _run_cbw, _run_fonbw, _run_zhu, _run_zhu22,
                      _step_cbw, _step_fonbw, _step_zhu, _step_zhu22)

__all__ = [
    "compensate",
    "compensator",
    "Compensator",
    "CompensationResult",
    "compensate_file",
    "output_columns",
    "default_limits",
    "OK",
    "SAT_LOW",
    "SAT_HIGH",
    "NOT_CONVERGED",
]

_STATUS_NAMES = {OK: "ok", SAT_LOW: "saturated at u_min", SAT_HIGH: "saturated at u_max",
                 NOT_CONVERGED: "not converged"}

#: The paper's amplifier range [V] (Sec. IV-A: 0–120 V): the voltage limits
#: when the model does not know its training range.
DEFAULT_LIMITS = U_RANGE
#: Default tolerance on |H(u_k) − H_d,k| [µm] (0.1 pm).
DEFAULT_TOL = 1e-10
_MAX_ITER = 100


def _force_target(m, h, h1, h2, dt):
    """Right side of eq. (22), m0 Ḧd + c0 Ḣd + k0 (H_d − x0), with backward
    differences (h1, h2: H_d one and two samples back). Same arithmetic for
    arrays (batch) and floats (per step), so both give the same bits."""
    return m.m0 * ((h - 2.0 * h1) + h2) / (dt * dt) + m.c0 * (h - h1) / dt + m.k0 * (h - m.x0)


def _form(model, form):
    if form not in ("discrete", "eq22"):
        raise ValueError(f"form must be 'discrete' or 'eq22', got {form!r}")
    if form == "eq22" and not isinstance(model, _hy.Zhu2016):
        raise ValueError(f"form='eq22' is the Zhu2016 compensator of eq. (22); "
                         f"a {type(model).__name__} has no such form")
    return form


def _entries(model, form="discrete"):
    """(batch, per-step) compiled entry points for the model's kernels."""
    if form == "eq22":
        return _run_zhu22, _step_zhu22
    if isinstance(model, _hy.FONBW):
        return _run_fonbw, _step_fonbw
    if isinstance(model, _hy.CBW):
        return _run_cbw, _step_cbw
    return _run_zhu, _step_zhu


# ---------------------------------------------------------------------------
# validation

def check_model(model):
    if not isinstance(model, (_hy.FONBW, _hy.CBW, _hy.Zhu2016)):
        raise ValueError(f"cannot compensate a {type(model).__name__}: expected a fonbw model "
                         "(FONBW, NBW, CBW or Zhu2016)")


def default_limits(model):
    """Voltage limits (u_min, u_max) [V] for ``model``: its training input range
    (``model.meta["u_range"]``, stored at identification), else the paper's 0–120 V.

    A bipolar stage identified on ±150 V thus gets ±150 V, not a clip at 0 V.
    """
    from ..invertibility import model_u_range
    return model_u_range(model, DEFAULT_LIMITS)


def _warn_invertible(model, dt, stacklevel=3):
    """Warn (RuntimeWarning) when the causal inverse of ``model`` at ``dt`` does
    not exist everywhere (one-step slope ≤ 0 at a state the default
    excitation visits). The Zhu model is not checked (no analytic slope)."""
    if not isinstance(model, (_hy.FONBW, _hy.CBW)):
        return None
    from ..invertibility import check_invertible
    ok, smin, msg = check_invertible(model, dt)
    if not ok:
        warnings.warn(f"{type(model).__name__} {msg}", RuntimeWarning, stacklevel=stacklevel + 1)
    return ok


def _limits(limits):
    try:
        lo, hi = (float(v) for v in limits)
    except (TypeError, ValueError):
        raise ValueError(f"limits must be a pair (u_min, u_max) of volts, got {limits!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"limits must be finite with u_min < u_max [V], got {limits!r}")
    return lo, hi


def _tol(tol):
    tol = float(tol)
    if not (math.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a positive number of µm, got {tol!r}")
    return tol


def _max_iter(n):
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise ValueError(f"max_iter must be a positive integer, got {n!r}")
    return int(n)


def _explicit_coeffs(model, explicit):
    """(ku, kh) of the explicit form u = (H_d − kh·x_(k−1) − Σ_(i≥2) ku_i u^i)/ku_1."""
    if isinstance(model, _hy.FONBW):
        ku, kh = np.asarray(model.ku, dtype=float), float(model.kh)
    elif isinstance(model, _hy.CBW):
        ku, kh = np.array([model.ka]), float(model.kb * model.D)
    else:
        if explicit:
            raise ValueError("explicit=True is not defined for Zhu2016: eq. (22) divides by "
                             "(k1/τ)e^(−t/τ), which vanishes after a few τ; use the implicit "
                             "per-step inversion (explicit=False)")
        return np.ones(1), 0.0
    if explicit and ku[0] == 0.0:
        raise ValueError("explicit=True needs k_u1 ≠ 0 (eq. 16 divides by it)")
    return np.ascontiguousarray(ku), kh


def _hd(Hd):
    return as_signal(Hd, "desired displacement Hd [µm]")


def _history(model, dt, history, form="discrete"):
    """The voltage [V] run before t = 0 (:func:`fonbw.compensate.rest.history_input`).

    The Zhu model runs its start like the others (``validate`` scores it
    after its rest cycle, zeroed at the end of it), except in the eq.-22
    form: that form solves a force balance written on H_d's derivatives
    from rest, which a displacement zero set after a cycle does not fit.
    """
    from .rest import history_input
    if form == "eq22":
        if history is not None and len(history):
            raise ValueError("history is not defined for the eq.-22 form of the Zhu2016 model")
        if history is None and history_input(model, dt, None).size:
            warnings.warn("the eq.-22 form runs from rest: the model's rest cycle (meta['start']) is not "
                          "run; use form='discrete' to compensate from it", RuntimeWarning, stacklevel=3)
        return np.zeros(0)
    return history_input(model, dt, history)


# ---------------------------------------------------------------------------
# public API

@dataclasses.dataclass
class CompensationResult:
    """Outcome of :func:`compensate`. ``np.asarray(result)`` is the voltage u.

    Attributes
    ----------
    u : ndarray
        Compensating voltage [V], one per sample of H_d.
    y_model : ndarray
        The model's output for u [µm] (what the compensator expects the
        actuator to do); equals H_d to ``tol`` where ``status == OK``.
    Hd : ndarray
        Desired displacement [µm].
    dt : float
        Step [s].
    status : ndarray of int8
        Per sample: ``OK`` (0), ``SAT_LOW`` (1, u = u_min), ``SAT_HIGH``
        (2, u = u_max), ``NOT_CONVERGED`` (3).
    nfev : ndarray of int
        Model step evaluations per sample (0 for the explicit variant).
    limits : tuple
        (u_min, u_max) [V].
    tol : float
        Solver tolerance on |y_model − H_d| [µm].
    explicit : bool
        Whether the one-step-delayed variant was used.
    form : str
        "discrete" or "eq22" (see :func:`compensate`).
    history : ndarray
        Voltage [V] the model ran through before t = 0 (its rest cycle, or
        none); ``y_model`` counts from the model's output at its end.
    u_lead : ndarray
        Preview only: the pre-actuation [V] applied just before t = 0 (after
        the history). The actuator must be driven with ``u_full``.
    """

    @property
    def u_full(self) -> np.ndarray:
        """The voltage to apply [V]: the preview's pre-actuation, then u."""
        return np.concatenate([self.u_lead, self.u])

    u: np.ndarray
    y_model: np.ndarray
    Hd: np.ndarray
    dt: float
    status: np.ndarray
    nfev: np.ndarray
    limits: tuple
    tol: float
    explicit: bool = False
    form: str = "discrete"
    preview: bool = False
    history: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0), repr=False)
    u_lead: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0), repr=False)

    def __array__(self, dtype=None, copy=None):
        return self.u if dtype is None else self.u.astype(dtype)

    def __len__(self):
        return len(self.u)

    @property
    def converged(self) -> np.ndarray:
        """True where the implicit equation was solved to ``tol`` (no saturation)."""
        return self.status == OK

    @property
    def saturated(self) -> np.ndarray:
        """True where u sits on a limit because H_d was out of reach."""
        return (self.status == SAT_LOW) | (self.status == SAT_HIGH)

    @property
    def saturated_samples(self) -> np.ndarray:
        """Indices of the saturated samples."""
        return np.flatnonzero(self.saturated)

    @property
    def unconverged_samples(self) -> np.ndarray:
        """Indices of the samples where no root was found (not saturation)."""
        return np.flatnonzero(self.status == NOT_CONVERGED)

    @property
    def residual(self) -> np.ndarray:
        """y_model − H_d [µm]."""
        return self.y_model - self.Hd

    @property
    def ok(self) -> bool:
        """Every sample solved, none saturated."""
        return bool(np.all(self.status == OK))

    @property
    def counts(self) -> dict:
        """Samples by status: ``{"ok", "saturated_low", "saturated_high", "not_converged"}``."""
        return {"ok": int(np.count_nonzero(self.status == OK)),
                "saturated_low": int(np.count_nonzero(self.status == SAT_LOW)),
                "saturated_high": int(np.count_nonzero(self.status == SAT_HIGH)),
                "not_converged": int(np.count_nonzero(self.status == NOT_CONVERGED))}

    @property
    def tracking_impossible(self) -> str | None:
        """Why the model cannot track H_d with this voltage (None when it does):
        H_d out of reach within the limits (clipped samples) or samples
        without a root. A command line should exit non-zero on it."""
        c = self.counts
        parts = []
        if c["saturated_low"] or c["saturated_high"]:
            parts.append(f"H_d out of reach within {self.limits[0]:g}..{self.limits[1]:g} V at "
                         f"{c['saturated_low'] + c['saturated_high']} of {len(self.u)} samples "
                         f"({c['saturated_low']} clipped at u_min, {c['saturated_high']} at u_max)")
        if c["not_converged"]:
            parts.append(f"{c['not_converged']} samples without a root of H(u) = H_d"
                         + ("" if self.preview else " (model not invertible at this step? "
                            "see fonbw.invertibility.check_invertible; preview=True, "
                            "fonbw compensate --preview, helps)"))
        return "; ".join(parts) or None

    def summary(self) -> str:
        """One line: samples, saturation (with the first sample and time), failures."""
        n = len(self.u)
        parts = [f"{n} samples"]
        for code in (SAT_LOW, SAT_HIGH, NOT_CONVERGED):
            idx = np.flatnonzero(self.status == code)
            if idx.size:
                parts.append(f"{idx.size} {_STATUS_NAMES[code]} (first at sample {idx[0]}, "
                             f"t = {idx[0] * self.dt:.6g} s)")
        if len(parts) == 1:
            parts.append("all solved" if not self.explicit else "none saturated")
        res = np.abs(self.residual)
        parts.append(f"max |model − Hd| = {res.max() if n else 0.0:.3g} µm")
        return "; ".join(parts)


def compensate(model, Hd, dt, *, limits=None, explicit=False, tol=DEFAULT_TOL,
               max_iter=_MAX_ITER, form="discrete", preview=False, check=True,
               history=None, lead=None) -> CompensationResult:
    """Feedforward voltage for a desired displacement, from rest (eqs. 16–17, 21, 22).

    Parameters
    ----------
    model : FONBW, NBW, CBW or Zhu2016
        The identified model; its memory engine is used as is.
    Hd : array_like
        Desired displacement H_d [µm], sampled at dt.
    dt : float
        Step [s].
    limits : (float, float), optional
        Voltage range (u_min, u_max) [V]; default :func:`default_limits`
        (the model's training range, else the paper's 0–120 V).
    explicit : bool
        One-step-delayed variant (G from the previous step) instead of the
        per-step implicit solve (module docstring).
    tol : float
        Tolerance on |H(u_k) − H_d,k| [µm] of the implicit solve.
    max_iter : int
        Iteration cap of each bracketed solve.
    form : {"discrete", "eq22"}
        "discrete" (default, every kind): per-step inversion of the discrete
        model, H(u_k) = H_d,k. "eq22" (Zhu2016 only): eq. (22) made implicit,
        the mechanics inverted on H_d with backward differences and the force
        balance (k1/τ)e^(−t/τ)u + ĥ(u) = m0 Ḧd + c0 Ḣd + k0 (H_d − x0)
        solved per step; status and ``tol`` then refer to that force
        balance, and the model output differs from H_d by the mechanics'
        discretization.
    preview : bool
        Non-causal stable inversion of the whole known trajectory
        (:func:`fonbw.compensate.preview.compensate_preview`; FONBW, NBW,
        CBW): bounded, smooth voltage for any model, invertible or not.
        ``tol`` is then the target of max |H(u) − H_d| (default 1e-9 µm).
        Use it when H_d is known ahead (a scan); use the causal default
        online (one sample at a time, FMUs).
    check : bool
        Causal only: warn (RuntimeWarning) when the model is not invertible
        at ``dt`` (:func:`fonbw.invertibility.check_invertible`).
    history : array_like, optional
        Voltage [V] the model runs through before t = 0, its output counted
        from the end of it (a sensor zeroed there). Default: the model's own
        start (:func:`fonbw.compensate.rest.start_history`: its rest cycle
        when it was identified after one, else from rest); ``()``: from rest.
    lead : int, optional
        Preview only: samples of pre-actuation before t = 0
        (:func:`fonbw.compensate.preview.compensate_preview`).

    Returns
    -------
    CompensationResult
        u [V], the model output, and per-sample status (saturation and
        convergence).
    """
    check_model(model)
    if preview:
        from .preview import compensate_preview
        if explicit or form != "discrete":
            raise ValueError("preview=True inverts the discrete model as a whole: "
                             "explicit and form do not apply")
        return compensate_preview(model, Hd, dt, limits=limits, history=history, lead=lead,
                                  tol=1e-9 if tol == DEFAULT_TOL else tol)
    Hd = _hd(Hd)
    dt = _hy._dt(dt)
    lo, hi = _limits(default_limits(model) if limits is None else limits)
    tol = _tol(tol)
    if check and form == "discrete":
        _warn_invertible(model, dt)
    max_iter = _max_iter(max_iter)
    ku, kh = _explicit_coeffs(model, explicit)
    form = _form(model, form)
    pre = _history(model, dt, history, form)
    n = len(Hd)
    target = Hd
    if form == "eq22" and n:
        h1 = np.concatenate([Hd[:1], Hd[:-1]])
        h2 = np.concatenate([Hd[:1], Hd[:1], Hd[:-2]])[:n]
        target = np.ascontiguousarray(_force_target(model, Hd, h1, h2, dt))
    P, ss = model._pack(dt, n_steps=max(n + pre.size, 1))
    u = np.empty(n)
    y = np.empty(n)
    status = np.empty(n, dtype=np.int8)
    nfev = np.empty(n, dtype=np.int64)
    if n:
        _entries(model, form)[0](target, P, ss, lo, hi, tol, int(max_iter), bool(explicit), ku, kh,
                                 pre, u, y, status, nfev)
    return CompensationResult(u=u, y_model=y, Hd=Hd, dt=dt, status=status, nfev=nfev,
                              limits=(lo, hi), tol=tol, explicit=bool(explicit), form=form,
                              history=pre)


class Compensator:
    """The compensator one sample at a time: ``u_k = c.step(Hd_k)``.

    Gives the numbers of :func:`compensate` bit for bit (same compiled solver
    on the blocks of the model's own stepper). ``get_state``/``set_state``
    copy everything (model memory, previous voltage, slope estimate,
    counters) as one float64 array, for FMU rollback.

    Parameters
    ----------
    model, dt, limits, explicit, tol, max_iter, form, check, history
        As for :func:`compensate` (the invertibility warning is given once,
        at construction; the history is run at every reset).

    Attributes
    ----------
    status : int
        Status of the last step (``OK``, ``SAT_LOW``, ``SAT_HIGH``,
        ``NOT_CONVERGED``).
    y_model : float
        Model output for the last voltage [µm].
    n_saturated, n_not_converged, steps : int
        Counts since the last reset.
    """

    _NCTL = 10  # steps, u_prev, slope, n_sat, n_fail, status, y_model, H_d(k-1), H_d(k-2), zero

    def __init__(self, model, dt, *, limits=None, explicit=False, tol=DEFAULT_TOL,
                 max_iter=_MAX_ITER, form="discrete", check=True, history=None):
        check_model(model)
        self.model = model
        self.dt = _hy._dt(dt)
        self.limits = _limits(default_limits(model) if limits is None else limits)
        #: Whether the model is invertible at dt (None: not checked)
        self.invertible = _warn_invertible(model, self.dt) if check and form == "discrete" else None
        self.tol = _tol(tol)
        self.max_iter = _max_iter(max_iter)
        self.explicit = bool(explicit)
        self._ku, self._kh = _explicit_coeffs(model, explicit)
        self.form = _form(model, form)
        self.history = _history(model, self.dt, history, self.form)
        self._entry = _entries(model, self.form)[1]
        self._out = np.zeros(4)
        self.reset()

    def reset(self) -> None:
        """Back to rest at t = 0."""
        # The model's own stepper holds the packed blocks P, S (and grows the
        # exact engine's window); the compiled step solves on them.
        self._st = self.model.stepper(self.dt)
        self._growable = any(op.growable for op in getattr(self._st, "ops", ()))
        # the history (rest cycle) first; outputs count from its end
        self._y0 = run_start(self._st, self.history)
        u_rest = self.history[-1] if self.history.size else min(max(0.0, self.limits[0]), self.limits[1])
        self._ctl = np.array([u_rest, math.nan])
        self.steps = 0
        self.n_saturated = 0
        self.n_not_converged = 0
        self.status = OK
        self.y_model = 0.0
        self._hd1 = self._hd2 = 0.0

    def step(self, y_ref: float) -> float:
        """Voltage u_k [V] for the desired displacement y_ref = H_d,k [µm]."""
        hd = float(y_ref)
        if not math.isfinite(hd):
            raise ValueError(f"desired displacement at step {self.steps} is not finite: {y_ref!r}")
        st, out = self._st, self._out
        lo, hi = self.limits
        if self.form == "eq22":
            if self.steps == 0:
                self._hd1 = self._hd2 = hd  # at rest before t = 0
            target = _force_target(self.model, hd, self._hd1, self._hd2, self.dt)
            self._hd2, self._hd1 = self._hd1, hd
            hd = target
        # solve and commit in one compiled call, except when the exact
        # engine's window may have to grow first: the model stepper commits then
        self._entry(hd + self._y0, st.P, st.S, lo, hi, self.tol, self.max_iter, self.explicit,
                    self._ku, self._kh, self._ctl, out, not self._growable)
        u = float(out[0])
        if self._growable:
            self.y_model = st.step(u) - self._y0
            self._ctl[0] = u
        else:
            self.y_model = float(out[3]) - self._y0
            st._steps += 1  # keep the stepper's own count true (its state is ours)
        self.status = int(out[1])
        self.steps += 1
        if self.status in (SAT_LOW, SAT_HIGH):
            self.n_saturated += 1
        elif self.status == NOT_CONVERGED:
            self.n_not_converged += 1
        return u

    def get_state(self) -> np.ndarray:
        head = [float(self.steps), self._ctl[0], self._ctl[1], float(self.n_saturated),
                float(self.n_not_converged), float(self.status), float(self.y_model),
                self._hd1, self._hd2, self._y0]
        return np.concatenate([head, self._st.get_state()])

    def set_state(self, state) -> None:
        s = np.asarray(state, dtype=float)
        if s.ndim != 1 or len(s) <= self._NCTL:
            raise ValueError("state must be a 1-D array from Compensator.get_state()")
        self._st.set_state(s[self._NCTL:])
        self.steps = int(s[0])
        self._ctl = np.array([s[1], s[2]])
        self.n_saturated, self.n_not_converged, self.status = int(s[3]), int(s[4]), int(s[5])
        self.y_model = float(s[6])
        self._hd1, self._hd2, self._y0 = float(s[7]), float(s[8]), float(s[9])


def compensator(model, dt, *, limits=None, explicit=False, tol=DEFAULT_TOL,
                max_iter=_MAX_ITER, form="discrete", check=True, history=None) -> Compensator:
    """Per-sample compensator (for FMUs and loops); see :class:`Compensator`."""
    return Compensator(model, dt, limits=limits, explicit=explicit, tol=tol, max_iter=max_iter,
                       form=form, check=check, history=history)


def compensate_file(model_path, traj_path, out_path, *, limits=None, explicit=False,
                    tol=DEFAULT_TOL, form="discrete", preview=False) -> CompensationResult:
    """``fonbw compensate``: model JSON + trajectory CSV (t, Hd) -> CSV (t, u, Hd, y_model, status).

    ``limits`` default to the model's training range (:func:`default_limits`);
    ``preview`` selects the non-causal stable inversion. The result's
    ``tracking_impossible`` says why tracking fails, if it does. Errors in the
    inputs raise ValueError (``fonbw.io.DataError`` for the CSV) naming the file.
    """
    from ..io import read_record, write_csv

    model = _hy.load_model(model_path)
    rec = read_record(traj_path, need=("Hd",))
    res = compensate(model, rec.hd, rec.dt, limits=limits, explicit=explicit, tol=tol, form=form,
                     preview=preview)
    write_csv(out_path, output_columns(model, res, rec.t))
    return res


#: Status written for the preview's pre-actuation rows (before t = 0 of H_d).
LEAD = -1


def output_columns(model, res, t):
    """Columns t [s], u [V], Hd [µm], y_model [µm], status of a compensation's
    output file. A preview's pre-actuation comes first, on times before the
    trajectory's first (status ``LEAD``), with the model's output there."""
    cols = {"t": np.asarray(t, float), "u": res.u, "Hd": res.Hd, "y_model": res.y_model,
            "status": res.status.astype(float)}
    k = res.u_lead.size
    if not k:
        return cols
    full = np.concatenate([res.history, res.u_full])
    y = model.simulate(full, res.dt)
    y0 = y[res.history.size - 1] if res.history.size else 0.0
    lead = {"t": cols["t"][0] - res.dt * np.arange(k, 0, -1), "u": res.u_lead,
            "Hd": np.full(k, res.Hd[0]), "y_model": y[res.history.size:res.history.size + k] - y0,
            "status": np.full(k, float(LEAD))}
    return {c: np.concatenate([lead[c], cols[c]]) for c in cols}
