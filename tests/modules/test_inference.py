"""NavFormerPolicy on MultiRobotNavEnv-shaped tensordicts and inside ``env.rollout``."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from navformer_rl.modules import IncrementalNavFormer, NavFormerConfig, NavFormerModel, NavFormerPolicy


def make_model(seed=0):
    torch.manual_seed(seed)
    return NavFormerModel(NavFormerConfig(context_tokens=24)).eval()


def agents_td(pixels, target, step_count, reward=None):
    agents = {"pixels": pixels, "target_pixels": target, "step_count": step_count}
    if reward is not None:
        agents["reward"] = reward
    return TensorDict({"agents": TensorDict(agents, batch_size=[pixels.shape[0]])}, batch_size=[])


def frames(n, seed):
    gen = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (n, 84, 84, 3), dtype=torch.uint8, generator=gen)


def test_policy_matches_the_decoder_with_rtg_updated_by_rewards():
    model = make_model()
    policy = NavFormerPolicy(model)
    decoder = IncrementalNavFormer(model, 3)
    target = frames(3, 0)
    rewards = [torch.zeros(3, 1), torch.tensor([[0.0], [1.0], [0.0]]), torch.tensor([[0.5], [0.0], [0.0]])]
    rtg = torch.ones(3, 1)
    prev = torch.zeros(3, 2)
    for t in range(9):  # past the 6-step window
        pixels = frames(3, 100 + t)
        reward = rewards[t] if t < len(rewards) else torch.zeros(3, 1)
        td = agents_td(pixels, target, torch.full((3, 1), t), reward)
        action = policy(td)["agents", "action"]
        rtg = rtg - (reward if t > 0 else 0)
        expected = decoder.step(target, pixels, rtg, prev)
        prev = expected
        assert action.shape == (3, 2) and action.dtype == torch.float32
        torch.testing.assert_close(action, expected, rtol=0, atol=1e-6)
    torch.testing.assert_close(policy._return_to_go, torch.tensor([[0.5], [0.0], [1.0]]))


def test_step_count_zero_resets_only_that_robot():
    model = make_model()
    policy = NavFormerPolicy(model)
    fresh = NavFormerPolicy(make_model())
    target = frames(2, 0)
    for t in range(7):
        pixels = frames(2, 200 + t)
        step_count = torch.tensor([[t], [max(t - 4, 0)]])  # robot 1 restarts at t = 4
        action = policy(agents_td(pixels, target, step_count))["agents", "action"]
        if t >= 4:  # robot 1 behaves like a policy that has only seen its new episode
            alone = fresh(agents_td(pixels[1:], target[1:], step_count[1:]))["agents", "action"]
            torch.testing.assert_close(action[1:], alone, rtol=0, atol=1e-6)
    assert policy._decoder.steps_done.tolist() == [7, 3]


def test_policy_handles_root_keys_and_batched_leading_dims():
    model = make_model()
    single = NavFormerPolicy(model, pixels_key="pixels", target_pixels_key="target_pixels",
                             step_count_key=None, reward_key=None, action_key="action")  # fmt: skip
    td = TensorDict({"pixels": frames(1, 1)[0], "target_pixels": frames(1, 2)[0]}, batch_size=[])
    assert single(td)["action"].shape == (2,)
    batched = NavFormerPolicy(model)
    pixels, target = frames(6, 3).reshape(2, 3, 84, 84, 3), frames(6, 4).reshape(2, 3, 84, 84, 3)
    td = TensorDict(
        {"agents": TensorDict({"pixels": pixels, "target_pixels": target,
                               "step_count": torch.zeros(2, 3, 1, dtype=torch.long)}, batch_size=[2, 3])},
        batch_size=[2],
    )  # fmt: skip
    action = batched(td)["agents", "action"]
    flat = NavFormerPolicy(model)(
        agents_td(
            pixels.reshape(6, 84, 84, 3), target.reshape(6, 84, 84, 3), torch.zeros(6, 1, dtype=torch.long)
        )
    )
    torch.testing.assert_close(action.reshape(6, 2), flat["agents", "action"], rtol=0, atol=1e-6)


class TwoRobotEnv(EnvBase):
    """A minimal env with MultiRobotNavEnv's keys: random frames, episodes of ``horizon`` steps."""

    def __init__(self, robots=2, horizon=5):
        super().__init__(batch_size=[])
        self.robots, self.horizon = robots, horizon
        image = Bounded(0, 255, (robots, 84, 84, 3), dtype=torch.uint8)
        self.observation_spec = Composite(
            agents=Composite(
                pixels=image, target_pixels=image.clone(),
                step_count=Unbounded((robots, 1), dtype=torch.int64), shape=(robots,),
            )
        )  # fmt: skip
        self.action_spec = Composite(agents=Composite(action=Bounded(-1, 1, (robots, 2)), shape=(robots,)))
        self.reward_spec = Composite(agents=Composite(reward=Unbounded((robots, 1)), shape=(robots,)))
        self.done_spec = Composite(
            done=Categorical(2, (1,), dtype=torch.bool), terminated=Categorical(2, (1,), dtype=torch.bool),
            truncated=Categorical(2, (1,), dtype=torch.bool),
        )  # fmt: skip
        self.gen = torch.Generator().manual_seed(0)
        self.t = 0

    def _obs(self):
        pixels = torch.randint(0, 256, (self.robots, 84, 84, 3), dtype=torch.uint8, generator=self.gen)
        target = torch.full((self.robots, 84, 84, 3), 7, dtype=torch.uint8)
        step = torch.full((self.robots, 1), self.t)
        return TensorDict(
            {"pixels": pixels, "target_pixels": target, "step_count": step}, batch_size=[self.robots]
        )

    def _reset(self, tensordict=None):
        self.t = 0
        return TensorDict({"agents": self._obs(), "done": torch.zeros(1, dtype=torch.bool),
                           "terminated": torch.zeros(1, dtype=torch.bool),
                           "truncated": torch.zeros(1, dtype=torch.bool)}, batch_size=[])  # fmt: skip

    def _step(self, tensordict):
        action = tensordict["agents", "action"]
        assert action.shape == (self.robots, 2) and action.abs().max() <= 1
        self.t += 1
        done = torch.tensor([self.t >= self.horizon])
        agents = self._obs()
        agents.set("reward", torch.zeros(self.robots, 1))
        return TensorDict({"agents": agents, "done": done, "terminated": done.clone(),
                           "truncated": torch.zeros(1, dtype=torch.bool)}, batch_size=[])  # fmt: skip

    def _set_seed(self, seed):
        self.gen.manual_seed(seed or 0)


