"""DSAC and MA-TDN through the evaluation harness:
``evaluate(method, ..., checkpoint=PPO run)`` and the CLI."""

from __future__ import annotations

import json

import pytest

from navformer_rl.cli import main
from navformer_rl.evaluation.episodes import Setup, make_episode_set, save_episode_set
from navformer_rl.evaluation.harness import PolicySpec, evaluate
from navformer_rl.evaluation.paper_results import METHOD_TO_PAPER_COLUMN

from .conftest import SMALL

ONE_EPISODE = make_episode_set(
    [Setup("7.5m-2r", 7.5, ("jackal", "jackal"), (True, True))],
    trials_per_setup=1,
    trials_per_world=1,
    seed=3,
    name="one",
    max_steps=4,
)


@pytest.mark.parametrize("method", ["dsac", "matdn"])
def test_one_tiny_episode_through_the_harness(method, ppo_checkpoints, tmp_path):
    run_dir, _ = ppo_checkpoints[method]
    result = evaluate(
        method, ONE_EPISODE, tmp_path / method, checkpoint=run_dir, maps_per_setup=0, videos_per_setup=0,
        progress=False,
    )  # fmt: skip
    assert [(r.method, r.robot, r.steps) for r in result.records] == [(method, 0, 4), (method, 1, 4)]
    run = json.loads((tmp_path / method / "run.json").read_text())
    assert run["method"] == method
    assert run["model_config"] == {"method": method, **SMALL[method].to_dict()}
    # the mean action: a second evaluation gives the same rows
    again = evaluate(
        method, ONE_EPISODE, tmp_path / f"{method}-again", checkpoint=run_dir, maps_per_setup=0,
        videos_per_setup=0, progress=False,
    )  # fmt: skip
    assert [r.final_distance for r in again.records] == [r.final_distance for r in result.records]
    assert METHOD_TO_PAPER_COLUMN[method] == {"dsac": "DSAC", "matdn": "MA-TDN"}[method]  # report column


def test_the_cli_evaluates_a_ppo_run_and_refuses_the_wrong_checkpoint(ppo_checkpoints, tmp_path, capsys):
    episodes = save_episode_set(ONE_EPISODE, tmp_path / "one.json")
    run_dir, _ = ppo_checkpoints["matdn"]
    argv = ["evaluate", "--episodes", str(episodes), "--maps", "0", "--videos", "0", "--no-progress"]
    assert main([*argv, "--method", "matdn", "--checkpoint", str(run_dir), "--out", str(tmp_path / "m")]) == 0
    assert (tmp_path / "m" / "summary.csv").is_file()
    assert main([*argv, "--method", "dsac", "--checkpoint", str(run_dir), "--out", str(tmp_path / "d")]) == 2
    assert "holds the matdn baseline, not dsac" in capsys.readouterr().err
    with pytest.raises(ValueError, match="needs a checkpoint"):
        PolicySpec("dsac").validate()
