"""NavFormer cross-task training (paper §VI) as a library function: ``train(TrainConfig) -> TrainResult``.

One iteration (eq. 11)::

    batch = cross_task.sample()                  # CrossTaskReplayBuffer: 25 trajectories of D_e or 150 of D_ca, in turn
    pairs = ssl_batcher.sample()                 # 512 (o^s, o^d) pairs of D_ssl     (unless SSL is ablated)
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
- :mod:`~navformer_rl.training.checkpoint`: atomic checkpoint folders (run part + resume part), loading.
- :mod:`~navformer_rl.training.distributed`: data-parallel training under ``torchrun`` (process group, the
  global batch's split, gradient all-reduce, global BatchNorm for BYOL).
- :mod:`~navformer_rl.training.init_from`: fine-tuning from a checkpoint's weights (``init_from=``).
- :mod:`~navformer_rl.training.validation`: teacher-forced L_DT on held-out trajectories (``validation.*``,
  ``navformer validate``).
- :mod:`~navformer_rl.training.averaging`: one checkpoint from the mean of a run's checkpoints' weights
  (``navformer average-checkpoints``, an opt-in).
- :mod:`~navformer_rl.training.cli`, :mod:`~navformer_rl.training.validate_cli`,
  :mod:`~navformer_rl.training.average_cli`: ``navformer train``, ``navformer validate`` and
  ``navformer average-checkpoints``.

Names are imported lazily, so the commands answer ``--help`` and argument errors without importing torch.
"""

from __future__ import annotations

from navformer_rl.utils.lazy import lazy_exports

_EXPORTS = {
    "ABLATIONS": "navformer_rl.training.config",
    "BATCH_KEYS": "navformer_rl.training.trainer",
    "CheckpointConfig": "navformer_rl.training.config",
    "DATASET_KEYS": "navformer_rl.training.datasets",
    "DataConfig": "navformer_rl.training.config",
    "ENCODER_TRAINING": "navformer_rl.training.config",
    "LOGGER_BACKENDS": "navformer_rl.training.config",
    "LogWindow": "navformer_rl.training.log_window",
    "LoggerConfig": "navformer_rl.training.config",
    "MODEL_KEYS_SET_ELSEWHERE": "navformer_rl.training.config",
    "OptimConfig": "navformer_rl.training.config",
    "RESOLVED_MODEL_KEY": "navformer_rl.training.config_io",
    "RESUME_MAY_CHANGE": "navformer_rl.training.trainer",
    "SSLConfig": "navformer_rl.training.config",
    "TRAJECTORY_KEYS": "navformer_rl.training.trainer",
    "TrainConfig": "navformer_rl.training.config",
    "TrainResult": "navformer_rl.training.run",
    "Trainer": "navformer_rl.training.trainer",
    "average_checkpoints": "navformer_rl.training.averaging",
    "build_trainer": "navformer_rl.training.run",
    "check_datasets_fit_model": "navformer_rl.training.datasets",
    "config_from_dict": "navformer_rl.training.config_io",
    "default_config_path": "navformer_rl.training.config_io",
    "load_train_config": "navformer_rl.training.config_io",
    "model_config": "navformer_rl.training.config",
    "open_datasets": "navformer_rl.training.datasets",
    "open_validation_datasets": "navformer_rl.training.datasets",
    "printable_config": "navformer_rl.training.config_io",
    "train": "navformer_rl.training.run",
    "validate_config": "navformer_rl.training.config",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