def test_policy_runs_in_env_rollout_across_episodes():
    env = TwoRobotEnv(robots=2, horizon=4)
    policy = NavFormerPolicy(make_model())
    rollout = env.rollout(10, policy, break_when_any_done=False)
    assert rollout["agents", "action"].shape == (10, 2, 2)
    # every reset (step_count 0) restarted each robot's context: steps 0-3, 0-3, 0-1
    assert policy._decoder.steps_done.tolist() == [2, 2]


def test_policy_leaves_a_training_model_in_training_mode():
    # evaluating the model being trained (e.g. every k iterations) must not switch its dropout off
    model = make_model().train()
    policy = NavFormerPolicy(model)
    td = agents_td(frames(2, 1), frames(2, 2), torch.zeros(2, 1, dtype=torch.long))
    action = policy(td)["agents", "action"]
    assert model.training
    reference = NavFormerPolicy(make_model())(
        agents_td(frames(2, 1), frames(2, 2), torch.zeros(2, 1, dtype=torch.long))
    )
    torch.testing.assert_close(action, reference["agents", "action"], rtol=0, atol=0)  # decided in eval mode


def test_is_init_restarts_the_context_like_step_count_zero():
    # a single-robot env without step_count gets its resets from TorchRL's InitTracker ("is_init")
    model = make_model()
    keys = dict(pixels_key="pixels", target_pixels_key="target_pixels", step_count_key=None, reward_key=None,
                action_key="action")  # fmt: skip
    policy = NavFormerPolicy(model, **keys)

    def td(step, is_init):
        return TensorDict(
            {"pixels": frames(1, 10 + step)[0], "target_pixels": frames(1, 2)[0],
             "is_init": torch.tensor([is_init])},
            batch_size=[],
        )  # fmt: skip

    for step in range(3):
        policy(td(step, step == 0))
    restarted = policy(td(0, True))["action"]
    fresh = NavFormerPolicy(make_model(), **keys)(td(0, True))["action"]
    torch.testing.assert_close(restarted, fresh, rtol=0, atol=1e-6)
    assert policy._decoder.steps_done.tolist() == [1]


def test_torchrl_weight_sync_through_data_is_read_at_the_next_episode():
    """Collectors copy new weights with ``TensorDict.from_module(policy).data.update_(...)``, which no
    version counter sees: a new episode must still act with them (the running one keeps its KV cache)."""
    policy = NavFormerPolicy(make_model(0))
    target, pixels = frames(2, 0), frames(2, 1)
    for t in range(3):
        policy(agents_td(pixels, target, torch.full((2, 1), t)))
    new_weights = TensorDict.from_module(make_model(1))
    TensorDict.from_module(policy.model).data.update_(new_weights.data)
    action = policy(agents_td(pixels, target, torch.zeros(2, 1, dtype=torch.long)))["agents", "action"]
    expected = NavFormerPolicy(make_model(1))(agents_td(pixels, target, torch.zeros(2, 1, dtype=torch.long)))
    torch.testing.assert_close(action, expected["agents", "action"], rtol=0, atol=1e-6)


