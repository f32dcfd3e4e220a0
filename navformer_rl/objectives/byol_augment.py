"""BYOL image augmentations (paper §IV.B: random resizing, cropping, colour jittering) with kornia."""

from __future__ import annotations

import math

import torch
from kornia.enhance import (
    adjust_brightness_accumulative,
    adjust_contrast_with_mean_subtraction,
    adjust_hue,
    adjust_saturation_with_gray_subtraction,
)
from kornia.geometry.transform import crop_and_resize
from torch import Tensor, nn

from navformer_rl.modules.models.cnn import check_images, images_to_float

_CROP_TRIES = 10  # torchvision / kornia RandomResizedCrop: tries before falling back to the whole image


_COLOUR_OPS = {  # the ops of kornia.augmentation.ColorJitter, factors per sample
    "brightness": adjust_brightness_accumulative,
    "contrast": adjust_contrast_with_mean_subtraction,
    "saturation": adjust_saturation_with_gray_subtraction,
    "hue": lambda image, turns: adjust_hue(image, turns * 2 * math.pi),
}


class BYOLAugmentation(nn.Module):
    """uint8 HWC ``[B, H, W, 3]`` -> augmented float NCHW ``[B, 3, H, W]`` in [0, 1], on the input's device.

    Pipeline, parameters drawn per sample, every op one batched kornia call:

    1. random resized crop (torchvision's ``RandomResizedCrop`` sampling: area fraction in ``scale``,
       log-uniform aspect ratio in ``ratio``, up to 10 tries per sample, else the whole image; integer box
       at a uniform position) resampled bilinearly to ``H x H`` by ``kornia.geometry.crop_and_resize``;
    2. with probability ``jitter_p`` per sample, colour jitter (the ``kornia.augmentation.ColorJitter``
       ops: brightness factor in ``[1 - b, 1 + b]`` multiplicative, contrast ``[1 - c, 1 + c]`` around the
       grey mean, saturation ``[1 - s, 1 + s]`` blended with grey, hue shift in ``[-h, h]`` turns), in an
       order drawn once per call as kornia does; samples without jitter get the neutral factors.

    Seeding: the module owns a CPU ``torch.Generator`` (``seed``) and draws every parameter from it (then
    moves them to the batch's device), so results are reproducible and the global RNG is untouched.
    Defaults follow BYOL's view 1 (colour jitter 0.4/0.4/0.2, p = 0.8) with a crop scale of [0.3, 1]
    instead of [0.08, 1] (84 px navigation views) and hue 0: kornia's hue shift goes through HSV and
    costs more than the other three ops together (see ``docs/model.md``). ``chunk``: images per pass on
    the CPU (32 keeps the elementwise passes in cache); other devices take the batch in one pass.
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
        chunk: int = 32,
    ) -> None:
        super().__init__()
        if not (0.0 < scale[0] <= scale[1] <= 1.0):
            raise ValueError(f"scale={scale!r}: expected 0 < low <= high <= 1")
        if not (0.0 < ratio[0] <= ratio[1]):
            raise ValueError(f"ratio={ratio!r}: expected 0 < low <= high")
        if chunk < 1:
            raise ValueError(f"chunk={chunk!r}: expected a positive number of images")
        if not 0.0 <= jitter_p <= 1.0:
            raise ValueError(f"jitter_p={jitter_p!r}: expected a probability in [0, 1]")
        for name, value in (("brightness", brightness), ("contrast", contrast), ("saturation", saturation)):
            if not value >= 0.0:
                raise ValueError(f"{name}={value!r}: expected a jitter strength >= 0")
        if not 0.0 <= hue <= 0.5:
            raise ValueError(f"hue={hue!r}: expected a value in [0, 0.5]")
        self.image_size = image_size
        self.scale = scale
        self.log_ratio = (math.log(ratio[0]), math.log(ratio[1]))
        self.jitter = {"brightness": brightness, "contrast": contrast, "saturation": saturation, "hue": hue}
        self.jitter_p = jitter_p if max(self.jitter.values()) > 0 else 0.0
        self.chunk = chunk
        self.generator = torch.Generator().manual_seed(seed)

    def _uniform(self, n: int, low: float, high: float, tries: int = 1) -> Tensor:
        shape = (n,) if tries == 1 else (n, tries)
        return torch.rand(shape, generator=self.generator) * (high - low) + low

    def crop_boxes(self, n: int) -> Tensor:
        """``n`` crop boxes ``[n, 4, 2]`` (x, y corners: top-left, top-right, bottom-right, bottom-left)."""
        size = self.image_size
        area = self._uniform(n, *self.scale, tries=_CROP_TRIES) * size * size
        aspect = torch.exp(self._uniform(n, *self.log_ratio, tries=_CROP_TRIES))
        width = torch.sqrt(area * aspect).round()
        height = torch.sqrt(area / aspect).round()
        valid = (width >= 1) & (width <= size) & (height >= 1) & (height <= size)
        first = valid.to(torch.uint8).argmax(dim=1, keepdim=True)  # first valid try (0 if none)
        found = valid.any(dim=1)
        width = torch.where(found, width.gather(1, first).squeeze(1), torch.full((n,), float(size)))
        height = torch.where(found, height.gather(1, first).squeeze(1), torch.full((n,), float(size)))
        # integer offsets uniform in [0, size - extent]
        x0 = (torch.rand(n, generator=self.generator) * (size - width + 1)).floor()
        y0 = (torch.rand(n, generator=self.generator) * (size - height + 1)).floor()
        x1, y1 = x0 + width - 1, y0 + height - 1
        return torch.stack(
            [
                torch.stack([x0, y0], -1),
                torch.stack([x1, y0], -1),
                torch.stack([x1, y1], -1),
                torch.stack([x0, y1], -1),
            ],
            dim=1,
        )

    def jitter_factors(self, n: int) -> dict[str, Tensor]:
        """Per-sample colour factors ``{name: [n]}``; samples drawn without jitter get the neutral factor."""
        applied = torch.rand(n, generator=self.generator) < self.jitter_p
        factors = {}
        for name, strength in self.jitter.items():
            neutral = 0.0 if name == "hue" else 1.0
            low, high = (-strength, strength) if name == "hue" else (max(0.0, 1 - strength), 1 + strength)
            drawn = self._uniform(n, low, high)
            factors[name] = torch.where(applied, drawn, torch.full((n,), neutral))
        return factors

    def forward(
        self, pixels: Tensor, dtype: torch.dtype = torch.float32, channels_last: bool = False
    ) -> Tensor:
        """pixels: uint8 ``[B, H, W, 3]`` -> views ``[B, 3, H, W]`` of ``dtype`` (channels_last memory if
        asked).

        The views are computed in float32 chunk by chunk and written straight into the output's dtype and
        layout, so an encoder running in bf16 / channels_last needs no further conversion pass.
        """
        check_images(pixels, self.image_size)
        if pixels.dim() != 4:
            raise ValueError(
                f"pixels: expected [B, {self.image_size}, {self.image_size}, 3], got {tuple(pixels.shape)}"
            )
        n = pixels.shape[0]
        boxes = self.crop_boxes(n).to(pixels.device)
        factors = {k: v.to(pixels.device) for k, v in self.jitter_factors(n).items()}
        active = [name for name, strength in self.jitter.items() if strength > 0 and self.jitter_p > 0]
        order = [active[i] for i in torch.randperm(len(active), generator=self.generator).tolist()]
        size = self.image_size
        memory_format = torch.channels_last if channels_last else torch.contiguous_format
        views = torch.empty(n, 3, size, size, dtype=dtype, device=pixels.device, memory_format=memory_format)
        # CPU: chunks keep the ~10 elementwise passes in cache; a GPU takes the batch in one pass (a chunk
        # would only add kernel launches). The views do not depend on the chunk size.
        step = self.chunk if pixels.device.type == "cpu" else max(n, 1)
        for start in range(0, n, step):
            part = slice(start, start + step)
            chunk = images_to_float(pixels[part], channels_last=False)
            chunk = crop_and_resize(chunk, boxes[part], (size, size), mode="bilinear", align_corners=True)
            for name in order:
                chunk = _COLOUR_OPS[name](chunk, factors[name][part])
            views[part] = chunk.clamp_(0.0, 1.0)
        return views

    def rng_state(self) -> Tensor:
        """The generator state (uint8 tensor), for checkpoints."""
        return self.generator.get_state()

    def set_rng_state(self, state: Tensor) -> None:
        """Restore a state returned by ``rng_state``."""
        self.generator.set_state(state)
