"""Image encoders' common front-end and the paper's 3-layer CNN encoder (paper §IV.B)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from navformer_rl.modules.models.ops.conv_grad import conv2d_matmul_weight_grad


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


def images_to_float(pixels: Tensor, channels_last: bool = True, dtype: torch.dtype = torch.float32) -> Tensor:
    """uint8 HWC ``[M, H, W, 3]`` -> float NCHW ``[M, 3, H, W]`` in [0, 1], of ``dtype``.

    ``permute`` of an HWC tensor *is* a channels_last NCHW tensor, so with ``channels_last`` no copy
    beyond the dtype conversion happens; otherwise the result is made contiguous (NCHW memory).
    """
    x = pixels.permute(0, 3, 1, 2)
    x = x.to(dtype).mul_(1.0 / 255.0)
    return x if channels_last else x.contiguous()


def compute_dtype(device: torch.device) -> torch.dtype:
    """The dtype convolutions run in on ``device``: the autocast dtype when autocast is on, else float32.

    Converting images straight to it saves the float32 copy autocast would cast again.
    """
    if torch.is_autocast_enabled(device.type):
        return torch.get_autocast_dtype(device.type)
    return torch.float32


def encode_images(encoders: list[ImageEncoder], pixels: Tensor) -> Tensor:
    """Several encoders on the same uint8 images ``[..., H, W, 3]`` -> ``[..., n_encoders, d_out]``.

    Each micro-batch is converted once (``encoders[0].prepare``) and shared by the encoders, which must
    agree on ``input_layout`` (``encoders[0]`` sets the micro-batch size).
    """
    first = encoders[0]
    if any(encoder.input_layout != first.input_layout for encoder in encoders):
        raise ValueError(
            "encode_images: the encoders must share their input layout, got "
            f"{[encoder.input_layout for encoder in encoders]}"
        )
    check_images(pixels, first.image_size)
    lead = pixels.shape[:-3]
    flat = pixels.reshape(-1, first.image_size, first.image_size, 3)
    dtype = compute_dtype(pixels.device)
    outs = []
    for part in flat.split(first.micro_batch or max(flat.shape[0], 1)):
        images = first.prepare(part, dtype)
        outs.append(torch.stack([encoder.encode_nchw(images) for encoder in encoders], dim=1))
    out = outs[0] if len(outs) == 1 else torch.cat(outs)
    return out.reshape(*lead, len(encoders), first.d_out)


def pixels_space_to_depth(pixels: Tensor, block: int = 4) -> Tensor:
    """uint8 HWC ``[M, H, W, 3]`` -> uint8 ``[M, H/b, W/b, b * b * 3]``: each b x b block as channels.

    Channel ``dy * 3b + dx * 3 + c`` of output pixel (i, j) is channel c of input pixel
    (b i + dy, b j + dx). A block row of b pixels is 3b contiguous bytes, moved as 3b/4 int32 words by
    one ``gather`` (2x faster than a permuted copy).
    """
    m, height, width, _ = pixels.shape
    words = pixels.contiguous().view(m, height * width * 3).view(torch.int32)
    order = torch.arange(words.shape[1], device=pixels.device)
    order = order.view(height // block, block, width // block, 3 * block // 4).permute(0, 2, 1, 3).reshape(-1)
    moved = torch.gather(words, 1, order.expand(m, -1))  # [M, (H/b, W/b, dy, (dx, c) as words)]
    return moved.view(torch.uint8).view(m, height // block, width // block, block * block * 3)


class ImageEncoder(nn.Module):
    """Base class: uint8 HWC images of any leading shape -> embeddings ``[..., d_out]``.

    Subclasses implement ``encode_nchw(x) -> [M, d_out]`` on what ``prepare`` (from uint8 HWC) and
    ``prepare_float`` (from float NCHW) produce - float NCHW ``[M, 3, H, W]`` in [0, 1] unless they
    override them. ``forward`` converts in chunks of ``micro_batch`` frames (so no full-batch float copy
    is ever materialised), in the autocast dtype when autocast is on.
    """

    def __init__(self, image_size: int, d_out: int, micro_batch: int | None, channels_last: bool) -> None:
        super().__init__()
        self.image_size = image_size
        self.d_out = d_out
        self.micro_batch = micro_batch
        self.channels_last = channels_last

    @property
    def input_layout(self) -> tuple:
        """What ``prepare`` produces: encoders with equal layouts can share one prepared input."""
        return (type(self).prepare, self.image_size, self.channels_last)

    def prepare(self, pixels: Tensor, dtype: torch.dtype) -> Tensor:
        """uint8 HWC ``[M, H, W, 3]`` -> ``encode_nchw``'s input: float NCHW ``[M, 3, H, W]`` in [0, 1]."""
        return images_to_float(pixels, self.channels_last, dtype)

    def prepare_float(self, images: Tensor, dtype: torch.dtype) -> Tensor:
        """float NCHW ``[M, 3, H, W]`` in [0, 1] -> ``encode_nchw``'s input (at most one copy)."""
        memory_format = torch.channels_last if self.channels_last else torch.contiguous_format
        return images.to(dtype, memory_format=memory_format)

    def encode_nchw(self, x: Tensor) -> Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def forward(self, pixels: Tensor) -> Tensor:
        """pixels: uint8 ``[..., H, W, 3]`` -> float ``[..., d_out]``."""
        return encode_images([self], pixels).squeeze(-2)

    def forward_float(self, images: Tensor) -> Tensor:
        """images: float NCHW ``[M, 3, H, W]`` in [0, 1] (e.g. augmented views) -> ``[M, d_out]``."""
        if images.dim() != 4 or images.shape[1] != 3:
            raise ValueError(f"images: expected float [M, 3, H, W], got {tuple(images.shape)}")
        images = self.prepare_float(images, compute_dtype(images.device))
        chunk = self.micro_batch or max(images.shape[0], 1)
        outs = [self.encode_nchw(part) for part in images.split(chunk)]
        return outs[0] if len(outs) == 1 else torch.cat(outs)


