"""`navformer evaluate seeds`: per-seed metrics, mean ± std over seeds and the pooled estimate, on
hand-made evaluation folders whose answers are computed by hand."""

import dataclasses
import json
import math

import pytest

from navformer_rl.cli import main
from navformer_rl.evaluation.measures import RobotTrial, clustered_wilson_interval
from navformer_rl.evaluation.seeds import seed_table_markdown, summarize_seed_groups
from navformer_rl.evaluation.tables import records_to_jsonl

EPISODE_SET = {"name": "t", "content_sha256": "a" * 64, "episodes": 2, "max_steps": 10, "setups": ["s"]}


def _trial(episode: str, robot: int, success: bool, collisions: int) -> RobotTrial:
    return RobotTrial(
        method="navformer",
        episode_id=episode,
        setup="s",
        size=7.5,
        n_robots=2,
        world_seed=0,
        trial=int(episode[-1]),
        robot=robot,
        robot_style="jackal",
        measured=True,
        success=success,
        success_step=5 if success else None,
        steps=10,
        collisions=collisions,
        path_length=4.0,  # SPL term of a success: l / max(p, l) = 2 / 4
        shortest_path=2.0,
        shortest_path_to_disc=0.5,
        final_distance=1.0 if success else 4.0,
    )


def _folder(
    root, name, successes, collisions, checkpoint_sha="0", episode_set=EPISODE_SET, method="navformer"
):
    """An evaluation folder with 2 trials x 2 robots; ``successes`` / ``collisions`` per robot-trial in the
    order (trial 0 robot 0, trial 0 robot 1, trial 1 robot 0, trial 1 robot 1)."""
    folder = root / name
    folder.mkdir()
    rows = [
        _trial(f"e{i // 2}", i % 2, success, collision)
        for i, (success, collision) in enumerate(zip(successes, collisions, strict=True))
    ]
    (folder / "episodes.jsonl").write_text(records_to_jsonl(rows))
    run = {"label": "navformer", "method": method, "episode_set": episode_set, "seed": 0}
    if checkpoint_sha is not None:
        run |= {"checkpoint": f"runs/{name}", "checkpoint_sha256": checkpoint_sha * 64}
    (folder / "run.json").write_text(json.dumps(run))
    return folder


@pytest.fixture
def two_seeds(tmp_path):
    a = _folder(tmp_path, "s0", [True, True, False, False], [0, 0, 5, 5], checkpoint_sha="1")
    b = _folder(tmp_path, "s1", [True, False, False, False], [0, 0, 0, 10], checkpoint_sha="2")
    return a, b


def test_mean_std_and_pooled_values_match_the_hand_computation(two_seeds):
    (group,) = summarize_seed_groups({"nf": two_seeds})
    assert [r.metrics.sr for r in group.runs] == [0.5, 0.25]
    assert group.mean["sr"] == pytest.approx(0.375)
    assert group.std["sr"] == pytest.approx(math.sqrt(2 * 0.125**2))  # sample std (ddof 1) of 0.5, 0.25
    # SPL: each success contributes 0.5 -> seeds 0.25 and 0.125
    assert group.mean["spl"] == pytest.approx(0.1875)
    assert group.std["spl"] == pytest.approx(math.sqrt(2 * 0.0625**2))
    # CR: seed 0 (0 + 0 + .5 + .5) / 4 = .25; seed 1 (0 + 0 + 0 + 1) / 4 = .25
    assert group.mean["cr"] == pytest.approx(0.25) and group.std["cr"] == pytest.approx(0.0)
    # pooled: 3 of 8 robot-trials, the 4 trials of the two seeds as 4 clusters (not 2 shared ones)
    assert group.pooled.sr == pytest.approx(0.375)
    assert group.pooled.n_trials == 4
    successes = [True, True, False, False, True, False, False, False]
    expected = clustered_wilson_interval(successes, [0, 0, 1, 1, 2, 2, 3, 3])
    assert group.pooled.sr_ci == pytest.approx(expected)


def test_one_seed_has_no_spread_and_the_table_says_so(tmp_path, two_seeds):
    summaries = summarize_seed_groups(
        {"nf": two_seeds, "single": [_folder(tmp_path, "x", [True] * 4, [0] * 4)]}
    )
    assert math.isnan(summaries[1].std["sr"]) and summaries[1].mean["sr"] == 1.0
    table = seed_table_markdown(summaries)
    assert "| nf | 2 | 50.0%, 25.0% | 37.5 ± 17.7% | 0.188 ± 0.088 | 0.250 ± 0.000 |" in table
    assert "| single | 1 | 100.0% | 100.0% | 0.500 | 0.000 |" in table
    json.dumps([s.to_dict() for s in summaries], allow_nan=False)  # nan written as null


