"""Inference helper: the static and general CNN encoders run as one fused convolution stack."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor, nn

from navformer_rl.modules.decoding.derived import DerivedCache
from navformer_rl.modules.models.cnn import ConvEncoder, check_images, images_to_float
from navformer_rl.modules.models.ops.conv_grad import im2col_view

KERNELS = (8, 4, 3)
"""Kernel sizes of ``ConvEncoder``'s three convolutions."""
STRIDES = (4, 2, 2)
"""Strides of ``ConvEncoder``'s three convolutions."""
GROUPS = (1, 2, 2)
"""Groups of the fused convolutions: conv1 runs both filter banks on the same image, conv2/conv3 one each."""


class FusedWeights(NamedTuple):
    """Both encoders' parameters laid out for the two fused paths.

    conv path: ``conv = ((weight [G*O, C, k, k], bias [G*O]), ...)`` per conv layer, both filter banks
    concatenated; ``linear = (weight [2, C*h*w, d], bias [2, 1, d])``, the two Linear layers.
    im2col path: ``gemm_conv = ((weight [G, k*k*C, O], bias [G, 1, O]), ...)`` per conv layer, rows in
    (kh, kw, c) order (conv1's weight divided by 255: it reads raw pixel values); ``gemm_linear =
    (weight [2, h*w*C, d], bias [2, 1, d])``, rows in (h, w, c) order.
    """

    conv: tuple[tuple[Tensor, Tensor], ...]
    linear: tuple[Tensor, Tensor]
    gemm_conv: tuple[tuple[Tensor, Tensor], ...]
    gemm_linear: tuple[Tensor, Tensor]


class FusedConvEncoders:
    """Inference helper: two ``ConvEncoder``s on the same images as one grouped convolution stack.

    ``fused(pixels u8 [B, H, W, 3]) -> [B, 2, d_out]`` equals ``stack([first(pixels), second(pixels)], 1)``
    (same maths, half the kernel launches): conv1 with both filter banks, conv2/conv3 with ``groups=2``,
    and one batched matmul for the two Linear layers. Two paths, picked by the number of images ``M``:

    - ``M <= gemm_max_batch`` (default 4): im2col on channels_last views (``unfold``, one copy per layer
      into a scratch buffer kept for the next call, about 1 MB per image) and one batched matmul per layer.
      At batch 1 the oneDNN convolutions cost 150-250 us each, mostly per-call overhead; this path takes
      about half as long in all.
    - larger batches: ``conv2d`` (oneDNN, channels_last), which is faster there.

    The fused weights are rebuilt whenever a parameter of either encoder changes (in-place updates bump
    ``Tensor._version``; ``.data`` swaps such as ``model.to`` change ``data_ptr``; ``derived.parameter_key``
    lists what is not seen: ``p.data`` writes, fused optimizers). A layer replaced by a new module is not
    followed: make a new helper then.
    No autograd: call it under ``torch.no_grad()``.
    """

    def __init__(self, first: ConvEncoder, second: ConvEncoder, gemm_max_batch: int = 4) -> None:
        if not (isinstance(first, ConvEncoder) and isinstance(second, ConvEncoder)):
            raise ValueError("FusedConvEncoders: expected two ConvEncoder instances")
        if (first.image_size, first.d_out) != (second.image_size, second.d_out):
            raise ValueError("FusedConvEncoders: the encoders must have the same image_size and d_out")
        if gemm_max_batch < 0:
            raise ValueError(f"gemm_max_batch={gemm_max_batch!r}: expected a non-negative int")
        self.encoders = (first, second)
        self.gemm_max_batch = gemm_max_batch
        # gathered once: ``nn.Module`` attribute access costs ~2 us, more than the check itself
        params = (
            tensor
            for encoder in self.encoders
            for layer in (encoder.convs[0], encoder.convs[2], encoder.convs[4], encoder.linear)
            for tensor in (layer.weight, layer.bias)
        )
        self._weights = DerivedCache(params)
        self._plans: dict[tuple, GemmPlan] = {}

    def _build_weights(self) -> FusedWeights:
        first, second = self.encoders
        conv = tuple(
            (torch.cat([first.convs[i].weight, second.convs[i].weight]),
             torch.cat([first.convs[i].bias, second.convs[i].bias]))
            for i in (0, 2, 4)
        )  # fmt: skip
        linear_bias = torch.stack([first.linear.bias, second.linear.bias])[:, None]  # [2, 1, d]
        linear = (torch.stack([first.linear.weight.T, second.linear.weight.T]), linear_bias)  # [2, 1024, d]
        # conv1 reads raw uint8 values in the im2col path: images_to_float's 1/255 goes into its weight
        gemm_conv = tuple(
            (gemm_conv_weight(weight, groups, scale), bias.view(groups, 1, -1))
            for (weight, bias), groups, scale in zip(conv, GROUPS, (1 / 255, 1.0, 1.0))
        )
        channels = conv[-1][0].shape[0] // 2
        hwc_linear = torch.stack([hwc_linear_weight(e.linear.weight, channels) for e in self.encoders])
        return FusedWeights(conv, linear, gemm_conv, (hwc_linear, linear_bias))

    def __call__(self, pixels: Tensor) -> Tensor:
        """pixels: uint8 ``[..., H, W, 3]`` -> ``[M, 2, d_out]`` (M = number of images)."""
        size = self.encoders[0].image_size
        check_images(pixels, size)
        pixels = pixels.reshape(-1, size, size, 3)
        weights = self._weights.get(self._build_weights)
        if pixels.shape[0] <= self.gemm_max_batch:
            return self._gemm_stack(pixels, weights)
        return self._conv_stack(pixels, weights)

    def _conv_stack(self, pixels: Tensor, weights: FusedWeights) -> Tensor:
        """uint8 ``[M, H, W, 3]`` -> ``[M, 2, d]`` through ``conv2d`` (grouped) and a batched matmul."""
        x = images_to_float(pixels, self.encoders[0].channels_last)
        for (weight, bias), stride, groups in zip(weights.conv, STRIDES, GROUPS):
            x = torch.relu(nn.functional.conv2d(x, weight, bias, stride=stride, groups=groups))
        x = x.reshape(x.shape[0], 2, -1).transpose(0, 1)  # [2, M, 1024]
        linear_weight, linear_bias = weights.linear
        return torch.baddbmm(linear_bias, x, linear_weight).transpose(0, 1)  # [M, 2, d]

    def _gemm_stack(self, pixels: Tensor, weights: FusedWeights) -> Tensor:
        """uint8 ``[M, H, W, 3]`` -> ``[M, 2, d]`` through im2col and one batched matmul per layer.

        The images, patches and activations live in buffers kept between calls (``GemmPlan``; allocating
        them afresh costs more than the copies themselves: glibc serves blocks this size with mmap, page
        faults included), and every view between them is made once, so a call is one copy per layer, its
        matmul and ReLU, and the Linear layers' matmul.
        """
        plan = self._plan(pixels.shape[0], weights, pixels.device)
        # converted first: conv1's im2col copies float -> float 1.5x faster than from uint8
        plan.pixels.copy_(pixels)
        layers = zip(plan.patches, plan.patch_copies, plan.patch_rows, plan.outputs, weights.gemm_conv)
        for patches, patch_copy, patch_rows, output, (weight, bias) in layers:
            patch_copy.copy_(patches)
            torch.baddbmm(bias, patch_rows, weight, out=output).clamp_min_(0.0)
        linear_weight, linear_bias = weights.gemm_linear
        return torch.baddbmm(linear_bias, plan.features, linear_weight).transpose(0, 1)  # [M, 2, d]

    def _plan(self, images: int, weights: FusedWeights, device: torch.device) -> GemmPlan:
        """The ``GemmPlan`` for ``images`` images on ``device`` (made on first use, then reused).

        Allocated outside inference mode: an inference tensor could not be written by a later call made
        under plain ``no_grad``.
        """
        key = (images, device)
        plan = self._plans.get(key)
        if plan is None:
            self._plans[key] = plan = make_gemm_plan(images, self.encoders[0].image_size, weights, device)
        return plan


