"""Open a finished dataset folder, validate it, and build replay buffers / batchers over it.

``open_dataset(path, kind=None, verify=False) -> NavDataset``. The structural checks happen before any
memmap is touched, so a foreign, truncated or half-written folder raises ``ValueError``/``FileNotFoundError``
naming the path and what was expected instead of crashing (a truncated memmap would otherwise fault on first
read); then the small columns' content is checked (cheap), and with ``verify=True`` every file's sha256.
"""

from __future__ import annotations

import hashlib
import warnings
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict
from torchrl.data import TensorDictReplayBuffer, TensorStorage
from torchrl.data.replay_buffers import ImmutableDatasetWriter, SamplerWithoutReplacement
from torchrl.data.replay_buffers.checkpointers import StorageCheckpointerBase
from torchrl.envs.transforms import Transform

from navformer_rl.data.integrity import (
    HASHES_KEY,
    hashes_problem,
    short_repr,
    trajectory_content_problem,
    verify_hashes,
)
from navformer_rl.data.samplers import (
    DEFAULT_CONTEXT_STEPS,
    EpisodeTable,
    PairBatcher,
    TrajectoryBatcher,
    TrajectorySampler,
)
from navformer_rl.data.schema import SCHEMA_VERSION, TARGET_FIELDS, DatasetKind, fields_for
from navformer_rl.data.writer import (
    CONSOLIDATED_DIR,
    METADATA_FILE,
    consolidated_file_names,
    load_checked,
    read_json_object,
)
from navformer_rl.utils.checks import is_count
from navformer_rl.utils.durable import atomic_write_json

_DAMAGED = (
    "the dataset folder was damaged after it was written (its files are written atomically): restore it "
    "from a backup or collect the dataset again"
)


class AttachTargetPixels(Transform):
    """Replay-buffer transform writing ``target_pixels``
    (uint8 ``[..., 84, 84, 3]``) looked up by ``target_id``."""

    def __init__(self, targets: torch.Tensor):
        super().__init__(in_keys=["target_id"], out_keys=["target_pixels"])
        self.targets = targets

    def _call(self, tensordict: TensorDict) -> TensorDict:
        tensordict.set("target_pixels", self.targets[tensordict.get("target_id")])
        return tensordict

    def forward(self, tensordict: TensorDict) -> TensorDict:
        return self._call(tensordict)


class DatasetReferenceCheckpointer(StorageCheckpointerBase):
    """Storage checkpointer of a dataset-backed buffer: ``dumps`` writes which dataset it is, not its rows.

    The storage *is* the dataset's memmap: TorchRL's default checkpointer would copy every row into each
    dump and, on ``loads``, write the dumped rows back into the dataset's files. This one writes
    ``reference.json`` (the dataset's folder, row count and a sha256 of its ``metadata.json``) and
    ``loads`` checks that the buffer stands on that same dataset (ValueError naming both otherwise), so
    ``ReplayBuffer.dumps`` / ``loads`` save and restore the sampler state over an unchanged dataset.
    """

    FILENAME = "reference.json"

    def __init__(self, dataset: NavDataset) -> None:
        super().__init__()
        self.reference = {
            "format": "navformer_rl.dataset_reference",
            "dataset": str(Path(dataset.root).resolve()),
            "rows": len(dataset),
            "metadata_sha256": hashlib.sha256((dataset.root / METADATA_FILE).read_bytes()).hexdigest(),
        }
        if "subset" in dataset.metadata:
            self.reference["subset"] = dataset.metadata["subset"]

    def dumps(self, storage, path) -> None:
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        atomic_write_json(path / self.FILENAME, self.reference)

    def loads(self, storage, path) -> None:
        file = Path(path) / self.FILENAME
        saved = read_json_object(file, "dump the buffer again with a dataset-backed buffer")
        if saved.get("format") != self.reference["format"]:
            raise ValueError(f"{file} is not a dataset reference (format {saved.get('format')!r})")
        differ = [k for k in ("rows", "metadata_sha256", "subset") if saved.get(k) != self.reference.get(k)]
        if differ:
            raise ValueError(
                f"{file} was dumped over the dataset {saved.get('dataset')!r}, which differs from this "
                f"buffer's {self.reference['dataset']!r} in {differ}: load it into a buffer over that dataset"
            )


