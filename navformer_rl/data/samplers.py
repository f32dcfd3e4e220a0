"""Samplers for the DT loss (whole trajectories, cropped to the context) and for BYOL pairs.

Two layers:

* :class:`TrajectorySampler` is a TorchRL :class:`~torchrl.data.replay_buffers.Sampler`: inside a
  ``TensorDictReplayBuffer`` it returns flat indices ``[N * T]`` (right padding repeats the last valid step)
  and writes ``("collector", "mask")``, the convention of ``SliceSampler(pad_output=True)``, so
  ``batch.reshape(N, -1)`` gives the padded trajectories.
* :class:`TrajectoryBatcher` / :class:`PairBatcher` are the fast path used for training: they draw with
  the same sampler and gather every key once with ``torch.index_select(..., out=)`` into buffers allocated
  once, returning ``[N, T]`` (or ``[B]``) TensorDicts with the target images attached. (TorchRL's
  ``SliceSampler`` gathers the pixels twice and allocates fresh tensors: ~17x slower, see
  ``benchmarks/data.md``.) ``TrajectoryBatcher`` is itself a TorchRL ``TensorDictReplayBuffer`` (read-only,
  over the dataset's rows), so it composes where TorchRL takes a buffer, e.g. in
  :class:`~navformer_rl.data.cross_task.CrossTaskReplayBuffer`.

Randomness: one ``torch.Generator`` per sampler; ``state_dict()``/``load_state_dict()`` capture it together
with the epoch permutation and cursor, so a resumed run draws exactly the batches an uninterrupted run would.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict
from torchrl.data.replay_buffers import (
    ImmutableDatasetWriter,
    Sampler,
    Storage,
    TensorDictReplayBuffer,
    TensorStorage,
)

from navformer_rl.data.schema import TRAJECTORY_FIELDS, FieldSpec
from navformer_rl.utils.length_groups import length_sorted_groups

DEFAULT_CONTEXT_STEPS = 256
"""The target token + 4 tokens per step, the last step's action dropped: 1 + 4 * 256 - 1 = 1024 tokens
(§IV.C)."""


class EpochPermutation:
    """Draws ids ``0..n-1`` in batches without replacement within an epoch.

    A new random permutation starts each epoch; a tail shorter than the batch is skipped (``drop_last``),
    so a batch never holds the same id twice.
    """

    def __init__(self, n: int, seed: int):
        if n < 1:
            raise ValueError(f"cannot sample from an empty set (n={n})")
        self.n = int(n)
        self.generator = torch.Generator().manual_seed(int(seed))
        self.epoch = 0
        self._perm = torch.randperm(self.n, generator=self.generator)
        self._cursor = 0

    def draw(self, k: int) -> torch.Tensor:
        """int64 ``[k]`` distinct ids."""
        if not 1 <= k <= self.n:
            raise ValueError(
                f"batch of {k} items requested from a set of {self.n}; expected 1 <= k <= {self.n}"
            )
        if self._cursor + k > self.n:
            self.epoch += 1
            self._perm = torch.randperm(self.n, generator=self.generator)
            self._cursor = 0
        ids = self._perm[self._cursor : self._cursor + k]
        self._cursor += k
        return ids

    def restart(self, generator_state: torch.Tensor) -> None:
        """Start a new epoch (a fresh permutation) drawn from a generator in ``generator_state``."""
        self.generator.set_state(generator_state)
        self._perm = torch.randperm(self.n, generator=self.generator)
        self._cursor = 0

    def state_dict(self) -> dict[str, Any]:
        return {
            "n": self.n,
            "generator": self.generator.get_state(),
            "epoch": self.epoch,
            "perm": self._perm.clone(),
            "cursor": self._cursor,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if int(state["n"]) != self.n:
            raise ValueError(f"sampler state is for {state['n']} items, this dataset has {self.n}")
        self.generator.set_state(state["generator"])
        self.epoch = int(state["epoch"])
        self._perm = state["perm"].clone()
        self._cursor = int(state["cursor"])


@dataclass
class EpisodeTable:
    """Where each trajectory lies in the flat storage: int64 ``[n]`` ``start``, ``length``, ``target_id``."""

    start: torch.Tensor
    length: torch.Tensor
    target_id: torch.Tensor

    @classmethod
    def from_rows(
        cls, episode: torch.Tensor, target_id: torch.Tensor, where: str = "dataset"
    ) -> EpisodeTable:
        """Build from the ``episode`` / ``target_id`` columns (int64 ``[rows]``); trajectories must be stored
        contiguously with ids ``0..n-1`` in order (as the writer does)."""
        episode = torch.as_tensor(episode).to(torch.int64)
        if episode.numel() == 0:
            raise ValueError(f"{where}: no rows")
        if episode[0] != 0 or bool((torch.diff(episode) < 0).any()) or bool((torch.diff(episode) > 1).any()):
            raise ValueError(
                f"{where}: 'episode' ids must be contiguous and numbered 0..n-1 in storage order"
            )
        length = torch.bincount(episode)
        start = torch.cumsum(length, 0) - length
        return cls(start=start, length=length, target_id=torch.as_tensor(target_id)[start].to(torch.int64))

    def __len__(self) -> int:
        return int(self.start.numel())


@dataclass
class TrajectoryDraw:
    """One batch of N windows: ``index`` int64 ``[N, T]`` storage rows (padding repeats the last valid row),
    ``mask`` bool ``[N, T]``, ``trajectory`` int64 ``[N]`` ids."""

    index: torch.Tensor
    mask: torch.Tensor
    trajectory: torch.Tensor


class TrajectorySampler(Sampler):
    """N whole trajectories per batch, without replacement within an epoch, cropped to ``context_steps``.

    A trajectory longer than ``context_steps`` is cut to a window of that length at a uniformly random
    offset; windows never cross trajectories. In a TorchRL replay buffer the buffer's ``batch_size`` is the
    number of trajectories N and the output is flat ``[N * T]`` with the validity mask under ``"mask"``
    (what ``ActionMSELoss`` and the actor read) and ``("collector", "mask")`` (TorchRL's slice-sampler key).

    It is made for offline datasets: trajectories stored contiguously with ids ``0..n-1``. In a buffer
    that grows (``extend``), a table built from the storage is rebuilt at the next ``sample`` (the epoch
    restarts over the larger set; the random stream continues); a ring buffer that overwrites old rows
    breaks the id order and is refused with a ``ValueError`` - use TorchRL's ``SliceSampler`` there.

    Args:
        num_trajectories: N per batch (25 for D_e, 150 for D_ca in the paper); the replay buffer's
            ``batch_size`` overrides it when given.
        context_steps: maximum window length T (default 256 steps: the target token plus 4 tokens per step,
            the last step's action dropped, = 1024 tokens, the model's whole context).
        seed: seed of the sampler's ``torch.Generator``.
        episodes: the trajectory table; built from the storage's ``episode``/``target_id`` columns on first
            use when omitted.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
        >>> from navformer_rl.data import TrajectorySampler
        >>> # three trajectories of 4, 2 and 5 steps, stored whole and in order (ids 0, 1, 2)
        >>> episode = torch.tensor([0, 0, 0, 0, 1, 1, 2, 2, 2, 2, 2])
        >>> step = torch.cat([torch.arange(4), torch.arange(2), torch.arange(5)])
        >>> rows = TensorDict({"episode": episode, "target_id": episode, "step": step}, batch_size=[11])
        >>> buffer = TensorDictReplayBuffer(
        ...     storage=LazyTensorStorage(11),
        ...     sampler=TrajectorySampler(3, context_steps=4, seed=0),
        ...     batch_size=3,
        ... )
        >>> _ = buffer.extend(rows)
        >>> # flat [N * T] -> [N, T]: every trajectory, cropped to 4 steps
        >>> batch = buffer.sample().reshape(3, -1)
        >>> batch["step"].shape, batch["mask"].sum(1).sort().values.tolist()
        (torch.Size([3, 4]), [2, 4, 4])
    """

    def __init__(
        self,
        num_trajectories: int,
        context_steps: int = DEFAULT_CONTEXT_STEPS,
        seed: int = 0,
        episodes: EpisodeTable | None = None,
    ):
        if num_trajectories < 1:
            raise ValueError(f"num_trajectories must be >= 1, got {num_trajectories}")
        if context_steps < 1:
            raise ValueError(f"context_steps must be >= 1, got {context_steps}")
        self.num_trajectories = int(num_trajectories)
        self.context_steps = int(context_steps)
        self.seed = int(seed)
        self.episodes = episodes
        self._ids: EpochPermutation | None = None
        self._pending_state: dict[str, Any] | None = None
        self._from_storage = episodes is None  # the table is read from the storage, so follows its growth
        self._stale = False
        if episodes is not None:
            self.bind(episodes)

    def bind(self, episodes: EpisodeTable) -> None:
        """Use ``episodes`` (restoring a state loaded before the table was known)."""
        self.episodes = episodes
        self._ids = EpochPermutation(len(episodes), self.seed)
        if self._pending_state is not None:
            self._ids.load_state_dict(self._pending_state)
            self._pending_state = None

    @property
    def epoch(self) -> int:
        return 0 if self._ids is None else self._ids.epoch

    def draw(self, num_trajectories: int | None = None) -> TrajectoryDraw:
        """Draw one batch of windows (needs the episode table)."""
        if self._ids is None:
            raise RuntimeError(
                "TrajectorySampler has no episode table yet; pass episodes= or sample a storage"
            )
        n = self.num_trajectories if num_trajectories is None else int(num_trajectories)
        traj = self._ids.draw(n)
        length = self.episodes.length[traj]
        start = self.episodes.start[traj]
        window = length.clamp(max=self.context_steps)
        slack = length - window
        # uniform offset in [0, slack]; one draw per trajectory from the sampler's generator
        u = torch.rand(n, generator=self._ids.generator, dtype=torch.float64)
        offset = torch.minimum((u * (slack + 1).to(torch.float64)).floor().to(torch.int64), slack)
        T = int(window.max())
        t = torch.arange(T, dtype=torch.int64)
        mask = t[None, :] < window[:, None]
        index = (start + offset)[:, None] + torch.minimum(t[None, :], (window - 1)[:, None])
        return TrajectoryDraw(index=index, mask=mask, trajectory=traj)

    # --- torchrl Sampler API -------------------------------------------------------------------------
    def sample(self, storage, batch_size: int) -> tuple[torch.Tensor, dict]:
        if self._ids is None or self._stale:
            rows = storage.get(slice(None))
            table = EpisodeTable.from_rows(rows["episode"], rows["target_id"], "replay buffer storage")
            previous = self._ids
            self.bind(table)
            if previous is not None:  # the random stream continues over the grown set
                self._ids.restart(previous.generator.get_state())
            self._stale = False
        out = self.draw(batch_size)
        mask = out.mask.reshape(-1)
        return out.index.reshape(-1), {"mask": mask, ("collector", "mask"): mask}

    def extend(self, index) -> None:
        self._stale = self._stale or self._from_storage

    def add(self, index) -> None:
        self._stale = self._stale or self._from_storage

    def _empty(self) -> None:
        self.episodes = None
        self._ids = None

    def state_dict(self) -> dict[str, Any]:
        if self._ids is None:
            return {} if self._pending_state is None else dict(self._pending_state)
        return self._ids.state_dict()

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        if not state_dict:
            return
        if self._ids is None:
            self._pending_state = dict(state_dict)
        else:
            self._ids.load_state_dict(state_dict)

    def dumps(self, path) -> None:
        Path(path).mkdir(parents=True, exist_ok=True)
        torch.save(self.state_dict(), f"{path}/trajectory_sampler.pt")

    def loads(self, path) -> None:
        self.load_state_dict(torch.load(f"{path}/trajectory_sampler.pt", weights_only=True))

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(num_trajectories={self.num_trajectories}, "
            f"context_steps={self.context_steps}, seed={self.seed})"
        )


def _gather_into(
    source: torch.Tensor, index: torch.Tensor, buffer: torch.Tensor | None, pin_memory: bool = False
) -> torch.Tensor:
    """``source[index]`` written into the first ``len(index)`` rows of ``buffer`` (no allocation), or into a
    new tensor (page-locked with ``pin_memory``) when ``buffer`` is None."""
    if buffer is None:
        out = torch.empty((index.numel(), *source.shape[1:]), dtype=source.dtype, pin_memory=pin_memory)
    else:
        out = buffer[: index.numel()]
    torch.index_select(source.as_subclass(torch.Tensor), 0, index, out=out)
    return out


def _check_buffer_options(buffer_sets: int, pin_memory: bool) -> None:
    if isinstance(buffer_sets, bool) or not isinstance(buffer_sets, int) or buffer_sets < 1:
        raise ValueError(f"buffer_sets must be an integer >= 1, got {buffer_sets!r}")
    if pin_memory and not torch.cuda.is_available():
        raise ValueError("pin_memory=True needs CUDA (page-locked memory speeds up copies to a GPU)")


def _rows_as_gathered(rows: TensorDict) -> TensorDict:
    """The collate function of a :class:`TrajectoryBatcher`'s storage reads:
    its storages return TensorDicts."""
    return rows


class TrajectoryBatcher(TensorDictReplayBuffer):
    """Fast padded trajectory batches, a read-only TorchRL replay buffer: ``sample() -> TensorDict [N]``.

    Per-step keys have shape ``[N, T, ...]``: every trajectory key of the schema (``pixels`` uint8
    ``[N, T, 84, 84, 3]``, ``action`` ``[N, T, 2]``, ``return_to_go`` ``[N, T, 1]``, ``step`` ``[N, T]``, ...)
    and ``mask`` bool ``[N, T]`` (False on padding, which repeats the last valid step). Per-trajectory keys:
    ``target_pixels`` uint8 ``[N, 84, 84, 3]`` (from the targets table via ``target_id``) and ``trajectory``
    int64 ``[N]``. T is the longest window in the batch. (The root batch size is ``[N]`` because the target
    image is per trajectory.)

    As a ``TensorDictReplayBuffer`` its storage is a ``TensorStorage`` over the dataset's rows, its sampler
    the :class:`TrajectorySampler` and its writer TorchRL's ``ImmutableDatasetWriter`` (``extend`` raises: the
    rows are the dataset's files); ``sample(batch_size)`` takes the number of trajectories (at most the
    sampler's ``num_trajectories``, the default), and ``state_dict()`` / ``load_state_dict()`` hold the
    sampler's state (positions and generator), not the rows.

    With ``reuse_buffers=True`` (default) every key is gathered with ``index_select(out=)`` into buffers that
    are reused across calls (grown in steps of 32 timesteps up to ``N * context_steps`` rows when a batch
    needs more), so the returned tensors are overwritten by the ``buffer_sets``-th next ``sample()`` (the
    next one by default): consume (or ``.clone()``) a batch before then. ``buffer_sets=2`` lets one batch
    train while the next is drawn (:class:`~navformer_rl.data.prefetch.Prefetcher`). ``pin_memory=True``
    (CUDA only) allocates page-locked buffers, so ``.to("cuda", non_blocking=True)`` copies asynchronously.
    ``reuse_buffers=False`` allocates fresh tensors per batch.

    Examples:
        >>> import tempfile
        >>> from navformer_rl.data import make_synthetic_dataset, open_dataset
        >>> root = make_synthetic_dataset(tempfile.mkdtemp() + "/e", "e", n_trajectories=6, seed=0)
        >>> batcher = open_dataset(root).trajectory_batcher(4, context_steps=16, seed=0)
        >>> batch = batcher.sample()
        >>> batch.batch_size, batch["pixels"].dtype, batch["pixels"].shape[2:], batch["mask"].shape[0]
        (torch.Size([4]), torch.uint8, torch.Size([84, 84, 3]), 4)
        >>> batch["target_pixels"].shape
        torch.Size([4, 84, 84, 3])
    """

    _GROWTH_STEPS = 32

    def __init__(
        self,
        rows: TensorDict,
        targets: torch.Tensor,
        sampler: TrajectorySampler,
        keys: list[tuple[str, ...]] | None = None,
        reuse_buffers: bool = True,
        buffer_sets: int = 1,
        pin_memory: bool = False,
        *,
        storage: Storage | None = None,
        checkpointer=None,
    ):
        _check_buffer_options(buffer_sets, pin_memory)
        if sampler.episodes is None:
            sampler.bind(EpisodeTable.from_rows(rows["episode"], rows["target_id"]))
        super().__init__(
            storage=TensorStorage(rows) if storage is None else storage,
            sampler=sampler,
            writer=ImmutableDatasetWriter(),
            batch_size=sampler.num_trajectories,
            checkpointer=checkpointer,
            collate_fn=_rows_as_gathered,
        )
        self.rows = rows
        self.targets = targets.as_subclass(torch.Tensor)
        self.fields: dict[tuple[str, ...], FieldSpec] = (
            TRAJECTORY_FIELDS if keys is None else {tuple(k): TRAJECTORY_FIELDS[tuple(k)] for k in keys}
        )
        self.reuse_buffers = reuse_buffers
        self.pin_memory = pin_memory
        self._sources = {key: rows.get(key).as_subclass(torch.Tensor) for key in self.fields}
        self._buffer_sets: list[dict[tuple[str, ...], torch.Tensor]] = [{} for _ in range(buffer_sets)]
        self._target_buffers = [
            torch.empty(
                (sampler.num_trajectories, *targets.shape[1:]), dtype=targets.dtype, pin_memory=pin_memory
            )
            if reuse_buffers
            else None
            for _ in range(buffer_sets)
        ]
        self._turn = 0  # which buffer set the next sample() fills

    def _buffer(
        self, buffers: dict[tuple[str, ...], torch.Tensor], key: tuple[str, ...], n_rows: int, N: int
    ) -> torch.Tensor | None:
        """The reusable buffer of ``key`` in ``buffers`` with at least ``n_rows`` rows
        (None without reuse)."""
        if not self.reuse_buffers:
            return None
        buffer = buffers.get(key)
        if buffer is None or buffer.shape[0] < n_rows:
            steps = -(-n_rows // (N * self._GROWTH_STEPS)) * self._GROWTH_STEPS
            rows = min(N * min(steps, self.sampler.context_steps), N * self.sampler.context_steps)
            spec = self.fields[key]
            buffer = torch.empty(
                (max(rows, n_rows), *spec.shape), dtype=spec.dtype, pin_memory=self.pin_memory
            )
            buffers[key] = buffer
        return buffer

    def sample(
        self, batch_size: int | None = None, return_info: bool = False
    ) -> TensorDict | tuple[TensorDict, dict[str, torch.Tensor]]:
        """The next batch of the sampler's draws (see the class docstring for keys and shapes).

        ``batch_size``: trajectories, at most (and by default) the sampler's ``num_trajectories``.
        ``return_info``: also return ``{"index": int64 [N, T] storage rows, "mask": bool [N, T]}``.
        """
        if batch_size is not None and not 1 <= batch_size <= self.sampler.num_trajectories:
            raise ValueError(
                f"sample(batch_size={batch_size!r}): expected 1 to {self.sampler.num_trajectories} "
                "trajectories (the sampler's num_trajectories, which sizes the reused buffers)"
            )
        draw = self.sampler.draw(batch_size)
        batch = self.gather(draw)
        return (batch, {"index": draw.index, "mask": draw.mask}) if return_info else batch

    def gather(self, draw: TrajectoryDraw) -> TensorDict:
        """The batch of the windows in ``draw`` (at most the sampler's ``num_trajectories`` of them), e.g. a
        fixed draw kept for validation; the same keys, shapes and buffer reuse as :meth:`sample`."""
        N, T = draw.index.shape
        if N > self.sampler.num_trajectories:
            raise ValueError(
                f"the draw holds {N} trajectories, more than this batcher's {self.sampler.num_trajectories}"
            )
        flat = draw.index.reshape(-1)
        turn, self._turn = self._turn, (self._turn + 1) % len(self._buffer_sets)
        buffers = self._buffer_sets[turn]
        out = TensorDict(batch_size=[N])
        for key, spec in self.fields.items():
            buffer = self._buffer(buffers, key, flat.numel(), N)
            out.set(key, self._gather_rows(key, flat, buffer).view(N, T, *spec.shape))
        target_rows = self.sampler.episodes.target_id[draw.trajectory]
        out.set("target_pixels", self._gather_targets(target_rows, self._target_buffers[turn]))
        out.set("mask", draw.mask)
        out.set("trajectory", draw.trajectory)
        return out

    def _gather_rows(
        self, key: tuple[str, ...], index: torch.Tensor, buffer: torch.Tensor | None
    ) -> torch.Tensor:
        """Rows ``index`` (int64 ``[N*T]``) of column ``key``, written into ``buffer`` when one is given."""
        return _gather_into(self._sources[key], index, buffer, self.pin_memory)

    def _gather_targets(self, index: torch.Tensor, buffer: torch.Tensor | None) -> torch.Tensor:
        """Target images ``index`` (int64 ``[N]``) as uint8 ``[N, 84, 84, 3]``, into ``buffer`` when given."""
        return _gather_into(self.targets, index, buffer, self.pin_memory)

    def state_dict(self) -> dict[str, Any]:
        """The sampler's state (torch tensors and ints): where the epoch stands and its generator."""
        return self.sampler.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.sampler.load_state_dict(state)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(rows={len(self)}, sampler={self.sampler!r})"


PER_TRAJECTORY_KEYS = ("target_pixels", "trajectory")
"""The keys of a :class:`TrajectoryBatcher` batch with one value per trajectory (``[N, ...]``,
no time axis)."""


def split_by_length(batch: TensorDict, parts: int) -> list[TensorDict]:
    """Split a padded trajectory batch into ``parts`` groups of similar window length, each cropped to its
    own longest window.

    ``batch``: a :class:`TrajectoryBatcher` batch (``[N]``; per-step keys ``[N, T, ...]``, ``mask`` bool
    ``[N, T]`` with the padding on the right; per-trajectory keys :data:`PER_TRAJECTORY_KEYS`). The groups are
    :func:`~navformer_rl.utils.length_groups.length_sorted_groups`; group ``i`` keeps ``[n_i, T_i, ...]`` with
    ``T_i`` its longest valid window. Every valid step appears exactly once, with the steps before it in its
    trajectory, so a causal model right-padded to ``T_i`` sees the same context as in the whole batch: only
    padding is dropped.
    """
    if parts < 1:
        raise ValueError(f"parts must be >= 1, got {parts}")
    out = []
    for rows, steps in length_sorted_groups(batch["mask"], parts):
        part = batch[rows]
        cropped = TensorDict(batch_size=part.batch_size, device=part.device)
        for key, value in part.items(include_nested=True, leaves_only=True):
            name = key if isinstance(key, str) else key[-1]
            cropped.set(key, value if name in PER_TRAJECTORY_KEYS else value[:, :steps])
        out.append(cropped)
    return out


class PairBatcher:
    """D_ssl batches of ``batch_size`` image pairs (512 in the paper), without replacement within an epoch.

    ``sample() -> TensorDict [B]`` with ``pixels_static`` / ``pixels_dynamic`` uint8 ``[B, 84, 84, 3]``,
    ``world`` int64 ``[B]``, ``pose`` float32 ``[B, 3]``. Buffers (``reuse_buffers``, ``buffer_sets``,
    ``pin_memory``) work as in :class:`TrajectoryBatcher`.
    """

    def __init__(
        self,
        rows: TensorDict,
        batch_size: int = 512,
        seed: int = 0,
        reuse_buffers: bool = True,
        buffer_sets: int = 1,
        pin_memory: bool = False,
    ):
        from navformer_rl.data.schema import SSL_FIELDS

        _check_buffer_options(buffer_sets, pin_memory)
        if batch_size < 1 or batch_size > rows.shape[0]:
            raise ValueError(
                f"batch_size must be in [1, {rows.shape[0]}] (pairs in the dataset), got {batch_size}"
            )
        self.batch_size = int(batch_size)
        self.ids = EpochPermutation(rows.shape[0], seed)
        self.fields = SSL_FIELDS
        self._sources = {key: rows.get(key).as_subclass(torch.Tensor) for key in SSL_FIELDS}
        self.pin_memory = pin_memory
        self._buffer_sets = [
            {
                key: (
                    torch.empty((batch_size, *spec.shape), dtype=spec.dtype, pin_memory=pin_memory)
                    if reuse_buffers
                    else None
                )
                for key, spec in SSL_FIELDS.items()
            }
            for _ in range(buffer_sets)
        ]
        self._turn = 0  # which buffer set the next sample() fills

    @property
    def epoch(self) -> int:
        return self.ids.epoch

    def sample(self) -> TensorDict:
        """The next batch of ``batch_size`` pairs (see the class docstring for keys and shapes)."""
        return self.gather(self.draw())

    def draw(self) -> torch.Tensor:
        """The next batch's pair ids, int64 ``[batch_size]`` (advances the sampler; gathers nothing)."""
        return self.ids.draw(self.batch_size)

    def gather(self, index: torch.Tensor) -> TensorDict:
        """The pairs ``index`` (int64 ``[n]``, ``n <= batch_size``, e.g. one process's share of a drawn batch)
        as :meth:`sample` returns them, with the same buffer reuse."""
        if index.numel() > self.batch_size:
            raise ValueError(
                f"{index.numel()} pairs requested from a batcher of batch_size={self.batch_size}"
            )
        buffers = self._buffer_sets[self._turn]
        self._turn = (self._turn + 1) % len(self._buffer_sets)
        out = TensorDict(batch_size=[index.numel()])
        for key in self.fields:
            out.set(key, _gather_into(self._sources[key], index, buffers[key], self.pin_memory))
        out.set("index", index)
        return out

    def state_dict(self) -> dict[str, Any]:
        return self.ids.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.ids.load_state_dict(state)
