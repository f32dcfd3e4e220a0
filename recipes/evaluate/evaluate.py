"""Evaluation recipe (paper §VII):
``python recipes/evaluate/evaluate.py method=fca protocol=table1 workers=2``.

Builds the episode set (a file, or a protocol generated on the fly), then runs
:func:`navformer_rl.evaluation.harness.evaluate`, which writes per-robot-trial JSONL, the Table I-layout
CSV / markdown with 95 % intervals, bar plots, top-down maps and videos into ``output_dir`` (by default a
new timestamped hydra run directory). It prints that folder first, with the command that resumes it:
a rerun reuses finished episodes only when given the same ``output_dir``.

A mistake the user can fix (an unknown method, a missing checkpoint, a bad label, protocol or worker count) is
printed as one line, ``evaluate.py: error: <message>``, with exit status 2, like the ``navformer`` command
(``NAVFORMER_DEBUG=1`` shows the traceback); the method, checkpoint and label are checked before anything
else, and a refused run leaves no output folder behind.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from utils import check_policy, make_episode_set, resume_hint, run_evaluation

# recipes/ holds recipe_errors.py, which the recipes share
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from recipe_errors import user_errors  # noqa: E402


@hydra.main(config_path="", config_name="config", version_base="1.3")
def main(cfg) -> None:
    # A mistake (bad method, checkpoint, label, protocol, ...) ends in one line and exit status 2
    with user_errors("evaluate.py"):
        check_policy(cfg)  # before the output folder is announced: a refused run has nothing to resume
        print(resume_hint(cfg.output_dir, HydraConfig.get().overrides.task, sys.argv[0]), flush=True)
        episode_set = make_episode_set(cfg)
        result = run_evaluation(cfg, episode_set)
        print((result.out_dir / "summary.md").read_text(), end="")
        print(f"results in {result.out_dir}")


if __name__ == "__main__":
    main()
