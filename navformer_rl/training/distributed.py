"""Data-parallel training over processes: ``torchrun --nproc-per-node N -m navformer_rl train ...``.

Launch. ``torchrun`` starts N processes with ``RANK`` / ``WORLD_SIZE`` / ``LOCAL_RANK`` (and the rendezvous
address) in their environment; :func:`process_group` (entered by :func:`~navformer_rl.training.train`) reads
them, starts the process group - gloo on CPU, NCCL on CUDA with ``cuda:LOCAL_RANK`` - and destroys it at the
end, also on an error. Without those variables (or with ``WORLD_SIZE=1``) training runs in one process as
usual.

The split. The configured batch sizes are **global** (the paper's 25 / 150 trajectories and 512 pairs per
iteration). Every process draws the *same* global batch from the same seeded sampler stream and gathers only
its own contiguous rows of it (:func:`shard_rows`: the first ``n % N`` processes take one row more, so any
batch of at least N rows splits). Each process weights its losses by its share of the global batch - L_DT
(a masked mean over valid steps) by its valid steps over the global batch's valid steps, L_BYOL (a mean over
pairs) by its pairs over the global pairs - so the *sum* of the per-process losses is the global loss, and
:meth:`Distributed.all_reduce_gradients` sums the gradients: every process then holds the gradient one
process computes on the whole batch (up to float summation order), whatever the split. Samplers, the BYOL
augmentation parameters (:class:`ShardedAugmentation` draws them for the whole batch and keeps its rows) and
the optimiser states therefore stay identical on every process; only the global RNG streams (dropout masks)
differ per process (:func:`rank_seed`). The BYOL heads' BatchNorm normalises over the whole global batch
(:class:`GlobalBatchNorm1d`, gradients through the all-reduce), so BYOL's loss and its EMA target equal one
process's. Validation is sharded (each process scores every N-th batch; the sums are all-reduced).

Gradients are all-reduced explicitly after the backward pass (one flat buffer per dtype) instead of wrapping
the model in ``DistributedDataParallel``: the losses run the model through TensorDict functional parameters
(TorchRL's ``convert_to_functional``), iterations alternate between tasks, and a parameter without a
gradient on every process (``None``) must stay without one, which the explicit form handles directly.
"""

from __future__ import annotations

import contextlib
import datetime
import os
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from tensordict import TensorDict
from torch import nn
from torchrl.data.replay_buffers import ImmutableDatasetWriter, TensorDictReplayBuffer

from navformer_rl.data.samplers import TrajectoryDraw
from navformer_rl.objectives.byol_augment import BYOLAugmentation
from navformer_rl.utils.devices import resolve_device

LAUNCH_VARIABLES = ("RANK", "WORLD_SIZE", "LOCAL_RANK")
"""The environment variables ``torchrun`` sets in every process it starts (with ``MASTER_ADDR`` /
``MASTER_PORT``)."""
TIMEOUT_VARIABLE = "NAVFORMER_DIST_TIMEOUT_S"
"""Seconds a collective waits for the other processes before failing (default: torch's, 10 to 30 minutes)."""
BUCKET_ELEMENTS = 1 << 24
"""Gradient elements per all-reduce (64 MiB of float32)."""


def launch_environment() -> tuple[int, int, int] | None:
    """``(rank, world_size, local_rank)`` from ``torchrun``'s environment; None when not launched by it.

    Raises:
        ValueError: the variables are set but are not integers with ``0 <= RANK < WORLD_SIZE``.
    """
    if "WORLD_SIZE" not in os.environ:
        return None
    values = {}
    for name in LAUNCH_VARIABLES:
        text = os.environ.get(name, "0")
        try:
            values[name] = int(text)
        except ValueError:
            raise ValueError(
                f"environment variable {name}={text!r}: expected an integer (set by torchrun)"
            ) from None
    rank, world_size, local_rank = (values[name] for name in LAUNCH_VARIABLES)
    if world_size < 1 or not 0 <= rank < world_size or local_rank < 0:
        raise ValueError(
            f"RANK={rank}, WORLD_SIZE={world_size}, LOCAL_RANK={local_rank}: expected 0 <= RANK < WORLD_SIZE "
            "and LOCAL_RANK >= 0 (as torchrun sets them)"
        )
    return rank, world_size, local_rank


