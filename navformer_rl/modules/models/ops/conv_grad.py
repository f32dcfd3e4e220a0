"""A strided convolution whose weight gradient is one matmul on im2col patches (CPU, bf16 training).

oneDNN's bf16 weight-gradient kernel is slow for convolutions with a tiny output map: for the paper
encoder's last layer (3 x 3, stride 2, 9 x 9 x 64 -> 4 x 4 x 64) it reaches ~50 GFLOP/s at batch 512,
and takes more time than the layer's forward and input gradient together. Gathering the 3 x 3 x 64 input
patches (``[M * 16, 576]``, a 9 MB copy at batch 512) and multiplying them with the output gradient
(AMX matmul) gives the same gradient in a fraction of the time. The forward and the input gradient stay
with oneDNN. Measured (``benchmarks/model.md``, "Training levers in the code"): forward + backward of that
layer 19.3 -> 13.6 ms at 2 threads and 31 -> 20.6 ms at 1 thread (bf16, channels_last, batch 512). For larger
output maps (the encoder's other layers) the patch copy costs more than it saves, and in float32 oneDNN's
own kernel is as fast, so ``ConvEncoder`` uses this only for its last layer in bf16 on CPU.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor


def im2col_view(x: Tensor, kernel: int, stride: int) -> Tensor:
    """Patches of a channels-last stack as a view: ``[G, M, H, W, C]`` -> ``[G, M, S, S, k, k, C]``.

    S = ``(H - k) // stride + 1``: patch ``[g, m, i, j]`` is ``x[g, m, i*stride : i*stride + k, j*stride :
    j*stride + k]``, features in (kh, kw, c) order.
    """
    patches = x.unfold(2, kernel, stride).unfold(3, kernel, stride)  # [G, M, S, S, C, k, k]
    return patches.permute(0, 1, 2, 3, 5, 6, 4)


def im2col(x: Tensor, kernel: int, stride: int) -> Tensor:
    """float ``[N, C, H, W]`` -> patches ``[N * OH * OW, kernel * kernel * C]``, column order ``(kh, kw, c)``.

    No padding, no dilation: ``OH = (H - kernel) // stride + 1`` (same for OW). One copy (none extra
    when ``x`` is channels_last, whose NHWC view is contiguous).
    """
    n, c = x.shape[:2]
    patches = im2col_view(x.permute(0, 2, 3, 1)[None], kernel, stride)  # [1, N, OH, OW, k, k, C]
    return patches.reshape(n * patches.shape[2] * patches.shape[3], kernel * kernel * c)


class _ConvMatmulWeightGrad(torch.autograd.Function):
    """y = conv2d(x, weight, bias, stride) (no padding); dL/dweight = im2col(x)^T @ dL/dy."""

    @staticmethod
    def forward(ctx, x: Tensor, weight: Tensor, bias: Tensor | None, stride: int) -> Tensor:
        weight_c = weight.to(x.dtype)
        bias_c = None if bias is None else bias.to(x.dtype)
        ctx.save_for_backward(x, weight_c)
        ctx.stride = stride
        ctx.weight_dtype = weight.dtype
        ctx.bias_dtype = None if bias is None else bias.dtype
        with torch.autocast(x.device.type, enabled=False):
            return F.conv2d(x, weight_c, bias_c, stride=stride)

    @staticmethod
    def backward(ctx, grad_out: Tensor) -> tuple[Tensor | None, Tensor | None, Tensor | None, None]:
        x, weight = ctx.saved_tensors
        stride = ctx.stride
        out_channels, in_channels, kernel, _ = weight.shape
        grad_out = grad_out.to(x.dtype)
        grad_x = None
        if ctx.needs_input_grad[0]:
            grad_x = torch.ops.aten.convolution_backward(
                grad_out,
                x,
                weight,
                None,
                [stride, stride],
                [0, 0],
                [1, 1],
                False,
                [0, 0],
                1,
                [True, False, False],
            )[0]
        grad_rows = grad_out.permute(0, 2, 3, 1).reshape(-1, out_channels)  # [N * OH * OW, O]
        grad_weight = grad_bias = None
        if ctx.needs_input_grad[1]:
            grad_cols = im2col(x, kernel, stride).t() @ grad_rows  # [(kh, kw, c), O]
            grad_weight = (
                grad_cols.view(kernel, kernel, in_channels, out_channels)
                .permute(3, 2, 0, 1)
                .to(ctx.weight_dtype)
                .contiguous(memory_format=torch.channels_last)
            )
        if ctx.needs_input_grad[2]:
            accumulate = torch.promote_types(grad_rows.dtype, torch.float32)
            grad_bias = grad_rows.sum(0, dtype=accumulate).to(ctx.bias_dtype)
        return grad_x, grad_weight, grad_bias, None


def conv2d_matmul_weight_grad(x: Tensor, weight: Tensor, bias: Tensor | None, stride: int) -> Tensor:
    """``F.conv2d(x, weight, bias, stride=stride)`` (no padding, square kernel) with a matmul weight gradient.

    x: float ``[N, C, H, W]`` (any memory format); weight ``[O, C, k, k]`` and bias ``[O]`` are cast to
    ``x.dtype`` (as autocast does) and their gradients returned in their own dtypes. Returns
    ``[N, O, OH, OW]``. Same values as ``F.conv2d``; the weight gradient differs only by summation order.
    """
    if weight.dim() != 4 or weight.shape[-1] != weight.shape[-2] or weight.shape[1] != x.shape[1]:
        raise ValueError(
            f"conv2d_matmul_weight_grad: expected weight [O, {x.shape[1]}, k, k] for x of shape "
            f"{tuple(x.shape)}, got {tuple(weight.shape)}"
        )
    return _ConvMatmulWeightGrad.apply(x, weight, bias, stride)
