"""``chunked_dropout_attention``: the same values and gradients as the unchunked autograd graph."""

import pytest
import torch

from navformer_rl.modules.models.ops.attention import additive_mask, chunked_dropout_attention


def reference(q, k, v, bias, keep, scale):
    """The unchunked graph: what ``attention_with_dropout`` computed before chunking (plain autograd ops)."""
    scores = torch.baddbmm(bias, q, k.transpose(1, 2), alpha=q.shape[-1] ** -0.5)
    return torch.bmm(torch.where(keep, torch.softmax(scores, -1), 0), v).mul_(scale)


def inputs(dtype, n=7, length=6, slots=6, per_sequence_bias=False, seed=0):
    gen = torch.Generator().manual_seed(seed)
    q, k, v = (torch.randn(n, length if i == 0 else slots, 4, generator=gen, dtype=dtype) for i in range(3))
    allowed = torch.ones(length, slots, dtype=torch.bool).tril_(diagonal=slots - length)
    if per_sequence_bias:  # padding: sequence 2 may not attend its first slot (queries > 0)
        allowed = allowed.expand(n, length, slots).clone()
        allowed[2, 1:, 0] = False
    keep = torch.rand(n, length, slots, generator=gen) < 0.7
    return q, k, v, additive_mask(allowed, dtype), keep


@pytest.mark.parametrize("per_sequence_bias", [False, True])
@pytest.mark.parametrize("chunk", [1, 3, 7, 100])  # 3 does not divide the 7 sequences
def test_values_and_gradients_equal_the_unchunked_graph_in_float64(chunk, per_sequence_bias):
    q, k, v, bias, keep = inputs(torch.float64, per_sequence_bias=per_sequence_bias)
    grad = torch.randn(q.shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    results = []
    for fn in (reference, lambda *a: chunked_dropout_attention(*a, chunk=chunk)):
        leaves = [x.clone().requires_grad_() for x in (q, k, v)]
        out = fn(*leaves, bias, keep, 1 / 0.7)
        out.backward(grad)
        results.append([out.detach()] + [x.grad for x in leaves])
    for expected, got in zip(*results):
        torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-12)


def test_gradcheck():
    q, k, v, bias, keep = inputs(torch.float64, n=3, length=4, slots=5)
    leaves = [x.requires_grad_() for x in (q, k, v)]
    assert torch.autograd.gradcheck(
        lambda q, k, v: chunked_dropout_attention(q, k, v, bias, keep, 1.25, chunk=2), leaves
    )


def test_bfloat16_is_bit_identical_to_the_unchunked_graph():
    q, k, v, bias, keep = inputs(torch.bfloat16, n=9, length=16, slots=16)
    grad = torch.randn(q.shape, generator=torch.Generator().manual_seed(2)).bfloat16()
    results = []
    for fn in (reference, lambda *a: chunked_dropout_attention(*a, chunk=4)):
        leaves = [x.clone().requires_grad_() for x in (q, k, v)]
        out = fn(*leaves, bias, keep, 1 / 0.9)
        out.backward(grad)
        assert out.dtype == torch.bfloat16
        results.append([out.detach()] + [x.grad for x in leaves])
    for expected, got in zip(*results):
        assert torch.equal(got, expected)


def test_under_autocast_the_inputs_dtype_is_kept():
    q, k, v, bias, keep = inputs(torch.float32)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = chunked_dropout_attention(q, k, v, bias, keep, 1.0, chunk=2)
    assert out.dtype == torch.float32
    torch.testing.assert_close(out, reference(q, k, v, bias, keep, 1.0))


def test_bad_inputs_are_refused():
    q, k, v, bias, keep = inputs(torch.float32)
    with pytest.raises(ValueError, match="one dtype"):
        chunked_dropout_attention(q, k.double(), v, bias, keep, 1.0)
    with pytest.raises(ValueError, match=r"keep: expected bool \[7, 6, 6\]"):
        chunked_dropout_attention(q, k, v, bias, keep[:3], 1.0)
    with pytest.raises(ValueError, match=r"bias: expected \[6, 6\] or \[7, 6, 6\], got \(5, 6\)"):
        chunked_dropout_attention(q, k, v, bias[:5], keep, 1.0)
    with pytest.raises(ValueError, match="chunk=0"):
        chunked_dropout_attention(q, k, v, bias, keep, 1.0, chunk=0)
