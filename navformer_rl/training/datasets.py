"""The datasets of a training run: :func:`open_datasets` (D_e, D_ca, D_ssl as the ablation needs them),
:func:`open_validation_datasets` (the held-out sets) and :func:`check_datasets_fit_model` (the configured
model can read them). Errors name the config key to change.

A trajectory dataset setting may list several folders of its kind (``data.exploration_path=[a,b]``): they
are read as one (:class:`~navformer_rl.data.concat.ConcatNavDataset`, their trajectories in list order), and
``data.exploration_trajectories`` / ``data.collision_trajectories`` keep the first N of the concatenation.
One folder (or a list of one) is opened exactly as before.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from navformer_rl.tasks import DATASETS
from navformer_rl.training.config import PATH_KEYS, DatasetPaths, TrainConfig, dataset_folders, model_config

DATASET_KEYS = {kind: d.path_key for kind, d in DATASETS.items()}
"""The config key (under ``data.``) of each dataset kind."""
SUBSET_KEYS = {kind: d.subset_key for kind, d in DATASETS.items()}
"""The config key (under ``data.``) that keeps only a dataset's first N items."""


def open_datasets(cfg: TrainConfig) -> dict[str, Any]:
    """Open (and validate: schema version, kind, file sizes) the datasets the configuration uses.

    A dataset smaller than one batch is refused with the batch-size key to lower and the largest value that
    fits (every such dataset in one message, so that a single edit of the command line fixes them all).
    """
    used = {"e": cfg.uses_exploration, "ca": cfg.uses_collision, "ssl": cfg.uses_ssl}
    datasets = {}
    too_small: list[tuple[str, str, int | None]] = []
    for kind, info in DATASETS.items():
        key, batch_key = info.path_key, info.batch_key
        if not used[kind]:
            continue
        path = getattr(cfg.data, key)
        dataset = _open_dataset(path, kind, f"data.{key}")
        dataset = _head(dataset, SUBSET_KEYS[kind], getattr(cfg.data, SUBSET_KEYS[kind]), path)
        available = dataset.num_trajectories if kind != "ssl" else len(dataset)
        batch = getattr(cfg.data, batch_key)
        if batch > available:
            unit = "pairs" if kind == "ssl" else "trajectories"
            problem = (
                f"data.{key}={path!r} holds {available} {unit}, fewer than one batch of "
                f"data.{batch_key}={batch}"
            )
            too_small.append((problem, f"data.{batch_key}", _largest_batch(cfg, kind, available)))
        datasets[kind] = dataset
    if too_small:
        fixes = " ".join(f"{key}={fits}" for _, key, fits in too_small if fits is not None)
        hopeless = [key for _, key, fits in too_small if fits is None]
        chunks = cfg.optim.trajectory_chunks
        if hopeless:
            advice = f"no value of {' / '.join(hopeless)} fits this little data: collect more data"
            if chunks > 1 and any(key != "data.ssl_batch_pairs" for key in hopeless):
                advice += f" or lower optim.trajectory_chunks={chunks}"
            advice += f" (and add {fixes})" if fixes else ""
        else:
            if len(too_small) == 1:
                largest = "the largest batch size that fits"
                largest += f" and is a multiple of optim.trajectory_chunks={chunks}" if chunks > 1 else ""
            else:
                largest = "the largest batch sizes that fit"
                largest += f" and are multiples of optim.trajectory_chunks={chunks}" if chunks > 1 else ""
            advice = f"add {fixes} ({largest}) or collect more data"
        raise ValueError("; ".join([*(problem for problem, _, _ in too_small), advice]))
    return datasets


def _head(dataset: Any, key: str, first: int | None, path: str) -> Any:
    """``dataset.head(first)`` (``None``: the whole dataset), with an error naming ``data.<key>``."""
    if first is None:
        return dataset
    total = dataset.num_trajectories if key != "ssl_pairs" else len(dataset)
    if isinstance(first, bool) or not isinstance(first, int) or not 1 <= first <= total:
        raise ValueError(
            f"data.{key}={first!r}: expected null or an integer in [1, {total}] (what {path!r} holds)"
        )
    return dataset.head(first)


def open_validation_datasets(cfg: TrainConfig) -> dict[str, Any]:
    """Open (and validate) the held-out datasets of ``cfg.validation`` (``{}`` when validation is off)."""
    if not cfg.validation.enabled:
        return {}
    return {
        kind: _open_dataset(path, kind, f"validation.{PATH_KEYS[kind]}")
        for kind, path in cfg.validation.held_out_paths().items()
    }


def _open_dataset(path: DatasetPaths, kind: str, key: str) -> Any:
    """``open_dataset(path, kind)`` with errors that name the config ``key``; a list of several folders is
    opened folder by folder (errors name ``key[i]``) and read as one
    (:func:`~navformer_rl.data.concat.concat_datasets`)."""
    from navformer_rl.data import open_dataset
    from navformer_rl.data.concat import concat_datasets

    folders = dataset_folders(path)
    if len(folders) == 1:
        return _open_one(open_dataset, folders[0], kind, key)
    parts = [_open_one(open_dataset, folder, kind, f"{key}[{i}]") for i, folder in enumerate(folders)]
    try:
        return concat_datasets(parts)
    except ValueError as err:
        raise ValueError(f"{key}: {err}") from None


def _open_one(open_dataset: Any, path: str, kind: str, key: str) -> Any:
    """``open_dataset(path, kind)`` of one folder, with errors that name the config ``key``."""
    if not Path(path).exists():
        raise FileNotFoundError(f"{key}={path!r} does not exist")
    try:
        return open_dataset(path, kind=kind)
    except (ValueError, FileNotFoundError) as err:
        raise type(err)(f"{key}: {err}") from None


def _largest_batch(cfg: TrainConfig, kind: str, available: int) -> int | None:
    """The largest valid batch size of dataset ``kind`` holding ``available`` items (None when none is).

    Trajectory batches must divide by ``optim.trajectory_chunks``; BYOL needs at least 2 pairs.
    """
    if kind == "ssl":
        return available if available >= 2 else None
    fits = available - available % cfg.optim.trajectory_chunks
    return fits if fits > 0 else None


def check_datasets_fit_model(cfg: TrainConfig, datasets: Mapping[str, Any], section: str = "data") -> None:
    """Raise ``ValueError`` when the model of ``cfg`` cannot read ``datasets`` (opened by
    :func:`open_datasets`, or by :func:`open_validation_datasets` with ``section="validation"``: the config
    section that errors name).

    Checked: image size and action width (every dataset's images are ``image_size`` square; trajectory
    actions are ``action_dim`` wide) and the timestep table (the longest trajectory's last step must be
    ``< model.max_timestep``): :func:`navformer_rl.data.fit.check_model_reads`.
    """
    from navformer_rl.data.fit import check_model_reads

    model = model_config(cfg)
    for kind, dataset in datasets.items():
        key = f"{section}.{DATASET_KEYS[kind]}"
        parts = getattr(dataset, "parts", None)
        if parts is None:
            check_model_reads(model, {kind: dataset}, {kind: key}, tunable=True)
        for i, part in enumerate(parts or ()):
            check_model_reads(model, {kind: part}, {kind: f"{key}[{i}]"}, tunable=True)
