"""``DualVisualEncoder`` (DVE, paper §IV.B): the static encoder f_s and the general encoder f_g."""

from __future__ import annotations

import contextlib

import torch
from torch import Tensor, nn

from navformer_rl.modules.models.cnn import ConvEncoder, ImageEncoder, check_images, encode_images
from navformer_rl.modules.models.config import NavFormerConfig, autocast
from navformer_rl.modules.models.resnet import ResNet18Encoder

ENCODER_NAMES = ("static", "general")
"""The DVE's encoders in token order: f_s (static embeddings e^s), f_g (general embeddings e^ca)."""


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


class DualVisualEncoder(nn.Module):
    """f_s and f_g on the observation frames, f_g on the target image (f_s when f_g is absent).

    ``forward(pixels, target_pixels, mask=None)`` returns one embedding per encoder in use, in the order of
    ``names`` (``("static", "general")`` for NavFormer), then the target embedding e_g:

    - pixels: uint8 ``[..., H, W, 3]`` (``[B, T, H, W, 3]`` for trajectories) -> e^s, e^ca ``[..., d]``;
    - target_pixels: uint8 ``[B, H, W, 3]`` or ``[B, T, H, W, 3]`` -> e_g ``[B, d]`` or ``[B, T, d]``
      (a target expanded over T, stride 0, is encoded once and the embedding expanded);
    - mask: optional bool ``[...]`` (pixels' leading shape), True on valid frames: only those are encoded,
      padded frames get zero embeddings.

    The ablations are DVEs with one encoder (w/o f_s, w/o f_g, the DT baseline, ResNet18 in the DVE's
    place). Both encoders share each micro-batch's uint8 -> float conversion (``encode_images``).

    Args:
        static_encoder / general_encoder: f_s / f_g (None to drop one; at least one is needed).
        detach: encode under ``no_grad`` (losses downstream neither reach nor record the encoders).
        autocast_dtype: autocast dtype of ``forward`` (None: float32).
    """

    def __init__(
        self,
        static_encoder: ImageEncoder | None = None,
        general_encoder: ImageEncoder | None = None,
        *,
        detach: bool = False,
        autocast_dtype: torch.dtype | None = None,
    ) -> None:
        super().__init__()
        if static_encoder is None and general_encoder is None:
            raise ValueError("DualVisualEncoder: expected at least one of static_encoder / general_encoder")
        self.static_encoder = static_encoder
        self.general_encoder = general_encoder
        self.detach = detach
        self.autocast_dtype = autocast_dtype

    @classmethod
    def from_config(cls, config: NavFormerConfig) -> DualVisualEncoder:
        """The DVE of ``config``: fresh encoders of ``config.encoder`` kind where ``use_*_encoder`` is set."""
        return cls(
            make_encoder(config) if config.use_static_encoder else None,
            make_encoder(config) if config.use_general_encoder else None,
            detach=config.detach_encoders,
            autocast_dtype=config.torch_autocast_dtype,
        )

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the encoders in use, in token order (a subset of ``ENCODER_NAMES``)."""
        return tuple(name for name, _ in self.observation_encoders())

    def observation_encoders(self) -> list[tuple[str, ImageEncoder]]:
        """``[("static", f_s), ("general", f_g)]`` restricted to the encoders in use, in token order."""
        pairs = [("static", self.static_encoder), ("general", self.general_encoder)]
        return [(name, encoder) for name, encoder in pairs if encoder is not None]

    @property
    def target_encoder(self) -> ImageEncoder:
        """f_g (f_s when f_g is ablated)."""
        return self.general_encoder if self.general_encoder is not None else self.static_encoder

    def _grad(self) -> contextlib.AbstractContextManager:
        return torch.no_grad() if self.detach else contextlib.nullcontext()

    def encode_target(self, target_pixels: Tensor) -> Tensor:
        """target_pixels: uint8 ``[..., H, W, 3]`` -> target embedding e_g ``[..., d]``."""
        with self._grad():
            if target_pixels.dim() >= 5 and target_pixels.shape[1] > 1 and target_pixels.stride(1) == 0:
                embedding = self.target_encoder(target_pixels[:, 0])
                return embedding.unsqueeze(1).expand(-1, target_pixels.shape[1], -1)
            return self.target_encoder(target_pixels)

    def encode_observations(self, pixels: Tensor, mask: Tensor | None = None) -> Tensor:
        """pixels: uint8 ``[..., H, W, 3]`` -> ``[..., n_encoders, d]`` (in the order of ``names``).

        mask: optional bool ``[...]``: only valid frames are encoded, padded ones get zero embeddings (they
        only feed padded tokens, which no valid token attends).
        """
        encoders = [encoder for _, encoder in self.observation_encoders()]
        with self._grad():
            if mask is None or bool(mask.all()):
                return encode_images(encoders, pixels)
            embedding = encode_images(encoders, pixels[mask])
            return embedding.new_zeros(*mask.shape, *embedding.shape[1:]).index_put((mask,), embedding)

    def forward(
        self, pixels: Tensor, target_pixels: Tensor, mask: Tensor | None = None
    ) -> tuple[Tensor, ...]:
        """-> ``(*one [..., d] embedding per name in names, e_g)`` (see the class docstring)."""
        self._check_inputs(pixels, target_pixels, mask)
        with autocast(pixels.device, self.autocast_dtype):
            target = self.encode_target(target_pixels)
            observations = self.encode_observations(pixels, mask)
        return (*observations.unbind(-2), target)

    def _check_inputs(self, pixels: Tensor, target_pixels: Tensor, mask: Tensor | None) -> None:
        size = self.target_encoder.image_size
        check_images(pixels, size, "pixels")
        check_images(target_pixels, size, "target_pixels")
        lead, target_lead = tuple(pixels.shape[:-3]), tuple(target_pixels.shape[:-3])
        if target_lead not in (lead, lead[:-1]) or not target_lead:
            raise ValueError(
                f"target_pixels: expected leading shape {list(lead)} or {list(lead[:-1])} (one target per "
                f"trajectory) for pixels of shape {tuple(pixels.shape)}, got {tuple(target_pixels.shape)}"
            )
        if mask is not None and (mask.dtype != torch.bool or tuple(mask.shape) != lead):
            raise ValueError(f"mask: expected bool {list(lead)}, got {mask.dtype} {list(mask.shape)}")