def is_main_process() -> bool:
    """Whether this process is rank 0 (or not launched by ``torchrun``); reads the environment only."""
    launch = launch_environment()
    return launch is None or launch[0] == 0


def rank_seed(seed: int, rank: int) -> int:
    """The seed of process ``rank``'s global RNG streams (dropout): ``seed`` itself for rank 0, so one process
    under ``torchrun`` trains as without it; another stream for every other rank."""
    if rank == 0:
        return seed
    return int(np.random.SeedSequence([seed, rank]).generate_state(1, np.uint64)[0] >> 1)


def shard_rows(n: int, rank: int, world_size: int) -> slice:
    """The contiguous rows of a global batch of ``n`` that process ``rank`` of ``world_size`` takes: the first
    ``n % world_size`` processes take ``n // world_size + 1`` rows, the others ``n // world_size``."""
    if n < world_size:
        raise ValueError(f"a global batch of {n} cannot be split over {world_size} processes")
    base, extra = divmod(n, world_size)
    start = rank * base + min(rank, extra)
    return slice(start, start + base + (1 if rank < extra else 0))


@dataclass(frozen=True)
class Distributed:
    """Where this process stands in a data-parallel run, and the collectives the trainer uses.

    Attributes:
        rank / world_size / local_rank: as ``torchrun`` numbers the processes (0 / 1 / 0 for one process).
        backend: ``gloo`` or ``nccl``; None for one process (no process group, every collective a no-op).
        device: the device this process trains on (``cuda:LOCAL_RANK`` under NCCL); None: the configured one.
    """

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    backend: str | None = None
    device: torch.device | None = None

    @property
    def enabled(self) -> bool:
        """Whether more than one process trains (the collectives do something)."""
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        """Rank 0: the process that writes checkpoints, logs, run files and the progress bar."""
        return self.rank == 0

    def run_info(self) -> dict[str, Any]:
        """``{"world_size": N, "backend": "gloo" | "nccl" | None}``, recorded in the run files."""
        return {"world_size": self.world_size, "backend": self.backend}

    def rows(self, n: int) -> slice:
        """This process's rows of a global batch of ``n`` (:func:`shard_rows`)."""
        return shard_rows(n, self.rank, self.world_size)

    def all_reduce_sum(self, tensor: torch.Tensor) -> torch.Tensor:
        """``tensor`` summed over the processes, in place (unchanged for one process)."""
        if self.enabled:
            dist.all_reduce(tensor, op=dist.ReduceOp.SUM)
        return tensor

    def all_reduce_gradients(self, parameters: Iterable[torch.nn.Parameter]) -> None:
        """Sum every parameter's ``.grad`` over the processes, in place.

        A parameter with a gradient on some processes only gets zeros where it has none (the global batch
        has its gradient); one without a gradient anywhere keeps ``None`` (the optimiser skips it, as one
        process would). Gradients travel in flat buffers of at most :data:`BUCKET_ELEMENTS` per dtype.
        """
        if not self.enabled:
            return
        params = list({id(p): p for p in parameters}.values())
        device = params[0].device
        present = torch.tensor([p.grad is not None for p in params], dtype=torch.int32, device=device)
        self.all_reduce_sum(present)
        grads = []
        for param, count in zip(params, present.tolist(), strict=True):
            if count == 0:
                continue
            if param.grad is None:
                param.grad = torch.zeros_like(param)
            grads.append(param.grad)
        for bucket in _buckets(grads):
            flat = torch.cat([g.reshape(-1) for g in bucket])
            self.all_reduce_sum(flat)
            start = 0
            for grad in bucket:
                grad.copy_(flat[start : start + grad.numel()].view(grad.shape))
                start += grad.numel()

    def broadcast_tensors(self, tensors: Iterable[torch.Tensor]) -> None:
        """Overwrite ``tensors`` (parameters, buffers) on every process with rank 0's values, in place."""
        if not self.enabled:
            return
        tensors = [t.data for t in {id(t): t for t in tensors}.values()]
        for bucket in _buckets(tensors):
            flat = torch.cat([t.reshape(-1) for t in bucket])
            dist.broadcast(flat, src=0)
            start = 0
            for tensor in bucket:
                tensor.copy_(flat[start : start + tensor.numel()].view(tensor.shape))
                start += tensor.numel()

    def gather_object(self, obj: Any) -> list[Any] | None:
        """Every process's ``obj`` (picklable), in rank order, on rank 0; None on the other ranks."""
        if not self.enabled:
            return [obj]
        gathered: list[Any] | None = [None] * self.world_size if self.is_main else None
        dist.gather_object(obj, gathered, dst=0)
        return gathered

    def barrier(self) -> None:
        """Wait until every process gets here."""
        if not self.enabled:
            return
        if self.backend == "nccl":
            dist.barrier(device_ids=[self.local_rank])
        else:
            dist.barrier()


