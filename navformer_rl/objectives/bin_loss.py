"""``ActionBinLoss``: the opt-in L_DT of a ``BinnedActionHead`` (cross-entropy over action bins)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictParams, dispatch
from tensordict.utils import NestedKey
from torchrl.objectives import LossModule


class ActionBinLoss(LossModule):
    """Cross-entropy of the expert action under a ``BinnedActionHead``'s bins, over the valid steps.

    Each action dimension's target is "two-hot": the expert value x in [-1, 1] splits its mass between the two
    nearest bin centres ``linspace(-1, 1, K)`` in proportion to closeness (x = -1, 1 or a centre: one bin), so
    the target keeps x's value below the bin width. ``loss_dt = sum_{n,t valid} sum_a CE(target_a, logits_a)
    / #valid`` (the sum over action dims as eq. 10's squared norm). Opt-in (``model.action_bins``); the paper's
    L_DT is :class:`~navformer_rl.objectives.ActionMSELoss`.

    Keys (``set_keys``): ``action_target`` (default ``"action"``, float ``[N, T, A]``), ``action_logits``
    (default ``"action_logits"``, written by the actor, float ``[N, T, A, K]``), ``mask`` (default ``"mask"``,
    bool ``[N, T]``; missing: every step valid, refused when only ``("collector", "mask")`` is present).
    Output (``out_keys``): ``loss_dt``. The input tensordict is left unchanged.

    Args:
        actor_network: a ``TensorDictModule`` writing ``action_logits`` (``make_navformer_actor(model)`` of a
            model with ``action_bins``).
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            action_target: expert actions a_t. Defaults to ``"action"``.
            action_logits: the head's bin logits. Defaults to ``"action_logits"``.
            mask: valid steps (bool). Defaults to ``"mask"``.
        """

        action_target: NestedKey = "action"
        action_logits: NestedKey = "action_logits"
        mask: NestedKey = "mask"

    tensor_keys: _AcceptedKeys
    default_keys = _AcceptedKeys
    actor_network: TensorDictModule
    actor_network_params: TensorDictParams
    target_actor_network_params: TensorDictParams

    def __init__(self, actor_network: TensorDictModule) -> None:
        super().__init__()
        self.convert_to_functional(actor_network, "actor_network", create_target_params=False)
        self._out_keys = ["loss_dt"]

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    @property
    def in_keys(self) -> list[NestedKey]:
        keys = set(self.actor_network.in_keys) | {self.tensor_keys.action_target, self.tensor_keys.mask}
        return sorted(keys, key=str)

    @property
    def out_keys(self) -> list[str]:
        return self._out_keys

    @out_keys.setter
    def out_keys(self, values: list[str]) -> None:
        self._out_keys = list(values)

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Run the actor on (a shallow copy of) ``tensordict`` and return ``loss_dt``."""
        tensordict = tensordict.copy()
        keys = self.tensor_keys
        present = set(tensordict.keys(include_nested=True))
        if keys.action_target not in present:
            raise KeyError(f"ActionBinLoss: the batch has no {keys.action_target!r} (action_target key)")
        if keys.mask not in present and ("collector", "mask") in present:
            raise KeyError(
                f"ActionBinLoss: the batch has ('collector', 'mask') but no {keys.mask!r}; padded steps would "
                "count as valid. Use loss.set_keys(mask=('collector', 'mask')) or copy the mask to that key"
            )
        target = tensordict.get(keys.action_target).detach()
        with self.actor_network_params.to_module(self.actor_network):
            logits = self.actor_network(tensordict).get(keys.action_logits, None)
        if logits is None:
            raise KeyError(
                f"ActionBinLoss: the actor did not write {keys.action_logits!r} (action_logits key; a model "
                f"with model.action_bins >= 2 writes it); its out_keys are {self.actor_network.out_keys}"
            )
        if logits.shape[:-1] != target.shape:
            raise ValueError(
                f"{keys.action_logits}: shape {tuple(logits.shape)} does not match "
                f"{keys.action_target}: {tuple(target.shape)} plus a bins axis"
            )
        loss = masked_bin_cross_entropy(logits, target, tensordict.get(keys.mask, None))
        return TensorDict({"loss_dt": loss}, batch_size=[])


def two_hot(target: torch.Tensor, bins: int) -> torch.Tensor:
    """Actions ``[...]`` in [-1, 1] (clamped) -> probabilities ``[..., bins]`` on the two nearest of the centres
    ``linspace(-1, 1, bins)``, weighted so their mean is the action."""
    position = (target.float().clamp(-1.0, 1.0) + 1.0) * (bins - 1) / 2.0
    lower = position.floor().clamp(max=bins - 2)
    upper_weight = position - lower
    probabilities = torch.zeros(*target.shape, bins, device=target.device)
    probabilities.scatter_(-1, lower.long().unsqueeze(-1), (1.0 - upper_weight).unsqueeze(-1))
    probabilities.scatter_add_(-1, lower.long().unsqueeze(-1) + 1, upper_weight.unsqueeze(-1))
    return probabilities


def masked_bin_cross_entropy(
    logits: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None
) -> torch.Tensor:
    """``[N, T, A, K] x [N, T, A] x bool [N, T] -> scalar`` (see ``ActionBinLoss``)."""
    cross_entropy = -(two_hot(target, logits.shape[-1]) * logits.float().log_softmax(-1)).sum(-1).sum(-1)
    if mask is None:
        return cross_entropy.mean()
    return torch.where(mask, cross_entropy, 0.0).sum() / mask.sum().clamp_min(1)
