"""The CPU dropout (``keep_mask`` / ``fast_dropout`` / ``Dropout``) and the attention that uses it."""

import pytest
import torch
import torch.nn.functional as F

from navformer_rl.modules.models.ops import dropout
from navformer_rl.modules.models.ops.attention import attention_with_dropout
from navformer_rl.modules.models.ops.dropout import PARALLEL_WORDS, Dropout, fast_dropout, keep_mask


def test_keep_mask_has_the_requested_rate_and_no_lane_pattern():
    torch.manual_seed(0)
    mask = keep_mask((1000, 1000), 0.9, "cpu")
    assert mask.dtype == torch.bool and mask.shape == (1000, 1000)
    assert abs(mask.float().mean().item() - 0.9) < 0.002  # ~7 sigma for 1e6 draws
    # each of the four 16-bit lanes of a 64-bit word is uniform: every lane keeps ~90 %
    lanes = mask.reshape(-1, 4).float().mean(0)
    assert torch.allclose(lanes, torch.full((4,), 0.9), atol=0.004)
    # neighbours are independent: P(keep, keep) = 0.81
    flat = mask.reshape(-1).float()
    assert abs((flat[1:] * flat[:-1]).mean().item() - 0.81) < 0.003


def test_keep_mask_edge_probabilities_and_odd_sizes():
    assert keep_mask((7, 3), 1.0, "cpu").all()
    assert not keep_mask((5,), 0.0, "cpu").any()
    with pytest.raises(ValueError, match="keep_prob=1.5"):
        keep_mask((3,), 1.5, "cpu")


def test_keep_mask_is_reproducible_under_manual_seed():
    torch.manual_seed(3)
    first = keep_mask((33, 17), 0.9, "cpu")
    torch.manual_seed(3)
    assert torch.equal(first, keep_mask((33, 17), 0.9, "cpu"))


def test_large_masks_from_two_generators_have_the_rate_and_independent_halves():
    shape = (4 * PARALLEL_WORDS // 1000 + 1, 1000)  # just above the two-generator threshold
    torch.manual_seed(0)
    mask = keep_mask(shape, 0.9, "cpu")
    assert mask.dtype == torch.bool and mask.shape == shape
    flat = mask.reshape(-1).float()
    assert abs(flat.mean().item() - 0.9) < 0.002
    assert torch.allclose(flat.reshape(-1, 4).mean(0), torch.full((4,), 0.9), atol=0.004)
    assert abs((flat[1:] * flat[:-1]).mean().item() - 0.81) < 0.003
    half = flat.numel() // 2
    first, second = flat[:half], flat[half : 2 * half]
    assert abs((first * second).mean().item() - 0.81) < 0.003  # the halves' generators are independent


@pytest.mark.parametrize("shape", [(7, 3), (1, 9), (16,), (5, 5, 5)])
def test_two_generator_masks_do_not_depend_on_the_thread_count(monkeypatch, shape):
    monkeypatch.setattr(dropout, "PARALLEL_WORDS", 1)  # odd small shapes through the two-generator path
    threads = torch.get_num_threads()
    masks = []
    try:
        for n_threads in (1, 2, 1):
            torch.set_num_threads(n_threads)
            torch.manual_seed(7)
            masks.append(keep_mask(shape, 0.5, "cpu"))
    finally:
        torch.set_num_threads(threads)
    assert masks[0].shape == shape
    assert torch.equal(masks[0], masks[1]) and torch.equal(masks[0], masks[2])
    torch.manual_seed(8)  # another seed, another mask (deterministic: the seeds are fixed)
    assert masks[0].numel() < 16 or not torch.equal(masks[0], keep_mask(shape, 0.5, "cpu"))


def test_fast_dropout_zeroes_and_rescales_and_its_gradient_is_the_mask():
    x = torch.randn(64, 128, generator=torch.Generator().manual_seed(0)).requires_grad_()
    torch.manual_seed(1)
    y = fast_dropout(x, 0.25, training=True)
    torch.manual_seed(1)
    kept = keep_mask(x.shape, 0.75, "cpu")
    assert 0 < int((~kept).sum()) < kept.numel()  # some zeroed, some kept: the comparison is not vacuous
    assert torch.allclose(y, torch.where(kept, x / 0.75, 0))
    y.sum().backward()
    assert torch.allclose(x.grad, kept.float() / 0.75)
    assert fast_dropout(x, 0.25, training=False) is x
    assert fast_dropout(x, 0.0, training=True) is x


def test_dropout_module_matches_nn_dropout_interface():
    module = Dropout(0.1)
    assert isinstance(module, torch.nn.Dropout) and module.p == 0.1
    x = torch.randn(4, 8, generator=torch.Generator().manual_seed(0))
    assert module.eval()(x) is x
    with pytest.raises(ValueError, match="p=1.0"):
        Dropout(1.0)


@pytest.mark.parametrize("mask_kind", ["causal", "batch_mask"])
def test_attention_with_dropout_is_sdpa_when_nothing_is_dropped(mask_kind):
    torch.manual_seed(0)
    q, k, v = (torch.randn(3, 2, 10, 16) for _ in range(3))
    mask = None
    if mask_kind == "batch_mask":
        mask = torch.ones(3, 1, 10, 10, dtype=torch.bool).tril_()
        mask[1, :, :, 0] = False
        mask[1, :, 0, 0] = True  # every query keeps at least one key
    expected = F.scaled_dot_product_attention(q, k, v, attn_mask=mask, is_causal=mask is None)
    got = attention_with_dropout(q, k, v, mask, p=1e-9)  # keep probability rounds to 1
    assert torch.allclose(got, expected, atol=1e-5)


def test_attention_with_dropout_drops_attention_weights():
    torch.manual_seed(0)
    q, k, v = (torch.randn(2, 2, 6, 8) for _ in range(3))
    torch.manual_seed(5)
    got = attention_with_dropout(q, k, v, None, p=0.5)
    torch.manual_seed(5)
    kept = keep_mask((4, 6, 6), 0.5, "cpu").view(2, 2, 6, 6)
    scores = (q @ k.transpose(-2, -1)) / 8**0.5
    weights = scores.masked_fill(~torch.ones(6, 6, dtype=torch.bool).tril(), float("-inf")).softmax(-1)
    assert torch.allclose(got, (weights * kept / 0.5) @ v, atol=1e-5)