def _buckets(tensors: list[torch.Tensor]) -> Iterator[list[torch.Tensor]]:
    """``tensors`` in runs of one dtype of at most :data:`BUCKET_ELEMENTS` elements
    (one tensor may exceed it)."""
    by_dtype: dict[Any, list[torch.Tensor]] = {}
    for tensor in tensors:
        by_dtype.setdefault(tensor.dtype, []).append(tensor)
    for group in by_dtype.values():
        bucket: list[torch.Tensor] = []
        size = 0
        for tensor in group:
            if bucket and size + tensor.numel() > BUCKET_ELEMENTS:
                yield bucket
                bucket, size = [], 0
            bucket.append(tensor)
            size += tensor.numel()
        if bucket:
            yield bucket


def _device_and_backend(device: str, local_rank: int, world_size: int) -> tuple[torch.device, str]:
    """This process's device and the process group's backend for the configured ``device``."""
    resolved = resolve_device(device)
    if resolved.type == "cpu":
        return resolved, "gloo"
    if resolved.type != "cuda":
        raise ValueError(f"device={device!r}: data-parallel training runs on cpu (gloo) or cuda (NCCL)")
    if resolved.index is not None and world_size > 1:
        raise ValueError(
            f"device={device} names one GPU, but {world_size} processes train: use device=cuda or "
            "device=auto (each process takes cuda:LOCAL_RANK; choose the GPUs with CUDA_VISIBLE_DEVICES)"
        )
    count = torch.cuda.device_count()
    if local_rank >= count:
        raise ValueError(
            f"LOCAL_RANK={local_rank}, but torch sees {count} CUDA device(s): start at most {count} "
            "processes per machine (torchrun --nproc-per-node)"
        )
    return torch.device("cuda", local_rank), "nccl"


def current(device: str) -> Distributed:
    """The :class:`Distributed` of a process group already started (by :func:`process_group` or the caller),
    or of one process when none is.

    Raises:
        RuntimeError: ``torchrun`` started several processes but no process group is (every process would
            act as rank 0 and write the same files).
    """
    if not (dist.is_available() and dist.is_initialized()):
        launch = launch_environment()
        if launch is not None and launch[1] > 1:
            raise RuntimeError(
                f"torchrun started {launch[1]} processes but no process group is initialised: train with "
                "navformer_rl.training.train (it starts one) "
                "or inside navformer_rl.training.distributed.process_group"
            )
        return Distributed()
    world_size, rank = dist.get_world_size(), dist.get_rank()
    backend = str(dist.get_backend())
    if backend == "nccl":
        index = torch.cuda.current_device()
        return Distributed(rank, world_size, index, backend, torch.device("cuda", index))
    resolved, _ = _device_and_backend(device, 0, world_size)
    if resolved.type != "cpu":
        raise ValueError(
            f"device={device!r} with a {backend} process group: set device=cpu (gloo trains on CPU)"
        )
    launch = launch_environment()
    return Distributed(rank, world_size, launch[2] if launch else 0, backend, resolved)


