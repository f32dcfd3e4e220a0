"""Evaluation recipe (paper §VII): ``python recipes/evaluate/evaluate.py method=fca protocol=table1 workers=2``.

Builds the episode set (a file, or a protocol generated on the fly), then runs
:func:`navformer_rl.evaluation.harness.evaluate`, which writes per-robot-trial JSONL, the Table I-layout
CSV / markdown with 95 % intervals, bar plots, top-down maps and videos into the hydra run directory.
"""

from __future__ import annotations

import hydra
from utils import make_episode_set, run_evaluation


@hydra.main(config_path="", config_name="config", version_base="1.3")
def main(cfg) -> None:
    episode_set = make_episode_set(cfg)
    result = run_evaluation(cfg, episode_set)
    print((result.out_dir / "summary.md").read_text(), end="")
    print(f"results in {result.out_dir}")


if __name__ == "__main__":
    main()
