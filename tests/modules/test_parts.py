"""NavFormer's parts as TensorDict modules: composition, ablations, parts alone, old checkpoints, decoding.

``fixtures/pre_modules_checkpoints.tar.gz`` holds two checkpoints (``navformer``, ``dt``: d_embed 32, one
block, 36 px images) written by ``navformer_rl.training.checkpoint.save_checkpoint`` with the single-module
model of commit 7605c27 (state-dict names such as ``static_encoder.*``, ``transformer.blocks.*``), and in
``expected.json`` that model's outputs on the inputs of ``fixture_batch`` (teacher-forced forward, windowed
forward, ``IncrementalNavFormer`` torch path), its ``named_parameters`` order and the sums of the
weights ``torch.manual_seed(0)`` gave it.
"""

import json
import tarfile
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.modules import NormalParamExtractor, ProbabilisticActor, TanhNormal

from navformer_rl.modules import (
    MODEL_ABLATIONS,
    ActionHead,
    CausalTransformer,
    ConvEncoder,
    DualVisualEncoder,
    IncrementalNavFormer,
    NavFormerConfig,
    NavFormerModel,
    NavFormerPolicy,
    ObservationHead,
    ResNet18Encoder,
    THSCHead,
    dve_module,
    head_module,
    make_navformer_actor,
    transformer_module,
)
from navformer_rl.modules.decoding.native import native_status
from navformer_rl.objectives import ActionMSELoss, BYOLLoss
from navformer_rl.training import checkpoint as ckpt
from navformer_rl.training.checkpoint import upgrade_state_dict

FIXTURE = Path(__file__).parent / "fixtures" / "pre_modules_checkpoints.tar.gz"
SMALL = {
    "d_embed": 32,
    "n_blocks": 1,
    "n_heads": 2,
    "d_head": 16,
    "mlp_ratio": 2,
    "context_tokens": 16,
    "max_timestep": 16,
    "image_size": 36,
}
KEYS = ("target_pixels", "pixels", "return_to_go", "action", "step", "mask")


def fixture_batch(steps: int = 6, n: int = 2, size: int = 36, seed: int = 1) -> dict[str, torch.Tensor]:
    """The inputs the fixture's outputs were computed on (trajectory 1 padded after 4 steps)."""
    gen = torch.Generator().manual_seed(seed)
    batch = {
        "target_pixels": torch.randint(0, 256, (n, size, size, 3), dtype=torch.uint8, generator=gen),
        "pixels": torch.randint(0, 256, (n, steps, size, size, 3), dtype=torch.uint8, generator=gen),
        "return_to_go": torch.rand(n, steps, 1, generator=gen),
        "action": torch.rand(n, steps, 2, generator=gen) * 2 - 1,
        "step": torch.arange(steps).expand(n, steps).clone(),
        "mask": torch.ones(n, steps, dtype=torch.bool),
    }
    batch["mask"][1, 4:] = False
    return batch


def small_model(seed: int = 0, **changes) -> NavFormerModel:
    torch.manual_seed(seed)
    return NavFormerModel(NavFormerConfig(**{**SMALL, "context_tokens": 32, **changes})).eval()


