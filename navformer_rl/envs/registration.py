"""Gymnasium registration by string entry point: importing this starts no simulator."""

import gymnasium as gym

from navformer_rl.constants import MAX_EPISODE_STEPS

ENV_ID = "navformer_rl/TargetNav-v0"


def register_envs() -> None:
    """Register ``navformer_rl/TargetNav-v0`` once (idempotent), with ``max_episode_steps=500`` (paper
    §VII.A): ``gym.make(ENV_ID)`` truncates with gymnasium's ``TimeLimit`` at 500 steps and reports
    ``env.spec.max_episode_steps``; ``gym.make(ENV_ID, max_episode_steps=N)`` truncates at ``N`` instead."""
    if ENV_ID not in gym.registry:
        gym.register(
            id=ENV_ID,
            entry_point="navformer_rl.envs.target_nav:TargetNavEnv",
            max_episode_steps=MAX_EPISODE_STEPS,
        )
