"""The Gaussian actor-critic that DSAC and MA-TDN share: a method's trunk, a policy head and a value head.

Keys (the ``MultiRobotNavEnv`` group ``"agents"``, robot dimension ``A`` or a flat batch of robot-steps):

- the trunk reads the method's inputs (``("agents", "pixels")``, ``("agents", "target_pixels")``, ...) and
  writes ``("agents", "features")`` float ``[*, F]``;
- the actor (:meth:`ActorCriticNet.actor`, a ``ProbabilisticActor``) writes ``("agents", "loc")``,
  ``("agents", "scale")`` ``[*, 2]``, ``("agents", "action")`` float32 ``[*, 2]`` in ``[-1, 1]`` (a
  ``TanhNormal``: a Gaussian squashed by tanh onto the env's action bounds, not clipped) and
  ``("agents", "action_log_prob")`` ``[*]``;
- the critic (:meth:`ActorCriticNet.critic`, the trunk then a ``ValueOperator``) writes only
  ``("agents", "state_value")`` ``[*, 1]``.

Actor and critic share the trunk (one network with two heads, as in A3C / PPO on images), so
``ClipPPOLoss`` trains the trunk with both losses. The loss's critic (``critic(reuse_features=True)``)
reads the features the actor has just written into the same minibatch instead of running the trunk again:
one trunk forward and backward per minibatch, the same gradients (2x faster updates on CPU).
"""

from __future__ import annotations

import math

import torch
from tensordict.nn import (
    AddStateIndependentNormalScale,
    TensorDictModule,
    TensorDictModuleBase,
    TensorDictSequential,
)
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator

AGENTS = "agents"
PIXELS_KEY = (AGENTS, "pixels")
TARGET_PIXELS_KEY = (AGENTS, "target_pixels")
STEP_COUNT_KEY = (AGENTS, "step_count")
FEATURES_KEY = (AGENTS, "features")
LOC_KEY = (AGENTS, "loc")
SCALE_KEY = (AGENTS, "scale")
ACTION_KEY = (AGENTS, "action")
LOG_PROB_KEY = (AGENTS, "action_log_prob")
VALUE_KEY = (AGENTS, "state_value")
ACTION_DIM = 2


class ActorCriticNet(nn.Module):
    """A trunk with a Gaussian policy head and a value head; one ``state_dict`` for the whole network.

    Args:
        trunk: ``TensorDictModuleBase`` writing ``("agents", "features")`` float ``[*, features]``.
        features: the trunk's output width F.
        init_std: initial standard deviation of the (state-independent) pre-tanh Gaussian.
    """

    def __init__(self, trunk: TensorDictModuleBase, features: int, init_std: float = 1.0) -> None:
        super().__init__()
        self.trunk = trunk
        loc = nn.Linear(features, ACTION_DIM)
        nn.init.orthogonal_(loc.weight, gain=0.01)  # near-zero initial means: every action is tried
        nn.init.zeros_(loc.bias)
        self.policy_head = nn.Sequential(
            loc, AddStateIndependentNormalScale(ACTION_DIM, init_value=math.log(init_std))
        )
        self.value_head = nn.Linear(features, 1)
        self._views: dict[str, TensorDictModuleBase] = {}  # not registered: no duplicate state_dict keys

    def actor(self) -> ProbabilisticActor:
        """The policy: trunk -> ``(loc, scale)`` -> ``TanhNormal`` on [-1, 1]^2 -> action and its log-prob.

        Sampling follows TorchRL's exploration type (random in collectors; the mean action ``tanh(loc)``
        under ``set_exploration_type(DETERMINISTIC)``).
        """
        if "actor" not in self._views:
            head = TensorDictModule(
                Float32Head(self.policy_head), in_keys=[FEATURES_KEY], out_keys=[LOC_KEY, SCALE_KEY]
            )
            self._views["actor"] = ProbabilisticActor(
                TensorDictSequential(self.trunk, head),
                in_keys={"loc": LOC_KEY, "scale": SCALE_KEY},
                out_keys=[ACTION_KEY],
                spec=Bounded(-1.0, 1.0, (ACTION_DIM,)),  # one robot's action
                distribution_class=TanhNormal,
                distribution_kwargs={"low": -1.0, "high": 1.0},
                return_log_prob=True,
                log_prob_key=LOG_PROB_KEY,
            )
        return self._views["actor"]  # type: ignore[return-value]

    def critic(self, reuse_features: bool = False) -> TensorDictSequential:
        """The value function: trunk -> ``ValueOperator`` -> ``("agents", "state_value")`` (its only output).

        ``reuse_features``: skip the trunk when the input already holds ``("agents", "features")``, for inputs
        whose features the actor has just computed with the current parameters (inside ``ClipPPOLoss``).
        """
        name = "critic_reusing_features" if reuse_features else "critic"
        if name not in self._views:
            trunk = FeaturesOnce(self.trunk) if reuse_features else self.trunk
            value = ValueOperator(Float32Head(self.value_head), in_keys=[FEATURES_KEY], out_keys=[VALUE_KEY])
            self._views[name] = TensorDictSequential(trunk, value, selected_out_keys=[VALUE_KEY])
        return self._views[name]  # type: ignore[return-value]

    def forward(self, *args, **kwargs):  # pragma: no cover - use actor() / critic()
        raise RuntimeError("ActorCriticNet is a container: call net.actor() or net.critic()")


class Float32Head(nn.Module):
    """``head`` on float32 features with autocast off: under an autocast update (``optim.autocast_dtype``)
    only the trunk runs in low precision; the action distribution, its log-probs and the values stay
    float32."""

    def __init__(self, head: nn.Module) -> None:
        super().__init__()
        self.head = head

    def forward(self, features: torch.Tensor):
        with torch.autocast(features.device.type, enabled=False):
            return self.head(features.float())


class FeaturesOnce(TensorDictModuleBase):
    """``trunk``, skipped when its input already holds ``("agents", "features")``."""

    def __init__(self, trunk: TensorDictModuleBase) -> None:
        super().__init__()
        self.trunk = trunk
        self.in_keys = trunk.in_keys
        self.out_keys = trunk.out_keys

    def forward(self, tensordict):
        if FEATURES_KEY in tensordict.keys(include_nested=True):
            return tensordict
        return self.trunk(tensordict)


def load_state_checked(net: nn.Module, state: dict[str, torch.Tensor], source: str) -> None:
    """``net.load_state_dict(state)`` after checking names and shapes; ValueError naming the first
    mismatches (weights of another method or model configuration)."""
    from navformer_rl.training.checkpoint import state_dict_mismatch

    mismatch = state_dict_mismatch(net.state_dict(), state)
    if mismatch:
        raise ValueError(f"{source} does not match the network: {mismatch}")
    net.load_state_dict(state)
