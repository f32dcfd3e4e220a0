"""NavFormerModel: config validation, encoders, causality, THSC, padding, gradients, ablations,
overfitting."""

import pytest
import torch

from navformer_rl.modules import (
    ConvEncoder,
    NavFormerConfig,
    NavFormerModel,
    ObservationHead,
    ResNet18Encoder,
    THSCHead,
)
from navformer_rl.modules.decoding.fused_encoders import FusedConvEncoders
from navformer_rl.modules.models import MODEL_ABLATIONS
from navformer_rl.objectives import masked_action_mse

KEYS = ("target_pixels", "pixels", "return_to_go", "action", "step", "mask")


def run(model, batch, **kwargs):
    return model(*(batch[k] for k in KEYS), **kwargs)


def eval_model(seed=0, **config):
    torch.manual_seed(seed)
    return NavFormerModel(NavFormerConfig(**config)).eval()


# ------------------------------------------------------------------------------------------- config
@pytest.mark.parametrize(
    "changes, match",
    [
        ({"n_heads": 3}, "n_heads \\* d_head"),
        ({"use_static_encoder": False, "use_general_encoder": False}, "at least one"),
        ({"encoder": "vit"}, "encoder='vit'"),
        ({"dropout": 1.0}, "dropout"),
        ({"action_dropout": 1.5}, "action_dropout=1.5"),
        ({"autocast_dtype": "int8"}, "autocast_dtype"),
        ({"encoder_micro_batch": 0}, "encoder_micro_batch"),
        ({"context_tokens": 5}, "context_tokens"),
    ],
)
def test_config_rejects_bad_values(changes, match):
    with pytest.raises(ValueError, match=match):
        NavFormerConfig(**changes)


def test_config_defaults_are_the_papers():
    c = NavFormerConfig()
    assert (c.d_embed, c.n_blocks, c.n_heads, c.d_head, c.context_tokens, c.dropout) == (
        128,
        3,
        2,
        64,
        1024,
        0.1,
    )
    assert c.tokens_per_step == 4 and c.window_steps == 256
    dt = NavFormerConfig.dt_baseline()
    assert (dt.use_static_encoder, dt.use_general_encoder, dt.thsc, dt.tokens_per_step) == (
        False,
        True,
        False,
        3,
    )
    assert NavFormerConfig.ablation("no_ssl") == NavFormerConfig()  # a data ablation: the paper's model
    assert NavFormerConfig.ablation("dt") == dt
    with pytest.raises(ValueError, match="unknown ablation 'no_static_encoder'"):
        NavFormerConfig.ablation("no_static_encoder")
    # §VII.D (7): "a single pre-trained ResNet18" replaces the DVE (f_s and f_g)
    resnet = NavFormerConfig.ablation("resnet18")
    assert resnet.encoder == "resnet18" and not resnet.use_static_encoder and resnet.use_general_encoder
    assert resnet.tokens_per_step == 3 and resnet.thsc


