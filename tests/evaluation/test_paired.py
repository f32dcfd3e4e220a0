"""Paired differences of two evaluations of the same episodes (`navformer evaluate compare`)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from navformer_rl.cli.main import main
from navformer_rl.evaluation.measures import RobotTrial
from navformer_rl.evaluation.paired import (
    paired_differences,
    paired_markdown,
    pooled_paired_differences,
    unseen_obstacle_differences,
)
from navformer_rl.evaluation.tables import records_to_jsonl

BASE = RobotTrial(
    method="navformer", episode_id="", setup="", size=7.5, n_robots=2, world_seed=0, trial=0, robot=0,
    robot_style="jackal", measured=True, success=False, success_step=None, steps=100, collisions=0,
    path_length=5.0, shortest_path=4.0, shortest_path_to_disc=3.0, final_distance=3.0,
)  # fmt: skip


def trials(successes: list[list[bool]], setup: str = "7.5m-2r", collisions: int = 0) -> list[RobotTrial]:
    """One record per robot: ``successes[trial][robot]``; a success drives 5 m of a 4 m shortest path."""
    return [
        dataclasses.replace(
            BASE,
            episode_id=f"{setup}-{t}",
            setup=setup,
            size=float(setup.split("m")[0]),
            world_seed=t // 2,
            trial=t,
            robot=r,
            success=ok,
            success_step=50 if ok else None,
            collisions=collisions,
        )  # fmt: skip
        for t, robots in enumerate(successes)
        for r, ok in enumerate(robots)
    ]


def write(folder, label: str, records: list[RobotTrial], digest: str = "abc"):
    folder.mkdir()
    (folder / "run.json").write_text(json.dumps({"label": label, "episode_set": {"content_sha256": digest}}))
    (folder / "episodes.jsonl").write_text(records_to_jsonl(records))
    return folder


def test_known_differences_and_their_intervals(tmp_path):
    n = 10
    a = write(tmp_path / "a", "navformer", trials([[True, True]] * n, collisions=10))
    b = write(tmp_path / "b", "dt", trials([[True, False]] * n, collisions=30))
    labels, rows = paired_differences(a, b)
    assert labels == ("navformer", "dt") and [row.setup for row in rows] == ["7.5m-2r", "all"]
    row = rows[-1]
    assert (row.n_trials, row.n_robot_trials, row.n_clusters) == (n, 2 * n, n)
    assert row.a["sr"] == 1.0 and row.b["sr"] == 0.5 and row.difference["sr"] == pytest.approx(0.5)
    # every trial differs by exactly one success of two robots: no spread, the interval is the point
    assert row.interval["sr"] == pytest.approx((0.5, 0.5)) and row.excludes_zero("sr")
    assert row.difference["cr"] == pytest.approx(0.1 - 0.3) and row.interval["cr"] == pytest.approx(
        (-0.2, -0.2)
    )
    assert row.difference["spl"] == pytest.approx(0.8 - 0.4)
    table = paired_markdown(labels, rows)
    assert "| all | 10 | 20 | 100.0 % | 50.0 % | +50.0 [+50.0, +50.0] * |" in table


def test_equal_evaluations_differ_by_nothing_and_noise_gives_an_interval_around_the_difference(tmp_path):
    rng = np.random.default_rng(0)
    outcomes = rng.random((40, 3)) < 0.4
    a = write(tmp_path / "a", "navformer", trials(outcomes.tolist()))
    same = write(tmp_path / "same", "navformer-copy", trials(outcomes.tolist()))
    _, rows = paired_differences(a, same)
    assert rows[-1].difference["sr"] == 0.0 and rows[-1].interval["sr"] == (0.0, 0.0)
    assert not rows[-1].excludes_zero("sr")
    flipped = outcomes.copy()
    flipped[:10, 0] = ~flipped[:10, 0]  # ten robot-trials change outcome
    b = write(tmp_path / "b", "dt", trials(flipped.tolist()))
    _, rows = paired_differences(a, b)
    low, high = rows[-1].interval["sr"]
    assert low <= rows[-1].difference["sr"] <= high and high - low > 0
    # seeded: the same folders give the same interval; clustering by maze gives another
    assert paired_differences(a, b)[1][-1].interval == rows[-1].interval
    assert paired_differences(a, b, cluster="world")[1][-1].n_clusters == 20


def test_setups_are_compared_separately_and_unmeasured_robots_are_left_out(tmp_path):
    records = trials([[True, False]] * 6, "7.5m-2r") + trials([[False, False]] * 6, "12.5m-2r")
    records[1] = dataclasses.replace(records[1], measured=False)
    other = [dataclasses.replace(r, success=True) for r in records]
    a = write(tmp_path / "a", "navformer", records)
    b = write(tmp_path / "b", "fca", other)
    _, rows = paired_differences(a, b)
    by_setup = {row.setup: row for row in rows}
    assert list(by_setup) == ["7.5m-2r", "12.5m-2r", "all"]
    assert by_setup["7.5m-2r"].n_robot_trials == 11 and by_setup["12.5m-2r"].difference["sr"] == -1.0


def test_evaluations_of_other_episodes_are_refused(tmp_path):
    a = write(tmp_path / "a", "navformer", trials([[True]] * 6))
    other_set = write(tmp_path / "b", "dt", trials([[True]] * 6), digest="def")
    with pytest.raises(ValueError, match="ran different episode sets .*same --episodes file"):
        paired_differences(a, other_set)
    unfinished = write(tmp_path / "c", "dt", trials([[True]] * 5))
    with pytest.raises(ValueError, match=r"has robot 0 of episode '7.5m-2r-5' \(and 0 more\) that .* lacks"):
        paired_differences(a, unfinished)
    with pytest.raises(FileNotFoundError, match="not an evaluation folder"):
        paired_differences(a, tmp_path)


def test_cli_prints_and_writes_the_table(tmp_path, capsys):
    a = write(tmp_path / "a", "navformer", trials([[True, True]] * 6))
    b = write(tmp_path / "b", "dt", trials([[False, True]] * 6))
    out = tmp_path / "paired.md"
    assert main(["evaluate", "compare", str(a), str(b), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed == out.read_text() and "SR navformer - dt (points)" in printed
    assert main(["evaluate", "compare", str(a), str(tmp_path / "missing")]) == 2
    assert "navformer evaluate: error:" in capsys.readouterr().err


def test_models_with_several_seeds_pool_their_seeds_and_widen_with_their_spread(tmp_path):
    """Known answers: A's seeds succeed on 100 % / 50 % / 0 % of robots (mean 50 %), B's two on 25 % each;
    the pooled difference is their means' difference, and the two-level interval covers the seed spread
    where one folder per side gives the point."""
    n = 12
    a_folders = [
        write(tmp_path / f"a{i}", f"navformer_s{i}", trials([[ok, ok] for ok in pattern]))
        for i, pattern in enumerate(([True] * n, [True, False] * (n // 2), [False] * n))
    ]
    b_folders = [
        write(tmp_path / f"b{i}", f"dt_s{i}", trials([[ok, False] for ok in [True, False] * (n // 2)]))
        for i in range(2)
    ]
    (name_a, name_b), rows = pooled_paired_differences(a_folders, b_folders, ("navformer", "dt"))
    row = rows[-1]
    assert (name_a, name_b, row.n_seeds, row.n_robot_trials) == ("navformer", "dt", (3, 2), 2 * n)
    assert row.a["sr"] == pytest.approx(0.5) and row.b["sr"] == pytest.approx(0.25)
    assert row.difference["sr"] == pytest.approx(0.25)
    low, high = row.interval["sr"]
    assert low < 0 < high  # one A seed is below B, one above: the seeds' spread reaches past zero
    assert (
        pooled_paired_differences(a_folders, b_folders, ("navformer", "dt"))[1][-1].interval == row.interval
    )
    # one seed a side: the ordinary paired comparison, labels from the folders
    labels, single = pooled_paired_differences(a_folders[:1], b_folders[:1])
    assert labels == ("navformer_s0", "dt_s0")
    assert single[-1].interval == paired_differences(a_folders[0], b_folders[0])[1][-1].interval
    assert pooled_paired_differences(a_folders, b_folders[:1])[0] == ("navformer_s0 + 2 seeds", "dt_s0")
    table = paired_markdown(("navformer", "dt"), rows)
    assert (
        "mean over 3 seeds of navformer and 2 of dt" in table
        and "resampling each side's training seeds" in table
    )


def test_pooled_comparisons_refuse_empty_repeated_or_mismatched_sides(tmp_path):
    a = write(tmp_path / "a", "navformer", trials([[True]] * 6))
    b = write(tmp_path / "b", "dt", trials([[True]] * 6))
    other = write(tmp_path / "c", "dt", trials([[True]] * 6), digest="def")
    with pytest.raises(ValueError, match="side B has no evaluation folder"):
        pooled_paired_differences([a], [])
    with pytest.raises(ValueError, match="side A names a folder twice"):
        pooled_paired_differences([a, a], [b])
    with pytest.raises(ValueError, match="ran different episode sets"):
        pooled_paired_differences([a], [b, other])


def test_cli_compares_two_groups_of_seeds(tmp_path, capsys):
    a = [write(tmp_path / f"a{i}", f"nf{i}", trials([[True, i == 0]] * 6)) for i in range(2)]
    b = [write(tmp_path / f"b{i}", f"dt{i}", trials([[False, True]] * 6)) for i in range(2)]
    argv = ["evaluate", "compare", "--group", "navformer", *map(str, a), "--group", "dt", *map(str, b)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "SR navformer - dt (points)" in printed and "| all | 6 | 12 | 75.0 % | 50.0 % | +25.0" in printed
    assert main(["evaluate", "compare", "--group", "navformer", str(a[0])]) == 2
    assert "give it twice" in capsys.readouterr().err
    assert main(["evaluate", "compare", str(a[0]), "--group", "x", str(b[0]), "--group", "y", str(b[1])]) == 2
    assert "not both" in capsys.readouterr().err


def table3_records(seen: list[bool], unseen: list[bool]) -> list[RobotTrial]:
    """Table III's two setups over the same trials: 2 Jackals measured in seen, only robot 0 in unseen;
    robot 0's outcome per trial from ``seen`` / ``unseen``, robot 1 of seen always succeeds."""
    records = []
    for setup, outcomes in (("12.5m-4r-seen", seen), ("12.5m-4r-unseen", unseen)):
        for t, ok in enumerate(outcomes):
            for robot in (0, 1):
                records.append(
                    dataclasses.replace(
                        BASE, episode_id=f"{setup}/w{t // 2:02d}t{t % 2:02d}", setup=setup, size=12.5,
                        world_seed=t // 2, trial=t, robot=robot,
                        measured=robot == 0 or setup.endswith("-seen"),
                        success=ok if robot == 0 else True, success_step=50 if (ok or robot) else None,
                    )
                )  # fmt: skip
    return records


