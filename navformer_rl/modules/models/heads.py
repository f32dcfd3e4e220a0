"""Action heads on the causal transformer's hidden states: ``THSCHead`` (paper §IV.C), ``ObservationHead`` and
the opt-in ``BinnedActionHead``."""

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

    def actions(self, *hidden_and_mask: Tensor | None) -> Tensor:
        """The predicted actions float32 ``[B, T, A]`` (this head's ``forward``)."""
        return self(*hidden_and_mask)

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


class BinnedActionHead(nn.Module):
    """Opt-in head (``NavFormerConfig.action_bins`` = K): each action dimension as K logits over bins centred
    on ``centres = linspace(-1, 1, K)``, read from ``reads`` (``("target", "observation")`` concatenated as
    THSC's ``[h_g ; h_o]``, or ``("observation",)``).

    ``forward(*hidden, mask=None) -> (action [B, T, A], logits [B, T, A, K])``, both float32 and 0 on padded
    steps; ``actions(*hidden, mask=None)`` returns the first only. The action of a dimension is the most
    probable bin refined by the probability-weighted mean of the centres of it and its two neighbours: one
    mode of the predicted distribution, never the mean of two modes. Trained with
    :class:`~navformer_rl.objectives.ActionBinLoss` (cross-entropy on the expert action's two nearest bins).
    """

    def __init__(
        self,
        reads: tuple[str, ...],
        in_features: int,
        action_dim: int,
        bins: int,
        *,
        autocast_dtype: torch.dtype | None = None,
    ) -> None:
        super().__init__()
        if bins < 2:
            raise ValueError(f"BinnedActionHead: bins={bins!r}: expected an int >= 2")
        self.reads = tuple(reads)
        self.action_dim, self.bins = action_dim, bins
        self.linear = nn.Linear(in_features, action_dim * bins)
        self.autocast_dtype = autocast_dtype
        self.register_buffer("centres", torch.linspace(-1.0, 1.0, bins), persistent=False)

    def extra_repr(self) -> str:
        return f"reads={self.reads}, action_dim={self.action_dim}, bins={self.bins}"

    def logits(self, *hidden: Tensor) -> Tensor:
        """hidden ``[B, T, d]`` each (in ``reads`` order) -> float32 logits ``[B, T, A, K]``."""
        if len(hidden) != len(self.reads):
            raise ValueError(
                f"BinnedActionHead: expected {len(self.reads)} hidden states {self.reads}, got {len(hidden)}"
            )
        if any(h.shape != hidden[0].shape for h in hidden):
            raise ValueError(
                f"BinnedActionHead: hidden states {[list(h.shape) for h in hidden]} must "
                "have one shape [B, T, d]"
            )
        features = torch.cat(hidden, dim=-1) if len(hidden) > 1 else hidden[0]
        with autocast(features.device, self.autocast_dtype):
            logits = self.linear(features).float()
        return logits.unflatten(-1, (self.action_dim, self.bins))

    def decode(self, logits: Tensor) -> Tensor:
        """logits ``[..., A, K]`` -> actions ``[..., A]``: the most probable bin,
        refined over its neighbours."""
        probs = logits.softmax(-1)
        mode = probs.argmax(-1, keepdim=True)
        window = mode + torch.arange(-1, 2, device=logits.device)
        inside = (window >= 0) & (window < self.bins)
        window = window.clamp(0, self.bins - 1)
        weight = probs.gather(-1, window) * inside
        return (weight * self.centres[window]).sum(-1) / weight.sum(-1)

    def forward(self, *hidden_and_mask: Tensor | None) -> tuple[Tensor, Tensor]:
        hidden, mask = _split_mask(hidden_and_mask, len(self.reads))
        logits = self.logits(*hidden)
        action = self.decode(logits)
        if mask is not None:
            logits = logits.masked_fill(~mask[..., None, None], 0.0)
            action = action.masked_fill(~mask.unsqueeze(-1), 0.0)
        return action, logits

    def actions(self, *hidden_and_mask: Tensor | None) -> Tensor:
        """The predicted actions float32 ``[B, T, A]`` (``forward``'s first output)."""
        return self(*hidden_and_mask)[0]


def _split_mask(args: tuple[Tensor | None, ...], n_hidden: int) -> tuple[tuple[Tensor, ...], Tensor | None]:
    if len(args) not in (n_hidden, n_hidden + 1):
        raise ValueError(f"expected {n_hidden} hidden states and an optional mask, got {len(args)} arguments")
    mask = args[n_hidden] if len(args) > n_hidden else None
    return tuple(args[:n_hidden]), mask  # type: ignore[return-value]


def make_head(config: NavFormerConfig) -> ActionHead | BinnedActionHead:
    """``THSCHead`` when ``config.thsc``, else ``ObservationHead``; with ``config.action_bins`` the
    ``BinnedActionHead`` reading the same hidden states."""
    if config.action_bins:
        reads = THSCHead.reads if config.thsc else ObservationHead.reads
        in_features = config.d_embed * len(reads)
        return BinnedActionHead(
            reads,
            in_features,
            config.action_dim,
            config.action_bins,
            autocast_dtype=config.torch_autocast_dtype,
        )
    head = THSCHead if config.thsc else ObservationHead
    return head(config.d_embed, config.action_dim, autocast_dtype=config.torch_autocast_dtype)
