"""KV-cache incremental decoding == full forward, at every step, across the window slide and resets."""

import pytest
import torch

from navformer_rl.modules import IncrementalNavFormer, NavFormerConfig, NavFormerModel
from navformer_rl.modules.decoding.native import native_status
from navformer_rl.modules.decoding.step_layers import StepLayers
from navformer_rl.modules.decoding.transformer_step import TransformerStep
from navformer_rl.modules.models import sliding_window_mask
from navformer_rl.modules.models.gpt import KVCache
from navformer_rl.modules.models.ops.attention import additive_mask

KEYS = ("target_pixels", "pixels", "return_to_go", "action", "step", "mask")
NATIVE = [
    pytest.param(False, id="torch-step"),
    pytest.param(
        True,
        id="native-step",
        marks=pytest.mark.skipif(not native_status().available, reason=native_status().reason),
    ),
]
"""Both transformer paths of ``IncrementalNavFormer`` (the compiled kernel where it builds)."""


def small_context_model(seed=0, **changes):
    """The paper model with a 24-token context: a 6-step window (8 steps with 3 tokens per step)."""
    torch.manual_seed(seed)
    return NavFormerModel(NavFormerConfig(context_tokens=24, **changes)).eval()


def full(model, batch, steps, **kwargs):
    """Full forward on the first ``steps`` steps of every trajectory."""
    sliced = {k: v if k == "target_pixels" else v[:, :steps] for k, v in batch.items()}
    with torch.no_grad():
        return model(*(sliced[k] for k in KEYS), **kwargs)


def decode(decoder, batch, t):
    prev = batch["action"][:, t - 1] if t > 0 else torch.zeros_like(batch["action"][:, 0])
    return decoder.step(batch["target_pixels"], batch["pixels"][:, t], batch["return_to_go"][:, t], prev)


@pytest.mark.parametrize("native", NATIVE)
@pytest.mark.parametrize("robots", [1, 3, 6])  # 1, 3: im2col encoders; 6: oneDNN convolutions
@pytest.mark.parametrize("ablation", ["navformer", "dt", "action_bins"])
def test_cached_step_equals_full_forward_at_every_step_across_the_slide(
    batch_factory, ablation, robots, native
):
    changes = {
        "navformer": {},
        "dt": {"use_static_encoder": False, "thsc": False},
        "action_bins": {"action_bins": 11},  # the opt-in head, called as a module by StepLayers
    }[ablation]
    model = small_context_model(**changes)
    window = model.config.window_steps
    steps = window * 2 + 3
    batch = batch_factory(robots, steps, seed=1)
    decoder = IncrementalNavFormer(model, robots, native=native)
    assert decoder.native is native
    reference = full(model, batch, steps, window_steps=window)
    for t in range(steps):
        action = decode(decoder, batch, t)
        torch.testing.assert_close(action, reference[:, t], rtol=0, atol=1e-5)
        if t < window:  # before the slide the window is the whole episode: plain causal forward
            torch.testing.assert_close(action, full(model, batch, t + 1)[:, t], rtol=0, atol=1e-5)
    # past the slide the cache has really dropped old steps: the outputs differ from an unwindowed model
    unwindowed = full(model, batch, steps, window_steps=steps)
    # (the binned head's decoded action moves less with its inputs than tanh's: a smaller margin, still above
    # the 1e-5 tolerance of the equalities above)
    assert (unwindowed[:, -1] - reference[:, -1]).abs().max() > (2e-5 if ablation == "action_bins" else 1e-4)


def test_window_holds_at_most_context_tokens():
    model = small_context_model()
    config = model.config
    decoder = IncrementalNavFormer(model, 1)
    assert (
        decoder.cache.slots == 1 + config.window_steps * config.tokens_per_step <= config.context_tokens + 1
    )
    mask = sliding_window_mask(10, 4, 6, torch.device("cpu"))[0, 0]
    # the query tokens of a step see the target + 6 steps, minus the not-yet-known action: 24 tokens
    assert int(mask[-1].sum()) == config.context_tokens


