"""TorchRL's ``MinariExperienceReplay`` over a local Minari dataset, with its rows actually filled.

TorchRL 0.14.1's ``MinariExperienceReplay._download_and_preproc`` fills an in-memory TensorDict with the
episodes and then returns ``td_data.memmap_like(root / dataset_id)``: a memmap of the same keys and shapes
*without the content*, so every row it serves is zeros (any Minari dataset, local or downloaded). It
also reads the whole HDF5 file into memory first. :func:`minari_replay_buffer` builds the buffer as TorchRL
does (``load_from_local_minari=True``: same keys, specs and metadata) and then writes the episodes into its
storage one at a time, in TorchRL's TED layout:

==========================================  ==========================================================
key (rows ``[steps]``)                      from Minari episode ``e`` of ``T`` steps, rows ``i..i+T-1``
==========================================  ==========================================================
``("observation", k)``                      ``e.observations[k][:-1]``
``("next", "observation", k)``              ``e.observations[k][1:]``
``("info", k)`` / ``("next", "info", k)``   ``e.infos[k][:-1]`` / ``e.infos[k][1:]`` (keys TorchRL kept)
``"action"``                                ``e.actions``
``("next", "reward" | "terminated" |        ``e.rewards`` / ``e.terminations`` / ``e.truncations`` ``[T, 1]``;
"truncated" | "done")``                     done = terminated | truncated
``"episode"``                               ``e.id``
==========================================  ==========================================================
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from navformer_rl.export.minari import DATASETS_PATH_ENV, minari_root, require_minari


@contextlib.contextmanager
def _datasets_path(path: Path) -> Iterator[None]:
    """``MINARI_DATASETS_PATH=path`` inside the block, the previous value (or none) after it."""
    previous = os.environ.get(DATASETS_PATH_ENV)
    os.environ[DATASETS_PATH_ENV] = str(path)
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop(DATASETS_PATH_ENV, None)
        else:
            os.environ[DATASETS_PATH_ENV] = previous


def minari_replay_buffer(
    dataset_id: str,
    batch_size: int,
    *,
    datasets_path: str | os.PathLike | None = None,
    root: str | os.PathLike | None = None,
    **kwargs: Any,
) -> Any:
    """``MinariExperienceReplay(dataset_id, batch_size, root=root, load_from_local_minari=True, **kwargs)``
    with the episodes of the local Minari dataset written into its storage (module docstring).

    Args:
        dataset_id: a dataset under ``datasets_path`` (e.g. one written by ``navformer export minari``).
        batch_size: the buffer's default sample size.
        datasets_path: the Minari datasets folder (default: ``$MINARI_DATASETS_PATH``, else
            ``~/.minari/datasets``).
        root: TorchRL's folder for its memmapped copy (default: TorchRL's cache, ``~/.cache/torchrl/minari``);
            the copy goes to ``root/dataset_id``.
        **kwargs: other ``MinariExperienceReplay`` arguments (``sampler``, ``transform``, ...).

    Returns:
        The ``MinariExperienceReplay``; ``sample()`` rows hold ``index`` (the row, episodes in id order).
    """
    import torch
    from torchrl.data.datasets.minari_data import MinariExperienceReplay

    minari = require_minari()
    path = minari_root(datasets_path)
    with _datasets_path(path):
        if not (path / dataset_id / "data").is_dir():
            raise FileNotFoundError(f"no Minari dataset {dataset_id!r} in {path}")
        replay = MinariExperienceReplay(
            dataset_id, batch_size, root=root, load_from_local_minari=True, **kwargs
        )
        dataset = minari.load_dataset(dataset_id)
    storage = replay.storage
    row = 0
    for episode in dataset.iterate_episodes():
        steps = len(episode)
        rows = storage[row : row + steps]
        rows.set_("episode", torch.full((steps,), int(episode.id), dtype=rows["episode"].dtype))
        for group, name in (("observations", "observation"), ("infos", "info")):
            for key, value in (getattr(episode, group) or {}).items():
                if (name, key) in rows.keys(include_nested=True):
                    value = torch.as_tensor(value)
                    rows.set_((name, key), value[:-1])
                    rows.set_(("next", name, key), value[1:])
        rows.set_("action", torch.as_tensor(episode.actions))
        terminated = torch.as_tensor(episode.terminations).unsqueeze(-1)
        truncated = torch.as_tensor(episode.truncations).unsqueeze(-1)
        rows.set_(("next", "reward"), torch.as_tensor(episode.rewards).unsqueeze(-1))
        rows.set_(("next", "terminated"), terminated)
        rows.set_(("next", "truncated"), truncated)
        rows.set_(("next", "done"), terminated | truncated)
        storage[row : row + steps] = rows
        row += steps
    if row != len(storage):
        raise RuntimeError(
            f"Minari dataset {dataset_id} holds {row} steps, but TorchRL's buffer over it {len(storage)}"
        )
    return replay
