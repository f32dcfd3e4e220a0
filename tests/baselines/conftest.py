"""Tiny worlds, small DSAC / MA-TDN networks and PPO checkpoints for the baseline tests."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torchrl.envs import Compose, RewardSum, TransformedEnv

from navformer_rl.baselines.dsac import DSACConfig
from navformer_rl.baselines.matdn import MATDNConfig
from navformer_rl.baselines.online import build_net, checkpoint_model_config, env_primers
from navformer_rl.envs.multi_robot import MultiRobotNavEnv
from navformer_rl.envs.world import TargetSpec, world_from_layout
from navformer_rl.online.envs import EPISODE_RETURN_KEY
from navformer_rl.online.reward import REWARD_KEY, RewardWeights, ShapedNavReward
from navformer_rl.training.checkpoint import save_checkpoint

SMALL = {
    "dsac": DSACConfig(d_embed=32, hidden=32),
    "matdn": MATDNConfig(d_embed=32, memory_size=4, n_heads=2, hidden=32),
}
"""Networks small enough for a PPO update in a fraction of a second."""
OUTER_WALLS = np.array(
    [(2.5, 0.0, 2.55, 0.05), (2.5, 5.0, 2.55, 0.05), (0.0, 2.5, 0.05, 2.55), (5.0, 2.5, 0.05, 2.55)],
    dtype=np.float32,
)


def open_world(starts, targets):
    """A 5 m world with only its outer walls; ``targets``: ``(x, y, shape, colour)``; ``starts``:
    ``[R, 3]``."""
    specs = [TargetSpec(np.array([x, y], dtype=np.float32), s, c) for x, y, s, c in targets]
    return world_from_layout(5.0, OUTER_WALLS, specs, np.asarray(starts, dtype=np.float32))


CORRIDOR = open_world([(0.8, 2.5, 0.0)], [(4.2, 2.5, "sphere", "red")])
"""One robot facing its target 3.4 m ahead (1.9 m to the success disc): driving straight on succeeds."""


class FixedEpisodeEnv(MultiRobotNavEnv):
    """A ``MultiRobotNavEnv`` whose every reset replays ``world`` (its starts and targets)."""

    def __init__(self, world, **kwargs) -> None:
        super().__init__(world_config=world.config, n_robots=world.n_robots, **kwargs)
        self.fixed_world = world

    def _draw_world(self):
        return self.fixed_world


def shaped_env(world, method: str | None = None, max_steps: int = 16, weights: RewardWeights | None = None):
    """``FixedEpisodeEnv(world)`` with the PPO env's transforms (shaped reward, return,
    ``method``'s primers)."""
    base = FixedEpisodeEnv(world, max_steps=max_steps, seed=0)
    primers = env_primers(method, SMALL[method], world.n_robots) if method else []
    return TransformedEnv(
        base,
        Compose(
            ShapedNavReward(weights),
            RewardSum(in_keys=[REWARD_KEY], out_keys=[EPISODE_RETURN_KEY], reset_keys=["_reset"]),
            *primers,
        ),
    )


@pytest.fixture
def make_shaped_env():
    return shaped_env


@pytest.fixture
def small_net():
    """``small_net(method, seed=0)``: a seeded small ``ActorCriticNet``."""

    def make(method: str, seed: int = 0):
        torch.manual_seed(seed)
        return build_net(method, SMALL[method])

    return make


def save_ppo_checkpoint(run_dir, method: str, seed: int = 0):
    """A seeded, untrained PPO checkpoint of ``method`` (small network) in ``run_dir``."""
    torch.manual_seed(seed)
    net = build_net(method, SMALL[method])
    save_checkpoint(
        run_dir,
        1,
        model_state=net.state_dict(),
        model_config=checkpoint_model_config(method, SMALL[method]),
        train_config={"method": method},
        resume_state=None,
    )
    return run_dir, net


@pytest.fixture(scope="session")
def ppo_checkpoints(tmp_path_factory):
    """Untrained PPO checkpoints: ``{"dsac": (run_dir, net), "matdn": (run_dir, net)}``."""
    root = tmp_path_factory.mktemp("ppo_ckpt")
    return {method: save_ppo_checkpoint(root / method, method) for method in SMALL}
