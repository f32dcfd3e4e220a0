"""Write a trajectory dataset (D_e, D_ca) as a Minari dataset (``navformer export minari``, docs/datasets.md).

One stored trajectory is one Minari episode of ``T`` steps (our keys: :mod:`navformer_rl.data.schema`):

* ``observations["pixels"]`` uint8 ``[T+1, 84, 84, 3]``: ``pixels`` o_0 .. o_{T-1}, then o_{T-1} again;
* ``observations["target_pixels"]`` uint8 ``[T+1, 84, 84, 3]``: the trajectory's target image g, every step;
* ``actions`` float32 ``[T, 2]``: ``action``; ``rewards`` float32 ``[T]``: ``("next", "reward")``;
* ``terminations`` / ``truncations`` bool ``[T]``: ``("next", "terminated")`` / ``("next", "truncated")``;
* ``infos["collision"]`` bool ``[T+1]``: False at reset, then ``("next", "collision")``.

Minari wants ``T + 1`` observations (the one after the last action included); our datasets store the frame
taken before each action only, so the final observation repeats the last frame (TorchRL's
``("next", "observation")`` of an episode's last step equals its ``observation``). The observation and action
spaces are ``navformer_rl/TargetNav-v0``'s; D_e (single robot, mazes) also records that env's spec, D_ca
(a robot among 2-8 others in the arena, all driven by the expert) records none. Our ``metadata.json`` goes
into the Minari metadata under ``"navformer_rl"`` (kind, settings, seeds, counts, versions).

The episodes are written in chunks of whole trajectories of at most ``chunk_steps`` steps (a longer
trajectory is a chunk alone; collection caps them at 500 steps), so memory is bounded by a chunk, not the
dataset. Images are stored raw (no JPEG: Minari's JPEG option is lossy and TorchRL reads the HDF5 file
directly). The dataset is written in a temporary folder and renamed into place.

Only the standard library is imported at module level: ``navformer --help`` imports this module.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from navformer_rl.utils.checks import check_int

if TYPE_CHECKING:
    import gymnasium as gym
    from gymnasium.envs.registration import EnvSpec

    from navformer_rl.data.dataset import NavDataset

DEFAULT_CHUNK_STEPS = 1024
"""Steps per written chunk: about 45 MB of frames and target images in memory."""

INSTALL_HINT = 'pip install "navformer_rl[minari]"'

DATASETS_PATH_ENV = "MINARI_DATASETS_PATH"
"""Minari's (and TorchRL's ``load_from_local_minari=True``) datasets folder."""

LOCK_FILE = ".export.lock"
_TMP_PREFIX, _TMP_SUFFIX = ".data.", ".tmp"
_NAMESPACE_METADATA = "namespace_metadata.json"

_ID_PATTERN = re.compile(r"(?P<namespace>[-_\w][-_\w/]*[-_\w]+)/(?P<name>[-_\w]+?)-v(?P<version>\d+)")
"""``NAMESPACE/NAME-vN``: minari's dataset id pattern with the namespace and version required."""

EXPERTS = {
    "e": "ExplorationExpert (lidar log-odds map, frontier exploration, A*, DWA)",
    "ca": "NHORCAExpert (non-holonomic ORCA, every robot to its own target)",
}
"""``algorithm_name`` of each kind's collected data."""


class MinariNotInstalledError(ImportError):
    """``minari`` or ``h5py`` cannot be imported; the message says how to install them."""


def parse_minari_id(dataset_id: str) -> tuple[str, str, int]:
    """``"navformer/e-v0"`` -> ``("navformer", "e", 0)``; ``ValueError`` unless it is
    ``NAMESPACE/NAME-vN``."""
    match = _ID_PATTERN.fullmatch(dataset_id) if isinstance(dataset_id, str) else None
    if match is None:
        raise ValueError(
            f"Minari dataset id {dataset_id!r} is not NAMESPACE/NAME-vN (NAMESPACE: 2 or more letters, "
            "digits, '-', '_', '/'; NAME: letters, digits, '-', '_'; N: an integer; "
            "e.g. navformer/e-small-v0)"
        )
    return match["namespace"], match["name"], int(match["version"])


def minari_root(root: str | os.PathLike | None = None) -> Path:
    """The Minari datasets folder: ``root``, else ``$MINARI_DATASETS_PATH``, else ``~/.minari/datasets``."""
    if root is not None:
        return Path(root)
    env = os.environ.get(DATASETS_PATH_ENV)
    return Path(env) if env else Path.home() / ".minari" / "datasets"


