"""KV-cache incremental decoding == full forward, at every step, across the window slide and resets."""

import pytest
import torch

from navformer_rl.modules import IncrementalNavFormer, NavFormerConfig, NavFormerModel
from navformer_rl.modules.models import sliding_window_mask

KEYS = ("target_pixels", "pixels", "return_to_go", "action", "step", "mask")


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


@pytest.mark.parametrize("ablation", ["navformer", "dt"])
def test_cached_step_equals_full_forward_at_every_step_across_the_slide(batch_factory, ablation):
    model = small_context_model(
        **({} if ablation == "navformer" else {"use_static_encoder": False, "thsc": False})
    )
    window = model.config.window_steps
    steps = window * 2 + 3
    batch = batch_factory(3, steps, seed=1)
    decoder = IncrementalNavFormer(model, 3)
    reference = full(model, batch, steps, window_steps=window)
    for t in range(steps):
        action = decode(decoder, batch, t)
        torch.testing.assert_close(action, reference[:, t], rtol=0, atol=1e-5)
        if t < window:  # before the slide the window is the whole episode: plain causal forward
            torch.testing.assert_close(action, full(model, batch, t + 1)[:, t], rtol=0, atol=1e-5)
    # past the slide the cache has really dropped old steps: the outputs differ from an unwindowed model
    unwindowed = full(model, batch, steps, window_steps=steps)
    assert (unwindowed[:, -1] - reference[:, -1]).abs().max() > 1e-4


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


def test_per_robot_reset_clears_only_that_robots_state(batch_factory):
    model = small_context_model()
    window = model.config.window_steps
    steps = window + 4
    batch = batch_factory(2, steps, seed=2)
    decoder = IncrementalNavFormer(model, 2)
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
