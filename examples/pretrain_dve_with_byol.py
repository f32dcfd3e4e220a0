"""Pretrain the dual visual encoder alone with ``BYOLLoss`` on D_ssl, freeze it, and use it as the feature
extractor of a TorchRL actor of another algorithm (a Gaussian policy as PPO or SAC would train).

The DVE (f_s and f_g, paper §IV.B) is a plain module; ``BYOLLoss(dve)`` trains its encoders (eqs. 6-8) with
TorchRL's ``SoftUpdate`` for the EMA target. Frozen (``requires_grad_(False)``), it is wrapped by
``dve_module`` and composed before an MLP and a ``ProbabilisticActor``. The same DVE object fits
``NavFormerModel.dve`` too.

    .venv/bin/python examples/pretrain_dve_with_byol.py --iterations 5
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import Tensor, nn
from torchrl.modules import MLP, NormalParamExtractor, ProbabilisticActor, TanhNormal
from torchrl.objectives import SoftUpdate

from navformer_rl.data import open_dataset
from navformer_rl.data.synthetic import make_synthetic_dataset
from navformer_rl.modules import DualVisualEncoder, NavFormerConfig, dve_module
from navformer_rl.objectives import BYOLLoss, BYOLTauSchedule


def pretrain(dve: DualVisualEncoder, iterations: int) -> None:
    """``iterations`` BYOL steps on a synthetic D_ssl (swap in a folder from ``navformer collect``)."""
    with tempfile.TemporaryDirectory(prefix="navformer-example-") as tmp:
        pairs = open_dataset(make_synthetic_dataset(Path(tmp) / "ssl", "ssl", 64, seed=1)).pair_batcher(
            32, seed=3
        )
        byol = BYOLLoss(dve, seed=4)  # f_s and f_g of the DVE, each with its projector and predictor
        updater = SoftUpdate(byol, eps=0.996)
        tau = BYOLTauSchedule(updater, iterations)
        optimizer = torch.optim.Adam(byol.parameters(), lr=4e-4, weight_decay=4e-4)
        for iteration in range(iterations):
            loss = byol(pairs.sample())["loss_byol"]
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            updater.step()
            tau.step()
            print(f"{iteration:3d} L_BYOL {loss.item():.4f}")


class Concat(nn.Module):
    def forward(self, *features: Tensor) -> Tensor:
        return torch.cat(features, dim=-1)


def gaussian_actor(dve: DualVisualEncoder, d_embed: int, action_dim: int) -> ProbabilisticActor:
    """pixels, target_pixels -> DVE embeddings -> MLP -> TanhNormal action (the DVE frozen)."""
    names = [("embed", name) for name in (*dve.names, "target")]
    features = TensorDictModule(Concat(), in_keys=names, out_keys=["features"])
    mlp = MLP(in_features=len(names) * d_embed, out_features=2 * action_dim, num_cells=[64])
    head = TensorDictModule(
        nn.Sequential(mlp, NormalParamExtractor()), in_keys=["features"], out_keys=["loc", "scale"]
    )
    body = TensorDictSequential(dve_module(dve, in_keys=["pixels", "target_pixels", "mask"]), features, head)
    return ProbabilisticActor(
        body, in_keys=["loc", "scale"], distribution_class=TanhNormal, return_log_prob=True
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=10)
    args = parser.parse_args()
    torch.manual_seed(0)
    config = NavFormerConfig()
    dve = DualVisualEncoder.from_config(config)
    pretrain(dve, args.iterations)

    dve.requires_grad_(False).eval()  # frozen: another algorithm trains only what follows it
    actor = gaussian_actor(dve, config.d_embed, config.action_dim)
    frames = torch.randint(0, 256, (3, 84, 84, 3), dtype=torch.uint8)  # one step of 3 robots
    out = actor(TensorDict(pixels=frames, target_pixels=frames.flip(0), batch_size=[3]))
    trainable = sum(p.numel() for p in actor.parameters() if p.requires_grad)
    print(f"actor keys: {sorted(map(str, out.keys(True, True)))}")
    print(f"action {tuple(out['action'].shape)}, log-prob {tuple(out['action_log_prob'].shape)}")
    print(f"trainable parameters after the frozen DVE: {trainable}")


if __name__ == "__main__":
    main()