class GemmPlan(NamedTuple):
    """Buffers of the im2col path for ``M`` images, with every view between them made once.

    pixels ``[M, H, W, 3]`` float (the images, converted); per conv layer: patches ``[G, M, S, S, k, k, C]``
    (a view of the layer's input), patch_copies (the same shape, a view of the patch buffer), patch_rows
    ``[G, M * S * S, k * k * C]`` (the patch buffer as matrices), outputs ``[G, M * S * S, O]``; features
    ``[2, M, S * S * O]`` (the last output in (h, w, c) order, the Linear layers' input).
    """

    pixels: Tensor
    patches: tuple[Tensor, ...]
    patch_copies: tuple[Tensor, ...]
    patch_rows: tuple[Tensor, ...]
    outputs: tuple[Tensor, ...]
    features: Tensor


def make_gemm_plan(images: int, size: int, weights: FusedWeights, device: torch.device) -> GemmPlan:
    """Allocate a ``GemmPlan`` for ``images`` images of ``size`` x ``size`` pixels
    (outside inference mode)."""
    with torch.inference_mode(False), torch.no_grad():
        pixels = torch.empty(1, images, size, size, 3, device=device)  # [G=1, M, H, W, C]
        x, patches, copies, rows, outputs = pixels, [], [], [], []
        for (weight, _), kernel, stride in zip(weights.gemm_conv, KERNELS, STRIDES):
            groups, features, channels = weight.shape
            if x.shape[0] != groups:  # conv1's 2 * 32 channels -> 2 groups of 32 (a view)
                x = x[0].unflatten(-1, (groups, -1)).permute(3, 0, 1, 2, 4)
            layer_patches = im2col_view(x, kernel, stride)  # [G, M, S, S, k, k, C]
            buffer = torch.empty(layer_patches.shape, device=device)
            output = torch.empty(groups, buffer[0].numel() // features, channels, device=device)
            patches.append(layer_patches)
            copies.append(buffer)
            rows.append(buffer.view(groups, -1, features))
            outputs.append(output)
            x = output.view(*layer_patches.shape[:4], -1)
        return GemmPlan(pixels[0], *map(tuple, (patches, copies, rows, outputs)), x.flatten(2))


def gemm_conv_weight(weight: Tensor, groups: int, scale: float = 1.0) -> Tensor:
    """Conv weight ``[G * O, C, k, k]`` -> ``scale *`` it as ``[G, k * k * C, O]``
    (rows in (kh, kw, c) order)."""
    out_channels, in_channels, kernel, _ = weight.shape
    grouped = weight.view(groups, out_channels // groups, in_channels, kernel, kernel)
    return (grouped.permute(0, 3, 4, 2, 1) * scale).reshape(groups, kernel * kernel * in_channels, -1)


def hwc_linear_weight(weight: Tensor, channels: int) -> Tensor:
    """Linear weight ``[d, C * h * w]`` on NCHW-flattened features -> ``[h * w * C, d]``
    for (h, w, c) order."""
    d_out, features = weight.shape
    return weight.view(d_out, channels, features // channels).transpose(1, 2).reshape(d_out, -1).T