class NavDataset:
    """A validated, memmapped dataset folder.

    Attributes:
        root: the folder. metadata: parsed ``metadata.json``. kind: :class:`DatasetKind`.
        rows: memmapped ``TensorDict [rows]`` in the kind's schema (see :mod:`navformer_rl.data.schema`).
        targets: uint8 ``[n_trajectories, 84, 84, 3]`` target images (``None`` for D_ssl).
        episodes: :class:`EpisodeTable` (``None`` for D_ssl).
    """

    def __init__(self, root: Path, metadata: dict[str, Any], rows: TensorDict, targets: torch.Tensor | None):
        self.root = root
        self.metadata = metadata
        self.kind = DatasetKind.parse(metadata["kind"])
        self.rows = rows
        self.targets = targets
        self.episodes = (
            EpisodeTable.from_rows(rows["episode"], rows["target_id"], str(root / CONSOLIDATED_DIR / "rows"))
            if self.kind.is_trajectory
            else None
        )

    def __len__(self) -> int:
        return int(self.rows.shape[0])

    @property
    def num_trajectories(self) -> int:
        return 0 if self.episodes is None else len(self.episodes)

    def head(self, n: int) -> NavDataset:
        """The dataset's first ``n`` items (trajectories of D_e / D_ca, pairs of D_ssl), as a view: no copy.

        Trajectories are stored contiguously in id order, so the first ``n`` are a prefix of the rows; target
        images stay indexable by ``target_id``. The view's ``metadata`` records ``subset``
        (``{"first": n, "of": <items in the folder>}``) and its row count, so a sampler state dumped over
        one subset refuses to load over another (:class:`DatasetReferenceCheckpointer`). ``n`` equal to the
        number of items returns ``self``.
        """
        total = self.num_trajectories if self.kind.is_trajectory else len(self)
        unit = "trajectories" if self.kind.is_trajectory else "pairs"
        if not is_count(n) or not 1 <= n <= total:
            raise ValueError(f"head({n!r}) of {self.root}: expected 1 <= n <= {total} ({unit} in the folder)")
        if n == total:
            return self
        end = int(self.episodes.start[n]) if self.episodes is not None else n
        metadata = {**self.metadata, "subset": {"first": n, "of": total}}
        return NavDataset(self.root, metadata, self.rows[:end], self.targets)

    def storage(self) -> TensorStorage:
        """A TorchRL ``TensorStorage`` over the memmapped rows (no copy; writes into it reach the files)."""
        return TensorStorage(self.rows)

    def replay_buffer(self, sampler=None, batch_size: int | None = None, **kwargs) -> TensorDictReplayBuffer:
        """``TensorDictReplayBuffer`` over the rows with any TorchRL sampler (e.g. ``SliceSampler``).

        The buffer is read-only (``ImmutableDatasetWriter``, as TorchRL's offline-dataset buffers): the
        rows are the dataset's memmap, and a ``extend`` would write into the files on disk. To mix in new
        data, copy the rows into a buffer of your own. ``dumps`` / ``loads`` save and restore the sampler
        state with a reference to the dataset instead of its rows (:class:`DatasetReferenceCheckpointer`).
        Trajectory datasets get ``target_pixels`` per row (``AttachTargetPixels``) unless ``transform=`` is
        given.
        """
        kwargs.setdefault("writer", ImmutableDatasetWriter())
        kwargs.setdefault("checkpointer", DatasetReferenceCheckpointer(self))
        if self.targets is not None:
            kwargs.setdefault("transform", AttachTargetPixels(self.targets))
        return TensorDictReplayBuffer(
            storage=self.storage(), sampler=sampler, batch_size=batch_size, **kwargs
        )

    def trajectory_buffer(
        self, num_trajectories: int, context_steps: int = DEFAULT_CONTEXT_STEPS, seed: int = 0
    ) -> TensorDictReplayBuffer:
        """TorchRL buffer with :class:`TrajectorySampler`: ``sample()`` is flat ``[N * T]`` with ``"mask"``
        (also as ``("collector", "mask")``) and per-row ``target_pixels``; ``.reshape(N, -1)`` gives windows
        that ``ActionMSELoss`` takes as they are."""
        self._require_trajectories(num_trajectories)
        sampler = TrajectorySampler(num_trajectories, context_steps, seed=seed, episodes=self.episodes)
        return self.replay_buffer(sampler=sampler, batch_size=num_trajectories)

    def trajectory_batcher(
        self,
        num_trajectories: int,
        context_steps: int = DEFAULT_CONTEXT_STEPS,
        seed: int = 0,
        keys: list[tuple[str, ...]] | None = None,
        reuse_buffers: bool = True,
        buffer_sets: int = 1,
        pin_memory: bool = False,
    ) -> TrajectoryBatcher:
        """Fast padded batches ``[N]`` with per-step keys ``[N, T, ...]``, ``mask`` and ``target_pixels``
        (buffer options: :class:`TrajectoryBatcher`, a read-only TorchRL ``TensorDictReplayBuffer`` whose
        ``dumps`` / ``loads`` reference this dataset as ``replay_buffer``'s do)."""
        self._require_trajectories(num_trajectories)
        sampler = TrajectorySampler(num_trajectories, context_steps, seed=seed, episodes=self.episodes)
        return TrajectoryBatcher(
            self.rows,
            self.targets,
            sampler,
            keys=keys,
            reuse_buffers=reuse_buffers,
            buffer_sets=buffer_sets,
            pin_memory=pin_memory,
            checkpointer=DatasetReferenceCheckpointer(self),
        )

    def pair_buffer(self, batch_size: int = 512, seed: int = 0) -> TensorDictReplayBuffer:
        """TorchRL buffer of D_ssl pairs, without replacement within an epoch."""
        self._require_kind(DatasetKind.SSL)
        return self.replay_buffer(
            sampler=SamplerWithoutReplacement(drop_last=True),
            batch_size=batch_size,
            generator=torch.Generator().manual_seed(seed),
        )

    def pair_batcher(
        self,
        batch_size: int = 512,
        seed: int = 0,
        reuse_buffers: bool = True,
        buffer_sets: int = 1,
        pin_memory: bool = False,
    ) -> PairBatcher:
        """Fast D_ssl batches ``[B]`` (``pixels_static``, ``pixels_dynamic``, ``world``, ``pose``; buffer
        options: :class:`PairBatcher`)."""
        self._require_kind(DatasetKind.SSL)
        return PairBatcher(
            self.rows,
            batch_size=batch_size,
            seed=seed,
            reuse_buffers=reuse_buffers,
            buffer_sets=buffer_sets,
            pin_memory=pin_memory,
        )

    def _require_trajectories(self, num_trajectories: int) -> None:
        if not self.kind.is_trajectory:
            raise ValueError(
                f"{self.root} is a {self.kind.value!r} dataset; trajectory sampling needs 'e' or 'ca'"
            )
        if not 1 <= num_trajectories <= self.num_trajectories:
            raise ValueError(
                f"{num_trajectories} trajectories per batch requested from {self.root}, which holds "
                f"{self.num_trajectories}; expected 1 <= num_trajectories <= {self.num_trajectories}"
            )

    def _require_kind(self, kind: DatasetKind) -> None:
        if self.kind is not kind:
            raise ValueError(f"{self.root} is a {self.kind.value!r} dataset, expected {kind.value!r}")

    def __repr__(self) -> str:
        return (
            f"NavDataset(root={str(self.root)!r}, kind={self.kind.value!r}, rows={len(self)}, "
            f"trajectories={self.num_trajectories})"
        )


