"""navformer_rl: NavFormer (target-driven navigation in unknown dynamic mazes) as TorchRL components.

Importing the package is cheap: it starts no pybullet client. It registers the gymnasium id
``navformer_rl/TargetNav-v0`` through a string entry point.
"""

from navformer_rl.envs.registration import register_envs

__version__ = "0.1.0"

register_envs()

__all__ = ["__version__"]
