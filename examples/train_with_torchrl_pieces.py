"""Train NavFormer with our TorchRL pieces in your own loop (no recipe, no CLI).

Builds tiny synthetic datasets in the real on-disk format (swap in folders from ``navformer collect``), then
wires the pieces by hand: trajectory batchers alternating D_e / D_ca (``CrossTaskReplayBuffer``), the model's
DVE, causal transformer and head as TensorDict modules (``make_navformer_actor``), the DT loss (eq. 10,
``ActionMSELoss``), BYOL on D_ssl (eqs. 6-8, ``BYOLLoss`` + TorchRL ``SoftUpdate``), summed as in eq. 11. Then
scores the model on held-out trajectories (eq. 10 in eval mode on fixed windows: ``FixedTrajectoryBatches`` +
``teacher_forced_loss``).

Run: ``.venv/bin/python examples/train_with_torchrl_pieces.py --iterations 20``
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch
from torchrl.objectives import SoftUpdate

from navformer_rl.data import CrossTaskReplayBuffer, open_dataset
from navformer_rl.data.synthetic import make_synthetic_dataset
from navformer_rl.modules import NavFormerConfig, NavFormerModel, make_navformer_actor
from navformer_rl.objectives import ActionMSELoss, BYOLLoss, BYOLTauSchedule
from navformer_rl.training.validation import FixedTrajectoryBatches, evaluation_mode, teacher_forced_loss


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument(
        "--data",
        type=Path,
        default=None,
        help="folder with e/, ca/, ssl/ and optionally held_out_e/ (default: synthetic)",
    )
    args = parser.parse_args()
    if args.data is not None:
        train(args.data, args.iterations)
        return
    with tempfile.TemporaryDirectory(prefix="navformer-example-") as tmp:  # removed afterwards
        for kind, n in (("e", 12), ("ca", 24), ("ssl", 64)):
            make_synthetic_dataset(Path(tmp) / kind, kind, n, min_len=8, max_len=40, seed=1)
        make_synthetic_dataset(Path(tmp) / "held_out_e", "e", 6, min_len=8, max_len=40, seed=2)
        train(Path(tmp), args.iterations)


def train(root: Path, iterations: int) -> None:
    """``iterations`` NavFormer iterations on the datasets ``root/{e,ca,ssl}``, printing both losses."""
    torch.manual_seed(0)
    e, ca, ssl = (open_dataset(root / kind) for kind in ("e", "ca", "ssl"))

    # D_e and D_ca alternate each iteration (paper §VI); batches are [N] TensorDicts with [N, T] steps + mask.
    cross_task = CrossTaskReplayBuffer(e.trajectory_batcher(4, seed=1), ca.trajectory_batcher(8, seed=2))
    pairs = ssl.pair_batcher(32, seed=3)

    model = NavFormerModel(NavFormerConfig())
    dt_loss = ActionMSELoss(make_navformer_actor(model))  # reads pixels, target_pixels, return_to_go, ...
    byol_loss = BYOLLoss(model.dve, seed=4)  # the DVE's own encoder modules
    updater = SoftUpdate(byol_loss, eps=0.996)
    tau = BYOLTauSchedule(updater, iterations, 0.996)
    model_ids = {id(p) for p in model.parameters()}
    optim = torch.optim.AdamW(model.parameters(), lr=2e-4, weight_decay=1e-4)
    dve_optim = torch.optim.Adam(
        [p for p in byol_loss.parameters() if id(p) not in model_ids], lr=4e-4, weight_decay=4e-4
    )

    for iteration in range(iterations):
        batch = cross_task.sample()
        task = cross_task.task_of(batch)
        loss_dt = dt_loss(batch)["loss_dt"]
        loss_byol = byol_loss(pairs.sample())["loss_byol"]
        optim.zero_grad()
        dve_optim.zero_grad()
        (loss_dt + loss_byol).backward()  # eq. 11
        optim.step()
        dve_optim.step()
        updater.step()  # EMA target of BYOL
        tau.step()
        print(f"{iteration:3d} {task:>19}  L_DT {loss_dt.item():.4f}  L_BYOL {loss_byol.item():.4f}")

    # eq. 10 on trajectories the model never saw: eval mode (no dropout), one fixed window per trajectory
    if (root / "held_out_e").is_dir():
        held_out = FixedTrajectoryBatches(open_dataset(root / "held_out_e"), 8, context_steps=256, seed=0)
        with evaluation_mode(model):
            print(f"held-out D_e L_DT {teacher_forced_loss(dt_loss, held_out, torch.device('cpu')):.4f}")


if __name__ == "__main__":
    main()
