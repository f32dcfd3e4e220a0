"""``CausalTransformer`` (CT, paper §IV.C): the interleaved token sequence
(eq. 5) through the GPT-2 blocks."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from navformer_rl.modules.models.config import NavFormerConfig, autocast
from navformer_rl.modules.models.dve import ENCODER_NAMES
from navformer_rl.modules.models.gpt import GPT2Blocks
from navformer_rl.modules.models.ops.dropout import Dropout

MODALITIES = ("target", "return_to_go", "static", "general", "action")
"""Rows of the learnable modality embedding table."""
HIDDEN_NAMES = ("target", "observation", "tokens")
"""What ``CausalTransformer.forward`` returns, in order (see there)."""


class TokenEmbedding(nn.Module):
    """Token embeddings of eq. 4-5: every token gets ``modality_embed[type]``, step tokens also
    ``timestep_embed[step]`` (absolute timestep); then LayerNorm and dropout per token (``prepare``).

    There is no token-position embedding, so a cached key/value stays valid when the inference window
    slides (see ``docs/model.md``).

    Args:
        observation_names: the observation tokens of a step, in order (``("static", "general")``, or one).
        action_dropout: in training mode, the probability that a step's action token carries no action
            (``action_embed`` left out; modality and timestep kept). 0: never.
    """

    def __init__(
        self,
        d_embed: int,
        action_dim: int,
        max_timestep: int,
        observation_names: Sequence[str] = ENCODER_NAMES,
        dropout: float = 0.1,
        action_dropout: float = 0.0,
    ) -> None:
        super().__init__()
        unknown = [name for name in observation_names if name not in ENCODER_NAMES]
        if unknown or not observation_names:
            raise ValueError(
                f"observation_names={tuple(observation_names)!r}: expected one or more of {ENCODER_NAMES}"
            )
        self.observation_names = tuple(observation_names)
        self.return_embed = nn.Linear(1, d_embed)
        self.action_embed = nn.Linear(action_dim, d_embed)
        self.timestep_embed = nn.Embedding(max_timestep, d_embed)
        self.modality_embed = nn.Embedding(len(MODALITIES), d_embed)
        self.embed_ln = nn.LayerNorm(d_embed)
        self.embed_dropout = Dropout(dropout)
        self.action_dropout = float(action_dropout)
        step_types = ["return_to_go", *self.observation_names, "action"]
        self.register_buffer(
            "step_modalities", torch.tensor([MODALITIES.index(t) for t in step_types]), persistent=False
        )

    @classmethod
    def from_config(cls, config: NavFormerConfig) -> TokenEmbedding:
        """The token embeddings of ``config`` (observation tokens of the encoders it uses), PyTorch's default
        inits (the tables get GPT-2's from :func:`init_embedding_tables`, applied by the model after every
        part)."""
        used = (config.use_static_encoder, config.use_general_encoder)
        names = [name for name, use in zip(ENCODER_NAMES, used, strict=True) if use]
        return cls(
            config.d_embed,
            config.action_dim,
            config.max_timestep,
            names,
            config.dropout,
            config.action_dropout,
        )

    @property
    def tokens_per_step(self) -> int:
        """R-hat, the observation tokens and a: 4 for NavFormer, 3 with one encoder."""
        return 2 + len(self.observation_names)

    def target_token(self, target_embedding: Tensor) -> Tensor:
        """``[B, d]`` -> the target token ``[B, d]`` (modality embedding added, no timestep)."""
        return target_embedding + self.modality_embed.weight[MODALITIES.index("target")]

    def step_tokens(
        self, observations: Sequence[Tensor], return_to_go: Tensor, action: Tensor, step: Tensor
    ) -> Tensor:
        """Per-step tokens ``[B, T, tps, d]`` = (R-hat, observation embeddings.., a) + modality + timestep
        (in training, each step's ``a`` embedding dropped with probability ``action_dropout``).

        observations: one ``[B, T, d]`` per name of ``observation_names``; return_to_go ``[B, T, 1]``,
        action ``[B, T, A]`` (a_t, at its own timestep), step long ``[B, T]``.
        """
        timestep = self.timestep_embed(step)  # [B, T, d]
        modality = self.modality_embed(self.step_modalities)  # [tps, d]: R-hat, observations.., a
        tokens = [self.return_embed(return_to_go) + modality[0] + timestep]
        tokens += [embedding + modality[i] + timestep for i, embedding in enumerate(observations, 1)]
        action_embedding = self.action_embed(action)
        if self.training and self.action_dropout > 0.0:
            kept = torch.rand(action.shape[:-1], device=action.device) >= self.action_dropout
            action_embedding = action_embedding * kept.unsqueeze(-1).to(action_embedding.dtype)
        tokens.append(action_embedding + modality[-1] + timestep)
        return torch.stack(tokens, dim=-2)  # tps x [B, T, d] -> [B, T, tps, d]

    def prepare(self, tokens: Tensor) -> Tensor:
        """LayerNorm then dropout on token embeddings ``[..., d]`` (per token,
        as in the DT reference code)."""
        return self.embed_dropout(self.embed_ln(tokens))


class CausalTransformer(nn.Module):
    """The CT of paper §IV.C: embeddings, R-hat and actions -> token sequence -> hidden states.

    Token sequence of one trajectory of T steps (eq. 5), ``tps`` tokens a step::

        e_g, (e_R1, e^s_1, e^ca_1, e_a1), ..., (e_RT, e^s_T, e^ca_T)        # a_T is never fed: L = tps * T

    ``forward(target_embedding, return_to_go, action, step, mask=None, *, static=None, general=None)``
    returns (``HIDDEN_NAMES``):

    - target: h_g ``[B, T, d]`` (the target token's hidden state, expanded over the steps);
    - observation: h_o ``[B, T, d]``, the hidden state of each step's last observation token (h^ca_o
      for NavFormer); it precedes a_t in the causal order, so a_t never influences a prediction of step t;
    - tokens: ``[B, T, tps, d]``, the hidden states of the tokens each step feeds, ``(g or a_{t-1}, R_t,
      e.._t)`` (a view of the sequence's hidden states).

    Inputs: target_embedding ``[B, d]`` (or ``[B, T, d]``, constant over T: step 0 is read); static /
    general: e^s / e^ca ``[B, T, d]``, exactly those of ``observation_names``; return_to_go float
    ``[B, T, 1]``; action float ``[B, T, A]`` (a_t only feeds steps > t); step int64 ``[B, T]`` (absolute
    timestep < ``max_timestep`` on valid steps); mask bool ``[B, T]``, True on valid steps (padding on
    the right; None = all valid). Padded steps' inputs are zeroed (a NaN left there would reach valid
    outputs through 0 * NaN in the attention product).

    window_steps: None - plain causal attention (``tps * T`` must fit ``context_tokens``). An int W -
    sliding-window attention that reproduces the streaming KV cache exactly: a token created at the query
    of step c (R, e of step c and a_{c-1}) sees the target token and the tokens of steps >= c - W + 1.
    """

    def __init__(
        self,
        tokens: TokenEmbedding,
        gpt: GPT2Blocks,
        context_tokens: int,
        *,
        autocast_dtype: torch.dtype | None = None,
    ) -> None:
        super().__init__()
        self.tokens = tokens
        self.gpt = gpt
        self.context_tokens = context_tokens
        self.autocast_dtype = autocast_dtype

    @classmethod
    def from_config(cls, config: NavFormerConfig) -> CausalTransformer:
        """A fresh CT of ``config`` (observation tokens of the encoders ``config`` uses): the token
        embeddings, then the GPT-2 blocks, each with PyTorch's default inits. ``NavFormerModel`` builds it
        this way and then applies :func:`init_embedding_tables`; a CT used alone applies it too
        (``transformer.apply(init_embedding_tables)``)."""
        return cls(
            TokenEmbedding.from_config(config),
            GPT2Blocks.from_config(config),
            config.context_tokens,
            autocast_dtype=config.torch_autocast_dtype,
        )

    @property
    def observation_names(self) -> tuple[str, ...]:
        return self.tokens.observation_names

    @property
    def tokens_per_step(self) -> int:
        return self.tokens.tokens_per_step

    def forward(
        self,
        target_embedding: Tensor,
        return_to_go: Tensor,
        action: Tensor,
        step: Tensor,
        mask: Tensor | None = None,
        *,
        static: Tensor | None = None,
        general: Tensor | None = None,
        window_steps: int | None = None,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """-> ``(h_g [B, T, d], h_o [B, T, d], token hidden states [B, T, tps, d])``
        (see the class docstring)."""
        given = {"static": static, "general": general}
        if tuple(name for name, value in given.items() if value is not None) != self.observation_names:
            raise ValueError(
                f"CausalTransformer: expected the embeddings {self.observation_names}, got "
                f"{tuple(name for name, value in given.items() if value is not None)}"
            )
        observations = [given[name] for name in self.observation_names]
        batch, steps = self._check_inputs(target_embedding, observations, return_to_go, action, step, mask)
        tps = self.tokens_per_step
        if window_steps is None and tps * steps > self.context_tokens:
            raise ValueError(
                f"trajectory of T={steps} steps needs {tps * steps} tokens > context_tokens="
                f"{self.context_tokens}; use T <= {self.context_tokens // tps} or pass window_steps"
            )
        if window_steps is not None and window_steps <= 0:
            raise ValueError(f"window_steps={window_steps!r}: expected None or a positive int")
        if target_embedding.dim() == 3:
            target_embedding = target_embedding[:, 0]
        if mask is not None:
            step = step.masked_fill(~mask, 0)
            return_to_go = return_to_go.masked_fill(~mask[..., None], 0.0)
            action = action.masked_fill(~mask[..., None], 0.0)
        with autocast(return_to_go.device, self.autocast_dtype):
            target = self.tokens.target_token(target_embedding)  # [B, d]
            tokens = self.tokens.step_tokens(observations, return_to_go, action, step)  # [B, T, tps, d]
            # eq. 5: (g, R_1, e^s_1, e^ca_1, a_1, ..., R_T, e^s_T, e^ca_T) [B, tps * T, d]; a_T is never fed
            sequence = torch.cat([target.unsqueeze(1), tokens.reshape(batch, steps * tps, -1)[:, :-1]], dim=1)
            attn_mask = None
            if window_steps is not None and window_steps < steps:
                attn_mask = sliding_window_mask(steps, tps, window_steps, sequence.device)
            hidden, _ = self.gpt(self.tokens.prepare(sequence), attn_mask=attn_mask)
        # [B, tps * T, d] -> [B, T, tps, d]: step t's tokens (g or a_{t-1}, R_t, e.._t), shifted by the target
        token_hidden = hidden.view(batch, steps, tps, -1)
        # h_g [B, 1, d] -> [B, T, d]; h_o = step t's last observation token [B, T, d]
        return hidden[:, :1].expand(batch, steps, -1), token_hidden[:, :, -1], token_hidden

    def _check_inputs(
        self,
        target_embedding: Tensor,
        observations: list[Tensor],
        return_to_go: Tensor,
        action: Tensor,
        step: Tensor,
        mask: Tensor | None,
    ) -> tuple[int, int]:
        inputs = {
            "target_embedding": target_embedding,
            "return_to_go": return_to_go,
            "action": action,
            "step": step,
        }
        missing = [name for name, value in inputs.items() if value is None]
        if missing:
            raise ValueError(
                f"CausalTransformer: {missing[0]} is None; every input but mask is required "
                "(target_embedding [B, d], return_to_go [B, T, 1], action [B, T, A], step int64 [B, T])"
            )
        first = observations[0]
        if first.dim() != 3:
            raise ValueError(f"{self.observation_names[0]}: expected [B, T, d], got {tuple(first.shape)}")
        batch, steps, d_embed = first.shape
        action_dim = self.tokens.action_embed.in_features
        expected = {
            name: (value, (batch, steps, d_embed))
            for name, value in zip(self.observation_names, observations)
        }
        expected |= {
            "return_to_go": (return_to_go, (batch, steps, 1)),
            "action": (action, (batch, steps, action_dim)),
            "step": (step, (batch, steps)),
        }
        if mask is not None:
            expected["mask"] = (mask, (batch, steps))
        for name, (value, shape) in expected.items():
            if tuple(value.shape) != shape:
                raise ValueError(f"{name}: expected shape {list(shape)}, got {list(value.shape)}")
        if tuple(target_embedding.shape) not in ((batch, d_embed), (batch, steps, d_embed)):
            raise ValueError(
                f"target_embedding: expected [{batch}, {d_embed}] or [{batch}, {steps}, {d_embed}], got "
                f"{list(target_embedding.shape)}"
            )
        if not return_to_go.is_floating_point() or not action.is_floating_point():
            raise ValueError(
                f"return_to_go / action: expected float tensors, got {return_to_go.dtype} / {action.dtype}"
            )
        if step.dtype != torch.int64:
            raise ValueError(f"step: expected int64 timesteps, got {step.dtype}")
        if mask is not None and mask.dtype != torch.bool:
            raise ValueError(f"mask: expected bool, got {mask.dtype}")
        valid_steps = step if mask is None else step[mask]
        max_timestep = self.tokens.timestep_embed.num_embeddings
        if valid_steps.numel() and (valid_steps.min() < 0 or valid_steps.max() >= max_timestep):
            raise ValueError(
                f"step: valid timesteps must lie in [0, {max_timestep}), got "
                f"[{int(valid_steps.min())}, {int(valid_steps.max())}]"
            )
        return batch, steps


def init_embedding_tables(module: nn.Module) -> None:
    """GPT-2's init of an ``nn.Embedding`` table, N(0, 0.02) (nanoGPT's ``_init_weights``), for
    ``Module.apply``. ``NavFormerModel`` applies it once all its parts are built, so these draws come last:
    a seed gives the same weights as the single-module model of ``navformer_rl.run/1`` checkpoints."""
    if isinstance(module, nn.Embedding):
        nn.init.normal_(module.weight, mean=0.0, std=0.02)


def sliding_window_mask(steps: int, tokens_per_step: int, window_steps: int, device: torch.device) -> Tensor:
    """Bool attention mask ``[1, 1, L, L]`` (L = tps * steps, True = may attend) of the streaming window.

    Token j >= 1 belongs to step ``(j - 1) // tps``; it is created at the query of step c = its step, or
    its step + 1 for the action token. Query j may attend key k <= j if k is the target token or k's step
    >= c(j) - W + 1: exactly the keys the streaming KV cache holds when j is computed.
    """
    length = steps * tokens_per_step
    index = torch.arange(length, device=device)
    token_step = torch.where(index == 0, -1, (index - 1) // tokens_per_step)
    is_action = (index > 0) & ((index - 1) % tokens_per_step == tokens_per_step - 1)
    created_at = token_step + is_action.long()
    in_window = token_step[None, :] >= created_at[:, None] - window_steps + 1
    allowed = (index[None, :] <= index[:, None]) & (in_window | (index[None, :] == 0))
    return allowed[None, None]
