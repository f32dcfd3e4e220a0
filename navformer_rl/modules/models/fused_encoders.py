"""Inference helper: the static and general CNN encoders run as one fused convolution stack."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from navformer_rl.modules.models.cnn import ConvEncoder, check_images, images_to_float


class FusedConvEncoders:
    """Inference helper: two ``ConvEncoder``s on the same images as one grouped convolution stack.

    ``fused(pixels u8 [B, H, W, 3]) -> [B, 2, d_out]`` equals ``stack([first(pixels), second(pixels)], 1)``
    (same maths, half the kernel launches): conv1 with both filter banks, conv2/conv3 with ``groups=2``,
    and one batched matmul for the two Linear layers. The fused weights are rebuilt whenever a parameter
    of either encoder changes (in-place updates bump ``Tensor._version``; moves change ``data_ptr``), so
    the helper never serves stale weights. No autograd: call it under ``torch.no_grad()``.
    """

    def __init__(self, first: ConvEncoder, second: ConvEncoder) -> None:
        if not (isinstance(first, ConvEncoder) and isinstance(second, ConvEncoder)):
            raise ValueError("FusedConvEncoders: expected two ConvEncoder instances")
        if (first.image_size, first.d_out) != (second.image_size, second.d_out):
            raise ValueError("FusedConvEncoders: the encoders must have the same image_size and d_out")
        self.encoders = (first, second)
        self._key: tuple | None = None
        self._weights: tuple = ()

    def _fused_weights(self) -> tuple:
        params = [
            tensor
            for encoder in self.encoders
            for layer in (encoder.convs[0], encoder.convs[2], encoder.convs[4], encoder.linear)
            for tensor in (layer.weight, layer.bias)
        ]  # direct attribute access: ``parameters()`` would cost more than the check itself
        key = tuple((p.data_ptr(), p._version) for p in params)
        if key != self._key:
            first, second = self.encoders
            convs = tuple(
                (torch.cat([first.convs[i].weight, second.convs[i].weight]), torch.cat([first.convs[i].bias, second.convs[i].bias]))
                for i in (0, 2, 4)
            )  # fmt: skip
            linear_weight = torch.stack([first.linear.weight.T, second.linear.weight.T])  # [2, 1024, d]
            linear_bias = torch.stack([first.linear.bias, second.linear.bias])[:, None]  # [2, 1, d]
            self._weights, self._key = (convs, linear_weight, linear_bias), key
        return self._weights

    def __call__(self, pixels: Tensor) -> Tensor:
        first = self.encoders[0]
        check_images(pixels, first.image_size)
        convs, linear_weight, linear_bias = self._fused_weights()
        x = images_to_float(pixels.reshape(-1, first.image_size, first.image_size, 3), first.channels_last)
        for (weight, bias), stride, groups in zip(convs, (4, 2, 2), (1, 2, 2)):
            x = torch.relu(nn.functional.conv2d(x, weight, bias, stride=stride, groups=groups))
        x = x.reshape(x.shape[0], 2, -1).transpose(0, 1)  # [2, M, 1024]
        return torch.baddbmm(linear_bias, x, linear_weight).transpose(0, 1)  # [M, 2, d]