def episode_chunks(lengths: Sequence[int], chunk_steps: int) -> list[tuple[int, int]]:
    """Consecutive trajectory ranges ``[first, last)`` of at most ``chunk_steps`` steps each (a longer
    trajectory alone): ``episode_chunks([3, 4, 5, 9], 8) == [(0, 2), (2, 3), (3, 4)]``."""
    check_int(chunk_steps, "chunk_steps")
    chunks: list[tuple[int, int]] = []
    first, steps = 0, 0
    for index, length in enumerate(lengths):
        if index > first and steps + int(length) > chunk_steps:
            chunks.append((first, index))
            first, steps = index, 0
        steps += int(length)
    if len(lengths):
        chunks.append((first, len(lengths)))
    return chunks


def minari_spaces() -> tuple[gym.spaces.Dict, gym.spaces.Box]:
    """Observation and action spaces of the export (those of ``navformer_rl/TargetNav-v0``):
    ``Dict(pixels=Box(0, 255, (84, 84, 3), uint8), target_pixels=Box(same))`` and
    ``Box(-1, 1, (2,), float32)``."""
    import gymnasium as gym
    import numpy as np

    from navformer_rl.data.schema import IMAGE_SHAPE

    image = gym.spaces.Box(0, 255, IMAGE_SHAPE, dtype=np.uint8)
    observation = gym.spaces.Dict({"pixels": image, "target_pixels": image})
    return observation, gym.spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)


def env_spec_for(kind: str) -> EnvSpec | None:
    """``navformer_rl/TargetNav-v0``'s spec for D_e (``"e"``: one robot in a maze, as the env); ``None`` for
    D_ca (a robot among others all driven by the expert, which the single-robot env does not model)."""
    if kind != "e":
        return None
    import gymnasium as gym

    from navformer_rl.envs.registration import ENV_ID, register_envs

    register_envs()
    return gym.spec(ENV_ID)


def require_minari() -> Any:
    """The ``minari`` module (with ``h5py``), or :class:`MinariNotInstalledError`."""
    try:
        import h5py  # noqa: F401  (minari's HDF5 storage)
        import minari
        from minari.dataset._storages import get_minari_storage

        get_minari_storage("hdf5")
    except ImportError as err:
        raise MinariNotInstalledError(
            f"exporting to Minari needs minari and h5py, which are not installed ({err}): {INSTALL_HINT}"
        ) from None
    return minari


def _open_trajectories(path: Path, verify: bool) -> NavDataset:
    """Open ``path`` as D_e or D_ca; one-line errors for a missing folder and for D_ssl."""
    from navformer_rl.data import open_dataset
    from navformer_rl.data.schema import DatasetKind

    if not path.is_dir():
        raise FileNotFoundError(f"dataset folder {path} does not exist")
    dataset = open_dataset(path, verify=verify)
    if dataset.kind is DatasetKind.SSL:
        raise ValueError(
            f"{path} is a D_ssl dataset: image pairs (o^s, o^d), not trajectories, so it has no Minari "
            "episodes; export D_e or D_ca"
        )
    if dataset.num_trajectories == 0:
        raise ValueError(f"{path} holds no trajectories; nothing to export")
    return dataset


def _description(dataset: NavDataset, with_env: bool) -> str:
    """The Minari ``description``: what the data is, its spaces, and where the provenance is."""
    from navformer_rl.tasks import DATASETS

    info = DATASETS[dataset.kind.value]
    what = {
        "e": "single-robot exploration trajectories in random mazes",
        "ca": "collision-avoidance trajectories of robots among 2-8 others in a 12.5 m arena",
    }[dataset.kind.value]
    env = (
        "Environment: navformer_rl/TargetNav-v0 (its env spec is recorded; world sizes vary per episode)."
        if with_env
        else "Multi-robot arena data: no environment spec is recorded (navformer_rl/TargetNav-v0 drives one "
        "robot among scripted ones); the spaces are given explicitly and are TargetNav-v0's."
    )
    return (
        f"NavFormer {info.paper_name} ({info.task}): {dataset.num_trajectories} {what} "
        f"({len(dataset)} steps), collected by navformer_rl {dataset.metadata.get('package_version')}. "
        "Observations: 'pixels' = camera frame o_t, 'target_pixels' = target image g (uint8 84x84x3 RGB). "
        "Actions: (linear, angular) "
        "velocity normalised to [-1, 1]. Reward 1 on the step the robot ends within 1.5 m of its target, "
        "else 0 (paper §VII.A); terminated on success, truncated at time-out. The final observation of each "
        "episode repeats its last frame (the stored data has no frame after the last action); "
        f"infos['collision'] is the contact flag after each step. {env} Provenance (settings, seeds, "
        "counts): metadata key 'navformer_rl'."
    )