def test_bad_groups_are_refused_by_name(tmp_path, two_seeds):
    a, b = two_seeds
    with pytest.raises(ValueError, match="given twice"):
        summarize_seed_groups({"nf": [a], "other": [a]})
    same = _folder(tmp_path, "same_weights", [False] * 4, [0] * 4, checkpoint_sha="1")
    with pytest.raises(ValueError, match="same policy.*one folder per seed"):
        summarize_seed_groups({"nf": [a, same]})
    other_set = dict(EPISODE_SET, content_sha256="b" * 64)
    elsewhere = _folder(
        tmp_path, "other_episodes", [True] * 4, [0] * 4, checkpoint_sha="3", episode_set=other_set
    )
    with pytest.raises(ValueError, match="another episode set"):
        summarize_seed_groups({"nf": [a], "dt": [elsewhere]})
    vrw_0 = _folder(tmp_path, "vrw0", [False] * 4, [0] * 4, checkpoint_sha=None, method="vrw")
    vrw_again = _folder(tmp_path, "vrw0_again", [False] * 4, [0] * 4, checkpoint_sha=None, method="vrw")
    with pytest.raises(ValueError, match="method 'vrw' with seed 0"):
        summarize_seed_groups({"vrw": [vrw_0, vrw_again]})
    with pytest.raises(ValueError, match="no evaluation folder"):
        summarize_seed_groups({"nf": []})
    with pytest.raises(FileNotFoundError, match="no run.json"):
        summarize_seed_groups({"nf": [tmp_path]})


def test_cli_prints_the_table_writes_it_and_refuses_bad_groups(tmp_path, two_seeds, capsys):
    a, b = two_seeds
    out = tmp_path / "seeds.md"
    assert main(["evaluate", "seeds", "--group", "nf", str(a), str(b), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| nf | 2 | 50.0%, 25.0% |" in printed and out.read_text() == printed
    assert main(["evaluate", "seeds", "--group", "nf", str(a), str(b), "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)
    assert row["name"] == "nf" and row["mean"]["sr"] == pytest.approx(0.375) and len(row["runs"]) == 2
    assert main(["evaluate", "seeds", "--group", "nf"]) != 0
    assert "give the group's evaluation folders" in capsys.readouterr().err
    assert main(["evaluate", "seeds", "--group", "nf", str(a), "--group", "nf", str(b)]) != 0
    assert "given twice" in capsys.readouterr().err


def test_series_groups_plot_as_lines_of_mean_and_std(tmp_path, two_seeds):
    from navformer_rl.evaluation.plots import plot_seed_groups

    c = _folder(tmp_path, "s2", [True, True, True, False], [0, 0, 0, 0], checkpoint_sha="3")
    d = _folder(tmp_path, "s3", [True, True, True, True], [0, 0, 0, 0], checkpoint_sha="4")
    summaries = summarize_seed_groups({"navformer@350": list(two_seeds), "navformer@3496": [c, d]})
    drawn = plot_seed_groups(summaries, tmp_path / "slope.png", x_label="D_e trajectories")
    # seeds' SR: 50 % and 25 % at 350; 75 % and 100 % at 3,496 (sample std of two values: |a - b| / sqrt(2))
    assert list(drawn) == ["navformer"]
    (x0, m0, s0), (x1, m1, s1) = drawn["navformer"]
    assert (x0, x1) == (350.0, 3496.0)
    assert (m0, m1) == pytest.approx((37.5, 87.5))
    assert (s0, s1) == pytest.approx((25 / 2**0.5, 25 / 2**0.5))
    assert (tmp_path / "slope.png").stat().st_size > 0
    bars = plot_seed_groups(
        summaries[:1] + [dataclasses.replace(summaries[1], name="dt")], tmp_path / "b.png"
    )
    assert [name for name in bars] == ["navformer@350", "dt"]  # not all SERIES@X: one bar per group


def test_groups_of_one_run_plot_their_interval(tmp_path, two_seeds):
    from navformer_rl.evaluation.plots import _interval_bars, plot_seed_groups

    a, b = two_seeds
    summaries = summarize_seed_groups({"nf@1000": [a], "nf@2000": [b]})
    drawn = plot_seed_groups(summaries, tmp_path / "curve.png", x_label="iteration", x_scale="linear")
    assert drawn == {"nf": [(1000.0, 50.0, 0.0), (2000.0, 25.0, 0.0)]}
    bars = _interval_bars(summaries, [50.0, 25.0])
    for k, group in enumerate(summaries):  # below and above the point: the run's own 95 % interval
        low, high = group.pooled.sr_ci
        assert bars[:, k] == pytest.approx([50.0 - 25.0 * k - 100 * low, 100 * high - 50.0 + 25.0 * k])
        assert bars[0, k] > 0 and bars[1, k] > 0
    with pytest.raises(ValueError, match="x_scale='logit': expected one of auto, linear, log"):
        plot_seed_groups(summaries, tmp_path / "x.png", x_scale="logit")


def test_cli_writes_the_seed_plot(tmp_path, two_seeds, capsys):
    out = tmp_path / "plot.png"
    argv = [
        "evaluate",
        "seeds",
        "--group",
        "nf@1",
        *map(str, two_seeds),
        "--plot",
        str(out),
        "--x-label",
        "n",
    ]
    assert main(argv) == 0
    assert out.stat().st_size > 0
    assert main([*argv, "--x-scale", "linear"]) == 0
    assert main(["evaluate", "seeds", "--group", "nf", *map(str, two_seeds), "--plot", str(tmp_path)]) == 2
    assert "--plot" in capsys.readouterr().err


def test_a_linear_axis_labels_every_x_unless_the_labels_would_collide() -> None:
    from navformer_rl.evaluation.plots import _labels_collide

    assert not _labels_collide([1000.0, 2000.0, 3000.0])
    assert not _labels_collide([350.0, 1000.0, 3496.0])
    assert _labels_collide([1000.0, 2000.0, 2500.0, 3000.0, 10000.0])  # 500 apart on a 9,000 span
    assert not _labels_collide([5.0])
