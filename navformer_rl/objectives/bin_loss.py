"""``ActionBinLoss``: the opt-in L_DT of a ``BinnedActionHead`` (cross-entropy over action bins)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict.utils import NestedKey

from navformer_rl.objectives.dt_loss import TeacherForcedActionLoss


class ActionBinLoss(TeacherForcedActionLoss):
    """Cross-entropy of the expert action under a ``BinnedActionHead``'s bins, over the valid steps.

    Each action dimension's target is "two-hot": the expert value x in [-1, 1] splits its mass between the two
    nearest bin centres ``linspace(-1, 1, K)`` in proportion to closeness (x = -1, 1 or a centre: one bin), so
    the target keeps x's value below the bin width. ``loss_dt = sum_{n,t valid} sum_a CE(target_a, logits_a)
    / #valid`` (the sum over action dims as eq. 10's squared norm). Opt-in (``model.action_bins``); the
    paper's L_DT is :class:`~navformer_rl.objectives.ActionMSELoss`.

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
    prediction_key = "action_logits"

    def check_prediction(self, prediction: torch.Tensor, target: torch.Tensor) -> None:
        if prediction.shape[:-1] != target.shape:
            raise ValueError(
                f"{self.tensor_keys.action_logits}: shape {tuple(prediction.shape)} does not match "
                f"{self.tensor_keys.action_target}: {tuple(target.shape)} plus a bins axis"
            )

    def action_loss(
        self, prediction: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None
    ) -> torch.Tensor:
        return masked_bin_cross_entropy(prediction, target, mask)


def two_hot(target: torch.Tensor, bins: int) -> torch.Tensor:
    """Actions ``[...]`` in [-1, 1] (clamped) -> probabilities ``[..., bins]`` on the two nearest of the
    centres ``linspace(-1, 1, bins)``, weighted so their mean is the action."""
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
