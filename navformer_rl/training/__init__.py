"""NavFormer cross-task training (paper §VI) as a library function: ``train(TrainConfig) -> TrainResult``.

One iteration (eq. 11)::

    task, batch = cross_task.sample()            # 25 trajectories of D_e or 150 of D_ca, alternating
    pairs       = ssl_batcher.sample()           # 512 (o^s, o^d) pairs of D_ssl     (unless SSL is ablated)
    L = ActionMSELoss(batch)["loss_dt"] + BYOLLoss(pairs)["loss_byol"]
    L.backward(); AdamW.step() (NavFormer); Adam.step() (DVE: BYOL projector/predictor [+ encoders])
    SoftUpdate.step(); tau <- cosine schedule    # BYOL's EMA target

:func:`train` is the one training loop; ``navformer train`` and the hydra recipe (``recipes/navformer``)
both call it. Its pieces: :func:`load_train_config` (YAML/dict -> dataclasses), :func:`build_trainer`
(validates everything, opens the datasets, builds model, losses, optimisers, logger, restores a checkpoint
when resuming), ``Trainer.step()``, ``Trainer.record()`` (adds the iteration's metrics to the log window and
writes a row every ``logger.log_interval`` iterations), ``Trainer.save_checkpoint()``.

Library code: no hydra here. Configuration comes as plain dataclasses; ``navformer train`` and the hydra
recipe both build them from the packaged ``navformer_rl/config/train.yaml`` (the recipe composes it).

Modules (one job each):

- :mod:`~navformer_rl.training.config`: the configuration dataclasses (``TrainConfig`` and its sections),
  :data:`ABLATIONS`, :func:`validate_config` (static checks) and :func:`model_config` (the model it builds).
- :mod:`~navformer_rl.training.config_io`: configurations from ``train.yaml`` / dicts / ``key=value``
  overrides (:func:`load_train_config`, :func:`config_from_dict`) and back (:func:`printable_config`).
- :mod:`~navformer_rl.training.datasets`: opening the datasets a configuration names and checking that its
  model can read them.
- :mod:`~navformer_rl.training.log_window`: :class:`LogWindow`, the metrics summarised into each log row.
- :mod:`~navformer_rl.training.trainer`: :class:`Trainer`, one built run (``step``, logging, checkpoints,
  resume).
- :mod:`~navformer_rl.training.run`: :func:`build_trainer` and :func:`train` (the loop), :class:`TrainResult`.
"""

from navformer_rl.training.config import (
    ABLATIONS,
    ENCODER_TRAINING,
    LOGGER_BACKENDS,
    MODEL_KEYS_SET_ELSEWHERE,
    CheckpointConfig,
    DataConfig,
    LoggerConfig,
    OptimConfig,
    SSLConfig,
    TrainConfig,
    model_config,
    validate_config,
)
from navformer_rl.training.config_io import (
    RESOLVED_MODEL_KEY,
    config_from_dict,
    default_config_path,
    load_train_config,
    printable_config,
)
from navformer_rl.training.datasets import (
    DATASET_KEYS,
    check_datasets_fit_model,
    open_datasets,
    open_validation_datasets,
)
from navformer_rl.training.log_window import LogWindow
from navformer_rl.training.run import TrainResult, build_trainer, train
from navformer_rl.training.trainer import BATCH_KEYS, RESUME_MAY_CHANGE, TRAJECTORY_KEYS, Trainer

__all__ = [
    "ABLATIONS",
    "BATCH_KEYS",
    "DATASET_KEYS",
    "ENCODER_TRAINING",
    "LOGGER_BACKENDS",
    "MODEL_KEYS_SET_ELSEWHERE",
    "RESOLVED_MODEL_KEY",
    "RESUME_MAY_CHANGE",
    "TRAJECTORY_KEYS",
    "CheckpointConfig",
    "DataConfig",
    "LogWindow",
    "LoggerConfig",
    "OptimConfig",
    "SSLConfig",
    "TrainConfig",
    "TrainResult",
    "Trainer",
    "build_trainer",
    "check_datasets_fit_model",
    "config_from_dict",
    "default_config_path",
    "load_train_config",
    "model_config",
    "open_datasets",
    "open_validation_datasets",
    "printable_config",
    "train",
    "validate_config",
]