def test_a_used_policy_pickles_and_copies_start_new_episodes_on_their_own_weights():
    import copy
    import io
    import pickle

    policy = NavFormerPolicy(make_model(0))
    target, pixels = frames(1, 0), frames(1, 1)
    policy(agents_td(pixels, target, torch.zeros(1, 1, dtype=torch.long)))
    restored = pickle.loads(pickle.dumps(policy))
    buffer = io.BytesIO()
    torch.save(policy, buffer)  # what users and spawned collector workers do
    copied = copy.deepcopy(policy)
    assert policy._decoder is not None and copied._decoder is None and restored._decoder is None
    with torch.no_grad():
        for p in copied.model.parameters():
            p.add_(0.01)
    start = agents_td(pixels, target, torch.zeros(1, 1, dtype=torch.long))
    moved = NavFormerPolicy(copy.deepcopy(copied.model))
    torch.testing.assert_close(
        copied(start.clone())["agents", "action"], moved(start.clone())["agents", "action"]
    )
    torch.testing.assert_close(
        restored(start.clone())["agents", "action"],
        NavFormerPolicy(make_model(0))(start.clone())["agents", "action"],
    )


def test_policy_input_mistakes_are_named():
    import pytest

    policy = NavFormerPolicy(make_model())
    td = agents_td(frames(2, 0), frames(2, 1), torch.zeros(2, 1, dtype=torch.long))
    with pytest.raises(KeyError, match=r"reads .*pixels.* missing from the input tensordict"):
        NavFormerPolicy(make_model(), pixels_key="pixels")(td.clone())
    del td["agents", "target_pixels"]
    with pytest.raises(KeyError, match=r"reads .*agents.*target_pixels.* missing"):
        policy(td)
    small = torch.zeros(2, 64, 64, 3, dtype=torch.uint8)
    with pytest.raises(ValueError, match=r"expected frames \[\.\.\., 84, 84, 3\]"):
        policy(agents_td(small, small, torch.zeros(2, 1, dtype=torch.long)))
    with pytest.raises(ValueError, match="one target image per robot"):
        policy(TensorDict({"agents": {"pixels": frames(2, 0), "target_pixels": frames(1, 1)}}, batch_size=[]))
    assert "is_init" in policy.in_keys


def test_new_episodes_rebuild_the_tables_only_when_the_weights_changed(monkeypatch):
    policy = NavFormerPolicy(make_model(0))
    target, pixels = frames(1, 0), frames(1, 1)
    start = torch.zeros(1, 1, dtype=torch.long)
    policy(agents_td(pixels, target, start))
    rebuilds = []
    monkeypatch.setattr(policy._decoder, "refresh", lambda: rebuilds.append(1))
    for _ in range(3):  # an env whose episodes last one step: a new episode at every call
        policy(agents_td(pixels, target, start))
    assert rebuilds == []
    TensorDict.from_module(policy.model).data.update_(TensorDict.from_module(make_model(1)).data)
    policy(agents_td(pixels, target, start))
    assert rebuilds == [1]


def test_context_steps_runs_the_decoder_with_that_window_and_is_checked():
    model = make_model()  # a 6-step context
    policy = NavFormerPolicy(model, context_steps=2)
    decoder = IncrementalNavFormer(model, 2, window_steps=2)
    whole = IncrementalNavFormer(model, 2)
    target, prev = frames(2, 0), torch.zeros(2, 2)
    differs = False
    for t in range(5):
        pixels = frames(2, 300 + t)
        action = policy(agents_td(pixels, target, torch.full((2, 1), t)))["agents", "action"]
        expected = decoder.step(target, pixels, torch.ones(2, 1), prev)
        differs |= not torch.allclose(expected, whole.step(target, pixels, torch.ones(2, 1), prev), atol=1e-4)
        prev = expected
        torch.testing.assert_close(action, expected, rtol=0, atol=1e-6)
    assert policy._decoder.window_steps == 2 and differs
    policy.context_steps = None  # back to the whole context: a new decoder, new episodes
    policy(agents_td(frames(2, 9), target, torch.full((2, 1), 5)))
    assert policy._decoder.window_steps == 6 and policy._decoder.steps_done.tolist() == [1, 1]
    with pytest.raises(
        ValueError, match=r"context_steps=7: expected a whole number of timesteps from 1 to 6"
    ):
        NavFormerPolicy(model, context_steps=7)
