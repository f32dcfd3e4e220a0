"""NavFormer driving robots inside TorchRL's data collection: SerialEnv + Collector + a replay buffer.

Pieces, all standard TorchRL:

- ``SerialEnv`` of ``MultiRobotNavEnv`` (each env: one maze, ``--robots`` robots under the ``"agents"`` group;
  batch ``[E]``, agent entries ``[E, A, ...]``), ``InitTracker`` so that ``"is_init"`` marks each env's
  resets;
- ``NavFormerPolicy``: every robot of every env in one batch, one KV-cached timestep per call; a robot's
  context restarts when its env resets (``("agents", "step_count") == 0`` / ``is_init``);
- ``Collector`` (TorchRL's synchronous collector) pulling ``--frames`` env steps in batches, resetting
  finished episodes itself;
- ``TensorDictReplayBuffer`` on ``LazyTensorStorage`` receiving the collected steps (flattened to
  ``[steps * E]``), e.g. for on-policy fine-tuning or DAgger-style relabelling with the experts.

Run it with the project's environment (an untrained, seeded model by default)::

    .venv/bin/python examples/collect_with_navformer_policy.py
    .venv/bin/python examples/collect_with_navformer_policy.py --checkpoint runs/demo/train/navformer

It prints, per collected batch, the env steps, the robots that reached their target (reward 1) and the
steps in contact, and at the end the replay buffer's size and a sampled batch's keys.
"""

from __future__ import annotations

import argparse
import logging

import torch
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import InitTracker, SerialEnv, TransformedEnv

from navformer_rl.envs.multi_robot import MultiRobotNavEnv
from navformer_rl.modules import NavFormerConfig, NavFormerModel, NavFormerPolicy
from navformer_rl.training.checkpoint import load_policy_model


def make_env(env_seed: int, size: float, robots: int, max_steps: int):
    """A factory per env, as ``SerialEnv`` / ``ParallelEnv`` take them (each env its own seeded maze)."""

    def factory() -> MultiRobotNavEnv:
        return MultiRobotNavEnv(size=size, n_robots=robots, max_steps=max_steps, seed=env_seed)

    return factory


def make_policy(checkpoint: str | None) -> NavFormerPolicy:
    """The trained model of ``checkpoint`` (any path ``load_policy_model`` takes),
    or an untrained seeded one."""
    if checkpoint is not None:
        _, model = load_policy_model(checkpoint)
    else:
        torch.manual_seed(0)
        model = NavFormerModel(NavFormerConfig()).eval()
    return NavFormerPolicy(model)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", help="a NavFormer run dir or checkpoint (default: untrained model)")
    parser.add_argument("--envs", type=int, default=2, help="mazes stepped together (default 2)")
    parser.add_argument("--robots", type=int, default=2, help="robots per maze (default 2)")
    parser.add_argument("--size", type=float, default=7.5, help="maze side in metres (default 7.5)")
    parser.add_argument("--max-steps", type=int, default=40, help="steps per episode (paper: 500)")
    parser.add_argument(
        "--frames", type=int, default=120, help="env steps to collect, all envs (default 120)"
    )
    parser.add_argument("--frames-per-batch", type=int, default=40, help="env steps per batch (default 40)")
    args = parser.parse_args(argv)
    logging.getLogger("torchrl").setLevel(logging.WARNING)  # no INFO lines ("Initialized LazyTensorStorage")

    env = TransformedEnv(
        SerialEnv(
            args.envs, [make_env(seed, args.size, args.robots, args.max_steps) for seed in range(args.envs)]
        ),
        InitTracker(),
    )
    policy = make_policy(args.checkpoint)
    collector = Collector(env, policy, frames_per_batch=args.frames_per_batch, total_frames=args.frames)
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(args.frames), batch_size=16)
    try:
        with torch.no_grad():
            for batch in collector:  # [E, T] per batch; agent entries [E, T, A, ...]
                reached = batch["next", "agents", "reward"].sum().item()
                contacts = batch["next", "agents", "collision"].sum().item()
                print(
                    f"batch {tuple(batch.shape)}: robots reached their target {reached:.0f}, "
                    f"contact steps {contacts}"
                )
                buffer.extend(batch.reshape(-1))
    finally:
        collector.shutdown()  # closes the env too
    sample = buffer.sample()
    print(
        f"replay buffer: {len(buffer)} env steps; a sample of {sample.shape[0]} holds",
        sorted(map(str, sample["agents"].keys())),
    )


if __name__ == "__main__":
    main()
