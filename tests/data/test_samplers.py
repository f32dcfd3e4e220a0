"""Trajectory / pair samplers, on synthetic datasets with known contents."""

import io

import pytest
import torch
from tensordict import TensorDict

from navformer_rl.data import open_dataset
from navformer_rl.data.samplers import EpochPermutation, split_by_length


def _drain(batcher, n):
    return [batcher.sample().clone() for _ in range(n)]


def test_epoch_without_replacement(e_dataset):
    ds = open_dataset(e_dataset)
    batcher = ds.trajectory_batcher(4, context_steps=255, seed=0)
    seen = torch.cat([b["trajectory"] for b in _drain(batcher, 3)])
    assert sorted(seen.tolist()) == list(range(12))  # one epoch = every trajectory exactly once
    assert batcher.sampler.epoch == 0
    batcher.sample()
    assert batcher.sampler.epoch == 1


def test_epoch_drops_the_short_tail():
    perm = EpochPermutation(10, seed=0)
    first = [perm.draw(4) for _ in range(2)]
    assert len(torch.cat(first).unique()) == 8
    third = perm.draw(4)  # only 2 left in epoch 0: a new epoch starts, no id repeats inside the batch
    assert perm.epoch == 1 and len(third.unique()) == 4
    with pytest.raises(ValueError, match="batch of 11 items requested from a set of 10"):
        perm.draw(11)


def test_windows_mask_padding_and_targets(e_dataset):
    ds = open_dataset(e_dataset)
    lengths = ds.episodes.length
    batcher = ds.trajectory_batcher(6, context_steps=10, seed=1)
    for batch in _drain(batcher, 6):
        traj = batch["trajectory"]
        N, T = batch["mask"].shape
        window = lengths[traj].clamp(max=10)
        assert T == int(window.max())
        assert torch.equal(batch["mask"].sum(1), window)
        assert torch.equal(batch["mask"], torch.arange(T)[None] < window[:, None])  # right padding only
        for i in range(N):
            L = int(window[i])
            # never crosses an episode (padding included) and steps are consecutive in the valid part
            assert (batch["episode"][i] == traj[i]).all()
            steps = batch["step"][i, :L]
            assert torch.equal(steps, steps[0] + torch.arange(L))
            assert 0 <= steps[0] and steps[-1] < lengths[traj[i]]
            # padding repeats the last valid step
            assert (batch["step"][i, L:] == steps[-1]).all()
            assert torch.equal(batch["pixels"][i, L:], batch["pixels"][i, L - 1 : L].expand(T - L, 84, 84, 3))
            # rows are exactly the stored rows
            rows = ds.rows[ds.episodes.start[traj[i]] + steps]
            assert torch.equal(batch["pixels"][i, :L], rows["pixels"])
            assert torch.equal(batch["action"][i, :L], rows["action"])
            # the target image is the trajectory's own
            assert torch.equal(batch["target_pixels"][i], ds.targets[batch["target_id"][i, 0]])
            assert (batch["target_id"][i] == ds.episodes.target_id[traj[i]]).all()


def test_long_trajectories_get_random_windows(e_dataset):
    ds = open_dataset(e_dataset)
    long = int(torch.argmax(ds.episodes.length))
    assert ds.episodes.length[long] > 12
    batcher = ds.trajectory_batcher(12, context_steps=4, seed=2)
    starts = set()
    for _ in range(20):
        b = batcher.sample()
        i = int((b["trajectory"] == long).nonzero()[0, 0])
        assert b["mask"][i].all()
        starts.add(int(b["step"][i, 0]))
    assert len(starts) > 3 and max(starts) <= ds.episodes.length[long] - 4


def test_deterministic_for_a_seed_and_differs_across_seeds(e_dataset):
    ds = open_dataset(e_dataset)
    a = _drain(ds.trajectory_batcher(5, 8, seed=7), 4)
    b = _drain(ds.trajectory_batcher(5, 8, seed=7), 4)
    c = _drain(ds.trajectory_batcher(5, 8, seed=8), 4)
    assert all((x == y).all() for x, y in zip(a, b))
    assert any(not torch.equal(x["trajectory"], y["trajectory"]) for x, y in zip(a, c))


