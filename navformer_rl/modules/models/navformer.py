"""``NavFormerModel``: the DVE, the causal transformer and the action head of one config (paper §IV)."""

from __future__ import annotations

from collections.abc import Mapping

from torch import Tensor, nn

from navformer_rl.modules.models.cnn import ImageEncoder
from navformer_rl.modules.models.config import NavFormerConfig
from navformer_rl.modules.models.dve import DualVisualEncoder
from navformer_rl.modules.models.gpt import GPT2Blocks
from navformer_rl.modules.models.thsc import ActionHead, BinnedActionHead, make_head
from navformer_rl.modules.models.transformer import HIDDEN_NAMES, CausalTransformer, TokenEmbedding

RENAMED_PREFIXES = {
    "static_encoder.": "dve.static_encoder.",
    "general_encoder.": "dve.general_encoder.",
    "return_embed.": "transformer.tokens.return_embed.",
    "action_embed.": "transformer.tokens.action_embed.",
    "timestep_embed.": "transformer.tokens.timestep_embed.",
    "modality_embed.": "transformer.tokens.modality_embed.",
    "embed_ln.": "transformer.tokens.embed_ln.",
    "transformer.blocks.": "transformer.gpt.blocks.",
    "transformer.ln_final.": "transformer.gpt.ln_final.",
}
"""State-dict names of the single-module model (checkpoints of ``navformer_rl.run/1`` written before the
model was split into its parts) -> the names of the parts."""


def upgrade_state_dict(state: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """``state`` with the single-module model's names (``RENAMED_PREFIXES``) mapped to the current ones;
    current names are kept as they are."""
    upgraded = {}
    for name, tensor in state.items():
        for old, new in RENAMED_PREFIXES.items():
            if name.startswith(old):
                name = new + name[len(old) :]
                break
        upgraded[name] = tensor
    return upgraded


class NavFormerModel(nn.Module):
    """The parameters of NavFormer (or of an ablation) as three parts, and their composition on tensors.

    - ``dve``: ``DualVisualEncoder`` (f_s, f_g; one encoder for the ablations and the DT baseline);
    - ``transformer``: ``CausalTransformer`` (token embeddings + GPT-2 blocks);
    - ``head``: ``THSCHead`` (``config.thsc``) or ``ObservationHead``; ``BinnedActionHead`` with
      ``config.action_bins``.

    ``forward(target_pixels, pixels, return_to_go, action, step, mask=None, window_steps=None)`` runs
    ``head(transformer(dve(...)))`` -> ``action_pred`` float32 ``[B, T, A]`` in [-1, 1], 0 on padded
    steps. ``make_navformer_actor(model)`` composes the same parts as TensorDict modules (what training
    runs); ``IncrementalNavFormer`` decodes with their parameters. Shapes: see the parts' docstrings.
    """

    def __init__(self, config: NavFormerConfig | None = None) -> None:
        super().__init__()
        self.config = config = config or NavFormerConfig()
        self.dve = DualVisualEncoder.from_config(config)
        tokens = TokenEmbedding.from_config(config)
        self.transformer = CausalTransformer(
            tokens,
            GPT2Blocks.from_config(config),
            config.context_tokens,
            autocast_dtype=config.torch_autocast_dtype,
        )
        self.head: ActionHead | BinnedActionHead = make_head(config)
        tokens.reset_tables()  # drawn last: a seed gives the weights of the RENAMED_PREFIXES layout

    @property
    def static_encoder(self) -> ImageEncoder | None:
        """The DVE's f_s (None when ablated)."""
        return self.dve.static_encoder

    @property
    def general_encoder(self) -> ImageEncoder | None:
        """The DVE's f_g (None when ablated)."""
        return self.dve.general_encoder

    def observation_encoders(self) -> list[tuple[str, ImageEncoder]]:
        """The DVE's ``[(name, encoder)]`` in token order."""
        return self.dve.observation_encoders()

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
        """Predict every step's action of a batch of right-padded trajectories.

        Args:
            target_pixels: uint8 ``[B, H, W, 3]`` (or ``[B, T, H, W, 3]``, constant over T).
            pixels: uint8 ``[B, T, H, W, 3]``.  return_to_go: float ``[B, T, 1]``.
            action: float ``[B, T, A]`` (the actions taken; a_t only feeds predictions of steps > t).
            step: int64 ``[B, T]`` absolute timestep (< ``max_timestep`` on valid steps).
            mask: bool ``[B, T]``, True on valid steps (padding on the right); None = all valid.
            window_steps: see ``CausalTransformer`` (None: plain causal attention).

        Returns:
            action_pred: float32 ``[B, T, A]`` in [-1, 1]; zeros on padded steps.
        """
        if pixels.dim() != 5:
            size = self.config.image_size
            raise ValueError(f"pixels: expected [B, T, {size}, {size}, 3], got {tuple(pixels.shape)}")
        *observations, target = self.dve(pixels, target_pixels, mask)
        hidden = self.transformer(
            target,
            return_to_go,
            action,
            step,
            mask,
            window_steps=window_steps,
            **dict(zip(self.dve.names, observations, strict=True)),
        )
        named = dict(zip(HIDDEN_NAMES, hidden, strict=True))
        return self.head.actions(*(named[name] for name in self.head.reads), mask)