@pytest.mark.parametrize("native", NATIVE)
def test_per_robot_reset_clears_only_that_robots_state(batch_factory, native):
    model = small_context_model()
    window = model.config.window_steps
    steps = window + 4
    batch = batch_factory(2, steps, seed=2)
    decoder = IncrementalNavFormer(model, 2, native=native)
    restart = 5
    reference_robot0 = full(model, batch, steps, window_steps=window)[0]
    # robot 1 restarts an episode at t = restart: its new episode is the tail of the batch from there
    tail = {k: v[1:2] if k == "target_pixels" else v[1:2, restart:] for k, v in batch.items()}
    tail["step"] = tail["step"] - restart
    reference_robot1 = full(model, tail, steps - restart, window_steps=window)[0]
    for t in range(steps):
        if t == restart:
            decoder.reset(torch.tensor([False, True]))
        prev = batch["action"][:, t - 1] if t > 0 else torch.zeros(2, 2)
        action = decoder.step(
            batch["target_pixels"], batch["pixels"][:, t], batch["return_to_go"][:, t], prev
        )
        torch.testing.assert_close(action[0], reference_robot0[t], rtol=0, atol=1e-5)
        if t >= restart:
            torch.testing.assert_close(action[1], reference_robot1[t - restart], rtol=0, atol=1e-5)
    assert decoder.steps_done.tolist() == [steps, steps - restart]


@pytest.mark.parametrize("native", NATIVE)
@pytest.mark.parametrize("ablation", ["navformer", "dt"])  # 4 and 3 tokens per step
def test_shared_path_equals_general_path_and_leaves_its_state_for_it(batch_factory, ablation, native):
    """The shared fast path (no slot bookkeeping, moving mask past the wrap) against the general path
    (positions and masks from ``slot_pos``) over two ring wraps; then a partial reset hands the shared
    decoder's state to the general path, which must continue exactly."""
    model = small_context_model(
        **({} if ablation == "navformer" else {"use_static_encoder": False, "thsc": False})
    )
    window = model.config.window_steps
    steps = 2 * window + 3
    batch = batch_factory(2, steps + 2, seed=6)
    shared, general = (IncrementalNavFormer(model, 2, native=native) for _ in range(2))
    general.reset(torch.tensor([True, False]))  # a partial reset: the general path from the start
    for t in range(steps):
        torch.testing.assert_close(decode(shared, batch, t), decode(general, batch, t), rtol=0, atol=0)
        assert shared.shared_slot_positions(t + 1).tolist() == general.slot_pos[0].tolist()
        assert shared.steps_done.tolist() == general.steps_done.tolist() == [t + 1, t + 1]
    shared.reset(torch.tensor([False, True]))  # the shared decoder leaves its fast path here
    general.reset(torch.tensor([False, True]))
    assert torch.equal(shared.slot_pos, general.slot_pos)
    for t in range(steps, steps + 2):
        torch.testing.assert_close(decode(shared, batch, t), decode(general, batch, t), rtol=0, atol=0)
    assert shared.steps_done.tolist() == [steps + 2, 2]


def test_decoder_requires_eval_mode_and_matching_batch(batch_factory):
    model = small_context_model()
    batch = batch_factory(2, 1)
    decoder = IncrementalNavFormer(model, 2)
    with pytest.raises(ValueError, match="robots"):
        decoder.step(
            batch["target_pixels"][:1],
            batch["pixels"][:1, 0],
            batch["return_to_go"][:1, 0],
            torch.zeros(1, 2),
        )
    model.train()
    with pytest.raises(ValueError, match="eval"):
        decode(decoder, batch, 0)


