"""``NavFormerModel``: the DVE, the causal transformer and the action head of one config (paper §IV)."""

from __future__ import annotations

from torch import Tensor, nn

from navformer_rl.modules.models.cnn import ImageEncoder
from navformer_rl.modules.models.config import NavFormerConfig
from navformer_rl.modules.models.dve import DualVisualEncoder
from navformer_rl.modules.models.heads import (
    ActionHead,
    BinnedActionHead,
    ObservationHead,
    THSCHead,
    make_head,
)
from navformer_rl.modules.models.transformer import CausalTransformer, init_embedding_tables


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
        # The initialisation order, fixed here once (tested: a seed gives the weights it always gave): each
        # part draws PyTorch's default inits as it is built, then the embedding tables get GPT-2's N(0, 0.02).
        self.dve = DualVisualEncoder.from_config(config)
        self.transformer = CausalTransformer.from_config(config)
        self.head: ActionHead | BinnedActionHead = make_head(config)
        self.apply(init_embedding_tables)

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
        # e^s_t, e^ca_t [B, T, d] (the encoders in use: dve.names), e_g [B, d]
        *observations, e_g = self.dve(pixels, target_pixels, mask)
        # the token sequence (g, R_1, e^s_1, e^ca_1, a_1, ...) through the GPT-2 blocks -> h_g, h_o [B, T, d]
        h_g, h_o, _ = self.transformer(
            e_g,
            return_to_go,
            action,
            step,
            mask,
            window_steps=window_steps,
            **dict(zip(self.dve.names, observations, strict=True)),
        )
        if self.head.reads == THSCHead.reads:  # THSC: a-hat_t = tanh(W [h_g ; h^ca_{o,t}] + b)
            return self.head.actions(h_g, h_o, mask)
        if self.head.reads == ObservationHead.reads:  # w/o THSC, DT: a-hat_t = tanh(W h_{o,t} + b)
            return self.head.actions(h_o, mask)
        raise ValueError(
            f"NavFormerModel.forward feeds its head h_g and h_o; {type(self.head).__name__} reads "
            f"{self.head.reads}: compose it after transformer_module (navformer_rl.modules.actors)"
        )
