"""Several trajectory dataset folders read as one (e.g. the paper's D_e plus the D_e of DAgger rounds).

:func:`concat_datasets` returns a :class:`ConcatNavDataset`: the trajectories of its parts in list order,
numbered ``0..n-1`` across them, with nothing copied (each part stays its own memmap). It offers what training
and validation read from a :class:`~navformer_rl.data.dataset.NavDataset` - ``kind``, ``num_trajectories``,
``episodes``, :meth:`~ConcatNavDataset.head`, :meth:`~ConcatNavDataset.trajectory_batcher` - and its batches
equal those of one folder holding the same trajectories in the same order (same sampler draws, same rows).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.data.replay_buffers import Storage

from navformer_rl.data.dataset import NavDataset
from navformer_rl.data.samplers import (
    DEFAULT_CONTEXT_STEPS,
    EpisodeTable,
    TrajectoryBatcher,
    TrajectorySampler,
)


def concat_datasets(parts: Sequence[NavDataset]) -> NavDataset | ConcatNavDataset:
    """``parts`` as one dataset: the single part itself, or a :class:`ConcatNavDataset` of several."""
    if len(parts) == 1:
        return parts[0]
    return ConcatNavDataset(parts)


def _offsets(sizes: Sequence[int]) -> torch.Tensor:
    """int64 ``[P + 1]``: where each of ``P`` consecutive blocks of ``sizes`` starts, then the total."""
    return torch.cumsum(torch.tensor([0, *sizes], dtype=torch.int64), 0)


class ConcatNavDataset:
    """Trajectory datasets of one kind read as one: the trajectories of ``parts`` in order.

    Trajectory ``k`` of part ``p`` is trajectory ``n_0 + ... + n_{p-1} + k``; its rows and target image stay
    in the part's files (batches shift their ``episode`` and ``target_id`` columns to the concatenation's
    ids). ``ValueError`` (one line naming the folders) unless there are at least two parts, all of one
    trajectory kind (D_e or D_ca) and one schema version.

    Attributes:
        parts: the :class:`~navformer_rl.data.dataset.NavDataset` s (each may be a ``head`` view).
        kind: their :class:`~navformer_rl.data.schema.DatasetKind`.
        roots: their folders.
        episodes: :class:`~navformer_rl.data.samplers.EpisodeTable` over the concatenated rows: ``start`` and
            ``target_id`` shifted by the rows / target images of the parts before.
    """

    def __init__(self, parts: Sequence[NavDataset]) -> None:
        parts = list(parts)
        if len(parts) < 2:
            raise ValueError(f"ConcatNavDataset needs at least two datasets, got {len(parts)}")
        first = parts[0]
        for part in parts:
            if not part.kind.is_trajectory:
                raise ValueError(
                    f"{part.root} is a {part.kind.value!r} dataset; "
                    "only trajectory datasets ('e', 'ca') concatenate"
                )
            if part.kind is not first.kind:
                raise ValueError(
                    f"{part.root} holds a {part.kind.value!r} dataset, {first.root} a {first.kind.value!r} "
                    "one: concatenated folders must be of one kind"
                )
            version = part.metadata.get("schema_version")
            if version != first.metadata.get("schema_version"):
                raise ValueError(
                    f"{part.root} has schema_version {version!r}, {first.root} "
                    f"{first.metadata.get('schema_version')!r}: concatenated folders must share one schema"
                )
        self.parts = parts
        self.kind = first.kind
        self.roots = [Path(part.root) for part in parts]
        self.row_offsets = _offsets([len(part) for part in parts])
        self.trajectory_offsets = _offsets([part.num_trajectories for part in parts])
        self.target_offsets = _offsets([len(part.targets) for part in parts])
        self.episodes = EpisodeTable(
            start=torch.cat([p.episodes.start + o for p, o in zip(parts, self.row_offsets)]),
            length=torch.cat([p.episodes.length for p in parts]),
            target_id=torch.cat([p.episodes.target_id + o for p, o in zip(parts, self.target_offsets)]),
        )

    def __len__(self) -> int:
        """Rows of every part."""
        return int(self.row_offsets[-1])

    @property
    def num_trajectories(self) -> int:
        return len(self.episodes)

    def head(self, n: int) -> NavDataset | ConcatNavDataset:
        """The first ``n`` trajectories of the concatenation (whole parts, then the first trajectories of the
        next: :meth:`~navformer_rl.data.dataset.NavDataset.head`); ``ValueError`` unless
        ``1 <= n <= num_trajectories``."""
        total = self.num_trajectories
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= total:
            raise ValueError(
                f"head({n!r}) of {self}: expected 1 <= n <= {total} (trajectories in the folders)"
            )
        kept, left = [], n
        for part in self.parts:
            take = min(left, part.num_trajectories)
            kept.append(part.head(take))
            left -= take
            if not left:
                break
        return concat_datasets(kept)

    def trajectory_batcher(
        self,
        num_trajectories: int,
        context_steps: int = DEFAULT_CONTEXT_STEPS,
        seed: int = 0,
        keys: list[tuple[str, ...]] | None = None,
        reuse_buffers: bool = True,
        buffer_sets: int = 1,
        pin_memory: bool = False,
    ) -> ConcatTrajectoryBatcher:
        """:meth:`NavDataset.trajectory_batcher <navformer_rl.data.dataset.NavDataset.trajectory_batcher>`
        over the concatenation: the same keys, shapes and options."""
        if not 1 <= num_trajectories <= self.num_trajectories:
            raise ValueError(
                f"{num_trajectories} trajectories per batch requested from {self}, which holds "
                f"{self.num_trajectories}; expected 1 <= num_trajectories <= {self.num_trajectories}"
            )
        sampler = TrajectorySampler(num_trajectories, context_steps, seed=seed, episodes=self.episodes)
        return ConcatTrajectoryBatcher(
            self,
            sampler,
            keys=keys,
            reuse_buffers=reuse_buffers,
            buffer_sets=buffer_sets,
            pin_memory=pin_memory,
        )

    def __repr__(self) -> str:
        roots = ", ".join(repr(str(root)) for root in self.roots)
        return f"ConcatNavDataset([{roots}], kind={self.kind.value!r}, trajectories={self.num_trajectories})"


def _gather_parts(
    sources: list[torch.Tensor],
    offsets: torch.Tensor,
    index: torch.Tensor,
    buffer: torch.Tensor | None,
    pin_memory: bool,
    shifts: torch.Tensor | None = None,
) -> torch.Tensor:
    """``cat(sources)[index]`` without concatenating: each part's rows gathered from it, written into the
    first ``len(index)`` rows of ``buffer`` (or a new tensor). ``offsets``: int64 ``[P + 1]`` part starts;
    ``shifts``: int64 ``[P]`` added to the values gathered from each part (ids local to a part made
    global)."""
    n = index.numel()
    template = sources[0]
    if buffer is None:
        out = torch.empty((n, *template.shape[1:]), dtype=template.dtype, pin_memory=pin_memory)
    else:
        out = buffer[:n]
    part = torch.bucketize(index, offsets[1:], right=True)
    for p, source in enumerate(sources):
        rows = torch.nonzero(part == p).reshape(-1)
        shift = 0 if shifts is None else int(shifts[p])
        if rows.numel() == n:  # every row from this part: straight into the output
            torch.index_select(source, 0, index - offsets[p], out=out)
            if shift:
                out += shift
        elif rows.numel():
            values = torch.index_select(source, 0, index[rows] - offsets[p])
            out.index_copy_(0, rows, values + shift if shift else values)
    return out


class ConcatRowsStorage(Storage):
    """A read-only TorchRL ``Storage`` over the rows of a :class:`ConcatNavDataset` (nothing copied):
    ``get(index)`` gathers every key part by part, ids shifted to the concatenation's (the storage of a
    :class:`ConcatTrajectoryBatcher`)."""

    def __init__(self, dataset: ConcatNavDataset) -> None:
        super().__init__(max_size=len(dataset))
        self.dataset = dataset
        self._shifts = {
            "episode": dataset.trajectory_offsets[:-1],
            "target_id": dataset.target_offsets[:-1],
        }

    def get(self, index) -> TensorDict:
        rows = torch.arange(len(self))[index].reshape(-1)
        parts = self.dataset.parts
        out = TensorDict(batch_size=[rows.numel()])
        for key in parts[0].rows.keys(include_nested=True, leaves_only=True):
            sources = [part.rows.get(key).as_subclass(torch.Tensor) for part in parts]
            name = key if isinstance(key, str) else key[-1]
            out.set(
                key,
                _gather_parts(sources, self.dataset.row_offsets, rows, None, False, self._shifts.get(name)),
            )
        return out

    def set(self, cursor, data, *, set_cursor: bool = True):
        raise RuntimeError("ConcatRowsStorage is read-only: its rows are the dataset folders' files")

    def __len__(self) -> int:
        return len(self.dataset)

    def state_dict(self) -> dict:
        return {}

    def load_state_dict(self, state_dict: dict) -> None:
        return None

    def _empty(self) -> None:
        raise RuntimeError("ConcatRowsStorage is read-only: its rows are the dataset folders' files")


class ConcatTrajectoryBatcher(TrajectoryBatcher):
    """A :class:`~navformer_rl.data.samplers.TrajectoryBatcher` over a :class:`ConcatNavDataset`: the sampler
    draws over the concatenated episode table and each key is gathered part by part (:func:`_gather_parts`)
    into the same reusable buffers, so ``sample()`` / ``gather(draw)`` (inherited) return what one folder
    holding the same trajectories would."""

    def __init__(
        self,
        dataset: ConcatNavDataset,
        sampler: TrajectorySampler,
        keys: list[tuple[str, ...]] | None = None,
        reuse_buffers: bool = True,
        buffer_sets: int = 1,
        pin_memory: bool = False,
    ) -> None:
        first = dataset.parts[0]
        super().__init__(
            first.rows,
            first.targets,
            sampler,
            keys,
            reuse_buffers,
            buffer_sets,
            pin_memory,
            storage=ConcatRowsStorage(dataset),
        )
        self._part_sources = {
            key: [part.rows.get(key).as_subclass(torch.Tensor) for part in dataset.parts]
            for key in self.fields
        }
        self._part_targets = [part.targets.as_subclass(torch.Tensor) for part in dataset.parts]
        self._row_offsets = dataset.row_offsets
        self._target_offsets = dataset.target_offsets
        self._shifts = {
            ("episode",): dataset.trajectory_offsets[:-1],
            ("target_id",): dataset.target_offsets[:-1],
        }

    def _gather_rows(
        self, key: tuple[str, ...], index: torch.Tensor, buffer: torch.Tensor | None
    ) -> torch.Tensor:
        """Rows ``index`` of the concatenation's column ``key``, gathered part by part
        (ids shifted to global)."""
        return _gather_parts(
            self._part_sources[key], self._row_offsets, index, buffer, self.pin_memory, self._shifts.get(key)
        )

    def _gather_targets(self, index: torch.Tensor, buffer: torch.Tensor | None) -> torch.Tensor:
        """Target images ``index`` of the concatenation, gathered part by part."""
        return _gather_parts(self._part_targets, self._target_offsets, index, buffer, self.pin_memory)
