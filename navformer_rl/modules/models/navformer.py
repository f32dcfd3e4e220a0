"""``NavFormerModel``: dual-visual encoders + causal transformer + THSC head on plain tensors (paper §IV)."""

from __future__ import annotations

import contextlib

import torch
from torch import Tensor, nn

from navformer_rl.modules.models.cnn import ConvEncoder, ImageEncoder, check_images, encode_images
from navformer_rl.modules.models.config import NavFormerConfig
from navformer_rl.modules.models.dropout import Dropout
from navformer_rl.modules.models.resnet import ResNet18Encoder
from navformer_rl.modules.models.transformer import CausalTransformer

MODALITIES = ("target", "return_to_go", "static", "general", "action")
"""Rows of the learnable modality embedding table."""


def make_encoder(config: NavFormerConfig) -> ImageEncoder:
    """A fresh, randomly initialised image encoder of ``config.encoder`` kind (d_out = d_embed)."""
    if config.encoder == "resnet18":
        return ResNet18Encoder(
            config.d_embed, config.image_size, config.encoder_micro_batch, config.channels_last
        )
    return ConvEncoder(
        config.d_embed,
        config.image_size,
        config.encoder_micro_batch,
        config.channels_last,
        config.space_to_depth,
    )


class NavFormerModel(nn.Module):
    """NavFormer on tensors (eqs. 4, 5, 9 and the THSC head).

    Token sequence of one trajectory of T steps (eq. 5), ``tps`` = ``config.tokens_per_step`` tokens a step::

        e_g, (e_R1, e^s_1, e^ca_1, e_a1), ..., (e_RT, e^s_T, e^ca_T)        # a_T is never fed: L = tps * T

    Every token gets ``modality_embed[type]``; step tokens also get ``timestep_embed[step]`` (absolute
    timestep). There is no token-position embedding, so a cached key/value stays valid when the
    inference window slides (see ``docs/model.md``). Action prediction for step t reads the final hidden
    states of the target token and of step t's last observation token (THSC: ``tanh(W [h_g ; h^ca_t] + b)``),
    both of which precede ``a_t`` in the causal order, so ``a_t`` never influences ``a-hat_t``.

    The encoders ``static_encoder`` (f_s) and ``general_encoder`` (f_g) are ordinary sub-modules; BYOL
    trains the very same objects. The target image goes through f_g (through f_s when f_g is ablated).
    """

    def __init__(self, config: NavFormerConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or NavFormerConfig()
        d = config.d_embed
        self.static_encoder = make_encoder(config) if config.use_static_encoder else None
        self.general_encoder = make_encoder(config) if config.use_general_encoder else None
        self.return_embed = nn.Linear(1, d)
        self.action_embed = nn.Linear(config.action_dim, d)
        self.timestep_embed = nn.Embedding(config.max_timestep, d)
        self.modality_embed = nn.Embedding(len(MODALITIES), d)
        self.embed_ln = nn.LayerNorm(d)
        self.embed_dropout = Dropout(config.dropout)
        self.transformer = CausalTransformer(
            d, config.n_blocks, config.n_heads, config.d_head, config.mlp_ratio, config.dropout
        )
        self.head = nn.Linear(2 * d if config.thsc else d, config.action_dim)
        for table in (self.timestep_embed, self.modality_embed):
            nn.init.normal_(table.weight, mean=0.0, std=0.02)
        step_types = ["return_to_go"] + [name for name, _ in self.observation_encoders()] + ["action"]
        self.register_buffer(
            "step_modalities", torch.tensor([MODALITIES.index(t) for t in step_types]), persistent=False
        )

    # ----------------------------------------------------------------------------------- encoders
    def observation_encoders(self) -> list[tuple[str, ImageEncoder]]:
        """``[("static", f_s), ("general", f_g)]`` restricted to the encoders in use, in token order."""
        pairs = [("static", self.static_encoder), ("general", self.general_encoder)]
        return [(name, enc) for name, enc in pairs if enc is not None]

    @property
    def target_encoder(self) -> ImageEncoder:
        """f_g (f_s when f_g is ablated)."""
        return self.general_encoder if self.general_encoder is not None else self.static_encoder

    def encode_target(self, target_pixels: Tensor) -> Tensor:
        """target_pixels: uint8 ``[B, H, W, 3]`` -> target embedding e_g ``[B, d]``."""
        with self._encoder_grad():
            return self.target_encoder(target_pixels)

    def encode_observations(self, pixels: Tensor, mask: Tensor | None = None) -> Tensor:
        """pixels: uint8 ``[..., H, W, 3]`` -> ``[..., n_encoders, d]`` (static first, then general).

        Both encoders share each micro-batch's uint8 -> float conversion (``encode_images``).

        mask: optional bool ``[...]`` (pixels' leading shape), True on valid frames: only those are encoded
        and padded frames get zero embeddings (they only feed padded tokens, which no valid token attends).
        """
        encoders = [encoder for _, encoder in self.observation_encoders()]
        with self._encoder_grad():
            if mask is None or bool(mask.all()):
                return encode_images(encoders, pixels)
            embedding = encode_images(encoders, pixels[mask])
            return embedding.new_zeros(*mask.shape, *embedding.shape[1:]).index_put((mask,), embedding)

    def _encoder_grad(self) -> contextlib.AbstractContextManager:
        """``no_grad`` when ``detach_encoders`` (the DT loss then neither reaches nor records the encoders)."""
        return torch.no_grad() if self.config.detach_encoders else contextlib.nullcontext()

    # ------------------------------------------------------------------------------------ tokens
    def target_token(self, target_embedding: Tensor) -> Tensor:
        """``[B, d]`` -> the target token ``[B, d]`` (modality embedding added, no timestep)."""
        return target_embedding + self.modality_embed.weight[MODALITIES.index("target")]

    def return_token(self, return_to_go: Tensor, step: Tensor) -> Tensor:
        """return_to_go ``[..., 1]``, step long ``[...]`` -> R-hat token ``[..., d]``."""
        embedded = (
            self.return_embed(return_to_go) + self.modality_embed.weight[MODALITIES.index("return_to_go")]
        )
        return embedded + self.timestep_embed(step)

    def observation_tokens(self, obs_embedding: Tensor, step: Tensor) -> Tensor:
        """obs_embedding ``[..., n_enc, d]``, step long ``[...]`` -> observation tokens ``[..., n_enc, d]``."""
        modalities = self.modality_embed(self.step_modalities[1:-1])
        return obs_embedding + modalities + self.timestep_embed(step).unsqueeze(-2)

    def action_token(self, action: Tensor, step: Tensor) -> Tensor:
        """action ``[..., A]``, step long ``[...]`` (the action's own timestep) -> action token ``[..., d]``."""
        embedded = self.action_embed(action) + self.modality_embed.weight[MODALITIES.index("action")]
        return embedded + self.timestep_embed(step)

    def step_tokens(
        self, obs_embedding: Tensor, return_to_go: Tensor, action: Tensor, step: Tensor
    ) -> Tensor:
        """Per-step tokens ``[B, T, tps, d]`` = (R-hat, e^s, e^ca, a) + modality + timestep embeddings.

        obs_embedding ``[B, T, n_enc, d]``, return_to_go ``[B, T, 1]``, action ``[B, T, A]``, step long ``[B, T]``.
        """
        return torch.cat(
            [
                self.return_token(return_to_go, step).unsqueeze(-2),
                self.observation_tokens(obs_embedding, step),
                self.action_token(action, step).unsqueeze(-2),
            ],
            dim=-2,
        )

    def prepare_tokens(self, tokens: Tensor) -> Tensor:
        """LayerNorm then dropout on token embeddings ``[..., d]`` (per token, as in the DT reference code)."""
        return self.embed_dropout(self.embed_ln(tokens))

    def predict_action(self, target_hidden: Tensor, obs_hidden: Tensor) -> Tensor:
        """THSC head: ``tanh(Linear([h_g ; h_obs]))`` (or ``tanh(Linear(h_obs))`` without THSC).

        target_hidden ``[B, d]``, obs_hidden ``[B, T, d]`` -> actions ``[B, T, A]`` in [-1, 1].
        """
        if self.config.thsc:
            obs_hidden = torch.cat([target_hidden.unsqueeze(1).expand_as(obs_hidden), obs_hidden], dim=-1)
        return torch.tanh(self.head(obs_hidden))

    # ----------------------------------------------------------------------------------- forward
    def forward(
        self,
        target_pixels: Tensor,
        pixels: Tensor,
        return_to_go: Tensor,
        action: Tensor,
        step: Tensor,
        mask: Tensor | None = None,
        window_steps: int | None = None,
    ) -> Tensor:
        """Predict every step's action of a batch of (right-padded) trajectories.

        Args:
            target_pixels: uint8 ``[B, H, W, 3]`` (or ``[B, T, H, W, 3]``, constant over T: step 0 is used).
            pixels: uint8 ``[B, T, H, W, 3]``.  return_to_go: float ``[B, T, 1]``.
            action: float ``[B, T, A]`` (the actions taken; a_t only feeds predictions of steps > t).
            step: int64 ``[B, T]`` absolute timestep (< ``max_timestep`` on valid steps).
            mask: bool ``[B, T]``, True on valid steps (padding on the right); None = all valid.
            window_steps: None - plain causal attention (``tps * T`` must fit ``context_tokens``). An int W -
                sliding-window attention that reproduces the streaming KV cache exactly: a token created
                at the query of step c (R, e of step c and a_{c-1}) sees the target token and the tokens of
                steps >= c - W + 1. Used as the reference for incremental inference.

        Returns:
            action_pred: float32 ``[B, T, A]`` in [-1, 1]; zeros on padded steps.
        """
        batch, steps = self._check_inputs(target_pixels, pixels, return_to_go, action, step, mask)
        tps = self.config.tokens_per_step
        if window_steps is None and tps * steps > self.config.context_tokens:
            raise ValueError(
                f"trajectory of T={steps} steps needs {tps * steps} tokens > context_tokens="
                f"{self.config.context_tokens}; use T <= {self.config.window_steps} or pass window_steps"
            )
        if window_steps is not None and window_steps <= 0:
            raise ValueError(f"window_steps={window_steps!r}: expected None or a positive int")
        if target_pixels.dim() == pixels.dim():
            target_pixels = target_pixels[:, 0]
        if mask is not None:
            # padded steps' inputs zeroed: a NaN or 1e30 left there would reach valid outputs through
            # 0 * NaN in the attention product and LayerNorm overflow
            step = step.masked_fill(~mask, 0)
            return_to_go = return_to_go.masked_fill(~mask[..., None], 0.0)
            action = action.masked_fill(~mask[..., None], 0.0)
        dtype = self.config.torch_autocast_dtype
        autocast = (
            torch.autocast(pixels.device.type, dtype=dtype) if dtype is not None else contextlib.nullcontext()
        )
        with autocast:
            target = self.target_token(self.encode_target(target_pixels))
            tokens = self.step_tokens(self.encode_observations(pixels, mask), return_to_go, action, step)
            sequence = torch.cat([target.unsqueeze(1), tokens.reshape(batch, steps * tps, -1)[:, :-1]], dim=1)
            attn_mask = None
            if window_steps is not None and window_steps < steps:
                attn_mask = sliding_window_mask(steps, tps, window_steps, pixels.device)
            hidden, _ = self.transformer(self.prepare_tokens(sequence), attn_mask=attn_mask)
            # step t's last observation token sits at 1 + t * tps + (tps - 2)
            obs_hidden = hidden[:, tps - 1 :: tps]
            action_pred = self.predict_action(hidden[:, 0], obs_hidden).float()
        if mask is not None:
            action_pred = action_pred.masked_fill(~mask.unsqueeze(-1), 0.0)
        return action_pred

    def _check_inputs(
        self,
        target_pixels: Tensor,
        pixels: Tensor,
        return_to_go: Tensor,
        action: Tensor,
        step: Tensor,
        mask: Tensor | None,
    ) -> tuple[int, int]:
        size = self.config.image_size
        check_images(pixels, size, "pixels")
        check_images(target_pixels, size, "target_pixels")
        if pixels.dim() != 5:
            raise ValueError(f"pixels: expected [B, T, {size}, {size}, 3], got {tuple(pixels.shape)}")
        batch, steps = pixels.shape[:2]
        if target_pixels.shape[0] != batch or target_pixels.dim() not in (4, 5):
            raise ValueError(
                f"target_pixels: expected [{batch}, {size}, {size}, 3], got {tuple(target_pixels.shape)}"
            )
        expected = {
            "return_to_go": (return_to_go, (batch, steps, 1)),
            "action": (action, (batch, steps, self.config.action_dim)),
            "step": (step, (batch, steps)),
        }
        if mask is not None:
            expected["mask"] = (mask, (batch, steps))
        for name, (value, shape) in expected.items():
            if tuple(value.shape) != shape:
                raise ValueError(f"{name}: expected shape {list(shape)}, got {list(value.shape)}")
        if not return_to_go.is_floating_point() or not action.is_floating_point():
            raise ValueError(
                f"return_to_go / action: expected float tensors, got {return_to_go.dtype} / {action.dtype}"
            )
        if step.dtype != torch.int64:
            raise ValueError(f"step: expected int64 timesteps, got {step.dtype}")
        if mask is not None and mask.dtype != torch.bool:
            raise ValueError(f"mask: expected bool, got {mask.dtype}")
        valid_steps = step if mask is None else step[mask]
        if valid_steps.numel() and (valid_steps.min() < 0 or valid_steps.max() >= self.config.max_timestep):
            raise ValueError(
                f"step: valid timesteps must lie in [0, {self.config.max_timestep}), got "
                f"[{int(valid_steps.min())}, {int(valid_steps.max())}]"
            )
        return batch, steps


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
