"""NavFormer cross-task training recipe (paper §VI):
``python recipes/navformer/navformer.py [key=value ...]``.

Laid out as TorchRL's ``sota-implementations/decision_transformer/dt.py``: the ``make_*`` calls, then the
loop. Per iteration (:func:`~navformer_rl.training.step.train_step`): a batch of 25 D_e or 150 D_ca
trajectories (alternating) -> ActionMSELoss (eq. 10), a batch of 512 D_ssl pairs -> BYOLLoss (eq. 8), one
backward of L = L_BYOL + L_DT (eq. 11), the AdamW step of the navigation network and the Adam step of the DVE,
BYOL's EMA update. The pieces and the loop are the library's (:mod:`navformer_rl.training`), so
``navformer train`` runs the same loop on the same YAML. The configuration is the packaged
``navformer_rl/config/train.yaml`` (``config.yaml`` composes it); overrides go on the command line (hydra),
e.g.::

    python recipes/navformer/navformer.py data.exploration_path=/data/e data.collision_path=/data/ca \\
        data.ssl_path=/data/ssl ablation=no_thsc model.autocast_dtype=bfloat16
    torchrun --nproc-per-node 2 recipes/navformer/navformer.py ... output_dir=/abs/runs/nf \\
        hydra.run.dir=/abs/runs/nf

A mistake the user can fix is printed as one line, ``navformer.py: error: <message>``, with exit status 2,
like ``navformer train`` (``NAVFORMER_DEBUG=1`` shows the traceback); a refused run leaves no hydra folder
behind.
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

from navformer_rl.training import (  # noqa: E402
    TrainConfig,
    Trainer,
    TrainResult,
    make_batchers,
    make_learner,
    make_model_and_losses,
    make_optimizers,
    prepare_run,
    seed_everything,
    start_run,
    train_loop,
)
from navformer_rl.training.distributed import is_main_process, process_group  # noqa: E402
from navformer_rl.training.factories import TRAJECTORY_KEYS, context_steps, start_alike  # noqa: E402
from navformer_rl.training.validation import make_validator  # noqa: E402


@hydra.main(config_path="", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    # A mistake (unknown ablation, missing dataset, batch larger than a dataset, ...) ends in one line and
    # exit status 2 (NAVFORMER_DEBUG=1: the traceback)
    with user_errors("navformer.py"):
        # train.yaml + overrides -> TrainConfig (output_dir: hydra's run folder unless given)
        train_cfg = make_train_config(cfg)
        with process_group(train_cfg.device):  # under torchrun: one process of the group
            result = train(train_cfg)
    if is_main_process():  # under torchrun every process trains; rank 0 reports
        print(result.summary())


def train(train_cfg: TrainConfig) -> TrainResult:
    """The library's :func:`navformer_rl.training.train`, spelled out: the ``make_*`` calls, then the loop."""
    # every check, the datasets, the checkpoint to resume (resume=true) or the weights to start from
    # (init_from=)
    run = prepare_run(train_cfg)
    cfg, device, distributed = run.cfg, run.device, run.distributed
    seed_everything(cfg.seed)

    # D_e | D_ca trajectory batches (cross-task, alternating) and D_ssl (o^s, o^d) pairs
    cross_task, pairs = make_batchers(cfg, run.datasets, device=device, distributed=distributed)
    # NavFormer (DVE, causal transformer, THSC head), its TensorDict actor, ActionMSELoss (L_DT) and
    # BYOLLoss (L_BYOL) with its EMA target and tau schedule
    parts = make_model_and_losses(cfg, device=device, distributed=distributed)
    # §VI's optimisers: AdamW (embeddings, transformer, head), Adam (the DVE: encoders, BYOL heads)
    learner = make_learner(cfg, parts, make_optimizers(cfg, parts))
    validator = make_validator(
        cfg.validation, run.validation_datasets, run.datasets, context_steps(cfg), keys=TRAJECTORY_KEYS
    )
    start_alike(parts, cfg, distributed)  # data-parallel: rank 0's weights on every process
    trainer = Trainer(
        cfg,
        cross_task=cross_task,
        pairs=pairs,
        parts=parts,
        learner=learner,
        validator=validator,
        distributed=distributed,
    )
    start_run(run, trainer)  # resume / init_from, run files, logger

    # The loop `navformer train` runs: per iteration trainer.step() (sample; train_step: L_DT + L_BYOL, one
    # backward, AdamW and Adam steps, BYOL's EMA update), a log row, validation when due, checkpoints
    return train_loop(trainer)


if __name__ == "__main__":
    main()
