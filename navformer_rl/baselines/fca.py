"""Frontier + NH-ORCA (FCA), the paper's privileged upper bound (§VII.A), as an evaluation policy."""

from __future__ import annotations

from tensordict.utils import NestedKey

from navformer_rl.baselines.expert_policy import ExpertPolicy


class FCAPolicy(ExpertPolicy):
    """:class:`navformer_rl.experts.policies.FCAController` for ``MultiRobotNavEnv``: true map, other robots'
    true states and target positions, read through ``bind(env, seed)`` (:class:`ExpertPolicy`).

    Args:
        controller_kwargs: forwarded to ``FCAController`` (``config``, ``nh_orca``, ``frontier_bias``,
            ``noise``).
    """

    def __init__(
        self,
        done_key: NestedKey = ("agents", "done"),
        action_key: NestedKey = ("agents", "action"),
        **controller_kwargs,
    ) -> None:
        from navformer_rl.experts.policies import FCAController

        super().__init__(FCAController(**controller_kwargs), done_key, action_key)
