"""``NavFormerConfig``: every architecture number of paper §IV and every model-level ablation switch."""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

from navformer_rl.tasks import ABLATIONS

if TYPE_CHECKING:
    import torch

ENCODER_KINDS = ("cnn", "resnet18")
AUTOCAST_DTYPES = ("bfloat16", "float16")
"""The ``autocast_dtype`` values (names of torch dtypes)."""
MODEL_ABLATIONS = tuple(ABLATIONS)
"""Every ``ablation=`` name (:data:`navformer_rl.tasks.ABLATIONS`); the data / SSL ablations build the paper's
model."""


@dataclass(frozen=True)
class NavFormerConfig:
    """Hyper-parameters of the NavFormer model (paper §IV; defaults are the paper's).

    Architecture:
        d_embed: token width d_e (128).  n_blocks: GPT-2 blocks N (3).  n_heads / d_head: h = 2 heads of
        d_k = 64 (``n_heads * d_head`` must equal ``d_embed``).  mlp_ratio: MLP hidden = 4 * d_embed.
        context_tokens: the transformer's context (1024 tokens).  dropout: on the token embeddings, the
        attention weights and the residual branches (0.1).  max_timestep: size of the learnable timestep
        embedding table (512 > the 500-step episodes).  action_dim: 2 = (linear, angular).
        image_size: side of the square uint8 images (84).

    Ablation switches (Table IV):
        encoder: ``"cnn"`` (the paper's 3-conv encoder) or ``"resnet18"`` (randomly initialised, plain torch,
            GroupNorm). ``ablation("resnet18")`` also drops f_s: the paper's single ResNet18 replaces the DVE.
        use_static_encoder / use_general_encoder: drop f_s or f_g (and its token). Without f_g the target
        image goes through f_s.
        thsc: target hidden-state concatenation - the head reads ``[h_g ; h^ca_{o,t}]``; when False it reads
        the last observation token's hidden state only (the DT baseline).

    Training levers (no effect on the maths, see ``docs/model.md``):
        detach_encoders: the DT loss does not back-propagate into the encoders (they learn from BYOL only).
        encoder_micro_batch: run the encoders on chunks of this many frames (None: one chunk).
        autocast_dtype: ``"bfloat16"`` / ``"float16"`` autocast around the training forward, or None (fp32).
        channels_last: feed the convolutions channels_last tensors (free from uint8 HWC).
        space_to_depth: run the paper CNN's 8 x 8 / 4 first convolution on 4 x 4 pixel blocks as 48 channels
            (``ConvEncoder``; same maths, ~2x faster conv1 training on CPU in bf16). Ignored by ResNet18.

    Beyond the paper (opt-in, ``docs/deviations.md``):
        action_dropout: in training, each step's action token loses its action content with this
            probability (the token keeps its modality and timestep embeddings), so the model cannot lean on
            copying the previous action (behaviour cloning's "copycat" shortcut); inference always sees every
            action. 0 (default): the paper's training.
        action_bins: 0 (default) is the paper's head, ``tanh`` of a linear map trained with eq. 10's squared
            error. K >= 2: each action dimension as K logits over bins centred on ``linspace(-1, 1, K)``,
            trained with cross-entropy, the action read from the most probable bin
            (:class:`~navformer_rl.modules.models.heads.BinnedActionHead`): a state with two good turns gives
            one of them, where the squared error's mean of the two may be no turn.
    """

    d_embed: int = 128
    n_blocks: int = 3
    n_heads: int = 2
    d_head: int = 64
    mlp_ratio: int = 4
    context_tokens: int = 1024
    dropout: float = 0.1
    max_timestep: int = 512
    action_dim: int = 2
    image_size: int = 84
    encoder: str = "cnn"
    use_static_encoder: bool = True
    use_general_encoder: bool = True
    thsc: bool = True
    detach_encoders: bool = False
    encoder_micro_batch: int | None = None
    autocast_dtype: str | None = None
    channels_last: bool = True
    space_to_depth: bool = True
    action_dropout: float = 0.0
    action_bins: int = 0

    def __post_init__(self) -> None:
        positive = ("d_embed", "n_blocks", "n_heads", "d_head", "mlp_ratio", "max_timestep", "action_dim")
        for name in positive:
            value = getattr(self, name)
            if not isinstance(value, int) or value <= 0:
                raise ValueError(f"NavFormerConfig.{name}={value!r}: expected a positive int")
        if self.n_heads * self.d_head != self.d_embed:
            raise ValueError(
                f"NavFormerConfig: n_heads * d_head = {self.n_heads} * {self.d_head} must equal "
                f"d_embed = {self.d_embed}"
            )
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"NavFormerConfig.dropout={self.dropout!r}: expected a float in [0, 1)")
        if not 0.0 <= self.action_dropout <= 1.0:
            raise ValueError(
                f"NavFormerConfig.action_dropout={self.action_dropout!r}: expected a float in [0, 1]"
            )
        if not isinstance(self.action_bins, int) or self.action_bins < 0 or self.action_bins == 1:
            raise ValueError(
                f"NavFormerConfig.action_bins={self.action_bins!r}: expected 0 (the paper's regression head) "
                "or an int >= 2"
            )
        if self.encoder not in ENCODER_KINDS:
            raise ValueError(f"NavFormerConfig.encoder={self.encoder!r}: expected one of {ENCODER_KINDS}")
        if not (self.use_static_encoder or self.use_general_encoder):
            raise ValueError(
                "NavFormerConfig: at least one of use_static_encoder / use_general_encoder must be True"
            )
        if self.context_tokens < 2 * self.tokens_per_step:
            raise ValueError(
                f"NavFormerConfig.context_tokens={self.context_tokens}: expected at least "
                f"{2 * self.tokens_per_step} (two timesteps of {self.tokens_per_step} tokens)"
            )
        if self.image_size < 36 and self.encoder == "cnn":
            raise ValueError(
                f"NavFormerConfig.image_size={self.image_size}: the paper CNN needs at least 36 px"
            )
        if self.encoder_micro_batch is not None and self.encoder_micro_batch <= 0:
            raise ValueError(
                f"NavFormerConfig.encoder_micro_batch={self.encoder_micro_batch!r}: "
                "expected None or a positive int"
            )
        if self.autocast_dtype is not None and self.autocast_dtype not in AUTOCAST_DTYPES:
            raise ValueError(
                f"NavFormerConfig.autocast_dtype={self.autocast_dtype!r}: expected None or one of "
                f"{tuple(AUTOCAST_DTYPES)}"
            )

    @property
    def n_encoders(self) -> int:
        """Observation tokens per timestep (1 or 2)."""
        return int(self.use_static_encoder) + int(self.use_general_encoder)

    @property
    def tokens_per_step(self) -> int:
        """Tokens per timestep: R-hat, the observation embeddings, a (4 for NavFormer, 3 with one encoder)."""
        return 2 + self.n_encoders

    @property
    def window_steps(self) -> int:
        """Timesteps that fit in the context at inference: ``context_tokens // tokens_per_step`` (256).

        At a query the sequence is ``g, (R, e.., a) x (W-1), R, e..`` = ``tokens_per_step * W`` tokens.
        """
        return self.context_tokens // self.tokens_per_step

    @property
    def torch_autocast_dtype(self) -> torch.dtype | None:
        import torch

        return None if self.autocast_dtype is None else getattr(torch, self.autocast_dtype)

    def replace(self, **changes) -> NavFormerConfig:
        """A copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def dt_baseline(cls, **changes) -> NavFormerConfig:
        """The Decision Transformer baseline: one (general) encoder, tokens ``g, (R, e, a)...``, no THSC."""
        return cls(use_static_encoder=False, use_general_encoder=True, thsc=False, **changes)

    @classmethod
    def ablation(cls, name: str, **changes) -> NavFormerConfig:
        """The model of ablation ``name`` (a key of :data:`navformer_rl.tasks.ABLATIONS`: ``none``,
        ``no_thsc``, ``no_fs``, ``no_fg``, ``resnet18``, ``dt``, ...; the data / SSL ablations give the
        paper's model). §VII.D (7): "a single pre-trained ResNet18" replaces the dual visual encoder."""
        if name not in ABLATIONS:
            raise ValueError(f"unknown ablation {name!r}: expected one of {list(ABLATIONS)}")
        return cls(**{**ABLATIONS[name].model_switches, **changes})


def autocast(device: torch.device, dtype: torch.dtype | None) -> contextlib.AbstractContextManager:
    """``torch.autocast`` on ``device``'s type in ``dtype``, or a no-op context when ``dtype`` is None."""
    import torch

    return torch.autocast(device.type, dtype=dtype) if dtype is not None else contextlib.nullcontext()
