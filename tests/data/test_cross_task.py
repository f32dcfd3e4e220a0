"""CrossTaskReplayBuffer: a TorchRL ensemble alternating D_e / D_ca, drawing what the former sampler drew."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import (
    LazyTensorStorage,
    RandomSampler,
    ReplayBufferEnsemble,
    SliceSampler,
    TensorDictReplayBuffer,
)

from navformer_rl.data import CrossTaskReplayBuffer, open_dataset
from navformer_rl.modules import NavFormerConfig, NavFormerModel, make_navformer_actor
from navformer_rl.objectives import ActionMSELoss


class FormerCrossTaskSampler:
    """The ``CrossTaskSampler`` this buffer replaced, verbatim in behaviour: the reference for its draws and
    for the sampler state that older checkpoints hold."""

    def __init__(self, exploration, collision_avoidance):
        self.sources = [
            (name, batcher)
            for name, batcher in (("exploration", exploration), ("collision_avoidance", collision_avoidance))
            if batcher is not None
        ]
        self.iteration = 0

    def sample(self):
        name, batcher = self.sources[self.iteration % len(self.sources)]
        self.iteration += 1
        return name, batcher.sample()

    def state_dict(self):
        return {"iteration": self.iteration, **{name: b.state_dict() for name, b in self.sources}}


def _batchers(e_dataset, ca_dataset, **options):
    e, ca = open_dataset(e_dataset, "e"), open_dataset(ca_dataset, "ca")
    return e.trajectory_batcher(3, 30, seed=1, **options), ca.trajectory_batcher(5, 30, seed=2, **options)


def _same(a: TensorDict, b: TensorDict) -> bool:
    keys = sorted(a.keys(True, True), key=str)
    return keys == sorted(b.keys(True, True), key=str) and all(torch.equal(a[k], b[k]) for k in keys)


def test_it_is_a_torchrl_ensemble_alternating_the_tasks(e_dataset, ca_dataset):
    buffer = CrossTaskReplayBuffer(*_batchers(e_dataset, ca_dataset))
    assert isinstance(buffer, ReplayBufferEnsemble) and buffer.tasks == ("exploration", "collision_avoidance")
    assert buffer[1] is buffer.buffer("collision_avoidance")
    seen = []
    for _ in range(4):
        task = buffer.next_task
        batch = buffer.sample()
        n = batch.shape[0]
        assert batch["index", "buffer_ids"].shape == (n,)
        assert batch["pixels"].shape[:1] == (n,) and batch["mask"].shape == batch["step"].shape
        assert batch["target_pixels"].shape == (n, 84, 84, 3)
        seen.append((task, buffer.task_of(batch), n, int(batch["task"][0, 0])))
    assert (
        seen
        == [("exploration", "exploration", 3, 0), ("collision_avoidance", "collision_avoidance", 5, 1)] * 2
    )
    only_ca = CrossTaskReplayBuffer(None, _batchers(e_dataset, ca_dataset)[1])
    assert [only_ca.task_of(only_ca.sample()) for _ in range(3)] == ["collision_avoidance"] * 3
    assert CrossTaskReplayBuffer(_batchers(e_dataset, ca_dataset)[0]).tasks == ("exploration",)


def test_wrong_members_and_batch_sizes_are_refused_by_name(e_dataset, ca_dataset):
    with pytest.raises(ValueError, match="at least one of exploration= / collision_avoidance="):
        CrossTaskReplayBuffer(None, None)
    with pytest.raises(TypeError, match="expected a TorchRL ReplayBuffer"):
        CrossTaskReplayBuffer([1, 2, 3])
    frames = TensorDictReplayBuffer(storage=LazyTensorStorage(4), sampler=RandomSampler(), batch_size=2)
    with pytest.raises(ValueError, match="RandomSampler draws no trajectories"):
        CrossTaskReplayBuffer(frames)
    buffer = CrossTaskReplayBuffer(*_batchers(e_dataset, ca_dataset))
    with pytest.raises(ValueError, match="batch sizes are the members' own"):
        buffer.sample(8)
    with pytest.raises(KeyError, match="not sampled from a CrossTaskReplayBuffer"):
        buffer.task_of(TensorDict({}, []))


@pytest.mark.parametrize("prefetch_sets", [1, 2])
def test_draws_are_those_of_the_former_sampler_and_its_checkpoints_resume(
    e_dataset, ca_dataset, prefetch_sets
):
    """Bit-identical training: the same batches in the same order, the same generator states, and a state in
    the former layout (older checkpoints) continues the same stream."""
    former = FormerCrossTaskSampler(*_batchers(e_dataset, ca_dataset, buffer_sets=prefetch_sets))
    new = CrossTaskReplayBuffer(*_batchers(e_dataset, ca_dataset, buffer_sets=prefetch_sets))
    for _ in range(5):
        task, expected = former.sample()
        batch = new.sample()
        assert new.task_of(batch) == task and _same(batch.exclude("index"), expected)
    old_state, new_state = former.state_dict(), new.state_dict()
    assert old_state["iteration"] == new_state["iteration"] == 5
    for task in ("exploration", "collision_avoidance"):
        for key, value in old_state[task].items():
            assert torch.equal(torch.as_tensor(value), torch.as_tensor(new_state[task]["sampler"][key]))
    expected = [(task, batch.clone()) for task, batch in (former.sample() for _ in range(4))]
    resumed = CrossTaskReplayBuffer(*_batchers(e_dataset, ca_dataset))
    resumed.load_state_dict(old_state)  # the layout a checkpoint written before this buffer holds
    for task, batch in expected:
        got = resumed.sample()
        assert resumed.task_of(got) == task and _same(got.exclude("index"), batch)


def test_state_dict_dumps_and_task_mismatch(e_dataset, ca_dataset, tmp_path):
    buffer = CrossTaskReplayBuffer(*_batchers(e_dataset, ca_dataset))
    for _ in range(3):
        buffer.sample()
    buffer.dumps(tmp_path / "rb")
    state = buffer.state_dict()
    expected = [buffer.sample().clone() for _ in range(3)]
    for restore in (lambda b: b.load_state_dict(state), lambda b: b.loads(tmp_path / "rb")):
        resumed = CrossTaskReplayBuffer(*_batchers(e_dataset, ca_dataset))
        restore(resumed)
        assert all(_same(resumed.sample(), batch) for batch in expected)
    with pytest.raises(
        ValueError, match=r"lacks \['collision_avoidance'\]; it was saved with tasks \['exploration'\]"
    ):
        buffer.load_state_dict({"iteration": 0, "exploration": state["exploration"]})


def test_torchrl_members_come_out_as_trajectory_batches_the_loss_takes(e_dataset, ca_dataset):
    """A flat TrajectorySampler buffer and a SliceSampler(pad_output=True) buffer over a LazyTensorStorage:
    [N] batches with [N, T] steps, the mask from ("collector", "mask"), one target image per trajectory."""
    e, ca = open_dataset(e_dataset, "e"), open_dataset(ca_dataset, "ca")
    rows = ca.rows[:].clone()
    rows.set("target_pixels", ca.targets[rows["target_id"]])
    slices = TensorDictReplayBuffer(
        storage=LazyTensorStorage(len(rows)),
        sampler=SliceSampler(num_slices=4, traj_key="episode", strict_length=False, pad_output=True),
        batch_size=4 * 6,
        generator=torch.Generator().manual_seed(0),
    )
    slices.extend(rows)
    buffer = CrossTaskReplayBuffer(e.trajectory_buffer(2, context_steps=8, seed=0), slices)
    model = NavFormerModel(NavFormerConfig(d_embed=32, n_blocks=1, n_heads=2, d_head=16, dropout=0.0))
    loss = ActionMSELoss(make_navformer_actor(model))
    for n, steps in ((2, 8), (4, 6)):
        batch = buffer.sample()
        assert batch.batch_size == (n,) and batch["pixels"].shape == (n, steps, 84, 84, 3)
        assert batch["mask"].shape == (n, steps) and batch["target_pixels"].shape == (n, 84, 84, 3)
        assert batch["index", "index"].shape[0] == n and batch["index", "buffer_ids"].shape == (n,)
        assert torch.isfinite(loss(batch)["loss_dt"])
    # the slice member's generator is part of the state: the same windows after a restore
    state = buffer.state_dict()
    expected = [buffer.sample()["pixels"].clone() for _ in range(2)]
    buffer.load_state_dict(state)
    assert all(torch.equal(buffer.sample()["pixels"], pixels) for pixels in expected)