@pytest.mark.parametrize("thsc", [True, False])
def test_step_layers_equal_the_models_layers_and_follow_parameter_updates(thsc):
    model = small_context_model(thsc=thsc, max_timestep=8)
    layers = StepLayers(model)
    gen = torch.Generator().manual_seed(3)
    prev_action, rtg = torch.rand(4, 2, generator=gen), torch.rand(4, 1, generator=gen)
    obs, target = torch.randn(4, 2, 128, generator=gen), torch.randn(4, 128, generator=gen)
    hidden_g, hidden_obs = torch.randn(4, 128, generator=gen), torch.randn(4, 128, generator=gen)
    first = torch.tensor([True, False, False, False])
    t = torch.tensor([0, 1, 7, 12])  # 12 > max_timestep: timesteps clamp

    def check():
        embedding = model.transformer.tokens
        observations = list(obs.unbind(1))
        now = embedding.step_tokens(observations, rtg, prev_action, t.clamp(max=7))  # R_t, e_t.., (a)
        before = embedding.step_tokens(observations, rtg, prev_action, (t - 1).clamp(0, 7))  # a_{t-1}
        first_token = before[:, -1]
        first_token[first] = embedding.target_token(target[first])
        expected = embedding.prepare(torch.cat([first_token[:, None], now[:, :-1]], dim=1))
        tokens = layers.tokens(prev_action, rtg, obs, t.clamp(max=8), target[first], first)
        torch.testing.assert_close(tokens, expected)
        shared = layers.tokens(prev_action[1:2], rtg[1:2], obs[1:2], 1)  # an int row: the shared path
        torch.testing.assert_close(shared, expected[1:2])
        hidden = {"target": hidden_g[:, None], "observation": hidden_obs[:, None]}
        expected_action = model.head(*(hidden[name] for name in model.head.reads))[:, 0]
        torch.testing.assert_close(layers.action(hidden_g, hidden_obs), expected_action)

    with torch.no_grad():
        check()
        tokens = model.transformer.tokens
        for param in (tokens.timestep_embed.weight, tokens.action_embed.bias, model.head.weight):
            param.add_(0.5)  # in-place updates: the tables are rebuilt
            check()


@pytest.mark.parametrize("layout", ["slot_major", "separate"])
@pytest.mark.parametrize("write", ["slice", "index"])
def test_transformer_step_equals_the_module_path_and_follows_parameter_updates(write, layout):
    model = small_context_model()
    config = model.config
    step = TransformerStep(model.transformer.gpt)
    gen = torch.Generator().manual_seed(4)
    x = torch.randn(2, 4, config.d_embed, generator=gen)
    allowed = torch.rand(2, 1, 4, 9, generator=gen) > 0.3
    allowed[..., 0] = True  # every query attends at least one slot
    masks = (allowed, additive_mask(allowed, torch.float32))
    write_index = slice(5, 9) if write == "slice" else torch.tensor([[4, 6, 7, 8], [8, 5, 6, 7]])

    def check():
        for mask in masks:
            shape = (config.n_blocks, 2, config.n_heads, 12, config.d_head)
            caches = [KVCache.empty(*shape) for _ in range(2)]
            if layout == "separate":  # keys and values as their own tensors: TransformerStep writes each
                caches[1] = KVCache(list(torch.zeros(shape)), list(torch.zeros(shape)))
            for cache in caches:
                for tensor in cache.keys + cache.values:
                    tensor.copy_(torch.randn(tensor.shape, generator=torch.Generator().manual_seed(5)))
            expected, _ = model.transformer.gpt(
                x, attn_mask=mask, kv_cache=caches[0], write_index=write_index
            )
            torch.testing.assert_close(step(x, mask, caches[1], write_index), expected)
            for got, want in zip(caches[1].keys + caches[1].values, caches[0].keys + caches[0].values):
                torch.testing.assert_close(got, want)

    with torch.no_grad():
        check()
        model.transformer.gpt.blocks[1].mlp[0].weight.mul_(-2.0)  # an in-place update
        check()
        qkv = model.transformer.gpt.blocks[0].attn.qkv
        qkv.weight.data = torch.randn(qkv.weight.shape, generator=gen)  # a replaced tensor
        check()


