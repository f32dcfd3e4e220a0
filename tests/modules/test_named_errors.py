"""Mistakes a TorchRL user makes get one line naming the key or shape to fix, at the boundary: the actor, the
transformer module, the losses and the policy. Plus the policy's TorchRL-style keys and env transforms."""

import warnings

import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.envs import ToTensorImage, TransformedEnv, check_env_specs

from navformer_rl.envs.multi_robot import MultiRobotNavEnv
from navformer_rl.envs.policy_transforms import ToUint8Image, add_policy_transforms
from navformer_rl.envs.torchrl_target_nav import make_torchrl_target_nav_env
from navformer_rl.modules import (
    SINGLE_ROBOT_POLICY_KEYS,
    MissingKeyError,
    NavFormerConfig,
    NavFormerModel,
    NavFormerPolicy,
    make_navformer_actor,
    transformer_module,
)
from navformer_rl.objectives import ActionMSELoss, BYOLLoss

SMALL = {"d_embed": 32, "n_blocks": 1, "n_heads": 2, "d_head": 16, "dropout": 0.0}


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return NavFormerModel(NavFormerConfig(**SMALL))


def one_line(error: pytest.ExceptionInfo) -> str:
    message = str(error.value)
    assert "\n" not in message and not isinstance(error.value, AttributeError)
    return message


@pytest.mark.parametrize("missing", ["return_to_go", "step", "action", "pixels", "target_pixels"])
def test_a_missing_key_is_named_by_the_actor_and_the_loss(model, batch_factory, missing):
    batch = TensorDict(batch_factory(2, 4), batch_size=[2]).exclude(missing)
    for module, who in (
        (make_navformer_actor(model), "the NavFormer actor"),
        (ActionMSELoss(make_navformer_actor(model)), "ActionMSELoss"),
    ):
        with pytest.raises(MissingKeyError) as error:
            module(batch)
        assert isinstance(error.value, KeyError) and isinstance(error.value, ValueError)
        message = one_line(error)
        assert message.startswith(f"{who} reads {missing!r}") and "set it" in message


def test_the_transformer_module_names_its_missing_embedding(model, batch_factory):
    module = transformer_module(model.transformer)
    batch = TensorDict(batch_factory(2, 4), batch_size=[2])
    batch.set(("embed", "target"), torch.zeros(2, 32))
    batch.set(("embed", "general"), torch.zeros(2, 4, 32))
    with pytest.raises(MissingKeyError) as error:
        module(batch)
    assert "transformer_module reads ('embed', 'static')" in one_line(error)
    assert "in_keys" in str(error.value)
    with pytest.raises(ValueError, match="CausalTransformer: return_to_go is None"):
        model.transformer(
            torch.zeros(2, 32),
            None,
            torch.zeros(2, 4, 2),
            torch.zeros(2, 4, dtype=torch.long),
            static=torch.zeros(2, 4, 32),
            general=torch.zeros(2, 4, 32),
        )


def test_a_flat_replay_buffer_sample_is_named_as_such(model, batch_factory):
    flat = TensorDict(batch_factory(2, 4), batch_size=[2]).exclude("target_pixels")
    flat = TensorDict({k: v.reshape(8, *v.shape[2:]) for k, v in flat.items()}, [8])  # [N * T] rows
    flat.set("target_pixels", torch.zeros(8, 84, 84, 3, dtype=torch.uint8))
    with pytest.raises(ValueError) as error:
        make_navformer_actor(model)(flat)
    assert "'pixels' must be uint8 [N, T, H, W, 3], got shape [8, 84, 84, 3]" in one_line(error)
    assert "sample.reshape(N, -1)" in str(error.value) and "CrossTaskReplayBuffer" in str(error.value)


def test_a_padded_batch_without_its_mask_is_refused(model, batch_factory):
    batch = TensorDict(batch_factory(2, 5), batch_size=[2])
    batch["step"][1, 3:] = 2  # the data package's padding repeats the last valid step
    make_navformer_actor(model)(batch.clone())  # with the mask: fine
    unmasked = batch.exclude("mask")
    for module in (make_navformer_actor(model), ActionMSELoss(make_navformer_actor(model))):
        with pytest.raises(
            ValueError, match=r"has no 'mask' but its 'step' does not increase by one .* looks padded"
        ):
            module(unmasked)
    unpadded = TensorDict(batch_factory(2, 5), batch_size=[2]).exclude("mask")
    assert make_navformer_actor(model)(unpadded)["action_pred"].shape == (2, 5, 2)  # the mask is optional
    collector_mask = unmasked.clone()
    collector_mask.set(("collector", "mask"), batch["mask"])
    with pytest.raises(MissingKeyError, match=r"has \('collector', 'mask'\) but no 'mask'"):
        ActionMSELoss(make_navformer_actor(model))(collector_mask)


def test_byol_names_its_missing_and_malformed_images(model):
    byol = BYOLLoss(model.dve)
    pairs = TensorDict({"pixels_dynamic": torch.zeros(4, 84, 84, 3, dtype=torch.uint8)}, [4])
    with pytest.raises(MissingKeyError) as error:
        byol(pairs)
    assert one_line(error).startswith("BYOLLoss reads 'pixels_static'") and "set_keys" in str(error.value)
    pairs.set("pixels_static", torch.zeros(4, 3, 84, 84))
    with pytest.raises(ValueError, match=r"'pixels_static' must be uint8 \[B, H, W, 3\]"):
        byol(pairs)


