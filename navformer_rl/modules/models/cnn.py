"""Image encoders' common front-end and the paper's 3-layer CNN encoder (paper §IV.B)."""

from __future__ import annotations

import torch
from torch import Tensor, nn


def check_images(pixels: Tensor, image_size: int, name: str = "pixels") -> None:
    """Raise ``ValueError`` unless ``pixels`` is uint8 ``[..., image_size, image_size, 3]`` (HWC)."""
    if not isinstance(pixels, Tensor):
        raise ValueError(f"{name}: expected a torch.Tensor, got {type(pixels).__name__}")
    if pixels.dtype != torch.uint8:
        raise ValueError(f"{name}: expected dtype uint8 (HWC images), got {pixels.dtype}")
    if pixels.dim() < 3 or tuple(pixels.shape[-3:]) != (image_size, image_size, 3):
        raise ValueError(
            f"{name}: expected shape [..., {image_size}, {image_size}, 3], got {tuple(pixels.shape)}"
        )


def images_to_float(pixels: Tensor, channels_last: bool = True) -> Tensor:
    """uint8 HWC ``[M, H, W, 3]`` -> float32 NCHW ``[M, 3, H, W]`` in [0, 1].

    ``permute`` of an HWC tensor *is* a channels_last NCHW tensor, so with ``channels_last`` no copy
    beyond the dtype conversion happens; otherwise the result is made contiguous (NCHW memory).
    """
    x = pixels.permute(0, 3, 1, 2)
    x = x.to(torch.float32).div_(255.0)
    return x if channels_last else x.contiguous()


class ImageEncoder(nn.Module):
    """Base class: uint8 HWC images of any leading shape -> embeddings ``[..., d_out]``.

    Subclasses implement ``encode_nchw(x: float [M, 3, H, W]) -> [M, d_out]``. ``forward`` converts
    uint8 HWC to float NCHW (channels_last) and runs ``encode_nchw`` in chunks of ``micro_batch`` frames
    (conversion included, so no full-batch float copy is ever materialised).
    """

    def __init__(self, image_size: int, d_out: int, micro_batch: int | None, channels_last: bool) -> None:
        super().__init__()
        self.image_size = image_size
        self.d_out = d_out
        self.micro_batch = micro_batch
        self.channels_last = channels_last

    def encode_nchw(self, x: Tensor) -> Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def forward(self, pixels: Tensor) -> Tensor:
        """pixels: uint8 ``[..., H, W, 3]`` -> float ``[..., d_out]``."""
        check_images(pixels, self.image_size)
        lead = pixels.shape[:-3]
        flat = pixels.reshape(-1, self.image_size, self.image_size, 3)
        chunk = self.micro_batch or max(flat.shape[0], 1)
        outs = [self.encode_nchw(images_to_float(part, self.channels_last)) for part in flat.split(chunk)]
        out = outs[0] if len(outs) == 1 else torch.cat(outs)
        return out.reshape(*lead, self.d_out)

    def forward_float(self, images: Tensor) -> Tensor:
        """images: float NCHW ``[M, 3, H, W]`` in [0, 1] (e.g. augmented views) -> ``[M, d_out]``."""
        if images.dim() != 4 or images.shape[1] != 3:
            raise ValueError(f"images: expected float [M, 3, H, W], got {tuple(images.shape)}")
        if self.channels_last:
            images = images.contiguous(memory_format=torch.channels_last)
        chunk = self.micro_batch or max(images.shape[0], 1)
        outs = [self.encode_nchw(part) for part in images.split(chunk)]
        return outs[0] if len(outs) == 1 else torch.cat(outs)


class ConvEncoder(ImageEncoder):
    """The paper's encoder: conv (k8, s4, 32) - ReLU - (k4, s2, 64) - ReLU - (k3, s2, 64) - ReLU - Linear.

    84 x 84 x 3 -> 20 x 20 x 32 -> 9 x 9 x 64 -> 4 x 4 x 64 = 1024 -> Linear -> ``d_out`` (128).
    No activation after the final Linear (the token embedding is linear in the features).
    """

    def __init__(
        self,
        d_out: int = 128,
        image_size: int = 84,
        micro_batch: int | None = None,
        channels_last: bool = True,
    ) -> None:
        super().__init__(image_size, d_out, micro_batch, channels_last)
        self.convs = nn.Sequential(
            nn.Conv2d(3, 32, kernel_size=8, stride=4),
            nn.ReLU(inplace=True),
            nn.Conv2d(32, 64, kernel_size=4, stride=2),
            nn.ReLU(inplace=True),
            nn.Conv2d(64, 64, kernel_size=3, stride=2),
            nn.ReLU(inplace=True),
        )
        side = image_size
        for kernel, stride in ((8, 4), (4, 2), (3, 2)):
            side = (side - kernel) // stride + 1
        self.linear = nn.Linear(64 * side * side, d_out)

    def encode_nchw(self, x: Tensor) -> Tensor:
        """x: float ``[M, 3, H, W]`` -> ``[M, d_out]``."""
        return self.linear(self.convs(x).flatten(1))