def test_transformer_step_buffers_work_in_and_out_of_inference_mode():
    model = small_context_model()
    config = model.config
    step = TransformerStep(model.transformer.gpt)
    x = torch.randn(1, 4, config.d_embed, generator=torch.Generator().manual_seed(7))
    mask = torch.ones(1, 1, 4, 6, dtype=torch.bool).tril(diagonal=2)
    outputs = []
    for mode in (torch.inference_mode, torch.no_grad, torch.inference_mode):
        cache = KVCache.empty(config.n_blocks, 1, config.n_heads, 8, config.d_head)
        with mode():  # the first call allocates the buffers (in inference mode); later calls reuse them
            outputs.append(step(x, mask, cache, slice(2, 6)))
    for output in outputs[1:]:
        torch.testing.assert_close(output, outputs[0], rtol=0, atol=0)


def test_transformer_step_rejects_an_unknown_block_structure():
    model = small_context_model()
    model.transformer.gpt.blocks[0].mlp[1] = torch.nn.ReLU()
    with pytest.raises(ValueError, match="GELU"):
        TransformerStep(model.transformer.gpt)


@pytest.mark.parametrize("native", NATIVE)
def test_refresh_picks_up_updates_the_caches_cannot_see(batch_factory, native):
    model = small_context_model()
    batch = batch_factory(2, 3)
    decoder = IncrementalNavFormer(model, 2, native=native)
    decode(decoder, batch, 0)
    with torch.no_grad():  # a write through .data bypasses the version counter
        model.transformer.gpt.blocks[0].mlp[0].weight.data.mul_(2.0)
        model.head.bias.data.add_(0.5)
    decoder.reset()
    decoder.refresh()
    fresh = IncrementalNavFormer(model, 2, native=native)
    torch.testing.assert_close(decode(decoder, batch, 0), decode(fresh, batch, 0), rtol=0, atol=0)


def test_inference_mode_model_and_state_and_float32_only(batch_factory):
    batch = batch_factory(2, 3)
    with torch.inference_mode():  # a model built and a decoder made under inference mode
        model = small_context_model()
        decoder = IncrementalNavFormer(model, 2)
        decode(decoder, batch, 0)
    decoder.reset(torch.tensor([True, False]))  # in-place state updates outside inference mode
    with torch.no_grad():
        decode(decoder, batch, 1)
    with pytest.raises(ValueError, match="float32 models; this one holds torch.float64"):
        IncrementalNavFormer(small_context_model().double(), 1)


@pytest.mark.parametrize("native", NATIVE)
@pytest.mark.parametrize("window", [1, 3])
def test_shorter_window_equals_forward_with_that_window(batch_factory, window, native):
    """``window_steps`` below the model's context: the cache holds that many steps and every step equals
    ``forward(window_steps=W)``, which differs from the whole-context decoding once the window slides."""
    model = small_context_model()
    steps = model.config.window_steps + 4
    batch = batch_factory(2, steps, seed=3)
    decoder = IncrementalNavFormer(model, 2, native=native, window_steps=window)
    assert decoder.window_steps == window
    assert decoder.cache.slots == 1 + window * model.config.tokens_per_step
    reference = full(model, batch, steps, window_steps=window)
    for t in range(steps):
        torch.testing.assert_close(decode(decoder, batch, t), reference[:, t], rtol=0, atol=1e-5)
    whole_context = full(model, batch, steps, window_steps=model.config.window_steps)
    assert torch.equal(reference[:, :window], whole_context[:, :window])
    assert (reference[:, -1] - whole_context[:, -1]).abs().max() > 1e-4


@pytest.mark.parametrize("window", [0, -2, 7, 2.5, True, "4"])
def test_window_outside_the_context_is_refused_naming_it(window):
    model = small_context_model()  # a 6-step context
    with pytest.raises(
        ValueError, match=rf"window_steps={window!r}: expected a whole number of timesteps from 1 to 6"
    ):
        IncrementalNavFormer(model, 1, window_steps=window)