def minari_metadata(dataset: NavDataset, dataset_id: str, minari_version: str, author: str) -> dict[str, Any]:
    """The Minari metadata of ``dataset`` (besides the spaces, env spec and counts Minari writes itself):
    ``dataset_id``, ``minari_version``, ``author``, ``algorithm_name``, ``description``, ``requirements``
    (D_e: ``navformer_rl``, to recover the env) and ``navformer_rl``: our ``metadata.json`` without its file
    hashes, plus the exporting package version and the source folder with its ``metadata.json`` sha256."""
    from navformer_rl import __version__
    from navformer_rl.data.integrity import HASHES_KEY
    from navformer_rl.data.writer import METADATA_FILE
    from navformer_rl.tasks import DATASETS

    source = dataset.metadata
    synthetic = (source.get("settings") or {}).get("generator") == "synthetic"
    with_env = env_spec_for(dataset.kind.value) is not None
    algorithm = "synthetic (navformer_rl.data.synthetic)" if synthetic else EXPERTS[dataset.kind.value]
    source_sha256 = hashlib.sha256((Path(dataset.root) / METADATA_FILE).read_bytes()).hexdigest()
    metadata: dict[str, Any] = {
        "dataset_id": dataset_id,
        "minari_version": minari_version,
        "author": {author},
        "algorithm_name": algorithm,
        "description": _description(dataset, with_env),
        "navformer_rl": {
            **{key: value for key, value in source.items() if key != HASHES_KEY},
            "paper_name": DATASETS[dataset.kind.value].paper_name,
            "exported_with": __version__,
            "source": {"folder": str(Path(dataset.root).resolve()), "metadata_sha256": source_sha256},
            "final_observation": "repeats the episode's last frame",
        },
    }
    if with_env:
        metadata["requirements"] = ["navformer_rl"]
    return metadata


def _episode_buffers(dataset: NavDataset, first: int, last: int, buffer_cls: type) -> Iterator[Any]:
    """Minari ``EpisodeBuffer`` of trajectories ``first..last-1`` (fields: module docstring)."""
    import numpy as np

    rows, episodes = dataset.rows, dataset.episodes
    for trajectory in range(first, last):
        start, length = int(episodes.start[trajectory]), int(episodes.length[trajectory])
        end = start + length
        pixels = rows["pixels"][start:end].numpy()
        target = dataset.targets[int(episodes.target_id[trajectory])].numpy()
        collision = rows["next", "collision"][start:end, 0].numpy()
        yield buffer_cls(
            id=trajectory,
            observations={
                "pixels": np.concatenate([pixels, pixels[-1:]]),
                "target_pixels": np.repeat(target[None], length + 1, axis=0),
            },
            actions=rows["action"][start:end].numpy().copy(),
            rewards=rows["next", "reward"][start:end, 0].numpy().copy(),
            terminations=rows["next", "terminated"][start:end, 0].numpy().copy(),
            truncations=rows["next", "truncated"][start:end, 0].numpy().copy(),
            infos={"collision": np.concatenate([[False], collision])},
        )


def _write(
    folder: Path,
    dataset: NavDataset,
    metadata: dict[str, Any],
    chunk_steps: int,
    progress: bool,
) -> None:
    """Write the Minari ``data`` folder (``metadata.json``, ``main_data.hdf5``) into the empty ``folder``."""
    from minari.data_collector import EpisodeBuffer
    from minari.dataset.minari_storage import MinariStorage
    from tqdm.auto import tqdm

    observation_space, action_space = minari_spaces()
    storage = MinariStorage.new(
        folder,
        observation_space=observation_space,
        action_space=action_space,
        env_spec=env_spec_for(dataset.kind.value),
        data_format="hdf5",
        jpeg_encoding=False,
    )
    storage.update_metadata(metadata)
    lengths = dataset.episodes.length.tolist()
    with tqdm(
        total=len(dataset), desc="export minari", unit="step", disable=not progress, dynamic_ncols=True
    ) as bar:
        for first, last in episode_chunks(lengths, chunk_steps):
            storage.update_episodes(list(_episode_buffers(dataset, first, last, EpisodeBuffer)))
            bar.update(sum(lengths[first:last]))
    if (storage.total_episodes, storage.total_steps) != (len(lengths), len(dataset)):
        raise RuntimeError(
            f"the Minari storage in {folder} holds {storage.total_episodes} episodes and "
            f"{storage.total_steps} steps, expected {len(lengths)} and {len(dataset)}"
        )


