"""How the navigation network reads the target (navformer_rl.evaluation.diagnose.target_reading): attention
weights equal to the attention the module computes, the uniform-attention known answer through a model, THSC's
head terms adding up to the model's actions, and the summaries' known answers."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from navformer_rl.evaluation.diagnose.target_reading import (
    TargetAttentionRecorder,
    attention_weights,
    head_terms,
    target_reading_markdown,
    target_reading_summary,
)
from navformer_rl.modules import NavFormerConfig

TINY_MODEL = {"d_embed": 16, "d_head": 8, "n_blocks": 2, "max_timestep": 64, "dropout": 0.0}


def test_attention_weights_times_values_are_the_modules_causal_attention():
    from navformer_rl.modules.models.gpt import CausalSelfAttention

    torch.manual_seed(0)
    attention = CausalSelfAttention(16, 2, 8, dropout=0.0).eval()
    x = torch.randn(3, 9, 16)
    weights = attention_weights(attention, x, torch.arange(9))
    assert weights.shape == (3, 2, 9, 9)
    torch.testing.assert_close(weights.sum(-1), torch.ones(3, 2, 9))
    assert torch.all(weights.triu(diagonal=1) == 0)  # no weight on a later token
    q, k, v = attention.qkv(x).view(3, 9, 3, 2, 8).permute(2, 0, 3, 1, 4)
    expected = F.scaled_dot_product_attention(q, k, v, is_causal=True)
    torch.testing.assert_close(weights @ v, expected, rtol=1e-5, atol=1e-6)
    rows = attention_weights(attention, x, torch.tensor([2, 7]))  # a subset of queries: the same rows
    torch.testing.assert_close(rows, weights[:, :, [2, 7]])


def _model(dt: bool):
    from navformer_rl.modules.models.navformer import NavFormerModel

    torch.manual_seed(1)
    config = NavFormerConfig.dt_baseline(**TINY_MODEL) if dt else NavFormerConfig(**TINY_MODEL)
    return NavFormerModel(config).eval()


def _forward(model, batch: int = 2, steps: int = 5):
    torch.manual_seed(2)
    d = model.config.d_embed
    embeddings = {name: torch.randn(batch, steps, d) for name in model.dve.names}
    return model.transformer(
        torch.randn(batch, d),
        torch.ones(batch, steps, 1),
        torch.rand(batch, steps, 2) * 2 - 1,
        torch.arange(steps).expand(batch, steps),
        None,
        **embeddings,
    )


@pytest.mark.parametrize("dt, tokens_per_step", [(False, 4), (True, 3)])
def test_with_queries_blind_every_key_weighs_the_same_so_the_target_gets_one_over_the_keys(
    dt, tokens_per_step
):
    model = _model(dt)
    with torch.no_grad():
        for block in model.transformer.gpt.blocks:  # zero queries: every score 0, uniform attention
            rows = block.attn.n_heads * block.attn.d_head
            block.attn.qkv.weight[:rows] = 0.0
            block.attn.qkv.bias[:rows] = 0.0
        with TargetAttentionRecorder(model.transformer) as recorder:
            _forward(model)
    keys = tokens_per_step * torch.arange(1, 6)  # step t's head-read token is the last of its step
    assert recorder.keys.tolist() == keys.tolist()
    assert recorder.weights.shape == (2, 5, 2)
    torch.testing.assert_close(recorder.weights, (1.0 / keys.float())[None, :, None].expand(2, 5, 2))


def test_the_recorder_reads_each_blocks_attention_input_and_leaves_no_hook_behind():
    model = _model(dt=False)
    inputs = []
    handles = [
        b.attn.register_forward_hook(lambda m, a, o: inputs.append(a[0]))
        for b in model.transformer.gpt.blocks
    ]
    with torch.no_grad(), TargetAttentionRecorder(model.transformer) as recorder:
        _forward(model)
    for handle in handles:
        handle.remove()
    for i, (block, x) in enumerate(zip(model.transformer.gpt.blocks, inputs, strict=True)):
        expected = attention_weights(block.attn, x, torch.arange(1, 6) * 4 - 1)[..., 0].mean(dim=1)
        torch.testing.assert_close(recorder.weights[..., i], expected)
    assert all(not b.attn._forward_hooks for b in model.transformer.gpt.blocks)
    with (
        torch.no_grad(),
        torch.autocast("cpu", torch.bfloat16),
        TargetAttentionRecorder(model.transformer) as low,
    ):
        _forward(model)  # the shipped weights run under bf16 autocast: the weights are still float32
    assert low.weights.dtype == torch.float32
    torch.testing.assert_close(low.weights, recorder.weights, atol=0.02, rtol=0.05)
    with pytest.raises(ValueError, match="plain causal forward"), torch.no_grad():
        with TargetAttentionRecorder(model.transformer):
            _forward_windowed(model)


def _forward_windowed(model):
    steps, d = 5, model.config.d_embed
    return model.transformer(
        torch.randn(1, d), torch.ones(1, steps, 1), torch.zeros(1, steps, 2), torch.arange(steps)[None], None,
        window_steps=2, **{name: torch.randn(1, steps, d) for name in model.dve.names},
    )  # fmt: skip


@pytest.mark.parametrize("dt", [False, True])
def test_head_terms_add_up_to_the_heads_action(dt):
    model = _model(dt)
    with torch.no_grad():
        h_g, h_o, _ = _forward(model)
        terms = head_terms(model.head, h_g, h_o)
        action = model.head(*([h_g, h_o] if not dt else [h_o]))
    assert set(terms) == ({"observation_term"} if dt else {"target_term", "observation_term"})
    total = terms["observation_term"] + terms.get("target_term", 0.0) + model.head.bias.detach()
    torch.testing.assert_close(torch.tanh(total), action, rtol=1e-5, atol=1e-6)
    if not dt:  # h_g sees the target token only: one offset per trajectory
        torch.testing.assert_close(
            terms["target_term"], terms["target_term"][:, :1].expand_as(terms["target_term"])
        )


def test_the_summary_and_its_tables_known_answers():
    frames = {
        "trajectory": np.array([0, 0, 1, 1]),
        "attention_to_target": np.array([[0.5, 0.1], [0.3, 0.1], [0.1, 0.2], [0.1, 0.2]]),
        "attention_keys": np.array([4, 8, 4, 8]),
        "target_term": np.array([[1.0, 0.0], [1.0, 0.0], [3.0, 0.0], [3.0, 0.0]]),
        "observation_term": np.array([[0.0, 1.0], [0.0, -1.0], [0.0, 1.0], [0.0, -1.0]]),
    }
    in_view = np.array([True, False, False, False])
    summary = target_reading_summary(frames, in_view)
    att = summary["attention_to_target"]
    np.testing.assert_allclose(att["all"], [0.25, 0.15])
    np.testing.assert_allclose(att["in_view"], [0.5, 0.1])
    np.testing.assert_allclose(att["out_of_view"], [0.5 / 3, 0.5 / 3])
    np.testing.assert_allclose(att["x_uniform"], [(2.0 + 2.4 + 0.4 + 0.8) / 4, (0.4 + 0.8 + 0.8 + 1.6) / 4])
    terms = summary["head_terms"]
    assert terms["target_term_mean"] == [2.0, 0.0] and terms["target_term_sd"] == [1.0, 0.0]
    assert terms["observation_term_sd"] == [0.0, 1.0]
    table = target_reading_markdown({"NavFormer": summary, "DT": {"attention_to_target": att}})
    assert "| NavFormer | 0.250, 0.150 | 0.500, 0.100 | 0.167, 0.167 | 1.40, 0.90 |" in table
    assert "| DT | 0.250, 0.150 |" in table
    assert (
        "| NavFormer | 2.000, 0.000 | 1.0000, 0.0000 | 0.000, 1.000 |" in table and "| DT | 2." not in table
    )
    assert target_reading_summary({"trajectory": frames["trajectory"]}, in_view) == {}


def test_target_swap_maps_every_kind_of_target_to_the_next_distinct_one():
    from navformer_rl.evaluation.diagnose.target_reading import TargetSwap

    kinds = torch.stack([torch.full((4, 4, 3), v, dtype=torch.uint8) for v in (30, 10, 20)])
    targets = kinds[[0, 1, 1, 2, 0]]  # a dataset's targets: repeated kinds
    swap = TargetSwap(targets)
    assert swap.available
    swapped = swap.swap(kinds)  # lexicographic order 10 -> 20 -> 30 -> 10
    assert swapped[:, 0, 0, 0].tolist() == [10, 20, 30]
    assert swapped.shape == kinds.shape and swapped.dtype == torch.uint8
    with pytest.raises(ValueError, match="not one of the dataset's target images"):
        swap.swap(torch.full((1, 4, 4, 3), 99, dtype=torch.uint8))
    assert not TargetSwap(kinds[[0, 0]]).available


def test_the_swap_summary_counts_turns_towards_the_object_with_each_target_image():
    n = 4
    bearing = np.radians(40.0)  # at the edge of the 90° view, 2 m ahead-left
    frames = {
        "trajectory": np.array([0, 0, 1, 1]),
        "pose": np.zeros((n, 3)),
        "target": np.tile([2 * np.cos(bearing), 2 * np.sin(bearing)], (n, 1)),
        "action": np.tile([0.5, 0.3], (n, 1)),
        "action_own": np.array([[0.5, 0.5], [0.5, 0.5], [0.5, 0.5], [0.5, -0.5]]),
        "action_swapped": np.array([[0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [0.5, -0.5]]),
    }
    swap = target_reading_summary(frames, np.ones(n, dtype=bool))["target_swap"]
    assert swap["edge_steps"] == 4 and swap["expert_toward"] == 1.0
    assert swap["own_toward"] == 0.75 and swap["swapped_toward"] == 0.25
    np.testing.assert_allclose(swap["change"], [0.0, 0.5])
    np.testing.assert_allclose(swap["change_in_view"], [0.0, 0.5])
    table = target_reading_markdown({"M": {"target_swap": swap}})
    assert "| M | 0.000, 0.500 | 0.000, 0.500 | 0.000, 0.433 | 4 | 100.0 % / 75.0 % / 25.0 % |" in table
    assert "Attention of the token" not in table and "W_g h_g" not in table
