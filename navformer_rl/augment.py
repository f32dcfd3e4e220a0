"""BYOL image augmentations (paper §IV.B: random resizing, cropping, colour jittering) with kornia."""

from __future__ import annotations

import kornia.augmentation as K
import torch
from torch import Tensor, nn

from navformer_rl.modules.models.cnn import check_images, images_to_float


class BYOLAugmentation(nn.Module):
    """uint8 HWC ``[B, H, W, 3]`` -> augmented float NCHW ``[B, 3, H, W]`` in [0, 1], on the input's device.

    Pipeline (kornia, parameters drawn per sample): ``RandomResizedCrop(size=H, scale, ratio)`` then, with
    probability ``jitter_p``, ``ColorJitter(brightness, contrast, saturation, hue)``.

    Seeding: the module owns a ``torch.Generator`` (``seed``); each call draws a seed from it and runs
    kornia inside ``torch.random.fork_rng`` seeded with it, so results are reproducible and the global
    RNG is left untouched. Defaults follow BYOL's view 1 (colour jitter 0.4/0.4/0.2, p = 0.8) with a crop
    scale of [0.3, 1] instead of [0.08, 1] (84 px navigation views) and hue 0: kornia's hue shift costs
    about 2.5 ms per 84x84 image on one CPU core (see ``docs/model.md``).
    """

    def __init__(
        self,
        image_size: int = 84,
        scale: tuple[float, float] = (0.3, 1.0),
        ratio: tuple[float, float] = (3.0 / 4.0, 4.0 / 3.0),
        brightness: float = 0.4,
        contrast: float = 0.4,
        saturation: float = 0.2,
        hue: float = 0.0,
        jitter_p: float = 0.8,
        seed: int = 0,
    ) -> None:
        super().__init__()
        if not (0.0 < scale[0] <= scale[1] <= 1.0):
            raise ValueError(f"scale={scale!r}: expected 0 < low <= high <= 1")
        if not 0.0 <= jitter_p <= 1.0:
            raise ValueError(f"jitter_p={jitter_p!r}: expected a probability in [0, 1]")
        self.image_size = image_size
        self.crop = K.RandomResizedCrop((image_size, image_size), scale=scale, ratio=ratio)
        self.jitter = (
            K.ColorJitter(brightness, contrast, saturation, hue, p=jitter_p)
            if max(brightness, contrast, saturation, hue) > 0 and jitter_p > 0
            else None
        )
        self.generator = torch.Generator().manual_seed(seed)

    def forward(self, pixels: Tensor) -> Tensor:
        check_images(pixels, self.image_size)
        if pixels.dim() != 4:
            raise ValueError(
                f"pixels: expected [B, {self.image_size}, {self.image_size}, 3], got {tuple(pixels.shape)}"
            )
        images = images_to_float(pixels, channels_last=False)
        call_seed = int(torch.randint(0, 2**62, (1,), generator=self.generator))
        devices = [pixels.device] if pixels.device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            torch.manual_seed(call_seed)
            views = self.crop(images)
            if self.jitter is not None:
                views = self.jitter(views)
        return views

    def rng_state(self) -> Tensor:
        """The generator state (uint8 tensor), for checkpoints."""
        return self.generator.get_state()

    def set_rng_state(self, state: Tensor) -> None:
        """Restore a state returned by ``rng_state``."""
        self.generator.set_state(state)
