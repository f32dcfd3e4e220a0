"""One training iteration, eq. 11: :func:`train_step`, and the wrappers that change how L reaches the
gradients without changing them (:class:`ChunkedBackward`, :class:`DataParallelBackward`).

:func:`train_step` is the paper's iteration on one process and the whole batch: both losses, one backward of
their sum, the AdamW step of the navigation network, the Adam step of the DVE, BYOL's EMA update. With
``optim.trajectory_chunks > 1`` or several processes, a *backward* wrapper replaces the one backward (and
only that): it back-propagates the same L in parts, each weighted so that the summed gradient is the one
backward's, then (several processes) sums the gradients over the processes. :func:`make_backward` picks it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from tensordict import TensorDict

from navformer_rl.data.samplers import split_by_length
from navformer_rl.training.distributed import Distributed, shard_rows

if TYPE_CHECKING:
    from torchrl.objectives import LossModule, SoftUpdate

    from navformer_rl.objectives import BYOLLoss, BYOLTauSchedule
    from navformer_rl.training.config import TrainConfig

Backward = Callable[
    [TensorDict, TensorDict | None, torch.Tensor | None], tuple[torch.Tensor, torch.Tensor | None]
]
"""``backward(batch, pairs, loss_byol) -> (loss_dt, loss_byol)``: back-propagates L = L_DT + L_BYOL (given the
BYOL loss already computed) and returns the detached L_DT and the BYOL loss as it entered L."""


@dataclass
class Learner:
    """What one iteration of eq. 11 runs and updates
    (:func:`~navformer_rl.training.factories.make_learner`)."""

    dt_loss: LossModule
    """L_DT (eq. 10) on the actor: ``ActionMSELoss`` (``ActionBinLoss`` with ``model.action_bins``)."""
    byol_loss: BYOLLoss | None
    """L_BYOL (eq. 8) on the D_ssl pairs; None without SSL."""
    optimizers: dict[str, torch.optim.Optimizer]
    """``"navformer"``: AdamW of the navigation network; ``"dve"``: Adam of the DVE (the encoders under
    ``optim.encoder_optimizer=adam``, BYOL's projectors and predictors); absent when it would own nothing."""
    ema: SoftUpdate | None
    """BYOL's EMA target update (None without SSL)."""
    tau_schedule: BYOLTauSchedule | None
    """The EMA's cosine schedule of tau (None without SSL)."""
    scaler: torch.amp.GradScaler
    """Loss scaling, enabled only under float16 autocast (else every call is the identity)."""
    byol_weight: float = 1.0
    """w in L = L_DT + w L_BYOL (``ssl.loss_weight``; eq. 11: 1)."""
    clip_grad_norm: float | None = None
    """``optim.clip_grad_norm``: each optimiser's gradient norm is clipped to it (None: no clipping)."""

    def clip_gradients(self) -> None:
        """Clip each optimiser's parameters' gradient norm to :attr:`clip_grad_norm` (unscaled first)."""
        if self.clip_grad_norm is None:
            return
        for optimizer in self.optimizers.values():
            self.scaler.unscale_(optimizer)
            params = [p for group in optimizer.param_groups for p in group["params"]]
            torch.nn.utils.clip_grad_norm_(params, self.clip_grad_norm)


@dataclass
class StepLosses:
    """What :func:`train_step` computed: detached L_DT, BYOL's loss as it entered L (None without SSL), the
    BYOL loss module's output (``loss_byol`` unweighted, per-encoder terms; None without SSL) and the EMA's
    tau of this iteration (None without SSL)."""

    loss_dt: torch.Tensor
    loss_byol: torch.Tensor | None
    byol: TensorDict | None
    tau: float | None


def train_step(
    learner: Learner, batch: TensorDict, pairs: TensorDict | None, backward: Backward | None = None
) -> StepLosses:
    """One iteration of eq. 11: ``batch`` (D_e or D_ca trajectories ``[N, T]``) and ``pairs`` (D_ssl, None
    without SSL) on this process's device. ``backward``: None back-propagates L in one backward (one
    process, the whole batch); else a wrapper (:func:`make_backward`) that reaches the same gradient in parts.
    """
    from torchrl._utils import timeit

    sync = batch["mask"].device.type == "cuda"  # time the GPU work of each phase, not its launches
    for optimizer in learner.optimizers.values():
        optimizer.zero_grad(set_to_none=True)
    with timeit("forward_backward", sync=sync):
        byol = learner.byol_loss(pairs) if pairs is not None else None  # L_BYOL (eq. 8)
        loss_byol = None if byol is None else learner.byol_weight * byol["loss_byol"]
        if backward is None:
            loss_dt = learner.dt_loss(batch)["loss_dt"]  # L_DT (eq. 10)
            loss = loss_dt if loss_byol is None else loss_dt + loss_byol  # L = L_DT + L_BYOL (eq. 11)
            learner.scaler.scale(loss).backward()  # one backward (loss scaling under float16 only)
            loss_dt = loss_dt.detach()
        else:
            loss_dt, loss_byol = backward(batch, pairs, loss_byol)
    with timeit("optimizer", sync=sync):
        learner.clip_gradients()
        learner.scaler.step(learner.optimizers["navformer"])  # AdamW: embeddings, transformer, head
        if "dve" in learner.optimizers:
            learner.scaler.step(learner.optimizers["dve"])  # Adam: the DVE (encoders, BYOL heads)
        learner.scaler.update()  # float16 only: a step with an overflowed gradient was skipped
        tau = None
        if learner.ema is not None:
            tau = learner.ema.eps
            learner.ema.step()  # BYOL's target <- tau target + (1 - tau) online
            learner.tau_schedule.step()
    return StepLosses(loss_dt, loss_byol, byol, tau)


class ChunkedBackward:
    """L back-propagated in ``chunks`` parts of the trajectory batch (``optim.trajectory_chunks``): BYOL's
    loss in one backward, then each chunk's masked mean L_DT weighted by its share of the batch's valid steps,
    so that the summed gradient is the whole batch's (only peak memory changes). ``by_length``: chunks of
    similar trajectory length, their padding cropped (``optim.chunks_by_length``)."""

    def __init__(self, learner: Learner, chunks: int, by_length: bool = False) -> None:
        self.learner, self.chunks, self.by_length = learner, chunks, by_length

    def parts(self, batch: TensorDict) -> list[TensorDict]:
        if self.by_length:
            return split_by_length(batch, self.chunks)
        n = batch.shape[0]
        return [batch[shard_rows(n, i, min(self.chunks, n))] for i in range(min(self.chunks, n))]

    def __call__(
        self, batch: TensorDict, pairs: TensorDict | None, loss_byol: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        valid_total = batch["mask"].sum().clamp_min(1)
        return self.weighted(batch, loss_byol, valid_total), loss_byol

    def weighted(
        self, batch: TensorDict, loss_byol: torch.Tensor | None, valid_total: torch.Tensor
    ) -> torch.Tensor:
        """Back-propagate ``loss_byol`` and every chunk's L_DT x (its valid steps / ``valid_total``); returns
        the detached sum of the weighted L_DT terms."""
        scaler, dt_loss = self.learner.scaler, self.learner.dt_loss
        parts = self.parts(batch)
        if loss_byol is not None and len(parts) > 1:
            scaler.scale(loss_byol).backward()
        loss_dt = torch.zeros((), device=batch["mask"].device)
        for part in parts:
            # masked mean of the chunk x its share of the valid steps = its part of the batch's masked mean
            weighted = dt_loss(part)["loss_dt"] * (part["mask"].sum() / valid_total)
            together = loss_byol is not None and len(parts) == 1  # one backward, as one process does
            scaler.scale(weighted + loss_byol if together else weighted).backward()
            loss_dt += weighted.detach()
        return loss_dt


class DataParallelBackward:
    """L back-propagated by one process of a data-parallel run (:mod:`~navformer_rl.training.distributed`),
    around :class:`ChunkedBackward` (one chunk unless ``optim.trajectory_chunks`` says more): this process's
    L_DT weighted by its valid steps over the global batch's (all-reduced), L_BYOL by its share of the global
    pairs; the gradients are then summed over the processes, which gives every process the global batch's
    gradient of L."""

    def __init__(self, chunked: ChunkedBackward, distributed: Distributed, total_pairs: int) -> None:
        self.chunked, self.distributed, self.total_pairs = chunked, distributed, total_pairs

    def pair_share(self, pairs: TensorDict) -> float:
        """This process's share of the global D_ssl batch."""
        return pairs.shape[0] / self.total_pairs

    def __call__(
        self, batch: TensorDict, pairs: TensorDict | None, loss_byol: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        from torchrl._utils import timeit

        valid_total = self.distributed.all_reduce_sum(batch["mask"].sum())
        if loss_byol is not None:
            loss_byol = loss_byol * self.pair_share(pairs)
        loss_dt = self.chunked.weighted(batch, loss_byol, valid_total.clamp_min(1))
        with timeit("all_reduce", sync=batch["mask"].device.type == "cuda"):
            optimizers = self.chunked.learner.optimizers.values()
            self.distributed.all_reduce_gradients(
                p for optimizer in optimizers for group in optimizer.param_groups for p in group["params"]
            )
        return loss_dt, loss_byol


def make_backward(cfg: TrainConfig, learner: Learner, distributed: Distributed) -> Backward | None:
    """The backward of ``cfg``'s run: None (:func:`train_step`'s one backward) for one process and one chunk,
    else :class:`ChunkedBackward`, wrapped in :class:`DataParallelBackward` for several processes."""
    chunks = cfg.optim.trajectory_chunks
    if chunks == 1 and not distributed.enabled:
        return None
    chunked = ChunkedBackward(learner, chunks, cfg.optim.chunks_by_length)
    if not distributed.enabled:
        return chunked
    return DataParallelBackward(chunked, distributed, cfg.data.ssl_batch_pairs)
