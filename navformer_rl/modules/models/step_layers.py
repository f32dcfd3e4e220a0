"""Inference helper: NavFormer's per-step token embeddings and THSC head with precomputed tables."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from navformer_rl.modules.models.derived import DerivedCache
from navformer_rl.modules.models.navformer import MODALITIES, NavFormerModel
from navformer_rl.modules.models.transformer_step import layer_norm_weights


class StepTables(NamedTuple):
    """The model's per-step layers in fused form (``A`` = action_dim, ``d`` = d_embed, ``tps`` tokens a step).

    input_weight ``[A + 1, 2 d]`` / input_bias ``[2 d]``: ``[a ; R] -> [action_embed(a) ; return_embed(R)]``
        (block diagonal: one matmul for both).
    offsets ``[max_timestep + 1, tps, d]``: row ``r = min(t, max_timestep)`` holds what step t's tokens add
        to their inputs (modality and timestep embeddings): a_{t-1} (the target modality on row 0), R_t,
        then the observation tokens.
    head_obs ``[d, A]``, head_target ``[d, A]`` (None without THSC), head_bias ``[A]``: the THSC head
        ``tanh(h_obs W_obs + h_g W_target + b)``.
    """

    input_weight: Tensor
    input_bias: Tensor
    offsets: Tensor
    head_obs: Tensor
    head_target: Tensor | None
    head_bias: Tensor


class StepLayers:
    """``NavFormerModel``'s token embeddings and THSC head for one timestep, in a few fused ops.

    ``tokens(...)`` equals ``model.prepare_tokens(cat([first token, model.return_token(...),
    model.observation_tokens(...)], 1))`` in eval mode and ``action(...)`` equals ``model.predict_action``
    (up to float rounding), with about 6 ops instead of 30. The tables are rebuilt whenever a parameter
    they come from changes (``derived.parameter_key`` lists what is not seen: ``p.data`` writes, fused
    optimizers). No autograd: call under ``torch.no_grad()``.
    """

    def __init__(self, model: NavFormerModel) -> None:
        self.model = model
        # the parameters the tables come from, gathered once: ``nn.Module`` attribute access costs ~2 us
        sources = (
            model.action_embed.weight,
            model.action_embed.bias,
            model.return_embed.weight,
            model.return_embed.bias,
            model.timestep_embed.weight,
            model.modality_embed.weight,
            model.head.weight,
            model.head.bias,
        )
        self._embed_norm = layer_norm_weights(model.embed_ln)
        self._tables = DerivedCache(sources)

    def tables(self) -> StepTables:
        """The current ``StepTables`` (rebuilt if a parameter changed since the last call)."""
        return self._tables.get(self._build)

    def _build(self) -> StepTables:
        model = self.model
        d, actions = model.config.d_embed, model.config.action_dim
        weight = model.action_embed.weight.new_zeros(actions + 1, 2 * d)
        weight[:actions, :d] = model.action_embed.weight.T
        weight[actions:, d:] = model.return_embed.weight.T
        bias = torch.cat([model.action_embed.bias, model.return_embed.bias])
        return StepTables(weight, bias, self._offsets(), *self._head())

    def _offsets(self) -> Tensor:
        """``[max_timestep + 1, tps, d]``: modality + timestep embeddings of each step's tokens."""
        model = self.model
        timestep, modality = model.timestep_embed.weight, model.modality_embed.weight
        max_timestep = timestep.shape[0]
        rows = torch.arange(max_timestep + 1, device=timestep.device)
        step = timestep[rows.clamp(max=max_timestep - 1)]  # [max_timestep + 1, d]: R_t's and e_t's timestep
        first = modality[MODALITIES.index("action")] + timestep[(rows - 1).clamp(min=0)]  # a_{t-1}
        first[0] = modality[MODALITIES.index("target")]  # row 0: the target token (no timestep)
        rest = modality[model.step_modalities[:-1]][None] + step[:, None]  # R_t, e_t...: [rows, tps - 1, d]
        return torch.cat([first[:, None], rest], 1)

    def _head(self) -> tuple[Tensor, Tensor | None, Tensor]:
        head, d = self.model.head, self.model.config.d_embed
        weight = head.weight.T  # [d or 2 d, A]
        if self.model.config.thsc:  # the head reads [h_g ; h_obs]
            return weight[d:].contiguous(), weight[:d].contiguous(), head.bias
        return weight.contiguous(), None, head.bias

    def tokens(
        self,
        prev_action: Tensor,
        return_to_go: Tensor,
        obs_embedding: Tensor,
        row: int | Tensor,
        target_embedding: Tensor | None = None,
        first: Tensor | None = None,
    ) -> Tensor:
        """Step tokens ``[B, tps, d]``, after ``model.prepare_tokens`` (eval mode: its dropout is off).

        prev_action ``[B, A]`` (a_{t-1}), return_to_go ``[B, 1]``, obs_embedding ``[B, n_enc, d]``; row: int
        or long ``[B]``, ``min(t, max_timestep)`` (0 on a first step). target_embedding ``[B' , d]``: e_g of
        the robots at their first step, which take it as first token instead of the action: all of them
        (``first`` None) or those where ``first`` (bool ``[B]``) is True.
        """
        tables = self.tables()
        batch = prev_action.shape[0]
        inputs = torch.cat([prev_action, return_to_go], 1)
        embedded = torch.addmm(tables.input_bias, inputs, tables.input_weight).view(batch, 2, -1)
        if target_embedding is not None:
            index = slice(None) if first is None else first
            embedded[index, 0] = target_embedding.to(embedded.dtype)
        tokens = torch.cat([embedded, obs_embedding.to(embedded.dtype)], 1).add_(tables.offsets[row])
        return self._embed_norm(tokens)  # model.prepare_tokens in eval mode (no dropout)

    def action(self, target_hidden: Tensor, obs_hidden: Tensor) -> Tensor:
        """THSC head: target_hidden ``[B, d]``, obs_hidden ``[B, d]`` -> float actions ``[B, A]`` in [-1, 1]."""
        tables = self.tables()
        out = torch.addmm(tables.head_bias, obs_hidden, tables.head_obs)
        if tables.head_target is not None:
            out.addmm_(target_hidden, tables.head_target)
        return out.tanh_().float()
