"""The strided convolution with an im2col-matmul weight gradient, and its use in the paper encoder."""

import pytest
import torch
import torch.nn.functional as F

from navformer_rl.modules.models.cnn import ConvEncoder
from navformer_rl.modules.models.ops.conv_grad import conv2d_matmul_weight_grad, im2col


def _randn(*shape: int, seed: int, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    return torch.randn(*shape, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def test_im2col_equals_unfold_in_kh_kw_c_order():
    x = _randn(2, 5, 9, 9, seed=0)
    patches = im2col(x, kernel=3, stride=2)  # [2 * 4 * 4, 3 * 3 * 5]
    assert patches.shape == (32, 45)
    unfolded = F.unfold(x, kernel_size=3, stride=2)  # [2, (c, kh, kw), 16]
    expected = unfolded.view(2, 5, 3, 3, 16).permute(0, 4, 2, 3, 1).reshape(32, 45)
    torch.testing.assert_close(patches, expected, rtol=0, atol=0)
    # one patch by hand: output pixel (1, 2) of image 1 starts at input (2, 4)
    torch.testing.assert_close(patches[16 + 1 * 4 + 2], x[1, :, 2:5, 4:7].permute(1, 2, 0).reshape(-1))


@pytest.mark.parametrize("channels_last", [True, False])
@pytest.mark.parametrize("kernel,stride,side", [(3, 2, 9), (4, 2, 20), (2, 1, 6)])
def test_values_and_all_gradients_equal_conv2d(channels_last, kernel, stride, side):
    memory_format = torch.channels_last if channels_last else torch.contiguous_format
    x = _randn(3, 4, side, side, seed=1).contiguous(memory_format=memory_format).requires_grad_()
    weight = _randn(6, 4, kernel, kernel, seed=2).requires_grad_()
    bias = _randn(6, seed=3).requires_grad_()
    out = conv2d_matmul_weight_grad(x, weight, bias, stride)
    x_ref, weight_ref, bias_ref = (t.detach().clone().requires_grad_() for t in (x, weight, bias))
    ref = F.conv2d(x_ref, weight_ref, bias_ref, stride=stride)
    torch.testing.assert_close(out, ref)
    upstream = _randn(*ref.shape, seed=4)
    out.backward(upstream)
    ref.backward(upstream)
    torch.testing.assert_close(x.grad, x_ref.grad)
    torch.testing.assert_close(weight.grad, weight_ref.grad)
    torch.testing.assert_close(bias.grad, bias_ref.grad)


def test_bf16_input_casts_the_parameters_and_returns_their_grads_in_float32():
    x = _randn(8, 64, 9, 9, seed=5, dtype=torch.float32)
    weight = (_randn(64, 64, 3, 3, seed=6, dtype=torch.float32) * 0.05).requires_grad_()
    bias = torch.zeros(64, requires_grad=True)
    out = conv2d_matmul_weight_grad(x.bfloat16(), weight, bias, 2)
    assert out.dtype == torch.bfloat16
    out.float().square().sum().backward()
    assert weight.grad.dtype == torch.float32 and bias.grad.dtype == torch.float32
    weight_ref = weight.detach().clone().requires_grad_()
    bias_ref = bias.detach().clone().requires_grad_()
    F.conv2d(x, weight_ref, bias_ref, stride=2).square().sum().backward()
    scale = weight_ref.grad.abs().max()
    assert (weight.grad - weight_ref.grad).abs().max() < 0.03 * scale
    assert (bias.grad - bias_ref.grad).abs().max() < 0.03 * bias_ref.grad.abs().max()


def test_bad_weight_shape_is_refused():
    with pytest.raises(ValueError, match=r"expected weight \[O, 4, k, k\]"):
        conv2d_matmul_weight_grad(torch.zeros(1, 4, 9, 9), torch.zeros(6, 3, 3, 3), None, 2)


def _backward_names(tensor: torch.Tensor) -> set[str]:
    names, stack, seen = set(), [tensor.grad_fn], set()
    while stack:
        node = stack.pop()
        if node is None or node in seen:
            continue
        seen.add(node)
        names.add(type(node).__name__)
        stack.extend(next_fn for next_fn, _ in node.next_functions)
    return names


def test_encoder_uses_it_in_bf16_training_only_and_keeps_the_gradients():
    torch.manual_seed(0)
    fast = ConvEncoder(space_to_depth=True)
    plain = ConvEncoder(space_to_depth=True, matmul_weight_grad=False)
    plain.load_state_dict(fast.state_dict())
    pixels = torch.randint(
        0, 256, (6, 84, 84, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(1)
    )
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out_fast, out_plain = fast(pixels), plain(pixels)
    assert "_ConvMatmulWeightGradBackward" in _backward_names(out_fast)
    assert "_ConvMatmulWeightGradBackward" not in _backward_names(out_plain)
    torch.testing.assert_close(out_fast, out_plain, rtol=0, atol=0)  # the forward is oneDNN's in both
    out_fast.float().square().sum().backward()
    out_plain.float().square().sum().backward()
    for (name, a), b in zip(plain.named_parameters(), fast.parameters()):
        assert (b.grad - a.grad).abs().max() <= 0.03 * a.grad.abs().max() + 1e-6, name
    assert "_ConvMatmulWeightGradBackward" not in _backward_names(fast(pixels))  # float32: nn.Conv2d
