"""Diagnosing how a policy fails (``navformer evaluate diagnose``): :func:`diagnose` plays an episode set with
per-step records and measures the failures.

Modules: ``diagnosis`` (:func:`diagnose`, :func:`load_diagnosis`, the output folder), ``runner`` (one episode,
recorded), ``trace`` (the per-step arrays and their files), ``measures`` (failure measures per robot-trial),
``actions`` (the experts' commands and the teacher-forced turns), ``report`` (``diagnosis.md``), ``paired``
(two diagnoses' robot-trial shares, paired). This package imports nothing heavy by itself.
"""

from __future__ import annotations

from navformer_rl.utils.lazy import lazy_exports

_EXPORTS = {
    "ROBOT_TRIALS": "navformer_rl.evaluation.diagnose.diagnosis",
    "SUMMARY_JSON": "navformer_rl.evaluation.diagnose.diagnosis",
    "SUMMARY_MD": "navformer_rl.evaluation.diagnose.diagnosis",
    "diagnose": "navformer_rl.evaluation.diagnose.diagnosis",
    "load_diagnosis": "navformer_rl.evaluation.diagnose.diagnosis",
    "paired_robot_trial_shares": "navformer_rl.evaluation.diagnose.paired",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
