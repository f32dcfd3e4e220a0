"""Compose navformer_rl with plain TorchRL: replay buffers, the cross-task buffer, modules, losses, a
Collector.

Every piece is a TorchRL object, so each can be swapped for your own:

1. **Buffers** of tiny synthetic D_e / D_ca / D_ssl folders (the on-disk format ``navformer collect`` writes):
   D_e through ``dataset.trajectory_buffer(N)`` (a ``TensorDictReplayBuffer`` with our ``TrajectorySampler``:
   whole trajectories, flat ``[N * T]`` samples); D_ca in a plain ``TensorDictReplayBuffer`` on a
   ``LazyTensorStorage`` with TorchRL's ``SliceSampler(traj_key="episode", pad_output=True)``; D_ssl through
   ``dataset.pair_buffer(B)``.
2. **The cross-task buffer** of paper §VI, ``CrossTaskReplayBuffer`` (a ``ReplayBufferEnsemble``): D_e and
   D_ca in turn, each sample a trajectory batch ``[N]`` with ``[N, T]`` steps, its task in ``("index",
   "buffer_ids")``.
3. **NavFormer from its TensorDict modules** with a swapped head: ``dve_module``, ``transformer_module`` and
   ``head_module`` around an ``ActionHead`` of your own (h_g gating h_o) in a ``TensorDictSequential``.
4. **Both losses and their optimisers**: ``ActionMSELoss`` (L_DT, eq. 10) and ``BYOLLoss`` (eqs. 6-8) with
   TorchRL's ``SoftUpdate`` for BYOL's EMA target, summed as eq. 11; AdamW for the causal transformer and the
   head, Adam for the visual encoders and BYOL's projectors / predictors (§VI's two optimisers, as
   ``navformer train``'s ``optim.encoder_optimizer=adam`` default groups them, docs/training.md). A few steps.
5. **The trained policy in a Collector**: ``NavFormerPolicy`` (KV-cached, decoding with your head) driving a
   ``MultiRobotNavEnv`` through TorchRL's ``Collector``; ``add_policy_transforms`` appends the ``InitTracker``
   the collector looks for, so it runs without warnings.

    .venv/bin/python examples/compose_with_torchrl.py --steps 4
"""

from __future__ import annotations

import argparse
import logging
import tempfile
from pathlib import Path

import torch
from tensordict.nn import TensorDictSequential
from torch import Tensor, nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, SliceSampler, TensorDictReplayBuffer
from torchrl.objectives import SoftUpdate

from navformer_rl.data import CrossTaskReplayBuffer, make_synthetic_dataset, open_dataset
from navformer_rl.envs.multi_robot import MultiRobotNavEnv
from navformer_rl.envs.policy_transforms import add_policy_transforms
from navformer_rl.modules import (
    ActionHead,
    NavFormerConfig,
    NavFormerModel,
    NavFormerPolicy,
    dve_module,
    head_module,
    transformer_module,
)
from navformer_rl.objectives import ActionMSELoss, BYOLLoss, BYOLTauSchedule


class GatedHead(ActionHead):
    """``a-hat = tanh(W (h_o * sigmoid(V h_g)) + b)``: the target's hidden state gates the observation's,
    where THSC concatenates them."""

    reads = ("target", "observation")

    def __init__(self, d_embed: int, action_dim: int) -> None:
        super().__init__(d_embed, action_dim)
        self.gate = nn.Linear(d_embed, d_embed)

    def forward(
        self, target_hidden: Tensor, observation_hidden: Tensor, mask: Tensor | None = None
    ) -> Tensor:
        return self.predict(observation_hidden * torch.sigmoid(self.gate(target_hidden)), mask)