def test_state_dict_resume_gives_identical_next_batches(e_dataset):
    ds = open_dataset(e_dataset)
    batcher = ds.trajectory_batcher(5, 8, seed=3)
    _drain(batcher, 3)  # crosses an epoch boundary (12 // 5 = 2 batches per epoch)
    buf = io.BytesIO()
    torch.save(batcher.state_dict(), buf)
    expected = _drain(batcher, 5)
    resumed = ds.trajectory_batcher(5, 8, seed=999)
    buf.seek(0)
    resumed.load_state_dict(torch.load(buf, weights_only=True))
    got = _drain(resumed, 5)
    assert all((x == y).all() for x, y in zip(expected, got))


def test_reused_buffers_are_overwritten_and_copies_are_not(e_dataset):
    ds = open_dataset(e_dataset)
    reuse = ds.trajectory_batcher(2, 6, seed=0)
    first = reuse.sample()
    keep = first["pixels"].clone()
    reuse.sample()
    assert first["pixels"].data_ptr() == reuse.sample()["pixels"].data_ptr()
    fresh = ds.trajectory_batcher(2, 6, seed=0, reuse_buffers=False)
    a = fresh.sample()
    assert torch.equal(a["pixels"], keep)
    fresh.sample()
    assert torch.equal(a["pixels"], keep)


def test_torchrl_replay_buffer_path_matches_fast_path(e_dataset):
    ds = open_dataset(e_dataset)
    rb = ds.trajectory_buffer(4, context_steps=7, seed=5)
    fast = ds.trajectory_batcher(4, context_steps=7, seed=5)
    for _ in range(3):
        flat = rb.sample()
        batch = fast.sample()
        N, T = batch["mask"].shape
        padded = flat.reshape(N, -1)
        assert padded.shape == (N, T)
        assert torch.equal(padded["collector", "mask"], batch["mask"])
        assert torch.equal(padded["pixels"], batch["pixels"])
        assert torch.equal(padded["target_pixels"][:, 0], batch["target_pixels"])


def test_trajectory_sampling_refuses_ssl(ssl_dataset):
    with pytest.raises(ValueError, match="is a 'ssl' dataset"):
        open_dataset(ssl_dataset).trajectory_batcher(4)


def test_pairs_without_replacement_and_resume(ssl_dataset):
    ds = open_dataset(ssl_dataset)
    pairs = ds.pair_batcher(batch_size=8, seed=0)
    epoch = [pairs.sample().clone() for _ in range(5)]
    assert sorted(torch.cat([b["index"] for b in epoch]).tolist()) == list(range(40))
    b = epoch[0]
    assert torch.equal(b["pixels_static"], ds.rows["pixels_static"][b["index"]])
    assert torch.equal(b["pixels_dynamic"], ds.rows["pixels_dynamic"][b["index"]])
    state = pairs.state_dict()
    expected = [pairs.sample().clone() for _ in range(3)]
    other = ds.pair_batcher(batch_size=8, seed=1)
    other.load_state_dict(state)
    assert all((x == y).all() for x, y in zip(expected, [other.sample().clone() for _ in range(3)]))
    with pytest.raises(ValueError, match="batch_size must be in"):
        ds.pair_batcher(batch_size=41)
    assert ds.pair_buffer(batch_size=8).sample()["pixels_static"].shape == (8, 84, 84, 3)


def test_batch_larger_than_dataset_is_refused_up_front(e_dataset):
    with pytest.raises(ValueError, match=r"13 trajectories per batch requested from .* which holds 12"):
        open_dataset(e_dataset).trajectory_batcher(13)


def test_reused_buffers_grow_to_the_batch_and_never_past_the_context(e_dataset):
    ds = open_dataset(e_dataset)
    batcher = ds.trajectory_batcher(4, context_steps=40, seed=0)
    for _ in range(6):
        batch = batcher.sample()
        rows = batcher._buffer_sets[0][("pixels",)].shape[0]
        assert batch["mask"].numel() <= rows <= 4 * 40


