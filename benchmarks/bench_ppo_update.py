"""One PPO minibatch update of DSAC and MA-TDN: the trunk run once per minibatch against running it twice,
and the opt-in bfloat16 autocast of the trunk (``optim.autocast_dtype``).

``make_loss`` gives ``ClipPPOLoss`` a critic that reads the features the actor has just written
(``ActorCriticNet.critic(reuse_features=True)``); the reference is the same loss with the plain critic, which
runs the shared trunk (the Siamese CNN on two images, MA-TDN's attention) a second time. One update =
``ClipPPOLoss`` forward on ``--batch`` robot-steps (random 84x84 images, the default network sizes), the three
loss terms' backward, gradient clipping and an Adam step, as in ``ppo_update``. The three variants alternate
over ``--rounds`` rounds (after one warm-up each); the script prints the median milliseconds and the ratios
to the reference.

Usage: ``OMP_NUM_THREADS=1 python benchmarks/bench_ppo_update.py [--rounds 7] [--batch 256]``
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from tensordict import TensorDict

from navformer_rl.baselines.dsac import make_dsac
from navformer_rl.baselines.matdn import MATDNConfig, make_matdn
from navformer_rl.online.config import LossConfig, OptimConfig
from navformer_rl.online.ppo import make_loss, make_optimizer, ppo_update


def robot_steps(batch: int, method: str) -> TensorDict:
    """``batch`` random robot-steps with the keys ``ppo_update`` reads."""
    agents = {
        "pixels": torch.randint(0, 256, (batch, 84, 84, 3), dtype=torch.uint8),
        "target_pixels": torch.randint(0, 256, (batch, 84, 84, 3), dtype=torch.uint8),
        "action": torch.rand(batch, 2) * 1.8 - 0.9,
        "action_log_prob": torch.randn(batch),
        "advantage": torch.randn(batch, 1),
        "value_target": torch.randn(batch, 1),
        "state_value": torch.randn(batch, 1),
    }
    if method == "matdn":
        config = MATDNConfig()
        agents["memory"] = torch.randn(batch, config.memory_size, config.d_embed)
        agents["memory_mask"] = torch.rand(batch, config.memory_size) > 0.3
        agents["step_count"] = torch.randint(1, 100, (batch, 1))
    return TensorDict({"agents": TensorDict(agents, [batch])}, [batch])


def updater(method: str, reuse: bool, autocast_dtype: str | None = None):
    """A function running one minibatch update of a fresh network; ``reuse=False``:
    the critic reruns the trunk."""
    torch.manual_seed(0)
    net = make_dsac() if method == "dsac" else make_matdn()
    if not reuse:
        plain_critic = net.critic
        net.critic = lambda reuse_features=False: plain_critic()  # make_loss gets the trunk-running critic
    loss = make_loss(net, LossConfig())
    optimizer = make_optimizer(loss, OptimConfig())
    cfg = OptimConfig(epochs=1, autocast_dtype=autocast_dtype)
    return lambda steps: ppo_update(loss, optimizer, steps, cfg)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--batch", type=int, default=256)
    args = parser.parse_args()
    print(f"torch threads: {torch.get_num_threads()}, batch {args.batch}, {args.rounds} rounds\n")
    print(
        "| network | trunk once (make_loss) | trunk twice (reference) | ratio | once, "
        "bfloat16 autocast | ratio |"
    )
    print("|---|---|---|---|---|---|")
    for method in ("dsac", "matdn"):
        steps = robot_steps(args.batch, method)
        variants = {
            "once": updater(method, True),
            "twice": updater(method, False),
            "bf16": updater(method, True, "bfloat16"),
        }
        times: dict[str, list[float]] = {name: [] for name in variants}
        for update in variants.values():
            update(steps)  # warm-up
        for _ in range(args.rounds):
            for name, update in variants.items():
                start = time.perf_counter()
                update(steps)
                times[name].append(1e3 * (time.perf_counter() - start))
        once, twice, bf16 = (statistics.median(times[name]) for name in ("once", "twice", "bf16"))
        print(
            f"| {method} | {once:.0f} ms | {twice:.0f} ms | {once / twice:.2f}x | "
            f"{bf16:.0f} ms | {bf16 / twice:.2f}x |"
        )


if __name__ == "__main__":
    main()