def _write_namespace_metadata(root: Path, namespace: str) -> None:
    """``namespace_metadata.json`` (``{}``) in every level of ``namespace`` that lacks one, as
    ``minari.create_namespace`` writes them (``minari list`` shows the namespace)."""
    from navformer_rl.utils.durable import atomic_write_json

    parts = namespace.split("/")
    for depth in range(1, len(parts) + 1):
        path = root.joinpath(*parts[:depth], _NAMESPACE_METADATA)
        if not path.exists():
            atomic_write_json(path, {})


def export_minari(
    dataset: str | os.PathLike,
    dataset_id: str,
    root: str | os.PathLike | None = None,
    *,
    force: bool = False,
    chunk_steps: int = DEFAULT_CHUNK_STEPS,
    author: str = "navformer_rl",
    verify: bool = False,
    progress: bool = False,
) -> Path:
    """Write the D_e or D_ca folder ``dataset`` as the Minari dataset ``dataset_id`` under ``root``.

    ``minari.load_dataset(dataset_id)`` and TorchRL's ``MinariExperienceReplay(dataset_id, batch_size,
    load_from_local_minari=True)`` open it when ``MINARI_DATASETS_PATH`` is ``root``.

    Args:
        dataset: a finished D_e or D_ca folder (``navformer collect``).
        dataset_id: ``NAMESPACE/NAME-vN`` (e.g. ``navformer/e-small-v0``).
        root: Minari datasets folder (default :func:`minari_root`); the dataset goes to
            ``root/NAMESPACE/NAME-vN/data/``.
        force: replace a dataset already under that id (``FileExistsError`` otherwise).
        chunk_steps: steps written per chunk (memory bound; a longer trajectory is a chunk alone).
        author: Minari ``author``.
        verify: check every file of ``dataset`` against its recorded sha256 first
            (``open_dataset(..., verify=True)``).
        progress: show a progress bar (steps).

    Returns:
        The Minari dataset folder ``root/NAMESPACE/NAME-vN``.

    Raises:
        ValueError: a bad id, a D_ssl or invalid dataset folder, ``chunk_steps < 1``.
        FileNotFoundError: ``dataset`` does not exist. FileExistsError: the id exists and not ``force``.
        MinariNotInstalledError: minari or h5py is missing (the message gives the ``pip`` command).
        FolderLockedError: another export writes the same id.
    """
    from navformer_rl.utils.durable import folder_lock, publish_folder

    namespace, name, version = parse_minari_id(dataset_id)
    check_int(chunk_steps, "chunk_steps")
    minari = require_minari()
    source = _open_trajectories(Path(dataset), verify)
    metadata = minari_metadata(source, dataset_id, minari.__version__, author)
    root = minari_root(root)
    target = root.joinpath(*namespace.split("/"), f"{name}-v{version}")
    created = [folder for folder in (target, *target.parents) if not folder.exists()]  # deepest first
    target.mkdir(parents=True, exist_ok=True)
    try:
        with folder_lock(target, LOCK_FILE, "exported"):
            final = target / "data"
            if final.exists() and not force:
                raise FileExistsError(
                    f"Minari dataset {dataset_id} already exists in {target}; pass --force (force=True) to "
                    "replace it, or choose another NAME or version"
                )
            for leftover in target.glob(f"{_TMP_PREFIX}*{_TMP_SUFFIX}"):  # from a killed export
                shutil.rmtree(leftover, ignore_errors=True)
            tmp = Path(tempfile.mkdtemp(prefix=_TMP_PREFIX, suffix=_TMP_SUFFIX, dir=target))
            try:
                _write(tmp, source, metadata, chunk_steps, progress)
                publish_folder(tmp, final)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
    except BaseException:
        for folder in created:  # the folders this call made, when empty: a failed first export leaves none
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    _write_namespace_metadata(root, namespace)
    return target
