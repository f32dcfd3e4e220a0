"""The baselines trained online with PPO (DSAC, MA-TDN): building them by name, their checkpoints' model
config, and the evaluation policy :class:`OnlinePolicy`.

A PPO checkpoint is a house training checkpoint (:mod:`navformer_rl.training.checkpoint`): its
``model.safetensors`` holds the ``ActorCriticNet`` state dict and its ``model_config`` is
``{"method": "dsac" | "matdn", **the method's config fields}``.
"""

from __future__ import annotations

import os
from typing import Any

from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

ONLINE_METHODS: tuple[str, ...] = ("dsac", "matdn")
"""The baselines trained online with PPO (paper §VII.A)."""


def _check_method(method: str) -> None:
    if method not in ONLINE_METHODS:
        raise ValueError(f"unknown online method {method!r}; expected one of {', '.join(ONLINE_METHODS)}")


def model_config_class(method: str) -> type:
    """``DSACConfig`` or ``MATDNConfig``."""
    _check_method(method)
    if method == "dsac":
        from navformer_rl.baselines.dsac import DSACConfig

        return DSACConfig
    from navformer_rl.baselines.matdn import MATDNConfig

    return MATDNConfig


def build_net(method: str, config: Any = None):
    """A fresh ``ActorCriticNet`` of ``method`` with ``config`` (its ``DSACConfig`` / ``MATDNConfig``;
    None: the defaults)."""
    _check_method(method)
    if method == "dsac":
        from navformer_rl.baselines.dsac import make_dsac

        return make_dsac(config)
    from navformer_rl.baselines.matdn import make_matdn

    return make_matdn(config)


def env_primers(method: str, config: Any, n_agents: int) -> list:
    """The ``TensorDictPrimer`` transforms an env needs for ``method``'s recurrent state (MA-TDN's memory;
    none for DSAC)."""
    _check_method(method)
    if method == "matdn":
        from navformer_rl.baselines.matdn import memory_primer

        return [memory_primer(config, n_agents)]
    return []


def checkpoint_model_config(method: str, config: Any) -> dict[str, Any]:
    """The ``model_config`` a PPO checkpoint stores: ``{"method": method, **config fields}``."""
    return {"method": method, **config.to_dict()}


def load_online_net(checkpoint: str | os.PathLike, method: str):
    """``(ActorCriticNet in eval mode on the CPU, model config)`` from a PPO checkpoint (any path
    ``navformer_rl.training.checkpoint.resolve_checkpoint`` accepts: run dir, checkpoint folder, weights
    file).

    Raises:
        FileNotFoundError: nothing at ``checkpoint``.
        ValueError: not a navformer_rl checkpoint, a checkpoint of another method (e.g. NavFormer or DT), or
            weights that do not fit the stored configuration.
    """
    import dataclasses

    from navformer_rl.baselines.actor_critic import load_state_checked
    from navformer_rl.training.checkpoint import load_model_state

    _check_method(method)
    fields, state = load_model_state(checkpoint)
    stored = fields.get("method")
    if stored != method:
        what = f"the {stored} baseline" if stored in ONLINE_METHODS else "a NavFormer / DT model"
        raise ValueError(
            f"checkpoint {checkpoint} holds {what}, not {method}; evaluate it with "
            f"--method {stored if stored in ONLINE_METHODS else 'navformer or dt'}"
        )
    config_cls = model_config_class(method)
    known = {f.name for f in dataclasses.fields(config_cls)}
    values = {k: v for k, v in fields.items() if k != "method"}
    if set(values) - known:
        raise ValueError(
            f"checkpoint {checkpoint} has {method} model fields {sorted(set(values) - known)} that "
            f"{config_cls.__name__} does not know; it was written by another version"
        )
    config = config_cls(**values)
    net = build_net(method, config)
    load_state_checked(net, state, f"checkpoint {checkpoint}")
    net.eval()
    return net, config


def load_online_policy(checkpoint: str | os.PathLike, method: str):
    """``(OnlinePolicy, model config)`` from a PPO checkpoint of ``method`` (:func:`load_online_net`)."""
    net, config = load_online_net(checkpoint, method)
    return OnlinePolicy(net), config


class OnlinePolicy(TensorDictModuleBase):
    """A trained DSAC / MA-TDN actor for evaluation: the mean action ``tanh(loc)`` (no sampling, so an
    episode's actions depend on the episode only).

    Reads the method's inputs from the ``MultiRobotNavEnv`` tensordict (``("agents", "pixels")``,
    ``("agents", "target_pixels")``; MA-TDN also its memory, empty when absent, and
    ``("agents", "step_count")``) and writes ``("agents", "action")`` float32 ``[A, 2]`` (MA-TDN also
    ``("next", "agents", "memory")`` / ``("next", "agents", "memory_mask")``).

    Args:
        net: the trained ``ActorCriticNet``.
    """

    def __init__(self, net) -> None:
        super().__init__()
        self.net = net
        actor = net.actor()
        self.in_keys = list(actor.in_keys)
        self.out_keys = list(actor.out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            return self.net.actor()(tensordict)