@contextlib.contextmanager
def process_group(device: str) -> Iterator[Distributed]:
    """Start the process group ``torchrun``'s environment describes (gloo on CPU, NCCL on CUDA with
    ``cuda:LOCAL_RANK``) and destroy it on leaving, also on an error. Yields the :class:`Distributed` of this
    process; without ``torchrun`` (or with ``WORLD_SIZE=1``, or when the caller has started a group already)
    it starts nothing and yields :func:`current`."""
    launch = launch_environment()
    if launch is None or launch[1] == 1 or (dist.is_available() and dist.is_initialized()):
        yield current(device)
        return
    rank, world_size, local_rank = launch
    torch_device, backend = _device_and_backend(device, local_rank, world_size)
    if torch_device.type == "cuda":
        torch.cuda.set_device(torch_device)
    options: dict[str, Any] = {"backend": backend, "rank": rank, "world_size": world_size}
    if os.environ.get(TIMEOUT_VARIABLE):
        options["timeout"] = datetime.timedelta(seconds=float(os.environ[TIMEOUT_VARIABLE]))
    if backend == "nccl":
        options["device_id"] = torch_device
    dist.init_process_group(**options)
    try:
        yield Distributed(rank, world_size, local_rank, backend, torch_device)
    finally:
        dist.destroy_process_group()


# -- the pieces a process trains with ------------------------------------------------------------------------


class ShardedTrajectoryBatcher(TensorDictReplayBuffer):
    """A :class:`~navformer_rl.data.samplers.TrajectoryBatcher` that draws the global batch of its sampler and
    gathers this process's rows of it only (each row's window trimmed to the rows' longest).

    A read-only TorchRL buffer on the batcher's storage and sampler (so it is a member of a
    :class:`~navformer_rl.data.cross_task.CrossTaskReplayBuffer` as the batcher is). ``sample()`` returns the
    keys and shapes of ``TrajectoryBatcher.sample()`` for ``n`` = this process's rows; ``state_dict()`` /
    ``load_state_dict()`` are the sampler's, the same on every process.
    """

    def __init__(self, batcher: Any, distributed: Distributed) -> None:
        super().__init__(
            storage=batcher.storage,
            sampler=batcher.sampler,
            writer=ImmutableDatasetWriter(),
            batch_size=batcher.sampler.num_trajectories,
        )
        self.batcher = batcher
        self.rows = distributed.rows(batcher.sampler.num_trajectories)

    def sample(self, batch_size: int | None = None, return_info: bool = False) -> TensorDict:
        if batch_size is not None or return_info:
            raise ValueError(
                "ShardedTrajectoryBatcher.sample() draws its sampler's global batch; call sample()"
            )
        draw = self.batcher.sampler.draw()
        mask = draw.mask[self.rows]
        steps = int(mask.sum(1).max())
        return self.batcher.gather(
            TrajectoryDraw(
                index=draw.index[self.rows, :steps],
                mask=mask[:, :steps],
                trajectory=draw.trajectory[self.rows],
            )
        )

    def state_dict(self) -> dict[str, Any]:
        return self.batcher.state_dict()

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.batcher.load_state_dict(dict(state))


class ShardedPairBatcher:
    """A :class:`~navformer_rl.data.samplers.PairBatcher` that draws the global batch's pair ids and gathers
    this process's rows only (``sample()``: ``TensorDict [n]``, keys as ``PairBatcher.sample()``)."""

    def __init__(self, batcher: Any, distributed: Distributed) -> None:
        self.batcher = batcher
        self.rows = distributed.rows(batcher.batch_size)

    def sample(self) -> TensorDict:
        return self.batcher.gather(self.batcher.draw()[self.rows])

    def state_dict(self) -> dict[str, Any]:
        return self.batcher.state_dict()

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.batcher.load_state_dict(dict(state))