def open_dataset(path: str | Path, kind: DatasetKind | str | None = None, verify: bool = False) -> NavDataset:
    """Open and validate a finished dataset folder.

    Raises ``FileNotFoundError`` for a missing folder or memmap file, ``ValueError`` naming the file for
    everything else: a ``metadata.json`` that is not a JSON object or lacks a valid ``kind`` or ``counts``
    (or has a malformed ``content_hashes``), an unknown schema version, an unfinished collection, a wrong
    ``kind``, a memmap whose file size, dtype or shape differs from the schema and the recorded counts, rows
    whose trajectories / target ids do not match the recorded number of trajectories, or trajectory rows
    whose small columns are impossible (:func:`~navformer_rl.data.integrity.trajectory_content_problem`:
    steps, task, actions, rewards, return-to-go; milliseconds per 100k rows, the pixels are not read).

    ``verify=True`` also reads every memmap file and compares its sha256 with the one ``metadata.json``
    recorded at collection (about 1.1-1.6 s per GB, so off by default: paper-scale pixels are many GB); a
    dataset whose metadata records none gives a ``UserWarning`` and no check.
    """
    root = Path(path)
    meta_path = root / METADATA_FILE
    if not meta_path.is_file():
        raise FileNotFoundError(f"{root} is not a navformer_rl dataset: {METADATA_FILE} is missing")
    metadata = read_json_object(meta_path, _DAMAGED)
    version = metadata.get("schema_version")
    if version != SCHEMA_VERSION:
        raise ValueError(
            f"{root}: schema_version {version!r} is not supported; "
            f"this navformer_rl reads schema {SCHEMA_VERSION}"
        )
    try:
        found = DatasetKind.parse(metadata.get("kind"))
    except (ValueError, TypeError):
        raise ValueError(
            f"{meta_path}: 'kind' is {short_repr(metadata.get('kind'))}, expected one of "
            f"{[k.value for k in DatasetKind]}; {_DAMAGED}"
        ) from None
    if kind is not None and found is not DatasetKind.parse(kind):
        raise ValueError(
            f"{root} holds a {found.value!r} dataset, expected {DatasetKind.parse(kind).value!r}"
        )
    if metadata.get("status") != "complete":
        raise ValueError(
            f"{root}: collection is not finished (status {metadata.get('status')!r}); rerun the same collect "
            "command to resume it"
        )
    counts = metadata.get("counts")
    if not isinstance(counts, dict):
        raise ValueError(
            f"{meta_path}: 'counts' is {short_repr(counts)}, expected an object with the 'rows' and 'items' "
            f"counts; {_DAMAGED}"
        )
    for name in ("rows", "items"):
        if not is_count(counts.get(name)):
            raise ValueError(
                f"{meta_path}: counts.{name} is {short_repr(counts.get(name))}, expected a non-negative "
                f"integer; {_DAMAGED}"
            )
    n_rows, n_items = counts["rows"], counts["items"]
    hashes = metadata.get(HASHES_KEY)  # absent when the metadata records none
    if hashes is not None:
        problem = hashes_problem(hashes, consolidated_file_names(found))
        if problem is not None:
            raise ValueError(f"{meta_path}: {HASHES_KEY!r} {problem}; {_DAMAGED}")
    consolidated = root / CONSOLIDATED_DIR
    rows = load_checked(consolidated / "rows", fields_for(found), n_rows)
    targets = None
    if found.is_trajectory:
        targets = load_checked(consolidated / "targets", TARGET_FIELDS, n_items)["target_pixels"]
    if verify:
        _verify(root, hashes, meta_path)
    dataset = NavDataset(root, metadata, rows, targets)
    if found.is_trajectory:
        _check_trajectory_ids(dataset, meta_path, n_items)
        problem = trajectory_content_problem(dataset.rows, found)
        if problem is not None:
            key, what = problem
            file = consolidated.joinpath("rows", *key[:-1], f"{key[-1]}.memmap")
            raise ValueError(f"{file}: {what}; {_DAMAGED}")
    return dataset


