"""NavFormer cross-task training recipe (paper §VI): ``python recipes/navformer/navformer.py [key=value ...]``.

Per iteration: a batch of 25 D_e or 150 D_ca trajectories (alternating) -> ActionMSELoss (eq. 10), a batch of
512 D_ssl pairs -> BYOLLoss (eq. 8), one backward of L = L_BYOL + L_DT (eq. 11), AdamW + Adam steps, BYOL's EMA
update. The configuration is the packaged ``navformer_rl/config/train.yaml`` (``config.yaml`` composes it);
overrides go on the command line (hydra), e.g.::

    python recipes/navformer/navformer.py data.exploration_path=/data/e data.collision_path=/data/ca \\
        data.ssl_path=/data/ssl ablation=no_thsc model.autocast_dtype=bfloat16
    torchrun --nproc-per-node 2 recipes/navformer/navformer.py ... output_dir=/abs/runs/nf hydra.run.dir=/abs/runs/nf

A mistake the user can fix is printed as one line, ``navformer.py: error: <message>``, with exit status 2, like
``navformer train`` (``NAVFORMER_DEBUG=1`` shows the traceback); a refused run leaves no hydra folder behind.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

# recipes/ holds recipe_errors.py, which the recipes share
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from recipe_errors import user_errors  # noqa: E402
from utils import make_train_config  # noqa: E402

from navformer_rl.training import train  # noqa: E402
from navformer_rl.training.distributed import is_main_process  # noqa: E402


@hydra.main(config_path="", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    # A mistake (unknown ablation, missing dataset, batch larger than a dataset, ...) ends in one line and
    # exit status 2 (NAVFORMER_DEBUG=1: the traceback)
    with user_errors("navformer.py"):
        # train.yaml + overrides -> TrainConfig (output_dir: hydra's run folder unless given)
        train_cfg = make_train_config(cfg)
        # the library's loop, as `navformer train` runs it: every check, then (resuming from output_dir's
        # latest checkpoint when resume=true) sample (D_e | D_ca) + D_ssl -> L_DT + L_BYOL -> backward ->
        # AdamW / Adam -> EMA, with log rows, validation and checkpoints
        result = train(train_cfg)
    if is_main_process():  # under torchrun every process trains; rank 0 reports
        print(result.summary())


if __name__ == "__main__":
    main()
