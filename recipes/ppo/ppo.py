"""DSAC / MA-TDN trained online with PPO (paper §VII.A baselines):
``python recipes/ppo/ppo.py [key=value ...]``.

Per batch: a multi-process collector (``MultiSyncCollector`` over ``MultiRobotNavEnv`` workers, every robot
driven by the policy, shaped reward) -> GAE per robot -> ``ClipPPOLoss`` epochs over minibatches of
robot-steps -> Adam -> the workers' weights updated; a row in ``progress.csv``, the fixed-episode success
rate and a checkpoint every few batches. The configuration is the packaged ``navformer_rl/config/ppo.yaml``
(``config.yaml`` composes it); overrides go on the command line (hydra), e.g.::

    python recipes/ppo/ppo.py method=matdn collector.total_frames=200000 output_dir=/abs/runs/ppo/matdn

A mistake the user can fix is printed as one line, ``ppo.py: error: <message>``, with exit status 2, like
``navformer train-ppo`` (``NAVFORMER_DEBUG=1`` shows the traceback); a refused run leaves no hydra folder.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

# recipes/ holds recipe_errors.py, which the recipes share
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from recipe_errors import user_errors  # noqa: E402
from utils import make_ppo_config  # noqa: E402

from navformer_rl.online.train import train_ppo  # noqa: E402


@hydra.main(config_path="", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    with user_errors("ppo.py"):
        # ppo.yaml + overrides -> PPOConfig, every key and range checked
        ppo_cfg = make_ppo_config(cfg)
        # the library's loop, as `navformer train-ppo` runs it (resuming from output_dir's latest checkpoint
        # when resume=true): collect -> GAE -> ClipPPOLoss epochs -> Adam -> update the workers' weights,
        # with progress.csv, the fixed-episode evaluation, checkpoints and learning_curve.png
        result = train_ppo(ppo_cfg)
    print(result.summary())


if __name__ == "__main__":
    main()