def test_torchrl_buffer_feeds_the_loss_with_its_mask(e_dataset):
    # the buffer writes the validity mask under "mask" (what ActionMSELoss and the actor read), not only
    # under TorchRL's ("collector", "mask"): padded steps must not count
    from navformer_rl.modules import NavFormerConfig, NavFormerModel, make_navformer_actor
    from navformer_rl.objectives import ActionMSELoss

    batch = open_dataset(e_dataset).trajectory_buffer(3, context_steps=12, seed=1).sample().reshape(3, -1)
    assert torch.equal(batch["mask"], batch["collector", "mask"]) and not bool(batch["mask"].all())
    torch.manual_seed(0)
    loss = ActionMSELoss(
        make_navformer_actor(
            NavFormerModel(NavFormerConfig(d_embed=16, n_blocks=1, n_heads=1, d_head=16, dropout=0.0))
        )
    )
    expected = loss(batch)["loss_dt"]
    junk = batch.clone()
    junk["action"][~batch["mask"]] = 9.0  # padded steps' actions may be anything
    torch.testing.assert_close(loss(junk)["loss_dt"], expected, rtol=0, atol=0)
    del junk["mask"]
    with pytest.raises(KeyError, match="set_keys\\(mask=\\('collector', 'mask'\\)\\)"):
        loss(junk)


def test_dataset_buffers_are_read_only_and_attach_targets(e_dataset):
    from torchrl.data.replay_buffers import SliceSampler

    ds = open_dataset(e_dataset)
    before = ds.rows["pixels"][:4].clone()
    rb = ds.trajectory_buffer(2)
    with pytest.raises(RuntimeError):
        rb.extend(ds.rows[:4].clone().apply(lambda x: torch.zeros_like(x)))
    assert torch.equal(open_dataset(e_dataset).rows["pixels"][:4], before)  # nothing written to disk
    sliced = ds.replay_buffer(sampler=SliceSampler(slice_len=4, traj_key="episode"), batch_size=8).sample()
    assert sliced["target_pixels"].shape == (8, 84, 84, 3)
    assert torch.equal(sliced["target_pixels"], ds.targets[sliced["target_id"]])


def test_sampler_follows_a_growing_buffer_and_dumps_its_state(e_dataset, tmp_path):
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

    from navformer_rl.data.samplers import TrajectorySampler

    rows = open_dataset(e_dataset).rows
    episode = rows["episode"]
    first = int((episode < 2).sum())
    rb = TensorDictReplayBuffer(
        storage=LazyTensorStorage(len(rows)),
        sampler=TrajectorySampler(2, context_steps=5, seed=0),
        batch_size=2,
    )
    rb.extend(rows[:first].clone())
    assert set(rb.sample()["episode"].tolist()) <= {0, 1}
    rb.extend(rows[first:].clone())  # more trajectories: the next epochs draw from all of them
    seen = {e for _ in range(20) for e in rb.sample()["episode"].tolist()}
    assert seen == set(range(int(episode.max()) + 1))
    rb.dumps(tmp_path / "rb")  # the sampler's folder is created
    assert (tmp_path / "rb" / "sampler" / "trajectory_sampler.pt").is_file()


def test_split_by_length_groups_similar_lengths_and_crops_only_padding():
    lengths = torch.tensor([5, 2, 7, 2, 4])
    steps = 7
    mask = torch.arange(steps) < lengths[:, None]
    batch = TensorDict(
        {
            "pixels": torch.arange(5 * steps * 2, dtype=torch.uint8).reshape(5, steps, 1, 2),
            "action": torch.randn(5, steps, 2, generator=torch.Generator().manual_seed(0)),
            "mask": mask,
            "target_pixels": torch.arange(5 * steps, dtype=torch.uint8).reshape(5, steps),  # [N, 7]: like T
            "trajectory": torch.arange(5),
        },
        batch_size=[5],
    )
    parts = split_by_length(batch, 2)
    # stable order by length: rows 1, 3 (2 steps), 4 (4), 0 (5), 2 (7); the first group one larger
    assert [p["trajectory"].tolist() for p in parts] == [[1, 3, 4], [0, 2]]
    assert [p["mask"].shape[1] for p in parts] == [4, 7]
    for part in parts:
        rows = part["trajectory"]
        t = part["mask"].shape[1]
        assert torch.equal(part["pixels"], batch["pixels"][rows, :t])
        assert torch.equal(part["action"], batch["action"][rows, :t])
        assert torch.equal(part["mask"], mask[rows, :t])
        assert torch.equal(part["target_pixels"], batch["target_pixels"][rows])  # per trajectory: uncropped
    assert sum(int(p["mask"].sum()) for p in parts) == int(mask.sum())  # every valid step once
    assert len(split_by_length(batch, 9)) == 5  # at most one group per trajectory
    with pytest.raises(ValueError, match="parts must be >= 1, got 0"):
        split_by_length(batch, 0)