class ShardedAugmentation(BYOLAugmentation):
    """:class:`~navformer_rl.objectives.byol_augment.BYOLAugmentation` of this process's ``rows`` of a global
    batch of ``total`` images: the crop boxes and colour factors are drawn for the whole batch and the rows
    kept, so the generator advances alike on every process and each image gets the augmentation one process
    would give it. ``kwargs``: ``BYOLAugmentation``'s (``seed``, ...)."""

    def __init__(self, rows: slice, total: int, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.rows, self.total = rows, int(total)

    def _check(self, n: int) -> None:
        count = self.rows.stop - self.rows.start
        if n != count:
            raise ValueError(
                f"ShardedAugmentation takes rows {self.rows.start}-{self.rows.stop - 1} "
                f"({count} images); got {n}"
            )

    def crop_boxes(self, n: int) -> torch.Tensor:
        self._check(n)
        return super().crop_boxes(self.total)[self.rows]

    def jitter_factors(self, n: int) -> dict[str, torch.Tensor]:
        self._check(n)
        return {name: value[self.rows] for name, value in super().jitter_factors(self.total).items()}


class _SumOverProcesses(torch.autograd.Function):
    """``x`` summed over the processes; the gradient of each process's copy is the sum of every process's
    (each process's loss is its part of a global loss that is their sum)."""

    @staticmethod
    def forward(ctx: Any, x: torch.Tensor) -> torch.Tensor:
        out = x.clone(memory_format=torch.contiguous_format)
        dist.all_reduce(out, op=dist.ReduceOp.SUM)
        return out

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> torch.Tensor:
        return _SumOverProcesses.apply(grad)


def sum_over_processes(x: torch.Tensor) -> torch.Tensor:
    """``x`` summed over the processes of the process group, differentiably (see
    :class:`_SumOverProcesses`)."""
    return _SumOverProcesses.apply(x)


class GlobalBatchNorm1d(nn.BatchNorm1d):
    """``nn.BatchNorm1d`` whose training statistics are those of the global batch, over every process: the
    sums are all-reduced by :func:`sum_over_processes`, so the gradient flows through them as on one process.
    Without a process group, or in eval mode, it is ``nn.BatchNorm1d``. Input ``[B, C]``.
    (``nn.SyncBatchNorm`` does the same on GPUs only; this one also runs on gloo.)"""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not (
            self.training and dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1
        ):
            return super().forward(x)
        if x.dim() != 2:
            raise ValueError(f"GlobalBatchNorm1d: expected input [B, C], got {tuple(x.shape)}")
        values = x.float()
        count = torch.full((1,), float(x.shape[0]), device=x.device)
        sums = sum_over_processes(torch.cat([values.sum(0), count]))
        n = sums[-1]
        mean = sums[:-1] / n
        centred = values - mean
        var = sum_over_processes(centred.square().sum(0)) / n  # biased, as BatchNorm normalises
        out = centred * torch.rsqrt(var + self.eps)
        if self.affine:
            out = out * self.weight + self.bias
        if self.track_running_stats:
            with torch.no_grad():
                self.num_batches_tracked.add_(1)
                factor = 1.0 / float(self.num_batches_tracked) if self.momentum is None else self.momentum
                self.running_mean.lerp_(mean.detach().to(self.running_mean.dtype), factor)
                unbiased = var.detach() * n / (n - 1).clamp_min(1)
                self.running_var.lerp_(unbiased.to(self.running_var.dtype), factor)
        return out.to(x.dtype)


def use_global_batch_norm(module: nn.Module) -> int:
    """Replace every ``nn.BatchNorm1d`` under ``module`` by a :class:`GlobalBatchNorm1d` holding the same
    parameter and buffer objects (as ``nn.SyncBatchNorm.convert_sync_batchnorm`` does). Returns how many."""
    replaced = 0
    for parent in list(module.modules()):
        for name, child in list(parent.named_children()):
            if type(child) is not nn.BatchNorm1d:
                continue
            new = GlobalBatchNorm1d(
                child.num_features,
                child.eps,
                child.momentum,
                child.affine,
                child.track_running_stats,
                device="meta",
            )
            if child.affine:
                new.weight, new.bias = child.weight, child.bias
            if child.track_running_stats:
                new.running_mean, new.running_var = child.running_mean, child.running_var
                new.num_batches_tracked = child.num_batches_tracked
            new.train(child.training)
            setattr(parent, name, new)
            replaced += 1
    return replaced