def test_unseen_robots_are_paired_with_the_same_robot_among_seen_obstacles(tmp_path, capsys):
    seen = [True] * 12 + [False] * 8
    unseen = [True] * 6 + [False] * 14  # six successes are lost, nothing gained
    folder = write(tmp_path / "nf", "navformer", table3_records(seen, unseen))
    label, row = unseen_obstacle_differences(folder)
    assert label == row.setup == "navformer"
    # robot 1 of the seen trials (always succeeding) plays no part
    assert (row.n_trials, row.n_robot_trials) == (20, 20)
    assert row.a["sr"] == pytest.approx(0.3) and row.b["sr"] == pytest.approx(0.6)
    assert row.difference["sr"] == pytest.approx(-0.3) and row.excludes_zero("sr")
    assert main(["evaluate", "unseen", str(folder)]) == 0
    assert "| navformer | 20 | 20 | 30.0 % | 60.0 % | -30.0 [" in capsys.readouterr().out


def test_unseen_trials_without_their_seen_trial_are_refused(tmp_path, capsys):
    records = table3_records([True] * 6, [False] * 6)
    partial = write(
        tmp_path / "partial", "dt", [r for r in records if r.episode_id != "12.5m-4r-seen/w02t01"]
    )
    with pytest.raises(ValueError, match="has no seen partner '12.5m-4r-seen/w02t01'"):
        unseen_obstacle_differences(partial)
    moved = write(tmp_path / "moved", "dt", [
        dataclasses.replace(r, shortest_path=9.0) if r.setup.endswith("-seen") else r for r in records
    ])  # fmt: skip
    with pytest.raises(ValueError, match="are not the same maze, start and target"):
        unseen_obstacle_differences(moved)
    table1 = write(tmp_path / "table1", "dt", trials([[True, False]] * 6))
    assert main(["evaluate", "unseen", str(table1)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no measured robot-trials in a '*-unseen' setup" in err[0]
