"""Inference helper: the per-step token embeddings and the action head with precomputed tables."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from navformer_rl.modules.decoding.derived import DerivedCache
from navformer_rl.modules.decoding.transformer_step import layer_norm_weights
from navformer_rl.modules.models.heads import ObservationHead, THSCHead
from navformer_rl.modules.models.navformer import NavFormerModel
from navformer_rl.modules.models.transformer import MODALITIES


class StepTables(NamedTuple):
    """The model's per-step layers in fused form (``A`` = action_dim, ``d`` = d_embed, ``tps`` tokens a step).

    input_weight ``[A + 1, 2 d]`` / input_bias ``[2 d]``: ``[a ; R] -> [action_embed(a) ; return_embed(R)]``
        (block diagonal: one matmul for both).
    offsets ``[max_timestep + 1, tps, d]``: row ``r = min(t, max_timestep)`` holds what step t's tokens add
        to their inputs (modality and timestep embeddings): a_{t-1} (the target modality on row 0), R_t,
        then the observation tokens.
    head_obs ``[d, A]``, head_target ``[d, A]`` (None for an ``ObservationHead``), head_bias ``[A]``: the
        head ``tanh(h_obs W_obs + h_g W_target + b)``; all three None for another head (called as a module).
    """

    input_weight: Tensor
    input_bias: Tensor
    offsets: Tensor
    head_obs: Tensor | None
    head_target: Tensor | None
    head_bias: Tensor | None


class StepLayers:
    """A ``NavFormerModel``'s token embeddings (``model.transformer.tokens``) and head for one timestep.

    ``tokens(...)`` equals ``tokens.prepare(cat([first token, R-hat token, observation tokens], 1))`` in eval
    mode and ``action(...)`` equals the head (up to float rounding), with about 6 ops instead of 30. A
    ``THSCHead`` or ``ObservationHead`` runs as precomputed matrices; any other ``ActionHead`` reading
    ``target`` / ``observation`` is called as a module. The tables are rebuilt whenever a parameter they
    come from changes (``derived.parameter_key`` lists what is not seen: ``p.data`` writes, fused
    optimizers). No autograd: call under ``torch.no_grad()``.

    Raises:
        ValueError: the head reads other hidden states than ``target`` / ``observation``.
    """

    def __init__(self, model: NavFormerModel) -> None:
        self.model = model
        self.embedding = embedding = model.transformer.tokens
        self.head = head = model.head
        if not set(head.reads) <= {"target", "observation"}:
            raise ValueError(
                f"StepLayers: the head {type(head).__name__} reads {head.reads}; one-step decoding provides "
                "'target' and 'observation'"
            )
        self._fused_head = isinstance(head, (THSCHead, ObservationHead))
        # the parameters the tables come from, gathered once: ``nn.Module`` attribute access costs ~2 us
        sources = (
            embedding.action_embed.weight,
            embedding.action_embed.bias,
            embedding.return_embed.weight,
            embedding.return_embed.bias,
            embedding.timestep_embed.weight,
            embedding.modality_embed.weight,
            *((head.weight, head.bias) if self._fused_head else ()),
        )
        self._embed_norm = layer_norm_weights(embedding.embed_ln)
        self._tables = DerivedCache(sources)

    def tables(self) -> StepTables:
        """The current ``StepTables`` (rebuilt if a parameter changed since the last call)."""
        return self._tables.get(self._build)

    def _build(self) -> StepTables:
        embedding = self.embedding
        d, actions = embedding.action_embed.out_features, embedding.action_embed.in_features
        weight = embedding.action_embed.weight.new_zeros(actions + 1, 2 * d)
        weight[:actions, :d] = embedding.action_embed.weight.T
        weight[actions:, d:] = embedding.return_embed.weight.T
        bias = torch.cat([embedding.action_embed.bias, embedding.return_embed.bias])
        return StepTables(weight, bias, self._offsets(), *self._head())

    def _offsets(self) -> Tensor:
        """``[max_timestep + 1, tps, d]``: modality + timestep embeddings of each step's tokens."""
        embedding = self.embedding
        timestep, modality = embedding.timestep_embed.weight, embedding.modality_embed.weight
        max_timestep = timestep.shape[0]
        rows = torch.arange(max_timestep + 1, device=timestep.device)
        step = timestep[rows.clamp(max=max_timestep - 1)]  # [max_timestep + 1, d]: R_t's and e_t's timestep
        first = modality[MODALITIES.index("action")] + timestep[(rows - 1).clamp(min=0)]  # a_{t-1}
        first[0] = modality[MODALITIES.index("target")]  # row 0: the target token (no timestep)
        rest = (
            modality[embedding.step_modalities[:-1]][None] + step[:, None]
        )  # R_t, e_t..: [rows, tps - 1, d]
        return torch.cat([first[:, None], rest], 1)

    def _head(self) -> tuple[Tensor | None, Tensor | None, Tensor | None]:
        head = self.head
        if not self._fused_head:
            return None, None, None
        weight = head.weight.T  # [d or 2 d, A]
        if isinstance(head, THSCHead):  # the head reads [h_g ; h_obs]
            d = weight.shape[0] // 2
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
        """Step tokens ``[B, tps, d]``, after ``TokenEmbedding.prepare`` (eval mode: its dropout is off).

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
        return self._embed_norm(tokens)  # TokenEmbedding.prepare in eval mode (no dropout)

    def action(self, target_hidden: Tensor, obs_hidden: Tensor) -> Tensor:
        """The head: target_hidden ``[B, d]`` (h_g), obs_hidden ``[B, d]`` (h_o)
        -> float actions ``[B, A]``."""
        tables = self.tables()
        if tables.head_obs is None:
            hidden = {"target": target_hidden[:, None], "observation": obs_hidden[:, None]}
            return self.head.actions(*(hidden[name] for name in self.head.reads))[:, 0].float()
        out = torch.addmm(tables.head_bias, obs_hidden, tables.head_obs)
        if tables.head_target is not None:
            out.addmm_(target_hidden, tables.head_target)
        return out.tanh_().float()