def _verify(root: Path, hashes: dict[str, Any] | None, meta_path: Path) -> None:
    """``verify=True`` of :func:`open_dataset`: every memmap file's sha256 against ``metadata.json``."""
    if hashes is None:
        warnings.warn(
            f"{meta_path} records no {HASHES_KEY} (the dataset was collected before navformer_rl recorded "
            "them), so verify=True has nothing to compare; only the structure and the small columns' "
            "content were checked",
            UserWarning,
            stacklevel=3,
        )
        return
    try:
        verify_hashes(root, hashes, meta_path)
    except ValueError as err:
        raise ValueError(f"{err}; {_DAMAGED}") from None


def _check_trajectory_ids(dataset: NavDataset, meta_path: Path, n_items: int) -> None:
    """``ValueError`` unless the rows hold ``n_items`` trajectories whose ``target_id`` index the targets
    table (one image per trajectory): ids out of range would otherwise fail deep inside sampling."""
    folder = dataset.root / CONSOLIDATED_DIR / "rows"
    if dataset.num_trajectories != n_items:
        raise ValueError(
            f"{folder}: 'episode' numbers {dataset.num_trajectories} trajectories, but {meta_path} records "
            f"counts.items = {n_items}; {_DAMAGED}"
        )
    target_id = dataset.rows["target_id"]
    low, high = int(target_id.min()), int(target_id.max())
    if low < 0 or high >= n_items:
        raise ValueError(
            f"{folder}: 'target_id' ranges over {low}..{high}, expected 0..{n_items - 1} (rows of the "
            f"{n_items} target images); {_DAMAGED}"
        )
