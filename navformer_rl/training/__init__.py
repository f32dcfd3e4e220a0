"""NavFormer cross-task training (paper §VI) as a library function: ``train(TrainConfig) -> TrainResult``.

One iteration (eq. 11, :func:`~navformer_rl.training.step.train_step`)::

    batch = cross_task.sample()                  # CrossTaskReplayBuffer: 25 trajectories of D_e or 150
                                                 # of D_ca, in turn
    pairs = ssl_batcher.sample()                 # 512 (o^s, o^d) pairs of D_ssl     (unless SSL is ablated)
    L = ActionMSELoss(batch)["loss_dt"] + BYOLLoss(pairs)["loss_byol"]
    L.backward(); AdamW.step() (navigation network); Adam.step() (DVE: encoders + BYOL projector/predictor)
    SoftUpdate.step(); tau <- cosine schedule    # BYOL's EMA target

Laid out TorchRL's way (``sota-implementations/decision_transformer``): ``make_*`` factories
(:mod:`~navformer_rl.training.factories`: batchers, model and losses, optimisers, learner, logger), a plain
``train_step`` with the trajectory-chunk and data-parallel backward as wrappers around it
(:mod:`~navformer_rl.training.step`), and one loop (:func:`train_loop`). :func:`train` =
:func:`prepare_run` (every check) + :func:`make_trainer` (the ``make_*`` calls) + :func:`start_run` (resume,
``init_from``, run files, logger) + :func:`train_loop`; ``navformer train`` calls it and the hydra recipe
(``recipes/navformer``) makes the same calls, so both run the one loop.

Library code: no hydra here. Configuration comes as plain dataclasses; ``navformer train`` and the hydra
recipe both build them from the packaged ``navformer_rl/config/train.yaml`` (the recipe composes it).

Modules (one job each):

- :mod:`~navformer_rl.training.config`: the configuration dataclasses (``TrainConfig`` and its sections),
  :data:`ABLATIONS`, :func:`validate_config` (static checks) and :func:`model_config` (the model it builds).
- :mod:`~navformer_rl.training.config_io`: configurations from ``train.yaml`` / dicts / ``key=value``
  overrides (:func:`load_train_config`, :func:`config_from_dict`) and back (:func:`printable_config`).
- :mod:`~navformer_rl.training.datasets`: opening the datasets a configuration names and checking that its
  model can read them.
- :mod:`~navformer_rl.training.factories`: the ``make_*`` pieces of a run.
- :mod:`~navformer_rl.training.step`: one iteration of eq. 11 and its backward wrappers.
- :mod:`~navformer_rl.training.log_window`: :class:`LogWindow`, the metrics summarised into each log row.
- :mod:`~navformer_rl.training.trainer`: :class:`Trainer`, one built run (``step`` with its metrics, logging,
  checkpoints, resume).
- :mod:`~navformer_rl.training.run`: :func:`prepare_run`, :func:`make_trainer`, :func:`start_run`,
  :func:`build_trainer`, :func:`train_loop` and :func:`train`, :class:`TrainResult`.
- :mod:`~navformer_rl.training.checkpoint`: atomic checkpoint folders (run part + resume part), loading, the
  state-dict names of earlier checkpoints (``upgrade_state_dict``).
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
    "BATCH_KEYS": "navformer_rl.training.factories",
    "CheckpointConfig": "navformer_rl.training.config",
    "DATASET_KEYS": "navformer_rl.training.datasets",
    "DataConfig": "navformer_rl.training.config",
    "ENCODER_TRAINING": "navformer_rl.training.config",
    "LOGGER_BACKENDS": "navformer_rl.training.config",
    "Learner": "navformer_rl.training.step",
    "LogWindow": "navformer_rl.training.log_window",
    "LoggerConfig": "navformer_rl.training.config",
    "MODEL_KEYS_SET_ELSEWHERE": "navformer_rl.training.config",
    "ModelAndLosses": "navformer_rl.training.factories",
    "OptimConfig": "navformer_rl.training.config",
    "PreparedRun": "navformer_rl.training.run",
    "RESOLVED_MODEL_KEY": "navformer_rl.training.config_io",
    "RESUME_MAY_CHANGE": "navformer_rl.training.trainer",
    "SSLConfig": "navformer_rl.training.config",
    "TRAJECTORY_KEYS": "navformer_rl.training.factories",
    "TrainConfig": "navformer_rl.training.config",
    "TrainResult": "navformer_rl.training.run",
    "Trainer": "navformer_rl.training.trainer",
    "average_checkpoints": "navformer_rl.training.averaging",
    "build_trainer": "navformer_rl.training.run",
    "check_datasets_fit_model": "navformer_rl.training.datasets",
    "config_from_dict": "navformer_rl.training.config_io",
    "default_config_path": "navformer_rl.training.config_io",
    "load_train_config": "navformer_rl.training.config_io",
    "make_batchers": "navformer_rl.training.factories",
    "make_learner": "navformer_rl.training.factories",
    "make_logger": "navformer_rl.training.factories",
    "make_model_and_losses": "navformer_rl.training.factories",
    "make_optimizers": "navformer_rl.training.factories",
    "make_trainer": "navformer_rl.training.run",
    "model_config": "navformer_rl.training.config",
    "open_datasets": "navformer_rl.training.datasets",
    "open_validation_datasets": "navformer_rl.training.datasets",
    "prepare_run": "navformer_rl.training.run",
    "printable_config": "navformer_rl.training.config_io",
    "seed_everything": "navformer_rl.training.factories",
    "start_run": "navformer_rl.training.run",
    "train": "navformer_rl.training.run",
    "train_loop": "navformer_rl.training.run",
    "train_step": "navformer_rl.training.step",
    "validate_config": "navformer_rl.training.config",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