def decode(decoder: IncrementalNavFormer, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Actions ``[B, T, A]`` of decoding every step of ``batch`` (a_{t-1} from the batch)."""
    actions = []
    for t in range(batch["pixels"].shape[1]):
        prev = batch["action"][:, t - 1] if t else torch.zeros_like(batch["action"][:, 0])
        pixels, rtg = batch["pixels"][:, t], batch["return_to_go"][:, t]
        actions.append(decoder.step(batch["target_pixels"], pixels, rtg, prev))
    return torch.stack(actions, 1)


# ---------------------------------------------------------------------------- checkpoints of before
@pytest.fixture(scope="module")
def old_checkpoints(tmp_path_factory):
    root = tmp_path_factory.mktemp("old")
    with tarfile.open(FIXTURE) as tar:
        tar.extractall(root, filter="data")
    return root, json.loads((root / "expected.json").read_text())


@pytest.mark.parametrize("name", ["navformer", "dt"])
def test_checkpoints_of_the_single_module_model_load_and_give_its_outputs(old_checkpoints, name):
    root, expected = old_checkpoints
    config, model = ckpt.load_policy_model(root / name)
    assert config == NavFormerConfig(
        **SMALL, **({} if name == "navformer" else {"use_static_encoder": False, "thsc": False})
    )
    batch = fixture_batch()
    first_steps = TensorDict({k: v if k == "target_pixels" else v[:, :3] for k, v in batch.items()}, [2])
    with torch.no_grad():
        composed = make_navformer_actor(model)(first_steps)["action_pred"]
        windowed = model(*(batch[k] for k in KEYS), window_steps=config.window_steps)
        incremental = decode(IncrementalNavFormer(model, 2, native=False), batch)
    torch.testing.assert_close(composed, torch.tensor(expected[name]["forward"]), rtol=0, atol=1e-6)
    torch.testing.assert_close(windowed, torch.tensor(expected[name]["forward_window"]), rtol=0, atol=1e-6)
    torch.testing.assert_close(incremental, torch.tensor(expected[name]["incremental"]), rtol=0, atol=1e-6)
    if native_status().available:
        native = decode(IncrementalNavFormer(model, 2, native=True), batch)
        torch.testing.assert_close(native, torch.tensor(expected[name]["incremental"]), rtol=0, atol=1e-5)
    # the parameters keep their order, so a resumed run's optimiser states still match them
    old_order = [next(iter(upgrade_state_dict({n: None}))) for n in expected[name]["parameter_order"]]
    assert [n for n, _ in model.named_parameters()] == old_order


@pytest.mark.parametrize("name", ["navformer", "dt"])
def test_a_seed_gives_the_weights_of_the_single_module_model(old_checkpoints, name):
    _, expected = old_checkpoints
    changes = {} if name == "navformer" else {"use_static_encoder": False, "thsc": False}
    torch.manual_seed(0)
    state = NavFormerModel(NavFormerConfig(**SMALL, **changes)).state_dict()
    sums = upgrade_state_dict(expected[name]["seed_0_sums"])
    assert sums.keys() == state.keys()
    for key, value in state.items():
        assert float(value.double().sum()) == pytest.approx(sums[key], rel=1e-12, abs=1e-12), key


@pytest.mark.parametrize("ablation", ["none", "dt", "resnet18"])
def test_the_initialisation_order_is_the_parts_from_config_then_the_tables(ablation):
    """``NavFormerModel(config)`` = DVE, CT and head built by their ``from_config`` (PyTorch's default inits,
    in that order), then GPT-2's N(0, 0.02) for the embedding tables; the same seed gives the same weights."""
    from navformer_rl.modules.models import CausalTransformer, init_embedding_tables, make_head

    config = NavFormerConfig.ablation(ablation)
    config = NavFormerConfig(
        **{**config.__dict__, **SMALL, "image_size": 84 if ablation == "resnet18" else 36}
    )
    torch.manual_seed(3)
    model = NavFormerModel(config)
    torch.manual_seed(3)
    parts = nn.ModuleDict(
        {
            "dve": DualVisualEncoder.from_config(config),
            "transformer": CausalTransformer.from_config(config),
            "head": make_head(config),
        }
    )
    parts.apply(init_embedding_tables)
    assert model.state_dict().keys() == parts.state_dict().keys()
    for key, value in model.state_dict().items():
        assert torch.equal(value, parts.state_dict()[key]), key
    tables = model.transformer.tokens
    for table in (tables.timestep_embed, tables.modality_embed):
        assert float(table.weight.detach().std()) == pytest.approx(
            0.02, rel=0.3
        )  # GPT-2's, not nn.Embedding's N(0, 1)


def test_upgrade_state_dict_keeps_current_names():
    state = small_model().state_dict()
    assert list(upgrade_state_dict(state)) == list(state)
    assert next(iter(upgrade_state_dict({"transformer.blocks.0.ln_attn.weight": None}))) == (
        "transformer.gpt.blocks.0.ln_attn.weight"
    )


# ------------------------------------------------------------------------------------- composition
def test_the_actor_is_the_parts_in_sequence_and_equals_the_model(batch_factory):
    model = small_model(image_size=84)
    actor = make_navformer_actor(model)
    assert isinstance(actor, TensorDictSequential)
    assert [part.module for part in actor] == [model.dve, model.transformer, model.head]
    batch = batch_factory(2, 5)
    batch["mask"][1, 3:] = False
    with torch.no_grad():
        expected = model(*(batch[k] for k in KEYS))
        out = actor(TensorDict(batch, [2]))
        # an [N, T] tensordict with the target expanded over T: the target is encoded once
        calls = []
        hook = model.dve.general_encoder.register_forward_hook(lambda m, a, o: calls.append(a[0].shape))
        wide = dict(batch, target_pixels=batch["target_pixels"][:, None].expand(-1, 5, -1, -1, -1))
        out_wide = actor(TensorDict(wide, [2, 5]))
        hook.remove()
    torch.testing.assert_close(out["action_pred"], expected, rtol=0, atol=0)
    torch.testing.assert_close(out_wide["action_pred"], expected, rtol=0, atol=1e-6)
    assert calls[-1] == (2, 84, 84, 3)  # the target pass of f_g: one image per trajectory
    d, tps = model.config.d_embed, model.config.tokens_per_step
    assert out["embed", "static"].shape == out["embed", "general"].shape == (2, 5, d)
    assert out["embed", "target"].shape == (2, d)
    assert out["hidden", "tokens"].shape == (2, 5, tps, d)
    torch.testing.assert_close(out["hidden", "observation"], out["hidden", "tokens"][:, :, -1])
    torch.testing.assert_close(out["hidden", "target"], out["hidden", "tokens"][:, :1, 0].expand(-1, 5, -1))
    assert (out["action_pred"][1, 3:] == 0).all()


def test_length_groups_give_the_padded_batchs_predictions_and_gradients(batch_factory):
    """Known answer: trajectories of lengths 7, 2, 5, 1 in one padded pass and in 3 groups of similar length
    (dropout off) give the same predictions, zeros on padding, the same hidden states and gradients."""
    model = small_model(image_size=84, dropout=0.0)
    batch = batch_factory(4, 7)
    batch["mask"] = torch.arange(7) < torch.tensor([7, 2, 5, 1])[:, None]
    results = {}
    for groups in (1, 3):
        model.zero_grad()
        out = make_navformer_actor(model, length_groups=groups)(TensorDict(dict(batch), [4]))
        loss = (out["action_pred"] ** 2).sum() + out["hidden", "observation"][batch["mask"]].sum()
        loss.backward()
        results[groups] = (
            out,
            {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None},
        )
    (padded, padded_grads), (grouped, grouped_grads) = results[1], results[3]
    assert grouped["action_pred"].shape == padded["action_pred"].shape == (4, 7, 2)
    torch.testing.assert_close(grouped["action_pred"], padded["action_pred"], rtol=1e-5, atol=1e-6)
    assert (grouped["action_pred"][~batch["mask"]] == 0).all()
    mask = batch["mask"]
    torch.testing.assert_close(
        grouped["hidden", "tokens"][mask], padded["hidden", "tokens"][mask], rtol=1e-5, atol=1e-5
    )
    assert grouped_grads.keys() == padded_grads.keys()
    for name, grad in padded_grads.items():  # float32 sums in another order: relative to the norm
        assert (grouped_grads[name] - grad).norm() <= 1e-5 * grad.norm() + 1e-8, name
    with pytest.raises(ValueError, match="groups=0: expected an integer >= 1"):
        make_navformer_actor(model, length_groups=0)


def test_renamed_keys_reach_every_part(batch_factory):
    model = small_model(image_size=84)
    names = ("goal", ("obs", "rgb"), "rtg", "act", "t", "valid")
    actor = make_navformer_actor(model, in_keys=names, out_keys=[("out", "a")])
    batch = batch_factory(2, 4)
    renamed = TensorDict({name: batch[key] for name, key in zip(names, KEYS)}, [2])
    with torch.no_grad():
        torch.testing.assert_close(actor(renamed)["out", "a"], model(*(batch[k] for k in KEYS)))
    assert set(actor.in_keys) == set(names)
    with pytest.raises(ValueError, match="expected 3 keys"):
        dve_module(model.dve, in_keys=["pixels", "target_pixels"])
    with pytest.raises(ValueError, match="expected 6 keys"):
        make_navformer_actor(model, in_keys=names[:5])


def test_the_parts_run_alone_on_tensors(batch_factory):
    model = small_model(image_size=84)
    batch = batch_factory(2, 4)
    with torch.no_grad():
        static, general, target = model.dve(batch["pixels"], batch["target_pixels"])
        hidden = model.transformer(
            target, batch["return_to_go"], batch["action"], batch["step"], static=static, general=general
        )
        torch.testing.assert_close(model.head(*hidden[:2]), model(*(batch[k] for k in KEYS)))
    with pytest.raises(
        ValueError, match=r"expected the embeddings \('static', 'general'\), got \('general',\)"
    ):
        model.transformer(target, batch["return_to_go"], batch["action"], batch["step"], general=general)
    with pytest.raises(ValueError, match="target_pixels: expected leading shape"):
        model.dve(batch["pixels"], batch["target_pixels"][:1])


# ---------------------------------------------------------------------------------------- ablations
@pytest.mark.parametrize("name", MODEL_ABLATIONS)
def test_every_ablation_is_a_composition_of_parts(name):
    config = NavFormerConfig.ablation(name)
    actor = make_navformer_actor(NavFormerModel(config))
    dve, transformer, head = (part.module for part in actor)
    assert isinstance(dve, DualVisualEncoder) and isinstance(transformer, CausalTransformer)
    names = {
        **dict.fromkeys(("none", "no_ssl", "no_de", "no_dca"), ("static", "general")),
        "no_thsc": ("static", "general"),
        "no_fs": ("general",),
        "no_fg": ("static",),
        "resnet18": ("general",),
        "dt": ("general",),
    }[name]
    assert dve.names == transformer.observation_names == names
    encoder = ResNet18Encoder if name == "resnet18" else ConvEncoder
    assert all(type(e) is encoder for _, e in dve.observation_encoders())
    assert type(head) is (ObservationHead if name in ("no_thsc", "dt") else THSCHead)
    assert actor[0].out_keys == [*(("embed", n) for n in names), ("embed", "target")]
    assert actor[2].in_keys == [*(("hidden", n) for n in head.reads), "mask"]


# -------------------------------------------------------------------------------- parts, swapped or alone
class TwoLayerHead(ActionHead):
    reads = ("target", "observation")

    def __init__(self, d_embed: int) -> None:
        super().__init__(16, 2)
        self.hidden = nn.Linear(2 * d_embed, 16)

    def forward(self, target_hidden, observation_hidden, mask=None):
        return self.predict(torch.relu(self.hidden(torch.cat([target_hidden, observation_hidden], -1))), mask)


def test_a_swapped_head_trains_with_the_dt_loss_and_is_decoded_with_the_kv_cache():
    model = small_model(dropout=0.0)
    model.head = TwoLayerHead(model.config.d_embed)
    batch = fixture_batch()
    loss = ActionMSELoss(make_navformer_actor(model.train()))(TensorDict(batch, [2]))["loss_dt"]
    loss.backward()
    assert model.head.hidden.weight.grad.abs().sum() > 0
    assert model.transformer.gpt.blocks[0].attn.qkv.weight.grad.abs().sum() > 0
    model.eval()
    with torch.no_grad():
        reference = model(*(batch[k] for k in KEYS), window_steps=model.config.window_steps)
        decoded = decode(IncrementalNavFormer(model, 2, native=False), batch)
    valid = batch["mask"]
    torch.testing.assert_close(decoded[valid], reference[valid], rtol=0, atol=1e-5)


def test_a_head_on_every_tokens_hidden_state_composes_after_the_transformer():
    model = small_model()
    mean_head = TensorDictModule(
        nn.Sequential(nn.Linear(model.config.d_embed, 2), nn.Tanh()),
        in_keys=[("hidden", "mean")],
        out_keys=["action_pred"],
    )
    pool = TensorDictModule(
        lambda tokens: tokens.mean(-2), in_keys=[("hidden", "tokens")], out_keys=[("hidden", "mean")]
    )
    actor = TensorDictSequential(
        dve_module(model.dve), transformer_module(model.transformer), pool, mean_head
    )
    out = actor(TensorDict(fixture_batch(steps=3), [2]))
    assert out["action_pred"].shape == (2, 3, 2)
    with pytest.raises(ValueError, match="reads"):
        bad = ObservationHead(model.config.d_embed, 2)
        bad.reads = ("tokens",)
        model.head = bad
        IncrementalNavFormer(model, 1)


def test_byol_trains_the_dve_given_alone():
    dve = small_model(image_size=84).dve
    byol = BYOLLoss(dve, hidden_dim=32, projection_dim=16)
    assert byol.online_network["static"].encoder is dve.static_encoder
    assert byol.online_network["general"].encoder is dve.general_encoder
    gen = torch.Generator().manual_seed(0)
    pairs = TensorDict(
        {
            key: torch.randint(0, 256, (4, 84, 84, 3), dtype=torch.uint8, generator=gen)
            for key in ("pixels_static", "pixels_dynamic")
        },
        [4],
    )
    byol(pairs)["loss_byol"].backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in dve.parameters())
    with pytest.raises(ValueError, match="DualVisualEncoder alone"):
        BYOLLoss(dve, dve.general_encoder)


