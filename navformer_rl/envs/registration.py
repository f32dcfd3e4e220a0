"""Gymnasium registration by string entry point: importing this starts no simulator."""

import gymnasium as gym

ENV_ID = "navformer_rl/TargetNav-v0"


def register_envs() -> None:
    """Register ``navformer_rl/TargetNav-v0`` once (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="navformer_rl.envs.target_nav:TargetNavEnv")
