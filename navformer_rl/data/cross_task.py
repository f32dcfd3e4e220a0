"""Cross-task trajectory batches (paper §VI): a TorchRL ``ReplayBufferEnsemble`` alternating D_e and D_ca.

:class:`CrossTaskReplayBuffer` holds one trajectory replay buffer per task - ours
(:meth:`NavDataset.trajectory_batcher <navformer_rl.data.dataset.NavDataset.trajectory_batcher>`, the fast
path training uses, or ``trajectory_buffer``) or any TorchRL buffer whose sampler draws trajectories
(``SliceSampler(traj_key="episode", ...)``) - and draws from them in turn: exploration, collision avoidance,
exploration, ... Each member keeps its own batch size in trajectories (the paper's 25 from D_e, 150 from
D_ca). The ablations "w/o D_e" / "w/o D_ca" (Table IV) pass one buffer: every draw comes from it.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import ReplayBuffer, ReplayBufferEnsemble
from torchrl.data.replay_buffers import SliceSampler

from navformer_rl.data.samplers import TrajectorySampler
from navformer_rl.tasks import DATASETS

EXPLORATION = DATASETS["e"].task
COLLISION_AVOIDANCE = DATASETS["ca"].task
BUFFER_IDS_KEY = ("index", "buffer_ids")
"""Where a sample carries the position of the member it came from (TorchRL's ``ReplayBufferEnsemble`` key)."""
PER_TRAJECTORY_KEYS = ("target_pixels",)
"""Keys kept once per trajectory (``[N, ...]``) when a member's sample holds them per step."""


class CrossTaskReplayBuffer(ReplayBufferEnsemble):
    """A ``ReplayBufferEnsemble`` of trajectory buffers drawn in turn, one batch per ``sample()`` (§VI).

    ``sample()`` takes the next member in order (exploration first when both are given) and returns its
    batch as a *trajectory batch*: root batch size ``[N]`` (one entry per trajectory, N = that member's
    trajectories per batch), every per-step key ``[N, T, ...]`` with ``mask`` bool ``[N, T]`` (False on
    right padding), ``target_pixels`` ``[N, 84, 84, 3]``, and the member's position in
    ``("index", "buffer_ids")`` int64 ``[N]`` (as TorchRL's ensemble writes it; ``task_of(batch)`` names the
    task). The actor of :func:`~navformer_rl.modules.make_navformer_actor` and the losses read it as it is.

    Members' samples are brought to that layout:

    - a batch of batch size ``[N]`` with a ``mask`` ``[N, T]`` (:class:`~navformer_rl.data.samplers.
      TrajectoryBatcher`) is taken as it is;
    - a flat ``[N * T]`` sample (``trajectory_buffer``, ``SliceSampler``) is reshaped to ``[N, T]``, N being
      the member's batch size for a :class:`~navformer_rl.data.samplers.TrajectorySampler`, ``num_slices`` (or
      batch size / ``slice_len``) for a ``SliceSampler``; an ``[N, T]`` sample is taken as reshaped;
    - then the root batch becomes ``[N]``, ``target_pixels`` given per step is kept once per trajectory
      (step 0), TorchRL's ``("collector", "mask")`` (``SliceSampler(pad_output=True)``) is copied to ``mask``
      when the sample has none, and a sampled ``index`` moves to ``("index", "index")``.

    A member whose sampler draws no trajectories (``RandomSampler``, ...) is refused by name.

    ``state_dict()`` is the sampling state, not the data: ``{"iteration": int, <task>: {"sampler": the
    member sampler's state, "generator": the member buffer's generator state or None}}`` (torch tensors and
    ints, ``weights_only``-safe); ``load_state_dict`` also reads the layout of the former ``CrossTaskSampler``
    (``{"iteration", <task>: sampler state}``) that older training checkpoints hold. A member's draws are
    reproducible when its sampler owns a generator (``TrajectorySampler``) or the member buffer was given
    ``generator=``; TorchRL samplers drawing from the global torch RNG are not captured. ``dumps`` /
    ``loads`` write / read that state (``cross_task.pt``). Writing through the ensemble is disabled, as on
    TorchRL's ensembles: extend a member (``buffer[i].extend(...)``).

    Args:
        exploration: the D_e trajectory buffer, or None (ablation without D_e).
        collision_avoidance: the D_ca trajectory buffer, or None (ablation without D_ca).

    Examples:
        >>> import tempfile
        >>> from navformer_rl.data import CrossTaskReplayBuffer, make_synthetic_dataset, open_dataset
        >>> tmp = tempfile.mkdtemp()
        >>> e = open_dataset(make_synthetic_dataset(tmp + "/e", "e", n_trajectories=8, seed=0))
        >>> ca = open_dataset(make_synthetic_dataset(tmp + "/ca", "ca", n_trajectories=12, seed=1))
        >>> buffer = CrossTaskReplayBuffer(e.trajectory_batcher(2, seed=0), ca.trajectory_buffer(3, seed=1))
        >>> for _ in range(3):
        ...     batch = buffer.sample()
        ...     print(buffer.task_of(batch), batch.batch_size, batch["pixels"].dim(), batch["mask"].shape[0])
        exploration torch.Size([2]) 5 2
        collision_avoidance torch.Size([3]) 5 3
        exploration torch.Size([2]) 5 2
        >>> # save the state with the checkpoint; load_state_dict(state) resumes the draws
        >>> state = buffer.state_dict()
        >>> buffer[1] is buffer.buffer("collision_avoidance")
        True
    """

    def __init__(
        self,
        exploration: ReplayBuffer | None = None,
        collision_avoidance: ReplayBuffer | None = None,
    ) -> None:
        members = [
            (name, buffer)
            for name, buffer in ((EXPLORATION, exploration), (COLLISION_AVOIDANCE, collision_avoidance))
            if buffer is not None
        ]
        if not members:
            raise ValueError(
                "CrossTaskReplayBuffer needs at least one of exploration= / "
                "collision_avoidance= (a replay buffer)"
            )
        for name, buffer in members:
            if not isinstance(buffer, ReplayBuffer):
                raise TypeError(
                    f"CrossTaskReplayBuffer({name}=...): expected a TorchRL ReplayBuffer holding "
                    f"trajectories (e.g. dataset.trajectory_batcher(N)), got {type(buffer).__name__}"
                )
            _trajectory_sampler(name, buffer)  # refuses a member that draws no trajectories
        self._tasks = tuple(name for name, _ in members)
        super().__init__(*(buffer for _, buffer in members))
        for _, buffer in members:  # the ensemble set its own (None) generator on the members' parts
            if buffer._rng is not None:
                buffer.set_rng(buffer._rng)
        self.iteration = 0

    # -- which task ---------------------------------------------------------------------------------------
    @property
    def tasks(self) -> tuple[str, ...]:
        """The members' task names, in member order (``"exploration"``, ``"collision_avoidance"``)."""
        return self._tasks

    @property
    def next_task(self) -> str:
        """The task the next ``sample()`` draws from."""
        return self._tasks[self.iteration % len(self._tasks)]

    def buffer(self, task: str) -> ReplayBuffer:
        """The member buffer of ``task`` (``buffer[i]`` indexes them by position)."""
        if task not in self._tasks:
            raise KeyError(f"no member buffer for task {task!r}; this buffer holds {list(self._tasks)}")
        return self._rbs[self._tasks.index(task)]

    def task_of(self, batch: TensorDictBase) -> str:
        """The task of a batch this buffer sampled (read from ``("index", "buffer_ids")``)."""
        ids = batch.get(BUFFER_IDS_KEY, None)
        if ids is None:
            raise KeyError(
                f"the batch has no {BUFFER_IDS_KEY!r}: it was not sampled from a CrossTaskReplayBuffer"
            )
        return self._tasks[int(ids.reshape(-1)[0])]

    # -- sampling -----------------------------------------------------------------------------------------
    def sample(
        self, batch_size: int | None = None, return_info: bool = False
    ) -> TensorDictBase | tuple[TensorDictBase, dict[str, Any]]:
        """The next task's batch (see the class docstring for its layout).

        ``batch_size`` must be None: each member keeps its own batch size (trajectories per batch).
        ``return_info`` also returns ``{"buffer_ids": int, "task": str}``.
        """
        if batch_size is not None:
            raise ValueError(
                f"CrossTaskReplayBuffer.sample(batch_size={batch_size!r}): the batch sizes are the members' "
                "own (trajectories per task, e.g. dataset.trajectory_batcher(25)); call sample()"
            )
        position = self.iteration % len(self._tasks)
        member = self._rbs[position]
        batch = trajectory_batch(member.sample(), self._tasks[position], member)
        batch.set(
            BUFFER_IDS_KEY, torch.full(batch.batch_size, position, dtype=torch.int64, device=batch.device)
        )
        self.iteration += 1
        if return_info:
            return batch, {"buffer_ids": position, "task": self._tasks[position]}
        return batch

    def __iter__(self) -> Iterator[TensorDictBase]:
        while True:
            yield self.sample()

    # -- checkpoints --------------------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """The sampling state (see the class docstring): a fresh object, later draws leave it unchanged."""
        state: dict[str, Any] = {"iteration": self.iteration}
        for name, member in zip(self._tasks, self._rbs, strict=True):
            generator = getattr(member, "_rng", None)
            state[name] = {
                "sampler": member.sampler.state_dict(),
                "generator": None if generator is None else generator.get_state(),
            }
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        missing = [name for name in self._tasks if name not in state]
        if missing:
            saved = sorted(set(state) - {"iteration"})
            raise ValueError(
                f"cross-task sampler state lacks {missing}; it was saved with tasks {saved}: build the "
                "buffer with the same tasks (the same ablation)"
            )
        for name, member in zip(self._tasks, self._rbs, strict=True):
            member_state = state[name]
            if "sampler" not in member_state:  # the former CrossTaskSampler's layout: the sampler's state
                member_state = {"sampler": member_state, "generator": None}
            member.sampler.load_state_dict(member_state["sampler"])
            if member_state.get("generator") is not None:
                member._rng.set_state(member_state["generator"])
        self.iteration = int(state["iteration"])

    def dumps(self, path: str | Path) -> None:
        """Write the sampling state to ``path/cross_task.pt`` (the members' data stay where they are)."""
        Path(path).mkdir(parents=True, exist_ok=True)
        torch.save(self.state_dict(), Path(path) / "cross_task.pt")

    def loads(self, path: str | Path) -> None:
        """Read the sampling state :meth:`dumps` wrote."""
        self.load_state_dict(torch.load(Path(path) / "cross_task.pt", weights_only=True))

    def __repr__(self) -> str:
        members = ", ".join(f"{name}={member!r}" for name, member in zip(self._tasks, self._rbs, strict=True))
        return f"{type(self).__name__}({members}, next_task={self.next_task!r})"


def _trajectory_sampler(task: str, buffer: ReplayBuffer) -> TrajectorySampler | SliceSampler:
    sampler = buffer.sampler
    if not isinstance(sampler, (TrajectorySampler, SliceSampler)):
        raise ValueError(
            f"CrossTaskReplayBuffer({task}=...): its sampler {type(sampler).__name__} draws no trajectories; "
            "use dataset.trajectory_batcher(N) / trajectory_buffer(N) (TrajectorySampler) or a "
            "SliceSampler(traj_key='episode', ...)"
        )
    return sampler


def _trajectories_per_sample(task: str, buffer: ReplayBuffer, rows: int) -> int:
    """N of a flat ``[N * T]`` sample of ``buffer`` holding ``rows`` rows."""
    sampler = _trajectory_sampler(task, buffer)
    if isinstance(sampler, TrajectorySampler):
        n = buffer.batch_size or sampler.num_trajectories
    elif sampler.num_slices is not None:
        n = sampler.num_slices
    else:
        n = buffer.batch_size // sampler.slice_len
    if n < 1 or rows % n:
        raise ValueError(
            f"CrossTaskReplayBuffer: the {task} buffer returned {rows} rows, not a whole number of "
            f"{n} trajectories; give its sampler a batch size that is a multiple of its slices"
        )
    return n


def trajectory_batch(sample: TensorDictBase, task: str, buffer: ReplayBuffer) -> TensorDictBase:
    """``sample`` of ``buffer`` (the ``task`` member) as a trajectory batch ``[N]`` with per-step keys
    ``[N, T, ...]`` (the layout of :class:`CrossTaskReplayBuffer`'s samples; see there)."""
    mask = sample.get("mask", None)
    if sample.batch_dims == 1 and mask is not None and mask.dim() == 2:
        return sample  # already [N] with [N, T] steps (TrajectoryBatcher)
    if sample.batch_dims == 1:
        sample = sample.reshape(_trajectories_per_sample(task, buffer, sample.shape[0]), -1)
    elif sample.batch_dims != 2:
        raise ValueError(
            f"CrossTaskReplayBuffer: the {task} buffer returned a batch of shape {tuple(sample.batch_size)}; "
            "expected flat [N * T] rows or [N, T] trajectories"
        )
    n = sample.shape[0]
    if "mask" not in sample.keys() and ("collector", "mask") in sample.keys(include_nested=True):
        sample.set("mask", sample.get(("collector", "mask")))
    moved = {key: sample.get(key)[:, 0] for key in PER_TRAJECTORY_KEYS if key in sample.keys()}
    index = sample.get("index", None)
    if isinstance(index, torch.Tensor):
        moved[("index", "index")] = index
        sample = sample.exclude("index")
    sample = sample.exclude(*PER_TRAJECTORY_KEYS)
    sample.batch_size = torch.Size([n])
    for key, value in moved.items():
        sample.set(key, value)
    return sample
