"""Swap NavFormer's THSC head for your own head, train it with the L_DT loss module, then drive a robot with
it.

Your head is an ``ActionHead`` subclass (``reads`` names the causal transformer's outputs it takes: here h_g
and h_o, through a small MLP). Put in ``model.head``, it is composed by ``make_navformer_actor`` like the
paper's head (``TensorDictSequential`` of the DVE, the causal transformer and the head), trained by
``ActionMSELoss`` (eq. 10), and decoded step by step by ``NavFormerPolicy`` (KV cache).
A head reading other keys (e.g. ``("hidden", "tokens")``, every token's hidden state) is any module in a
``TensorDictModule`` placed after ``transformer_module(model.transformer)``; it trains the same way.

    .venv/bin/python examples/swap_the_head.py --iterations 5
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch
from tensordict import TensorDict
from torch import Tensor, nn

from navformer_rl.data import open_dataset
from navformer_rl.data.synthetic import make_synthetic_dataset
from navformer_rl.modules import (
    ActionHead,
    NavFormerConfig,
    NavFormerModel,
    NavFormerPolicy,
    make_navformer_actor,
)
from navformer_rl.objectives import ActionMSELoss


class MLPHead(ActionHead):
    """``a-hat = tanh(W GELU(V [h_g ; h_o] + c) + b)``: a hidden layer before the paper's linear map."""

    reads = ("target", "observation")

    def __init__(self, d_embed: int, action_dim: int, hidden: int = 64) -> None:
        super().__init__(hidden, action_dim)
        self.mlp = nn.Sequential(nn.Linear(2 * d_embed, hidden), nn.GELU())

    def forward(
        self, target_hidden: Tensor, observation_hidden: Tensor, mask: Tensor | None = None
    ) -> Tensor:
        return self.predict(self.mlp(torch.cat([target_hidden, observation_hidden], dim=-1)), mask)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=10)
    args = parser.parse_args()
    torch.manual_seed(0)
    config = NavFormerConfig(dropout=0.0)
    model = NavFormerModel(config)
    model.head = MLPHead(config.d_embed, config.action_dim)  # the DVE and the causal transformer stay
    actor = make_navformer_actor(model)
    print("head:", actor[-1])

    with tempfile.TemporaryDirectory(prefix="navformer-example-") as tmp:
        batches = open_dataset(
            make_synthetic_dataset(Path(tmp) / "e", "e", 8, 6, 20, seed=1)
        ).trajectory_batcher(4, seed=1)
        loss_module = ActionMSELoss(actor)
        optimizer = torch.optim.AdamW(model.parameters(), lr=3e-4)
        for iteration in range(args.iterations):
            loss = loss_module(batches.sample())["loss_dt"]
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            print(f"{iteration:3d} L_DT {loss.item():.4f}")

    keys = {"pixels_key": "pixels", "target_pixels_key": "target_pixels", "action_key": "action"}
    policy = NavFormerPolicy(model.eval(), **keys, step_count_key=None, reward_key=None)
    frames = torch.randint(0, 256, (2, 84, 84, 3), dtype=torch.uint8)
    for t in range(3):  # two robots, one decoded step per call through the KV cache, with your head
        action = policy(TensorDict(pixels=frames, target_pixels=frames.flip(0), batch_size=[2]))["action"]
        print(f"decoded step {t}: {[[round(v, 3) for v in row] for row in action.tolist()]}")


if __name__ == "__main__":
    main()