# ----------------------------------------------------------------------------------------- encoders
def test_conv_encoder_shapes_microbatches_and_layouts():
    torch.manual_seed(0)
    enc = ConvEncoder()
    pixels = torch.randint(0, 256, (2, 5, 84, 84, 3), dtype=torch.uint8)
    out = enc(pixels)
    assert out.shape == (2, 5, 128)
    enc.micro_batch = 3
    torch.testing.assert_close(enc(pixels), out, rtol=1e-5, atol=1e-5)
    enc.channels_last = False
    torch.testing.assert_close(enc(pixels), out, rtol=1e-5, atol=1e-5)
    # the float path on the same images gives the same embeddings
    floats = pixels.reshape(-1, 84, 84, 3).permute(0, 3, 1, 2).float() / 255
    torch.testing.assert_close(enc.forward_float(floats).reshape(2, 5, 128), out, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("robots", [1, 3, 6])
@pytest.mark.parametrize("gemm_max_batch", [0, 4, 8], ids=["conv", "gemm-small-batch", "gemm"])
def test_fused_encoders_equal_the_separate_ones_and_follow_weight_updates(robots, gemm_max_batch):
    torch.manual_seed(0)
    first, second = ConvEncoder(), ConvEncoder()
    fused = FusedConvEncoders(first, second, gemm_max_batch=gemm_max_batch)
    pixels = torch.randint(0, 256, (robots, 84, 84, 3), dtype=torch.uint8)

    def check():
        torch.testing.assert_close(fused(pixels), torch.stack([first(pixels), second(pixels)], 1))

    with torch.no_grad():
        check()
        check()  # the gemm path's reused buffers give the same result again
        second.convs[2].weight.mul_(-1.5)  # an in-place update, like an optimizer step
        first.linear.bias.add_(0.3)
        check()
        first.convs[0].weight.data = torch.randn_like(first.convs[0].weight)  # a replaced tensor
        check()


def test_fused_encoders_equal_space_to_depth_encoders():
    torch.manual_seed(0)
    first, second = ConvEncoder(space_to_depth=True), ConvEncoder(space_to_depth=True)
    pixels = torch.randint(0, 256, (2, 84, 84, 3), dtype=torch.uint8)
    with torch.no_grad():
        expected = torch.stack([first(pixels), second(pixels)], 1)
        for gemm_max_batch in (0, 4):  # the conv2d path and the im2col path
            torch.testing.assert_close(FusedConvEncoders(first, second, gemm_max_batch)(pixels), expected)


def test_fused_encoders_buffers_work_in_and_out_of_inference_mode():
    torch.manual_seed(0)
    first, second = ConvEncoder(), ConvEncoder()
    fused = FusedConvEncoders(first, second)
    pixels = torch.randint(0, 256, (1, 84, 84, 3), dtype=torch.uint8)
    with torch.inference_mode():
        expected = fused(pixels).clone()
    with torch.no_grad():  # the scratch buffers made under inference mode stay writable here
        torch.testing.assert_close(fused(pixels), expected)


def test_fused_encoders_reject_bad_arguments():
    with pytest.raises(ValueError, match="ConvEncoder"):
        FusedConvEncoders(ConvEncoder(), ResNet18Encoder())
    with pytest.raises(ValueError, match="gemm_max_batch"):
        FusedConvEncoders(ConvEncoder(), ConvEncoder(), gemm_max_batch=-1)


def test_encoder_rejects_bad_images():
    enc = ConvEncoder()
    with pytest.raises(ValueError, match="uint8"):
        enc(torch.zeros(2, 84, 84, 3))
    with pytest.raises(ValueError, match="84, 84, 3"):
        enc(torch.zeros(2, 3, 84, 84, dtype=torch.uint8))


def test_resnet18_encoder_forward_shape_and_size():
    torch.manual_seed(0)
    enc = ResNet18Encoder().eval()
    out = enc(torch.randint(0, 256, (3, 84, 84, 3), dtype=torch.uint8))
    assert out.shape == (3, 128) and torch.isfinite(out).all()
    # ResNet-18 body: 11.18M parameters (torchvision's resnet18 without its fc layer; GroupNorm has the
    # affine parameters of its BatchNorm) + Linear 512 -> 128, and no buffers (no running statistics)
    assert sum(p.numel() for p in enc.parameters()) == 11_176_512 + 512 * 128 + 128
    norms = [m for m in enc.modules() if isinstance(m, torch.nn.GroupNorm)]
    assert len(norms) == 20 and all(m.num_groups == 32 and m.affine for m in norms)
    assert not any(isinstance(m, torch.nn.modules.batchnorm._BatchNorm) for m in enc.modules())
    assert not list(enc.buffers())


def test_resnet18_encoder_is_per_image_in_both_modes_and_any_micro_batch():
    """GroupNorm normalises each image on its own: train and eval modes compute the same function, and an
    image's embedding does not depend on the other images of the batch nor on the micro-batch size."""
    torch.manual_seed(0)
    enc = ResNet18Encoder(d_out=16)
    pixels = torch.randint(0, 256, (2, 5, 84, 84, 3), dtype=torch.uint8)
    with torch.no_grad():
        out = enc.train()(pixels)
        assert out.shape == (2, 5, 16)
        assert torch.equal(enc.eval()(pixels), out)
        for mode in (True, False):
            enc.train(mode)
            for micro_batch in (1, 3, 4):
                enc.micro_batch = micro_batch
                torch.testing.assert_close(enc(pixels), out, rtol=1e-5, atol=1e-5)
            enc.micro_batch = None
            torch.testing.assert_close(enc(pixels[1, 2:3]), out[1, 2:3], rtol=1e-5, atol=1e-5)


def test_resnet18_model_is_causal_in_training_mode(batch_factory):
    """Batch statistics (BatchNorm) let frames t+1.. change the train-mode prediction at t (by 0.12 here);
    per-image GroupNorm keeps the training forward causal, as the eval one."""
    torch.manual_seed(0)
    config = NavFormerConfig.ablation("resnet18", dropout=0.0, d_embed=16, d_head=8, n_blocks=1)
    model = NavFormerModel(config).train()
    batch = batch_factory(2, 6)
    perturbed = {k: v.clone() for k, v in batch.items()}
    gen = torch.Generator().manual_seed(1)
    perturbed["pixels"][:, 3:] = torch.randint(
        0, 256, perturbed["pixels"][:, 3:].shape, dtype=torch.uint8, generator=gen
    )
    with torch.no_grad():
        base, out = run(model, batch), run(model, perturbed)
        torch.testing.assert_close(run(model.eval(), batch), base, rtol=0, atol=1e-6)
    torch.testing.assert_close(out[:, :3], base[:, :3], rtol=0, atol=1e-6)
    assert (out[:, 3] - base[:, 3]).abs().max() > 1e-4


def test_resnet18_micro_batches_and_chunks_give_the_whole_batch_gradient(batch_factory):
    """The memory levers on ResNet18 (``encoder_micro_batch``, ``optim.trajectory_chunks``: chunk losses
    weighted by their share of valid steps) reproduce the whole-batch loss and gradient to float32 rounding.
    Noise images: flat-colour images make MaxPool's float32 tie-breaking pick other (equally valid)
    subgradients."""
    config = NavFormerConfig.ablation("resnet18", dropout=0.0, d_embed=16, d_head=8, n_blocks=1)
    batch = batch_factory(4, 3)
    batch["mask"][1, 1:] = False  # chunks of unequal valid length
    total = batch["mask"].sum()

    def loss_and_grads(chunks, micro_batch):
        torch.manual_seed(0)
        model = NavFormerModel(config.replace(encoder_micro_batch=micro_batch)).train()
        loss = 0.0
        for i in range(chunks):
            part = {k: v.chunk(chunks)[i] for k, v in batch.items()}
            share = part["mask"].sum() / total
            chunk_loss = masked_action_mse(run(model, part), part["action"], part["mask"]) * share
            chunk_loss.backward()
            loss += float(chunk_loss.detach())
        return loss, {n: p.grad for n, p in model.named_parameters() if p.grad is not None}

    loss, grads = loss_and_grads(1, None)
    assert any(n.startswith("dve.general_encoder.") for n in grads)
    for chunks, micro_batch in [(2, None), (1, 3), (2, 2)]:
        other_loss, other = loss_and_grads(chunks, micro_batch)
        assert other_loss == pytest.approx(loss, rel=1e-5)
        assert other.keys() == grads.keys()
        for name, grad in grads.items():
            scale = grad.abs().max().item()
            torch.testing.assert_close(other[name], grad, rtol=0, atol=1e-4 * scale + 1e-9, msg=name)


# ---------------------------------------------------------------------------------------- causality
def test_perturbing_step_t_plus_1_leaves_outputs_up_to_t_unchanged(batch_factory):
    model = eval_model()
    batch = batch_factory(2, 6)
    base = run(model, batch)
    t = 2
    perturbed = {k: v.clone() for k, v in batch.items()}
    gen = torch.Generator().manual_seed(1)
    perturbed["pixels"][:, t + 1 :] = torch.randint(
        0, 256, perturbed["pixels"][:, t + 1 :].shape, dtype=torch.uint8, generator=gen
    )
    perturbed["return_to_go"][:, t + 1 :] += torch.randn(2, 6 - t - 1, 1, generator=gen)
    perturbed["action"][:, t + 1 :] = torch.rand(2, 6 - t - 1, 2, generator=gen) * 2 - 1
    out = run(model, perturbed)
    torch.testing.assert_close(out[:, : t + 1], base[:, : t + 1], rtol=0, atol=1e-6)
    assert (out[:, t + 1] - base[:, t + 1]).abs().max() > 1e-4


def test_action_t_never_influences_its_own_prediction(batch_factory):
    model = eval_model()
    batch = batch_factory(2, 5)
    base = run(model, batch)
    t = 2
    changed = dict(batch, action=batch["action"].clone())
    changed["action"][:, t] = -changed["action"][:, t] + 0.5
    out = run(model, changed)
    torch.testing.assert_close(out[:, : t + 1], base[:, : t + 1], rtol=0, atol=1e-6)
    assert (out[:, t + 1 :] - base[:, t + 1 :]).abs().max() > 1e-4  # later steps do read a_t


def test_action_dropout_hides_actions_in_training_only(batch_factory):
    batch = batch_factory(2, 5)
    changed = dict(batch, action=-batch["action"])
    # every action hidden, dropout off: training outputs do not depend on the actions at all
    model = eval_model(dropout=0.0, action_dropout=1.0).train()
    torch.testing.assert_close(run(model, changed), run(model, batch), rtol=0, atol=1e-6)
    # inference reads every action, whatever action_dropout says
    model.eval()
    assert (run(model, changed) - run(model, batch))[:, 1:].abs().max() > 1e-4
    # the default draws nothing: the paper's training, bit for bit and with the same random stream
    paper, opt_out = eval_model(dropout=0.0).train(), eval_model(dropout=0.0, action_dropout=0.0).train()
    torch.manual_seed(3)
    out = run(paper, batch)
    after = torch.rand(1)
    torch.manual_seed(3)
    torch.testing.assert_close(run(opt_out, batch), out, rtol=0, atol=0)
    assert torch.equal(torch.rand(1), after)


def test_action_dropout_hides_about_its_share_of_action_tokens(batch_factory):
    model = eval_model(dropout=0.0, action_dropout=0.5).train()
    tokens = model.transformer.tokens
    action = torch.ones(64, 50, 2)
    torch.manual_seed(0)
    with_dropout = tokens.step_tokens(
        [], torch.zeros(64, 50, 1), action, torch.zeros(64, 50, dtype=torch.long)
    )
    tokens.action_dropout = 0.0
    without = tokens.step_tokens([], torch.zeros(64, 50, 1), action, torch.zeros(64, 50, dtype=torch.long))
    hidden = ~torch.isclose(with_dropout[..., -1, :], without[..., -1, :]).all(-1)
    assert 0.45 < hidden.float().mean().item() < 0.55


# --------------------------------------------------------------------------------------------- THSC
def test_changing_the_target_image_changes_the_actions(batch_factory):
    for thsc in (True, False):  # without THSC g still reaches the actions through attention
        model = eval_model(thsc=thsc)
        batch = batch_factory(2, 4)
        other = dict(batch, target_pixels=torch.flip(batch["target_pixels"], dims=[0]))
        assert (run(model, batch) - run(model, other)).abs().min() > 0


def test_thsc_head_is_a_linear_map_of_target_and_observation_hidden_states():
    model = eval_model()
    d = model.config.d_embed
    assert isinstance(model.head, THSCHead) and model.head.weight.shape == (2, 2 * d)
    gen = torch.Generator().manual_seed(0)
    h_g, h_obs = torch.randn(3, 1, d, generator=gen).expand(3, 4, d), torch.randn(3, 4, d, generator=gen)
    w, b = model.head.weight, model.head.bias
    expected = torch.tanh(h_g @ w[:, :d].T + h_obs @ w[:, d:].T + b)
    torch.testing.assert_close(model.head(h_g, h_obs), expected)
    mask = torch.tensor([[True] * 4, [True, True, False, False], [False] * 4])
    torch.testing.assert_close(model.head(h_g, h_obs, mask), expected * mask[..., None])
    # without THSC the head reads h_obs only, so h_g has no direct path
    plain = eval_model(thsc=False)
    assert isinstance(plain.head, ObservationHead) and plain.head.reads == ("observation",)
    assert plain.head.weight.shape == (2, d)
    torch.testing.assert_close(plain.head(h_obs), torch.tanh(h_obs @ plain.head.weight.T + plain.head.bias))


# ------------------------------------------------------------------------------------------ padding
def test_right_padding_changes_neither_valid_outputs_nor_the_loss(batch_factory):
    model = eval_model()
    batch = batch_factory(2, 6)
    mask = batch["mask"].clone()
    mask[1, 3:] = False
    batch["mask"] = mask
    out = run(model, batch)
    assert (out[1, 3:] == 0).all()
    # the short trajectory alone (no padding) gives the same valid outputs
    alone = {k: v[1:2, :3] if v.dim() > 1 and k != "target_pixels" else v[1:2] for k, v in batch.items()}
    torch.testing.assert_close(run(model, alone)[0], out[1, :3], rtol=0, atol=1e-6)
    # garbage in the padding (including out-of-range timesteps) changes nothing
    junk = {k: v.clone() for k, v in batch.items()}
    junk["pixels"][1, 3:] = 255
    junk["action"][1, 3:] = 7.0
    junk["return_to_go"][1, 3:] = -50.0
    junk["step"][1, 3:] = 10_000
    out_junk = run(model, junk)
    torch.testing.assert_close(out_junk, out, rtol=0, atol=1e-6)
    target = batch["action"]
    torch.testing.assert_close(
        masked_action_mse(out_junk, target, mask), masked_action_mse(out, target, mask), rtol=0, atol=1e-7
    )
    # non-finite or huge padding too (0 * NaN in the attention product, LayerNorm overflow): nothing leaks
    for bad in (float("nan"), float("inf"), 1e30):
        junk["action"][1, 3:] = bad
        junk["return_to_go"][1, 3:] = bad
        torch.testing.assert_close(run(model, junk), out, rtol=0, atol=1e-6)


# ---------------------------------------------------------------------------------------- gradients
@pytest.mark.parametrize("detach", [False, True])
def test_gradient_reaches_every_parameter_unless_encoders_are_detached(batch_factory, detach):
    torch.manual_seed(0)
    model = NavFormerModel(NavFormerConfig(detach_encoders=detach))
    batch = batch_factory(2, 4)
    loss = masked_action_mse(run(model, batch), batch["action"], batch["mask"])
    loss.backward()
    for name, param in model.named_parameters():
        is_encoder = name.startswith("dve.")
        if detach and is_encoder:
            assert param.grad is None, name
        else:
            assert param.grad is not None and param.grad.abs().sum() > 0, name


# ---------------------------------------------------------------------------------------- ablations
ABLATION_LAYOUT = {
    # name: (f_s, f_g, encoder class, THSC)
    **dict.fromkeys(("none", "no_ssl", "no_de", "no_dca"), (True, True, ConvEncoder, True)),
    "no_thsc": (True, True, ConvEncoder, False),
    "no_fs": (False, True, ConvEncoder, True),
    "no_fg": (True, False, ConvEncoder, True),
    "resnet18": (False, True, ResNet18Encoder, True),  # a single ResNet18 replaces the dual encoder
    "dt": (False, True, ConvEncoder, False),
}


@pytest.mark.parametrize("name", MODEL_ABLATIONS)
def test_every_model_ablation_builds_and_runs(batch_factory, name):
    static, general, encoder_class, thsc = ABLATION_LAYOUT[name]
    torch.manual_seed(0)
    model = NavFormerModel(NavFormerConfig.ablation(name)).eval()
    config, d, steps = model.config, model.config.d_embed, 3
    assert (config.use_static_encoder, config.use_general_encoder, config.thsc) == (static, general, thsc)
    assert (model.static_encoder is not None, model.general_encoder is not None) == (static, general)
    assert all(type(encoder) is encoder_class for _, encoder in model.observation_encoders())
    # the target image goes through f_g, through f_s when f_g is ablated
    assert model.dve.target_encoder is (model.general_encoder if general else model.static_encoder)
    assert model.dve.names == ("static",) * static + ("general",) * general
    tps = 2 + static + general  # R-hat, one token per encoder, a
    assert config.tokens_per_step == tps
    assert model.head.in_features == (2 * d if thsc else d)  # THSC reads [h_g ; h_obs]
    seen = {}
    model.transformer.gpt.register_forward_hook(
        lambda m, args, out: seen.update(tokens=args[0], hidden=out[0])
    )
    model.head.register_forward_hook(lambda m, args, out: seen.update(head_args=args))
    # row 1: row 0 with another target image; row 2: row 0's target with other steps (frames, RTG, actions)
    first, other = batch_factory(1, steps), batch_factory(1, steps, seed=1)
    batch = {k: torch.cat([first[k], first[k] if k != "target_pixels" else other[k], other[k]]) for k in KEYS}
    batch["target_pixels"][2] = first["target_pixels"][0]
    out = run(model, batch)
    assert out.shape == (3, steps, 2) and out.abs().max() <= 1
    # g, then tps tokens a step, without the last step's action
    assert seen["tokens"].shape == (3, 1 + tps * steps - 1, d)
    hidden = seen["hidden"]
    obs_hidden = hidden[:, tps - 1 :: tps]  # step t's last observation token: 1 + t * tps + (tps - 2)
    assert obs_hidden.shape == (3, steps, d)
    head_args = (hidden[:, :1].expand(-1, steps, -1), obs_hidden) if thsc else (obs_hidden,)
    assert len(seen["head_args"]) == len(head_args) + 1  # and the mask
    assert all(torch.equal(got, want) for got, want in zip(seen["head_args"], head_args))
    head_input = torch.cat(head_args, -1)
    torch.testing.assert_close(out, torch.tanh(head_input @ model.head.weight.T + model.head.bias))
    # h_g (what THSC adds to the head) depends on the target image alone: g comes first in causal order
    torch.testing.assert_close(hidden[2, 0], hidden[0, 0], rtol=0, atol=1e-6)
    assert not torch.allclose(hidden[1, 0], hidden[0, 0])
    # the target image is always the first token, so every ablation's actions depend on it
    assert not torch.allclose(out[1], out[0])


def test_bad_inputs_get_value_errors(batch_factory):
    model = eval_model()
    batch = batch_factory(1, 3)
    with pytest.raises(ValueError, match="step"):
        run(model, dict(batch, step=batch["step"] + 600))
    with pytest.raises(ValueError, match="return_to_go"):
        run(model, dict(batch, return_to_go=batch["return_to_go"][..., 0]))
    with pytest.raises(ValueError, match="context_tokens"):
        small = eval_model(context_tokens=8)
        run(small, batch)
    with pytest.raises(ValueError, match="mask"):
        run(model, dict(batch, mask=batch["mask"].long()))


def test_bf16_autocast_forward_is_close_to_fp32(batch_factory):
    model = eval_model()
    batch = batch_factory(2, 4)
    fp32 = run(model, batch)
    bf16_model = NavFormerModel(model.config.replace(autocast_dtype="bfloat16")).eval()
    bf16_model.load_state_dict(model.state_dict())
    bf16 = run(bf16_model, batch)
    assert bf16.dtype == torch.float32
    torch.testing.assert_close(bf16, fp32, rtol=0, atol=0.05)


# --------------------------------------------------------------------------------------- overfitting
def test_overfits_a_tiny_synthetic_batch(batch_factory):
    torch.manual_seed(0)
    model = NavFormerModel(NavFormerConfig(dropout=0.0))
    batch = batch_factory(2, 6, seed=3)
    batch["action"] = batch["action"] * 0.8  # reachable by tanh
    optimizer = torch.optim.AdamW(model.parameters(), lr=2e-4, weight_decay=1e-4)  # the paper's optimiser
    losses = []
    for _ in range(40):
        loss = masked_action_mse(run(model, batch), batch["action"], batch["mask"])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0] / 10, (losses[0], losses[-1])


def test_encoding_only_valid_frames_equals_encoding_all_frames_on_valid_steps(batch_factory):
    torch.manual_seed(0)
    model = NavFormerModel(NavFormerConfig()).eval()
    pixels = batch_factory(3, 5)["pixels"]
    mask = torch.tensor([[1, 1, 1, 1, 1], [1, 1, 0, 0, 0], [1, 1, 1, 0, 0]], dtype=torch.bool)
    with torch.no_grad():
        full = model.dve.encode_observations(pixels)
        masked = model.dve.encode_observations(pixels, mask)
    torch.testing.assert_close(masked[mask], full[mask])
    assert masked[~mask].abs().max() == 0