def make_buffers(root: Path) -> tuple[CrossTaskReplayBuffer, TensorDictReplayBuffer]:
    """The cross-task buffer over D_e and D_ca, and the D_ssl pair buffer
    (tiny synthetic folders in ``root``)."""
    e = open_dataset(make_synthetic_dataset(root / "e", "e", 8, min_len=6, max_len=16, seed=1))
    ca = open_dataset(make_synthetic_dataset(root / "ca", "ca", 12, min_len=4, max_len=12, seed=2))
    ssl = open_dataset(make_synthetic_dataset(root / "ssl", "ssl", 32, seed=3))

    exploration = e.trajectory_buffer(2, context_steps=16, seed=0)  # 2 whole trajectories per sample
    # D_ca as you would hold your own data: rows (with their target image) in a LazyTensorStorage, windows
    # of up to 8 steps from 3 trajectories, right-padded, the mask in ("collector", "mask")
    rows = ca.rows[:].clone()
    rows.set("target_pixels", ca.targets[rows["target_id"]])
    collision_avoidance = TensorDictReplayBuffer(
        storage=LazyTensorStorage(len(rows)),
        sampler=SliceSampler(num_slices=3, traj_key="episode", strict_length=False, pad_output=True),
        batch_size=3 * 8,
        generator=torch.Generator().manual_seed(0),
    )
    collision_avoidance.extend(rows)
    return CrossTaskReplayBuffer(exploration, collision_avoidance), ssl.pair_buffer(8, seed=4)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=4, help="training steps (default 4)")
    parser.add_argument("--frames", type=int, default=20, help="env steps to collect (default 20)")
    args = parser.parse_args()
    logging.getLogger("torchrl").setLevel(logging.WARNING)
    torch.manual_seed(0)

    # 3. the model from its TensorDict modules, with your head in place of THSC
    config = NavFormerConfig()
    model = NavFormerModel(config)
    model.head = GatedHead(config.d_embed, config.action_dim)
    actor = TensorDictSequential(
        dve_module(model.dve), transformer_module(model.transformer), head_module(model.head)
    )

    # 4. the losses and their optimisers
    dt_loss = ActionMSELoss(actor)
    byol_loss = BYOLLoss(model.dve, seed=0)  # the model's own encoders
    updater = SoftUpdate(byol_loss, eps=0.996)
    tau = BYOLTauSchedule(updater, total_steps=args.steps)
    encoder_ids = {id(p) for p in model.dve.parameters()}
    model_ids = {id(p) for p in model.parameters()}
    adamw = torch.optim.AdamW(
        [p for p in model.parameters() if id(p) not in encoder_ids], lr=2e-4, weight_decay=1e-4
    )
    adam = torch.optim.Adam(
        [*model.dve.parameters(), *(p for p in byol_loss.parameters() if id(p) not in model_ids)],
        lr=4e-4,
        weight_decay=4e-4,
    )

    with tempfile.TemporaryDirectory(prefix="navformer-compose-") as tmp:
        cross_task, pairs = make_buffers(Path(tmp))  # 1. and 2.
        for step in range(args.steps):
            batch = cross_task.sample()  # [N] trajectories, [N, T] steps
            loss_dt = dt_loss(batch)["loss_dt"]
            loss_byol = byol_loss(pairs.sample())["loss_byol"]
            adamw.zero_grad()
            adam.zero_grad()
            (loss_dt + loss_byol).backward()  # eq. 11
            adamw.step()
            adam.step()
            updater.step()
            tau.step()
            print(
                f"step {step} {cross_task.task_of(batch):>19} {tuple(batch['mask'].shape)}  "
                f"L_DT {loss_dt.item():.4f}  L_BYOL {loss_byol.item():.4f}"
            )

    # 5. the trained policy in TorchRL's Collector
    policy = NavFormerPolicy(model.eval())
    env = add_policy_transforms(MultiRobotNavEnv(size=7.5, n_robots=2, max_steps=12, seed=0), policy)
    collector = Collector(env, policy, frames_per_batch=10, total_frames=args.frames)
    try:
        with torch.no_grad():
            for batch in collector:
                actions = batch["agents", "action"]
                print(
                    f"collected {tuple(batch.shape)}: "
                    f"actions {tuple(actions.shape)} in [{actions.min():.2f}, {actions.max():.2f}]"
                )
    finally:
        collector.shutdown()


if __name__ == "__main__":
    main()