@pytest.mark.parametrize("frozen", [False, True])
def test_the_dve_is_the_feature_extractor_of_another_torchrl_actor(frozen):
    dve = small_model().dve
    dve.requires_grad_(not frozen)
    keys = [("embed", "static"), ("embed", "general"), ("embed", "target")]
    features = TensorDictModule(lambda *e: torch.cat(e, -1), in_keys=keys, out_keys=["features"])
    net = TensorDictModule(
        nn.Sequential(nn.Linear(3 * 32, 4), NormalParamExtractor()), ["features"], ["loc", "scale"]
    )
    body = TensorDictSequential(dve_module(dve), features, net)
    actor = ProbabilisticActor(
        body, in_keys=["loc", "scale"], distribution_class=TanhNormal, return_log_prob=True
    )
    frames = torch.randint(
        0, 256, (3, 36, 36, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(0)
    )
    out = actor(TensorDict(pixels=frames, target_pixels=frames.flip(0), batch_size=[3]))  # one step, 3 robots
    assert out["action"].shape == (3, 2) and out["embed", "target"].shape == (3, 32)
    out["action_log_prob"].sum().backward()
    assert all((p.grad is None) == frozen for p in dve.parameters())


def test_the_policy_describes_its_transformer_step_path():
    model = small_model()
    assert NavFormerPolicy(model, native=False).describe() == {"transformer_step": "torch"}
    expected = "native" if native_status().available else "torch"
    assert NavFormerPolicy(model).describe() == {"transformer_step": expected}
    assert NavFormerPolicy(model).describe(torch.device("meta")) == {"transformer_step": "torch"}


def test_head_module_reads_the_heads_inputs():
    head = THSCHead(8, 2)
    module = head_module(head)
    assert module.in_keys == [("hidden", "target"), ("hidden", "observation"), "mask"]
    hidden = torch.randn(2, 3, 8)
    out = module(TensorDict({("hidden", "target"): hidden, ("hidden", "observation"): hidden}, [2, 3]))
    torch.testing.assert_close(out["action_pred"], head(hidden, hidden))
