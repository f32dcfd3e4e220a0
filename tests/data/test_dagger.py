"""DAgger collections (a tiny seeded policy in the loop): known answers, resume, refusals, the CLI."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from navformer_rl.data import collect as collect_module
from navformer_rl.data import expert_episodes, open_dataset
from navformer_rl.data.cli import main as cli_main
from navformer_rl.data.collect import collect, settings_for
from navformer_rl.data.collect_settings import settings_record
from navformer_rl.data.dagger import dagger_settings
from navformer_rl.data.versions import VERSIONS_KEY, data_versions
from navformer_rl.modules import NavFormerConfig, NavFormerModel, NavFormerPolicy
from navformer_rl.training.checkpoint import load_policy_model, save_checkpoint

TINY_MODEL = NavFormerConfig(d_embed=16, d_head=8, n_blocks=1)
E_SETTINGS = {"n_trajectories": 2, "episodes_per_unit": 1, "world_sizes": (5.0,), "max_steps": 30}
"""Two 5 m mazes (one per unit), at most 30 steps each."""
CA_SETTINGS = {"n_trajectories": 5, "other_robots": (2, 2), "max_steps": 40}
"""Two arena episodes of 3 robots (DAgger keeps every robot's trajectory: 3 + the first 2 of the second)."""


def make_run(run_dir: Path, config: NavFormerConfig, seed: int, train_config: dict | None = None) -> Path:
    """A run directory with one seeded, untrained checkpoint of ``config``
    (``train_config`` in its header)."""
    torch.manual_seed(seed)
    model = NavFormerModel(config)
    save_checkpoint(
        run_dir,
        1,
        model_state=model.state_dict(),
        model_config=dataclasses.asdict(config),
        train_config=train_config or {},
        resume_state=None,
    )
    return run_dir


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """Tiny NavFormer policies (two seeds) and a tiny DT baseline."""
    root = tmp_path_factory.mktemp("dagger_runs")
    return {
        "navformer": make_run(root / "navformer", TINY_MODEL, 0),
        "other": make_run(root / "other", TINY_MODEL, 1),
        "dt": make_run(
            root / "dt", dataclasses.replace(NavFormerConfig.dt_baseline(), d_embed=16, d_head=8), 0
        ),
    }


def consolidated_bytes(root: Path, folder_bytes) -> dict[str, bytes]:
    return folder_bytes(root / "consolidated")


@pytest.mark.parametrize("kind", ["e", "ca"])
def test_beta_one_gives_exactly_the_plain_expert_data(kind, runs, tmp_path, folder_bytes):
    """With beta = 1 the policy runs at every step but never drives: the rows and targets are the plain
    expert's, byte for byte; only the settings and counts say that a policy was in the loop."""
    # the expert's own time limit (500 steps): it succeeds in every episode here, so no failure that a
    # DAgger collection keeps and a plain one drops
    overrides = {**(E_SETTINGS if kind == "e" else CA_SETTINGS), "max_steps": 500}
    plain = settings_for(kind, "small", seed=2, **overrides)
    dagger = settings_for(
        kind, "small", seed=2, dagger=dagger_settings(str(runs["navformer"]), 1.0), **overrides
    )
    a = collect(kind, tmp_path / "plain", plain, workers=1, progress=False)
    b = collect(kind, tmp_path / "dagger", dagger, workers=1, progress=False)
    assert consolidated_bytes(a, folder_bytes) == consolidated_bytes(b, folder_bytes)
    meta_a, meta_b = (json.loads((root / "metadata.json").read_text()) for root in (a, b))
    assert "dagger" not in meta_a["settings"] and meta_a["settings"][VERSIONS_KEY] == data_versions(kind)
    assert meta_b["settings"]["dagger"] == {
        "beta": 1.0,
        "weights_sha256": dagger.dagger.weights_sha256,
        "transformer_step": dagger.dagger.transformer_step,
    }
    assert meta_b["settings"][VERSIONS_KEY] == {**data_versions(kind), "dagger_policy": 1}
    assert meta_b["dagger"]["checkpoint"] == str(
        (runs["navformer"] / "checkpoints" / "iter_000001").resolve()
    )
    assert meta_b["counts"]["policy_steps"] == 0 and "policy_steps" not in meta_a["counts"]
    assert meta_a["counts"]["failed"] == meta_b["counts"]["failed"] == 0


def test_plain_settings_record_what_they_always_did():
    plain = settings_for("ca", "small", seed=3)
    record = settings_record(plain)
    assert "dagger" not in record and "worlds" not in record
    assert record == {k: v for k, v in dataclasses.asdict(plain).items() if k not in ("dagger", "worlds")}


def deployed_policy(run: Path, settings, context_steps: int | None = None) -> NavFormerPolicy:
    """The checkpoint at ``run`` as a collection runs it (keys of the raw simulator frames)."""
    _, model = load_policy_model(run)
    return NavFormerPolicy(
        model,
        pixels_key="pixels",
        target_pixels_key="target_pixels",
        action_key="action",
        step_count_key=None,
        reward_key=None,
        is_init_key=None,
        native=settings.dagger.transformer_step == "native",
        context_steps=context_steps,
    )


def policy_rollout(settings, unit: int, policy: NavFormerPolicy):
    """D_e episode 0 of ``unit`` driven by ``policy`` alone, with the expert asked at every step: poses
    float32 ``[T, 3]`` (before each step), the expert's labels and the policy's actions, ``[T, 2]`` each."""
    from navformer_rl.envs.robots import get_robot_spec
    from navformer_rl.envs.sim import Simulator
    from navformer_rl.envs.target_image import render_target_image
    from navformer_rl.experts.policies import ExplorationExpert

    world, rng = expert_episodes.exploration_world(settings, unit, 0)
    sim = Simulator(world, get_robot_spec(settings.robot))
    expert = ExplorationExpert()
    expert.reset(world, sim, rng)
    target = torch.from_numpy(render_target_image(world.targets[0].shape, world.targets[0].color))[None]
    policy.reset()
    poses, labels, driven = [], [], []
    try:
        for _ in range(settings.max_steps):
            poses.append(sim.poses[0])
            labels.append(np.clip(expert.act(sim, np.ones(1, bool))[0], -1, 1))
            frame = torch.from_numpy(sim.render(0))[None]
            td = TensorDict({"pixels": frame, "target_pixels": target}, batch_size=[1])
            with torch.no_grad():
                action = policy(td)["action"].numpy().astype(np.float32)
            driven.append(action[0])
            sim.step(np.clip(action, -1, 1), np.ones(1, bool))
            if expert_episodes.reached_targets(sim, world)[0] or expert.failed[0]:
                break
    finally:
        sim.close()
    return np.stack(poses), np.stack(labels), np.stack(driven)


@pytest.mark.parametrize("method", ["navformer", "dt"])
def test_beta_zero_drives_with_the_policy_and_stores_the_experts_labels(method, runs, tmp_path):
    """Known answer: the stored poses are those of the policy driving alone, the stored actions the expert's
    labels along that path (not the actions that moved the robot)."""
    s = settings_for("e", "small", seed=4, dagger=dagger_settings(str(runs[method]), 0.0), **E_SETTINGS)
    ds = open_dataset(collect("e", tmp_path / "e", s, workers=1, progress=False))
    policy = deployed_policy(runs[method], s)
    rows, ep = ds.rows, ds.episodes
    assert ds.metadata["counts"]["policy_steps"] == ds.metadata["counts"]["robot_steps"] == len(rows)
    for unit in range(2):
        poses, labels, driven = policy_rollout(s, unit, policy)
        start, length = int(ep.start[unit]), int(ep.length[unit])
        assert length == len(poses)
        np.testing.assert_array_equal(rows["privileged", "pose"][start : start + length].numpy(), poses)
        np.testing.assert_array_equal(rows["action"][start : start + length].numpy(), labels)
        assert np.abs(labels - driven).max() > 0.1  # the labels are not what moved the robot


def test_a_policy_trained_on_short_windows_drives_on_them(tmp_path):
    """A checkpoint trained with data.context_steps=W drives the collection attending to its last W steps,
    as `navformer evaluate` deploys it: the stored path is that policy's, not the whole-context one's; the
    settings record the window (and a whole-context policy's record stays as it was)."""
    run = make_run(tmp_path / "w2", TINY_MODEL, 0, train_config={"data": {"context_steps": 2}})
    dagger = dagger_settings(str(run), 0.0)
    assert dagger.context_steps == 2 and dagger.record()["context_steps"] == 2
    assert (
        "context_steps" not in dagger_settings(str(make_run(tmp_path / "whole", TINY_MODEL, 0)), 0.0).record()
    )
    s = settings_for("e", "small", seed=4, dagger=dagger, **E_SETTINGS)
    ds = open_dataset(collect("e", tmp_path / "e", s, workers=1, progress=False))
    length = int(ds.episodes.length[0])
    stored = ds.rows["privileged", "pose"][:length].numpy()
    poses, _, _ = policy_rollout(s, 0, deployed_policy(run, s, context_steps=2))
    np.testing.assert_array_equal(stored, poses)
    whole, _, _ = policy_rollout(s, 0, deployed_policy(run, s))
    assert len(whole) != length or not np.array_equal(whole, stored)


def test_a_resumed_dagger_collection_equals_an_uninterrupted_one(runs, tmp_path, folder_bytes):
    s = settings_for(
        "ca", "small", seed=5, dagger=dagger_settings(str(runs["navformer"]), 0.5), **CA_SETTINGS
    )
    ref = collect("ca", tmp_path / "ref", s, workers=1, progress=False)
    calls = {"n": 0}

    def crashing_unit(root, kind, settings, unit):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return collect_module.run_unit(root, kind, settings, unit)

    with pytest.raises(KeyboardInterrupt):
        collect("ca", tmp_path / "resumed", s, workers=1, progress=False, unit_fn=crashing_unit)
    assert (tmp_path / "resumed" / "shards" / "unit-000000").is_dir()
    resumed = collect("ca", tmp_path / "resumed", s, workers=1, progress=False)
    assert folder_bytes(resumed) == folder_bytes(ref)
    counts = open_dataset(ref).metadata["counts"]
    # every robot's trajectory is kept, and about half of the steps were the policy's
    assert counts["items"] == 5 and counts["attempted"] == 5 and counts["rows"] <= counts["robot_steps"]
    assert 0.3 < counts["policy_steps"] / counts["robot_steps"] < 0.7


@pytest.mark.slow
def test_the_data_do_not_depend_on_the_number_of_workers(runs, tmp_path, folder_bytes):
    """Two spawned workers (each loading the policy itself) collect the bytes of one in-process worker."""
    s = settings_for(
        "ca", "small", seed=9, dagger=dagger_settings(str(runs["navformer"]), 0.5), **CA_SETTINGS
    )
    one = collect("ca", tmp_path / "one", s, workers=1, progress=False)
    two = collect("ca", tmp_path / "two", s, workers=2, progress=False)
    assert folder_bytes(one) == folder_bytes(two)


@pytest.mark.parametrize(
    "change",
    [
        {"beta": 0.25},
        {"run": "other"},
        {"dagger": None},
    ],
    ids=["another-beta", "another-policy", "no-policy"],
)
def test_resuming_with_another_beta_or_policy_is_refused(runs, tmp_path, change):
    first = dagger_settings(str(runs["navformer"]), 0.5)
    s = settings_for("e", "small", seed=6, dagger=first, **E_SETTINGS)
    calls = {"n": 0}

    def crashing_unit(root, kind, settings, unit):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return collect_module.run_unit(root, kind, settings, unit)

    with pytest.raises(KeyboardInterrupt):
        collect("e", tmp_path / "e", s, workers=1, progress=False, unit_fn=crashing_unit)
    if "dagger" in change:
        other = None
    else:
        other = dagger_settings(str(runs[change.get("run", "navformer")]), change.get("beta", 0.5))
    again = settings_for("e", "small", seed=6, dagger=other, **E_SETTINGS)
    with pytest.raises(ValueError, match="already holds a dataset with settings") as info:
        collect("e", tmp_path / "e", again, workers=1, progress=False)
    assert "dagger" in str(info.value)


def test_a_changed_checkpoint_is_refused_by_the_workers(runs, tmp_path):
    s = settings_for("e", "small", seed=7, dagger=dagger_settings(str(runs["navformer"]), 0.5), **E_SETTINGS)
    forged = dataclasses.replace(s.dagger, weights_sha256="0" * 64)
    with pytest.raises(ValueError, match="changed since the collection started"):
        collect("e", tmp_path / "e", dataclasses.replace(s, dagger=forged), workers=1, progress=False)


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["ssl", "--dagger-policy", "{run}"], "--dagger-policy applies to e and ca"),
        (["e", "--dagger-beta", "0.3"], "--dagger-beta needs --dagger-policy CHECKPOINT"),
        (["e", "--dagger-policy", "{run}", "--action-noise", "0.1"], "--dagger-policy and --action-noise"),
        (["e", "--dagger-policy", "{tmp}/nothing"], "--dagger-policy: no checkpoint at '{tmp}/nothing'"),
        (["ca", "--dagger-policy", "pretrained:nonesuch"], "--dagger-policy: "),
    ],
    ids=["ssl", "beta-alone", "with-noise", "missing", "unknown-pretrained"],
)
def test_bad_dagger_options_are_one_line_errors(runs, tmp_path, capsys, argv, expected):
    args = [a.format(run=runs["navformer"], tmp=tmp_path) for a in argv]
    assert cli_main(["collect", *args, "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("navformer collect: error: "), err
    assert expected.format(tmp=tmp_path) in err[0]
    assert not (tmp_path / "out").exists()


def test_a_beta_outside_the_unit_interval_is_an_argument_error(capsys, tmp_path):
    with pytest.raises(SystemExit) as info:
        cli_main(["collect", "e", "--out", str(tmp_path), "--dagger-policy", "x", "--dagger-beta", "1.5"])
    assert info.value.code == 2
    assert "argument --dagger-beta: expected" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["e", "all"])
def test_the_cli_passes_the_policy_to_e_and_ca(runs, tmp_path, monkeypatch, kind):
    asked = {}

    def fake_collect(kind, out, settings, **options):
        asked[kind.value] = settings
        return out

    monkeypatch.setattr(collect_module, "collect", fake_collect)
    argv = ["collect", kind, "--out", str(tmp_path / "out"), "--workers", "1", "--no-progress"]
    assert cli_main([*argv, "--dagger-policy", str(runs["dt"]), "--dagger-beta", "0.25"]) == 0
    expected = dagger_settings(str(runs["dt"]), 0.25)
    assert asked.pop("e").dagger == expected
    if kind == "all":
        assert asked.pop("ca").dagger == expected and not hasattr(asked.pop("ssl"), "dagger")
    assert not asked


def test_the_recipe_reports_a_missing_policy_in_one_line(tmp_path):
    """``recipes/collect/collect.py dagger_policy=...``: a missing checkpoint is one line, no folder left."""
    recipe = Path(__file__).resolve().parents[2] / "recipes" / "collect" / "collect.py"
    done = subprocess.run(
        [sys.executable, str(recipe), "kind=e", "dagger_policy=nothing", "out=data", "progress=false"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        timeout=300,
    )
    assert done.returncode == 2, done.stderr[-2000:]
    assert len(done.stderr.splitlines()) == 1 and done.stderr.startswith(
        "collect.py: error: no checkpoint at "
    )
    assert list(tmp_path.iterdir()) == []
