"""The end-to-end demo (``navformer demo``): settings (:mod:`~navformer_rl.demo.config`), the resumable
stages collect -> train -> evaluate -> report (:mod:`~navformer_rl.demo.pipeline`), its report
(:mod:`~navformer_rl.demo.report`) and its command (:mod:`~navformer_rl.demo.cli`).

Names are imported lazily, so the command line answers ``--help`` without importing torch.
"""

from __future__ import annotations

from navformer_rl.utils.lazy import lazy_exports

_EXPORTS = {
    "DemoConfig": "navformer_rl.demo.config",
    "environment_summary": "navformer_rl.demo.config",
    "write_json": "navformer_rl.demo.config",
    "StageTimes": "navformer_rl.demo.pipeline",
    "collect_stage": "navformer_rl.demo.pipeline",
    "evaluate_stage": "navformer_rl.demo.pipeline",
    "run_demo": "navformer_rl.demo.pipeline",
    "stage_time_table": "navformer_rl.demo.pipeline",
    "train_stage": "navformer_rl.demo.pipeline",
    "write_demo_report": "navformer_rl.demo.report",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