def test_policy_keys_as_on_torchrl_modules(model):
    default = NavFormerPolicy(model)
    assert default.in_keys == [
        ("agents", "pixels"),
        ("agents", "target_pixels"),
        ("agents", "step_count"),
        ("agents", "reward"),
        "is_init",
    ]
    assert default.out_keys == [("agents", "action")]
    by_name = NavFormerPolicy(model).set_keys(**SINGLE_ROBOT_POLICY_KEYS)
    assert by_name.in_keys == ["pixels", "target_pixels", "step_count", "is_init"] and by_name.out_keys == [
        "action"
    ]
    listed = NavFormerPolicy(model, in_keys=["pixels", "target_pixels", "step_count"], out_keys=["action"])
    assert listed.in_keys == ["pixels", "target_pixels", "step_count"] and listed.is_init_key is None
    former = NavFormerPolicy(
        model,
        pixels_key="pixels",
        target_pixels_key="target_pixels",
        step_count_key=None,
        reward_key=None,
        action_key="action",
    )
    assert former.in_keys == ["pixels", "target_pixels", "is_init"] and former.action_key == "action"
    assigned = NavFormerPolicy(model)
    assigned.in_keys = {"pixels": "frame"}
    assert assigned.pixels_key == "frame" and assigned.target_pixels_key == ("agents", "target_pixels")
    by_name.in_keys = (
        by_name.in_keys
    )  # a list is taken for what the policy reads: a round trip changes nothing
    assert (
        by_name.in_keys == ["pixels", "target_pixels", "step_count", "is_init"] and by_name.reward_key is None
    )
    by_name.in_keys = ["frame", "goal"]  # renamed, and the keys past the list's end no longer read
    assert by_name.in_keys == ["frame", "goal"] and by_name.is_init_key is None
    with pytest.raises(ValueError, match=r"either as in_keys= / out_keys= or as \['pixels_key'\]"):
        NavFormerPolicy(model, in_keys=["a", "b"], pixels_key="pixels")
    with pytest.raises(ValueError, match=r"\['observation'\] are not keys of the policy"):
        NavFormerPolicy(model).set_keys(observation="pixels")
    with pytest.raises(ValueError, match="expected 2 to 5 keys"):
        NavFormerPolicy(model, in_keys=["pixels"])
    frames = torch.zeros(2, 84, 84, 3, dtype=torch.uint8)
    out = listed(
        TensorDict(
            pixels=frames,
            target_pixels=frames,
            step_count=torch.zeros(2, 1, dtype=torch.long),
            batch_size=[2],
        )
    )
    assert out["action"].shape == (2, 2)


def test_policy_names_missing_and_float_images(model):
    policy = NavFormerPolicy(model)
    td = TensorDict({"pixels": torch.zeros(2, 84, 84, 3, dtype=torch.uint8)}, [])
    with pytest.raises(MissingKeyError) as error:
        policy(td)
    assert "reads ('agents', 'pixels')" in one_line(error) and "policy.set_keys(pixels=...)" in str(
        error.value
    )
    policy.set_keys(pixels="pixels", target_pixels="pixels")
    td.set("pixels", torch.rand(2, 3, 84, 84))
    with pytest.raises(
        ValueError,
        match=r"must be uint8 HWC images .* append navformer_rl.envs.policy_transforms.ToUint8Image",
    ):
        policy(td)


def test_env_transforms_for_the_policy_and_uint8_images(model):
    policy = NavFormerPolicy(model.eval()).set_keys(**SINGLE_ROBOT_POLICY_KEYS)
    single = add_policy_transforms(make_torchrl_target_nav_env(size=5.0), policy)
    assert [type(t).__name__ for t in single.transform] == ["StepCounter", "InitTracker"]
    multi = MultiRobotNavEnv(size=5.0, n_robots=2, max_steps=6, seed=0)
    multi = add_policy_transforms(multi, NavFormerPolicy(model))
    assert type(multi.transform).__name__ == "InitTracker"
    assert add_policy_transforms(multi, NavFormerPolicy(model)) is multi  # nothing lacking: unchanged
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        collector = Collector(single, policy, frames_per_batch=4, total_frames=8)
        steps = [batch["step_count"].reshape(-1).tolist() for batch in collector]
        collector.shutdown()
    assert steps == [[0, 1, 2, 3], [4, 5, 6, 7]]
    assert not [w for w in caught if issubclass(w.category, FutureWarning)]
    keys = [("agents", "pixels"), ("agents", "target_pixels")]

    def uint8_again():
        env = TransformedEnv(MultiRobotNavEnv(size=5.0, n_robots=2, seed=0), ToTensorImage(in_keys=keys))
        assert env.reset()["agents", "pixels"].dtype == torch.float32
        env = TransformedEnv(MultiRobotNavEnv(size=5.0, n_robots=2, seed=0), ToTensorImage(in_keys=keys))
        return env.append_transform(ToUint8Image(keys))

    check_env_specs(uint8_again())
    plain = MultiRobotNavEnv(size=5.0, n_robots=2, seed=0).reset()
    assert torch.equal(
        uint8_again().reset()["agents", "pixels"], plain["agents", "pixels"]
    )  # exact round trip
