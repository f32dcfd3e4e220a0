"""The exploration expert of D_e (paper §V) as an evaluation policy: what NavFormer imitates,
run closed-loop."""

from __future__ import annotations

from tensordict.utils import NestedKey

from navformer_rl.baselines.expert_policy import ExpertPolicy


class FrontierPolicy(ExpertPolicy):
    """:class:`navformer_rl.experts.policies.ExplorationExpert` for ``MultiRobotNavEnv``, every robot on its
    own.

    Each robot explores with frontier exploration on its own lidar map (A*, DWA) and drives to its target
    once the camera-visibility test sees it, exactly as when it collected D_e; it does not know where its
    target is before that, and it avoids no other robot (its lidar map holds walls and targets only). It
    stops at 1.2 m from its target, or where it has nothing left to explore. Not a paper baseline: it
    measures the exploration NavFormer is trained to copy, on the evaluation's own episodes.

    Args:
        controller_kwargs: forwarded to ``ExplorationExpert`` (``config``, ``dwa``).
    """

    def __init__(
        self,
        done_key: NestedKey = ("agents", "done"),
        action_key: NestedKey = ("agents", "action"),
        **controller_kwargs,
    ) -> None:
        from navformer_rl.experts.policies import ExplorationExpert

        super().__init__(ExplorationExpert(**controller_kwargs), done_key, action_key)
