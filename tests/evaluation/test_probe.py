"""Linear probes of the encoders' frame embeddings (navformer_rl.evaluation.diagnose.probe): known answers of
the ridge fit, R² and ROC AUC; probes that find what an embedding holds and nothing where it holds nothing;
the embeddings of a checkpoint on held-out windows; the CLI and its errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from navformer_rl.evaluation.diagnose.probe import (
    PROBE_JSON,
    PROBE_MD,
    QUANTITIES,
    frame_embeddings,
    paired_probe_differences,
    probe_scores,
    r_squared,
    ridge_predict,
    roc_auc,
)

TINY_MODEL = {"d_embed": 16, "d_head": 8, "n_blocks": 1, "max_timestep": 64}


def test_ridge_recovers_an_exact_linear_map_and_shrinks_towards_the_mean():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(400, 5))
    y = x @ np.array([1.0, -2.0, 0.0, 0.5, 3.0]) + 4.0
    test = rng.normal(size=(50, 5))
    expected = test @ np.array([1.0, -2.0, 0.0, 0.5, 3.0]) + 4.0
    np.testing.assert_allclose(ridge_predict(x, y, test, ridge=1e-12), expected, atol=1e-8)
    shrunk = ridge_predict(x, y, test, ridge=1e6)  # all weight penalised away: the mean of y
    np.testing.assert_allclose(shrunk, np.full(50, y.mean()), atol=1e-3)
    two = ridge_predict(x, np.stack([y, -y], axis=1), test, ridge=1e-12)
    assert two.shape == (50, 2)
    np.testing.assert_allclose(two[:, 1], -expected, atol=1e-8)


def test_r_squared_known_answers():
    actual = np.array([1.0, 2.0, 3.0, 4.0])
    assert r_squared(actual, actual) == 1.0
    assert r_squared(np.full(4, 2.5), actual) == 0.0  # the mean
    assert r_squared(np.array([4.0, 3.0, 2.0, 1.0]), actual) == pytest.approx(-3.0)
    assert np.isnan(r_squared(actual, np.ones(4)))


def test_roc_auc_is_the_share_of_positive_negative_pairs_ordered_right():
    rng = np.random.default_rng(1)
    score = rng.integers(0, 5, size=60).astype(float)  # many ties
    positive = rng.random(60) < 0.4
    pairs = score[positive][:, None] - score[~positive][None, :]
    brute = (np.sum(pairs > 0) + 0.5 * np.sum(pairs == 0)) / pairs.size
    assert roc_auc(score, positive) == pytest.approx(brute)
    assert roc_auc(np.arange(4.0), np.array([False, False, True, True])) == 1.0
    assert roc_auc(np.arange(4.0), np.array([True, True, False, False])) == 0.0
    assert np.isnan(roc_auc(np.arange(3.0), np.ones(3, dtype=bool)))


def synthetic_frames(n_trajectories=40, steps=50, seed=0):
    """Frames whose ``general`` embedding holds the bearing, the in-view flag and the turn; ``static`` holds
    noise only."""
    rng = np.random.default_rng(seed)
    n = n_trajectories * steps
    pose = np.column_stack([rng.uniform(0, 5, n), rng.uniform(0, 5, n), rng.uniform(-np.pi, np.pi, n)])
    target = pose[:, :2] + rng.uniform(-4, 4, size=(n, 2))
    offset = target - pose[:, :2]
    bearing = np.arctan2(np.sin(np.arctan2(offset[:, 1], offset[:, 0]) - pose[:, 2]),
                         np.cos(np.arctan2(offset[:, 1], offset[:, 0]) - pose[:, 2]))  # fmt: skip
    in_view = (np.abs(bearing) <= np.radians(45)) & (np.hypot(*offset.T) <= 3.0)
    angular = np.clip(rng.normal(size=n) * 0.5, -1, 1)
    noise = rng.normal(size=(n, 6))
    general = np.column_stack([bearing * in_view, in_view.astype(float), angular, noise[:, :3]])
    return {
        "static": rng.normal(size=(n, 8)).astype(np.float32),
        "general": general.astype(np.float32),
        "action": np.column_stack([np.full(n, 0.5) + 0.1 * rng.normal(size=n), angular]).astype(np.float32),
        "pose": pose.astype(np.float32),
        "target": target.astype(np.float32),
        "trajectory": np.repeat(np.arange(n_trajectories), steps),
    }


def test_a_probe_finds_what_an_embedding_holds_and_nothing_in_noise():
    result = probe_scores(synthetic_frames())
    assert set(result["probes"]) == {"static", "general", "all"}
    assert result["frames"]["fit"] == result["frames"]["test"] == 1000
    general, static, both = (result["probes"][k] for k in ("general", "static", "all"))
    assert general["angular"] > 0.99 and general["in_view"] > 0.99
    assert general["bearing"] > 0.99 and general["bearing_sign"] > 0.97
    assert abs(static["angular"]) < 0.05 and abs(static["in_view"] - 0.5) < 0.1
    assert abs(static["bearing_sign"] - 0.5) < 0.15 and static["bearing"] < 0.1
    assert both["angular"] > 0.99  # the noise beside it costs nothing


def test_a_one_encoder_model_has_no_all_row_and_too_few_in_view_frames_give_no_bearing():
    frames = synthetic_frames(n_trajectories=4, steps=10)
    del frames["static"]
    frames["target"] = frames["pose"][:, :2] + 50.0  # never within range
    result = probe_scores(frames)
    assert set(result["probes"]) == {"general"}
    assert np.isnan(result["probes"]["general"]["bearing"]) and np.isnan(
        result["probes"]["general"]["in_view"]
    )
    with pytest.raises(ValueError, match="at least two trajectories"):
        probe_scores({**frames, "trajectory": np.zeros_like(frames["trajectory"])})


def test_paired_differences_are_zero_against_itself_and_exclude_zero_where_one_model_keeps_more():
    frames = synthetic_frames()
    same = paired_probe_differences(frames, frames, features=("all",), resamples=200)
    for quantity in QUANTITIES:
        assert same["all"][quantity] == {"difference": 0.0, "low": 0.0, "high": 0.0}
    rng = np.random.default_rng(5)
    blind = {**frames, "general": rng.normal(size=frames["general"].shape).astype(np.float32)}
    better = paired_probe_differences(frames, blind, features=("all", "head"), resamples=200)
    assert set(better) == {"all"}  # neither holds a head
    for quantity in ("angular", "in_view", "bearing", "bearing_sign"):
        assert better["all"][quantity]["low"] > 0.1, quantity
        assert better["all"][quantity]["low"] <= better["all"][quantity]["difference"]
        assert better["all"][quantity]["difference"] <= better["all"][quantity]["high"]
    shifted = {**frames, "trajectory": frames["trajectory"][::-1].copy()}
    with pytest.raises(ValueError, match="same frames.*'trajectory'"):
        paired_probe_differences(frames, shifted)


@pytest.fixture(scope="module")
def held_out_e(tmp_path_factory):
    from navformer_rl.data import make_synthetic_dataset

    return make_synthetic_dataset(tmp_path_factory.mktemp("probe") / "e", "e", 6, 5, 12, seed=21)


@pytest.mark.parametrize("dt", [False, True])
def test_frame_embeddings_are_the_encoders_on_every_valid_frame_of_the_validation_windows(
    tmp_path, held_out_e, checkpoint_factory, dt
):
    import torch

    from navformer_rl.data import open_dataset
    from navformer_rl.modules import NavFormerConfig
    from navformer_rl.training import checkpoint as ckpt

    config = NavFormerConfig.dt_baseline(**TINY_MODEL) if dt else NavFormerConfig(**TINY_MODEL)
    run = checkpoint_factory(tmp_path / "run", config)
    frames = frame_embeddings(str(run), held_out_e, batch_trajs=4)
    names = ["general"] if dt else ["static", "general"]
    readings = {"attention_to_target", "attention_keys", "observation_term", "action_own", "action_swapped"}
    readings |= set() if dt else {"target_term"}
    readings |= {f"action_without_{name}" for name in [*names, "past_actions"]}
    readings |= set() if dt else {"action_without_all"}
    assert set(frames) == {*names, "head", "h_o", "action", "pose", "target", "trajectory", *readings}
    assert frames["attention_to_target"].shape == (len(frames["head"]), 1)  # one block
    assert np.all((frames["attention_to_target"] > 0) & (frames["attention_to_target"] <= 1))
    np.testing.assert_array_equal(frames["head"][:, -16:], frames["h_o"])  # THSC reads [h_g; h_o]
    assert frames["head"].shape[1] == (16 if dt else 32)  # h_o; THSC's [h_g; h^ca_o]
    dataset = open_dataset(held_out_e, kind="e")
    assert all(len(v) == len(dataset) for v in frames.values())  # windows cover the short trajectories whole
    assert sorted(set(frames["trajectory"].tolist())) == list(range(dataset.num_trajectories))
    _, model = ckpt.load_policy_model(ckpt.resolve_checkpoint(str(run)))
    model.eval()
    first = int(frames["trajectory"][0])
    start, length = int(dataset.episodes.start[first]), int(dataset.episodes.length[first])
    with torch.no_grad():
        direct = model.dve.encode_observations(dataset.rows["pixels"][start : start + length])
    on_first = frames["trajectory"] == first
    with pytest.raises(ValueError, match="context_steps=1000"):
        frame_embeddings(str(run), held_out_e, context_steps=1000)
    np.testing.assert_allclose(frames[names[-1]][on_first], direct[:, -1].numpy(), rtol=1e-4, atol=1e-5)
    # the head's own read-out of the probed features is the model's teacher-forced prediction
    from navformer_rl.modules import make_navformer_actor
    from navformer_rl.training.validation import FixedTrajectoryBatches

    actor = make_navformer_actor(model)
    from navformer_rl.evaluation.diagnose.target_reading import TargetSwap

    swap = TargetSwap(dataset.targets)
    predicted, swapped = [], []
    with torch.no_grad():
        for batch in FixedTrajectoryBatches(dataset, 4, model.config.window_steps, 0):
            predicted.append(actor(batch.copy())["action_pred"][batch["mask"]].numpy())
            other = batch.copy().set("target_pixels", swap.swap(batch["target_pixels"]))
            swapped.append(actor(other)["action_pred"][batch["mask"]].numpy())
    head = torch.as_tensor(frames["head"])
    read_out = torch.tanh(head @ model.head.weight.T + model.head.bias).detach().numpy()
    np.testing.assert_allclose(read_out, np.concatenate(predicted), rtol=1e-4, atol=1e-5)
    terms = frames["observation_term"] + frames.get("target_term", 0.0) + model.head.bias.detach().numpy()
    np.testing.assert_allclose(np.tanh(terms), read_out, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(frames["action_own"], read_out, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(frames["action_swapped"], np.concatenate(swapped), rtol=1e-4, atol=1e-5)
    assert not np.allclose(frames["action_swapped"], frames["action_own"])  # another target, other actions
    # without an encoder: the actor's prediction with that encoder's embeddings set to their batch mean
    for name, knocked_out in ({n: [n] for n in names} | ({} if dt else {"all": names})).items():
        without = []
        with torch.no_grad():
            for batch in FixedTrajectoryBatches(dataset, 4, model.config.window_steps, 0):
                mask = batch["mask"]
                *observations, e_g = model.dve(batch["pixels"], batch["target_pixels"], mask)
                embeddings = dict(zip(model.dve.names, observations, strict=True))
                for encoder in knocked_out:
                    valid = embeddings[encoder][mask]  # [n, d]
                    embeddings[encoder] = valid.mean(dim=0).expand_as(embeddings[encoder])
                steps = (batch["return_to_go"], batch["action"], batch["step"], mask)
                h_g, h_o, _ = model.transformer(e_g, *steps, **embeddings)
                hidden = {"target": h_g, "observation": h_o}
                action = model.head.actions(*(hidden[r] for r in model.head.reads), mask)
                without.append(action[mask].numpy())
        np.testing.assert_allclose(frames[f"action_without_{name}"], np.concatenate(without), atol=1e-5)
        assert not np.allclose(frames[f"action_without_{name}"], frames["action_own"])
    # without the past actions: every action token given the mean of the window's expert actions
    without = []
    with torch.no_grad():
        for batch in FixedTrajectoryBatches(dataset, 4, model.config.window_steps, 0):
            mask = batch["mask"]
            mean_action = batch["action"][mask].mean(dim=0).expand_as(batch["action"])
            without.append(actor(batch.copy().set("action", mean_action))["action_pred"][mask].numpy())
    np.testing.assert_allclose(frames["action_without_past_actions"], np.concatenate(without), atol=1e-5)
    assert not np.allclose(frames["action_without_past_actions"], frames["action_own"])


def test_probe_cli_writes_a_table_per_model_and_refuses_a_missing_dataset(
    tmp_path, held_out_e, checkpoint_factory, capsys
):
    from navformer_rl.cli import main
    from navformer_rl.modules import NavFormerConfig

    nf = checkpoint_factory(tmp_path / "nf", NavFormerConfig(**TINY_MODEL))
    dt = checkpoint_factory(tmp_path / "dt", NavFormerConfig.dt_baseline(**TINY_MODEL))
    out = tmp_path / "probe"
    code = main(["evaluate", "probe", "--model", "NavFormer", str(nf), "--model", "DT", str(dt),
                 "--held-out", str(held_out_e), "--out", str(out)])  # fmt: skip
    assert code == 0
    record = json.loads((out / PROBE_JSON).read_text())
    assert list(record["results"]) == ["NavFormer", "DT"] and record["reference"] == "NavFormer"
    assert record["context_steps"] == 256  # NavFormer's 256 steps, not DT's 341: the same windows for both
    paired = record["results"]["DT"]["paired"]
    assert set(paired) == {"all", "head", "h_o"} and set(paired["head"]) == set(QUANTITIES)
    assert "paired" not in record["results"]["NavFormer"]
    assert set(record["results"]["NavFormer"]["probes"]) == {"static", "general", "all", "head", "h_o"}
    assert set(record["results"]["DT"]["probes"]) == {"general", "head"}
    table = (out / PROBE_MD).read_text()
    assert "| NavFormer | all |" in table and "| DT | general |" in table and "| DT | head |" in table
    assert "Minus NavFormer, paired on the same frames" in table
    reading = record["results"]["NavFormer"]["target_reading"]
    assert (
        len(reading["attention_to_target"]["all"]) == 1 and len(reading["head_terms"]["target_term_sd"]) == 2
    )
    assert "target_term_mean" not in record["results"]["DT"]["target_reading"]["head_terms"]
    assert "| NavFormer | W_g h_g" not in table and table.count("| NavFormer | ") == 5 + 1 + 1 + 1 + 4
    assert "Attention of the token the action head reads" in table and "target image swapped" in table
    capsys.readouterr()
    code = main(["evaluate", "probe", "--model", "DT", str(dt), "--held-out", str(tmp_path / "nowhere"),
                 "--out", str(tmp_path / "p2")])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code != 0 and "nowhere" in err and err.count("\n") == 0


def test_probe_cli_refuses_a_repeated_label_in_one_line(tmp_path, held_out_e, checkpoint_factory, capsys):
    from navformer_rl.cli import main
    from navformer_rl.modules import NavFormerConfig

    dt = checkpoint_factory(tmp_path / "dt", NavFormerConfig.dt_baseline(**TINY_MODEL))
    code = main(["evaluate", "probe", "--model", "A", str(dt), "--model", "A", str(dt),
                 "--held-out", str(held_out_e), "--out", str(tmp_path / "p")])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code == 2 and "['A'] repeat" in err and err.count("\n") == 0
    assert not (tmp_path / "p").exists()


def test_probe_reads_held_out_collision_avoidance_data_with_kind_ca(tmp_path, checkpoint_factory, capsys):
    from navformer_rl.cli import main
    from navformer_rl.data import make_synthetic_dataset
    from navformer_rl.modules import NavFormerConfig

    ca = make_synthetic_dataset(tmp_path / "ca", "ca", 6, 5, 12, seed=22)
    nf = checkpoint_factory(tmp_path / "nf", NavFormerConfig(**TINY_MODEL))
    out = tmp_path / "probe"
    code = main(["evaluate", "probe", "--model", "NavFormer", str(nf), "--held-out", str(ca), "--kind", "ca",
                 "--out", str(out)])  # fmt: skip
    assert code == 0
    record = json.loads((out / PROBE_JSON).read_text())
    assert record["kind"] == "ca" and record["results"]["NavFormer"]["frames"]["test"] > 0
    assert "target_swap" in record["results"]["NavFormer"]["target_reading"]
    capsys.readouterr()
    code = main(["evaluate", "probe", "--model", "NavFormer", str(nf), "--held-out", str(ca),
                 "--out", str(tmp_path / "p2")])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code != 0 and err.count("\n") == 0 and str(ca) in err  # a D_ca folder read as D_e: one line


@pytest.mark.parametrize("ablation", ["no_fs", "no_fg", "no_thsc", "resnet18"])
def test_probe_reads_every_ablated_model_with_a_knockout_per_encoder(
    tmp_path, held_out_e, checkpoint_factory, ablation
):
    from navformer_rl.modules import NavFormerConfig

    config = NavFormerConfig.ablation(ablation, **TINY_MODEL)
    frames = frame_embeddings(str(checkpoint_factory(tmp_path / ablation, config)), held_out_e, batch_trajs=4)
    scores = probe_scores(frames)
    encoders = [k for k in scores["probes"] if k not in ("all", "head", "h_o")]
    knockout = scores["encoder_knockout"]["encoders"]
    expected = [*encoders, *(["all"] if len(encoders) > 1 else []), "past_actions"]
    assert list(knockout) == expected
    assert all(np.isfinite(row["increase"]) for row in knockout.values())
