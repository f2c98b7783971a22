"""The result object of a gap diagnosis.

:class:`DiagnosisResult` holds the JSON contract of the design notes in six
parts (``nominal``, ``localization``, ``candidates``, ``verdict``, ``timing``,
``records``), readable as attributes or, as a read-only mapping, by key
(``res["verdict"]``, ``res.get("candidates", [])``). :meth:`~DiagnosisResult.to_dict`
gives the plain dict that is written as JSON.
"""
from __future__ import annotations

from collections.abc import Mapping

from ..io import jsonable

__all__ = ["DiagnosisResult", "jsonable"]

_PARTS = ("nominal", "localization", "candidates", "verdict", "timing", "records")


class DiagnosisResult(Mapping):
    """Outcome of :func:`fonbw.gap.diagnose`.

    Attributes
    ----------
    nominal : dict
        ``model`` (the refit nominal FONBW as a dict), ``rms_validate`` and
        ``rms_train`` [µm], ``noise_floor`` (σ [µm]) and
        ``given_model_rms_validate`` [µm] (None unless a model was given).
    localization : dict
        :func:`fonbw.gap.localize.localize` of the nominal validation residual.
    candidates : list of dict
        One per candidate effect, largest ``gap_closed`` first: ``effect``,
        ``gap_closed``, ``rms_validate`` [µm], ``accepted``, ``params``,
        ``checks``.
    verdict : dict
        ``effects`` (accepted, strongest first: in the order of acceptance), ``gap_closed``,
        ``unexplained``, ``at_noise_floor``, ``steps`` (the waterfall),
        ``coverage``, ``params``, ``later_steps`` (every candidate of each
        greedy step after the first, with its checks, and of the first step
        judged again on top of a limit named beyond the training range),
        ``within_training_rates``
        (accepted effects judged on the validation records within the
        training records' input rates), ``beyond_training`` (a rail or a
        stroke limit cross-fitted where only the validation records go past
        the training range: :func:`fonbw.gap.beyond.beyond_training`, whose
        own ``within_training_rates`` gives the share on the records it was
        judged on, the whole gap's being its ``gap_closed``), ``message``.
    timing : dict
        Wall-clock time of the stages [s].
    records : dict
        ``train`` and ``validate``: the records' paths.
    model : FONBW
        The refit nominal model itself (not part of the JSON).
    """

    def __init__(self, nominal, localization, candidates, verdict, timing, records, model=None):
        self.nominal = nominal
        self.localization = localization
        self.candidates = candidates
        self.verdict = verdict
        self.timing = timing
        self.records = records
        self.model = model

    # -- the verdict at a glance -------------------------------------------

    @property
    def effects(self):
        """Accepted effects, strongest first: in the order of acceptance (list of str)."""
        return self.verdict["effects"]

    @property
    def gap_closed(self):
        """Share of the excess gap (over the noise floor) the accepted effects close."""
        return self.verdict["gap_closed"]

    @property
    def unexplained(self):
        """True when the accepted effects close less than half of the excess gap."""
        return self.verdict["unexplained"]

    @property
    def message(self):
        """The verdict in one sentence."""
        return self.verdict.get("message", "")

    # -- JSON and mapping access -------------------------------------------

    def to_dict(self):
        """The JSON-ready dict (a new dict; the nested values are shared)."""
        return {k: getattr(self, k) for k in _PARTS}

    def __getitem__(self, key):
        if key not in _PARTS:
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self):
        return iter(_PARTS)

    def __len__(self):
        return len(_PARTS)

    def __repr__(self):
        return (f"DiagnosisResult(effects={self.effects!r}, gap_closed={self.gap_closed:.3g}, "
                f"unexplained={self.unexplained}, at_noise_floor={self.verdict['at_noise_floor']})")