class ConvEncoder(ImageEncoder):
    """The paper's encoder: conv (k8, s4, 32) - ReLU - (k4, s2, 64) - ReLU - (k3, s2, 64) - ReLU - Linear.

    84 x 84 x 3 -> 20 x 20 x 32 -> 9 x 9 x 64 -> 4 x 4 x 64 = 1024 -> Linear -> ``d_out`` (128).
    No activation after the final Linear (the token embedding is linear in the features).

    space_to_depth: feed the first convolution 4 x 4 pixel blocks as 48 channels (21 x 21 x 48) and run
    it as the equivalent 2 x 2 stride-1 convolution whose weights are the 8 x 8 kernel rearranged (same
    parameters, same maths). A 3-channel input starves the convolution's inner dimension; on CPU in bf16
    this makes the training forward + backward of conv1 about 2x faster. Needs ``image_size % 4 == 0``.
    Only uint8 input (``forward``) is rearranged: float input (``forward_float``, the BYOL views) keeps the
    3-channel layout, where a strided float rearrangement would cost more than it saves.

    matmul_weight_grad: when training in bf16 on CPU, compute the last convolution's weight gradient as
    one matmul on its input patches (``conv2d_matmul_weight_grad``; oneDNN's kernel is slow for its 4 x 4
    output map). Same maths; off, or on other devices and dtypes, ``nn.Conv2d`` runs.
    """

    def __init__(
        self,
        d_out: int = 128,
        image_size: int = 84,
        micro_batch: int | None = None,
        channels_last: bool = True,
        space_to_depth: bool = False,
        matmul_weight_grad: bool = True,
    ) -> None:
        super().__init__(image_size, d_out, micro_batch, channels_last)
        self.matmul_weight_grad = matmul_weight_grad
        if space_to_depth and image_size % 4:
            raise ValueError(f"ConvEncoder: space_to_depth needs image_size % 4 == 0, got {image_size}")
        self.space_to_depth = space_to_depth
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

    @property
    def input_layout(self) -> tuple:
        return (*super().input_layout, self.space_to_depth)

    def prepare(self, pixels: Tensor, dtype: torch.dtype) -> Tensor:
        """uint8 HWC ``[M, H, W, 3]`` -> float ``[M, 3, H, W]``,
        or ``[M, 48, H/4, W/4]`` with space_to_depth."""
        if not self.space_to_depth:
            return super().prepare(pixels, dtype)
        return pixels_space_to_depth(pixels).permute(0, 3, 1, 2).to(dtype).mul_(1.0 / 255.0)

    def encode_nchw(self, x: Tensor) -> Tensor:
        """x: float ``[M, 3, H, W]``, or its space-to-depth form ``[M, 48, H/4, W/4]`` -> ``[M, d_out]``."""
        conv1 = self.convs[0]
        if x.dim() != 4 or x.shape[1] not in (3, 48):
            raise ValueError(f"x: expected float [M, 3, H, W] or [M, 48, H/4, W/4], got {tuple(x.shape)}")
        if x.shape[1] == 3:
            x = conv1(x)
        else:  # kernel (o, c, 4 by + dy, 4 bx + dx) -> (o, (dy, dx, c), by, bx)
            weight = conv1.weight.view(32, 3, 2, 4, 2, 4).permute(0, 3, 5, 1, 2, 4).reshape(32, 48, 2, 2)
            x = nn.functional.conv2d(x, weight, conv1.bias)
        x = self.convs[1:4](x)  # ReLU, conv2, ReLU
        conv3 = self.convs[4]
        if self._use_matmul_weight_grad(x):
            x = conv2d_matmul_weight_grad(x, conv3.weight, conv3.bias, conv3.stride[0])
        else:
            x = conv3(x)
        return self.linear(self.convs[5](x).flatten(1))

    def _use_matmul_weight_grad(self, x: Tensor) -> bool:
        return (
            self.matmul_weight_grad
            and x.device.type == "cpu"
            and x.dtype == torch.bfloat16
            and torch.is_grad_enabled()
            and self.convs[4].weight.requires_grad
        )
