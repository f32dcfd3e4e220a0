"""Action heads on the causal transformer's hidden states: ``THSCHead`` (paper §IV.C) and ``ObservationHead``."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from navformer_rl.modules.models.config import NavFormerConfig, autocast


class ActionHead(nn.Module):
    """``a-hat = tanh(W x + b)`` on hidden states, in [-1, 1]; 0 on padded steps.

    ``reads`` names the ``CausalTransformer`` outputs the head takes, in ``forward``'s order (the
    TensorDict wrapper reads ``("hidden", name)`` for each, then ``mask``). ``weight [A, in_features]`` and
    ``bias [A]`` are initialised as ``nn.Linear``'s.
    """

    reads: tuple[str, ...] = ()

    def __init__(
        self, in_features: int, action_dim: int, *, autocast_dtype: torch.dtype | None = None
    ) -> None:
        super().__init__()
        self.in_features = in_features
        self.weight = nn.Parameter(torch.empty(action_dim, in_features))
        self.bias = nn.Parameter(torch.empty(action_dim))
        self.autocast_dtype = autocast_dtype
        nn.init.kaiming_uniform_(self.weight, a=math.sqrt(5))
        bound = 1 / math.sqrt(in_features)
        nn.init.uniform_(self.bias, -bound, bound)

    def extra_repr(self) -> str:
        return f"in_features={self.in_features}, action_dim={self.weight.shape[0]}"

    def predict(self, features: Tensor, mask: Tensor | None) -> Tensor:
        """features ``[B, T, in_features]``, mask bool ``[B, T]`` or None -> float32 actions ``[B, T, A]``."""
        with autocast(features.device, self.autocast_dtype):
            action = torch.tanh(F.linear(features, self.weight, self.bias)).float()
        if mask is not None:
            action = action.masked_fill(~mask.unsqueeze(-1), 0.0)
        return action


class THSCHead(ActionHead):
    """Target hidden-state concatenation: ``a-hat_t = tanh(W [h_g ; h^ca_{o,t}] + b)`` (paper §IV.C).

    ``forward(target_hidden [B, T, d], observation_hidden [B, T, d], mask=None) -> [B, T, A]``.
    """

    reads = ("target", "observation")

    def __init__(self, d_embed: int, action_dim: int, *, autocast_dtype: torch.dtype | None = None) -> None:
        super().__init__(2 * d_embed, action_dim, autocast_dtype=autocast_dtype)

    def forward(
        self, target_hidden: Tensor, observation_hidden: Tensor, mask: Tensor | None = None
    ) -> Tensor:
        if target_hidden.shape != observation_hidden.shape:
            raise ValueError(
                f"THSCHead: target_hidden {list(target_hidden.shape)} and observation_hidden "
                f"{list(observation_hidden.shape)} must have the same shape [B, T, d]"
            )
        return self.predict(torch.cat([target_hidden, observation_hidden], dim=-1), mask)


class ObservationHead(ActionHead):
    """The head of the DT baseline and of NavFormer w/o THSC: ``a-hat_t = tanh(W h_{o,t} + b)``.

    ``forward(observation_hidden [B, T, d], mask=None) -> [B, T, A]``.
    """

    reads = ("observation",)

    def __init__(self, d_embed: int, action_dim: int, *, autocast_dtype: torch.dtype | None = None) -> None:
        super().__init__(d_embed, action_dim, autocast_dtype=autocast_dtype)

    def forward(self, observation_hidden: Tensor, mask: Tensor | None = None) -> Tensor:
        return self.predict(observation_hidden, mask)


def make_head(config: NavFormerConfig) -> ActionHead:
    """``THSCHead`` when ``config.thsc``, else ``ObservationHead``."""
    head = THSCHead if config.thsc else ObservationHead
    return head(config.d_embed, config.action_dim, autocast_dtype=config.torch_autocast_dtype)
