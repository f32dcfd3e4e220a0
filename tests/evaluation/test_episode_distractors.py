"""Distractors in episode sets: targets no robot seeks (Table II's eight targets for three robots, Fig. 4).

They leave the robots' layout alone (so sets with and without pair robot-trial by robot-trial), stand in the
world as obstacles the camera sees, are never a robot's goal, and count as "other targets" in a diagnosis.
"""

import dataclasses
import json

import numpy as np
import pytest

from navformer_rl.evaluation.episodes import (
    Episode,
    Setup,
    load_episode_set,
    make_episode_set,
    make_protocol_episodes,
    protocol_setups,
    save_episode_set,
)

from .conftest import TINY_SETUP

SETUP = Setup("7.5m-2r", 7.5, ("jackal", "jackal"), (True, True))
WITH_THREE = dataclasses.replace(SETUP, distractors=3)


@pytest.fixture(scope="module")
def pair():
    """The same two trials without and with three distractors."""
    common = dict(trials_per_setup=2, trials_per_world=2, seed=4, max_steps=10)
    return make_episode_set([SETUP], **common), make_episode_set([WITH_THREE], **common)


def test_distractors_leave_the_robots_layout_and_add_distinct_targets_away_from_it(pair):
    plain, with_distractors = pair
    for a, b in zip(plain.episodes, with_distractors.episodes):
        assert (a.episode_id, a.world_seed, a.starts, a.targets, a.seed) == (
            b.episode_id, b.world_seed, b.starts, b.targets, b.seed,
        )  # fmt: skip
        assert a.distractors == () and len(b.distractors) == 3
        pairs = [(t["shape"], t["color"]) for t in b.targets + b.distractors]
        assert len(set(pairs)) == 5  # every target in the world is a different object
        others = np.array([t["position"] for t in b.targets] + [s[:2] for s in b.starts])
        for d in b.distractors:
            gaps = np.hypot(*(others - np.array(d["position"])).T)
            assert gaps.min() > 1.2  # placed as the generator places targets: 2 m apart, 1.2 m where crowded
        # they are obstacles: l goes around them, never shorter than without them
        assert all(lb >= la - 1e-9 for la, lb in zip(a.shortest_paths, b.shortest_paths))


def test_a_set_without_distractors_records_none_so_its_content_hash_is_unchanged(pair):
    plain, with_distractors = pair
    assert "distractors" not in plain.generation["setups"][0]
    assert "distractors" not in plain.episodes[0].to_json()
    assert with_distractors.generation["setups"][0]["distractors"] == 3
    explicit_zero = make_episode_set(
        [dataclasses.replace(SETUP, distractors=0)],
        trials_per_setup=2,
        trials_per_world=2,
        seed=4,
        max_steps=10,
    )
    assert explicit_zero.content_hash() == plain.content_hash()


def test_the_committed_table2_set_without_distractors_is_regenerated_row_for_row():
    """``make-episodes --protocol table2 --distractors 0`` is the set the one-target Table II records ran
    on."""
    import gzip
    from pathlib import Path

    record = Path(__file__).parents[2] / "docs/results/paper10k/table2_one_target/dt_10k_s0_it10000"
    run = json.loads((record / "run.json").read_text())
    assert run["episode_set"]["content_sha256"].startswith("9d7d08dbf0ba")
    made = make_protocol_episodes("table2", trials_per_setup=1, setups=["house"], distractors=0)
    (episode,) = made.episodes
    with gzip.open(record / "episodes.jsonl.gz", "rt") as rows:
        ran = [json.loads(line) for line in rows if json.loads(line)["episode_id"] == "house/w00t00"]
    assert [row["robot"] for row in ran] == [0, 1, 2]
    assert [row["shortest_path"] for row in ran] == pytest.approx(episode.shortest_paths)


def test_table2_holds_eight_targets_for_three_robots_and_round_trips(tmp_path):
    assert [s.distractors for s in protocol_setups("table2")] == [5, 5, 5]
    assert {s.distractors for s in protocol_setups("table1")} == {0}
    made = make_protocol_episodes("table2", trials_per_setup=1, setups=["cafe"])
    loaded = load_episode_set(save_episode_set(made, tmp_path / "t2.json"))
    assert loaded == made
    (episode,) = loaded.episodes
    world = episode.world_spec().build()
    episode.check_world(world)
    assert world.n_robots == 3 and len(world.targets) == 8 and len(world.distractors) == 5
    np.testing.assert_allclose(world.robot_target_positions, [t["position"] for t in episode.targets])
    for i in range(3):  # l is measured in the world with every target in it
        xy = np.array(episode.starts[i][:2])
        assert world.shortest_path_length(xy, i, clearance=0.30, reach=5) == pytest.approx(
            episode.shortest_paths[i]
        )


@pytest.mark.parametrize(
    "setup, message",
    [
        (Setup("17.5m-6r", 17.5, ("jackal",) * 6, (True,) * 6, distractors=5),
         r"setup 17.5m-6r: distractors=5 with 6 robots needs 11 distinct targets; the catalogue has 10, so "
         r"at most 4 distractors"),
        (dataclasses.replace(SETUP, distractors=-1),
         r"setup 7.5m-2r: distractors=-1, expected an integer >= 0"),
        (dataclasses.replace(SETUP, distractors=1.5), r"distractors=1.5, expected an integer >= 0"),
    ],
)  # fmt: skip
def test_impossible_distractor_counts_are_refused_in_one_line(setup, message):
    with pytest.raises(ValueError, match=message):
        make_episode_set([setup], trials_per_setup=1)


def test_a_distractor_row_is_checked_like_a_target(pair):
    row = json.loads(json.dumps(pair[1].episodes[0].to_json()))
    assert Episode.from_json(row) == pair[1].episodes[0]
    row["distractors"][0]["position"] = [1.0]
    with pytest.raises(ValueError, match="target positions \\[x, y\\]"):
        Episode.from_json(row)
    del row["distractors"][0]["shape"]
    with pytest.raises(ValueError, match="does not follow the episode schema"):
        Episode.from_json(row)


def test_the_env_gives_each_robot_its_own_target_and_renders_the_distractors(pair):
    from navformer_rl.envs.multi_robot import MultiRobotNavEnv
    from navformer_rl.envs.target_image import render_target_image

    episode = pair[1].episodes[0]
    env = MultiRobotNavEnv(size=7.5, n_robots=2, max_steps=10)
    try:
        env.set_next_episode(episode.world_spec())
        td = env.reset()
        pixels = td.get(("agents", "target_pixels"))
        assert pixels.shape[0] == 2
        for i, target in enumerate(episode.targets):
            assert np.array_equal(pixels[i].numpy(), render_target_image(target["shape"], target["color"]))
        assert len(env.world.targets) == 5 and len(env.simulator.world.targets) == 5
        # success is measured at each robot's own target
        np.testing.assert_allclose(
            td.get(("privileged", "target_position")).numpy(), [t["position"] for t in episode.targets]
        )
    finally:
        env.close()


def test_a_diagnosis_counts_the_distractors_among_the_other_targets(tmp_path, pair):
    from navformer_rl.evaluation.diagnose import diagnose
    from navformer_rl.evaluation.diagnose.trace import load_trace, save_trace

    one = dataclasses.replace(pair[1], episodes=pair[1].episodes[:1])
    diagnose("vrw", one, tmp_path / "vrw", seed=3, progress=False)
    (path,) = sorted((tmp_path / "vrw" / "traces").glob("*.npz"))
    trace = load_trace(path)
    np.testing.assert_allclose(trace.distractors, [d["position"] for d in one.episodes[0].distractors])
    other = trace.robot(0).other_targets
    assert other.shape == (1 + 3, 2)  # the other robot's target, then the three distractors
    np.testing.assert_allclose(other[0], one.episodes[0].targets[1]["position"])
    np.testing.assert_allclose(other[1:], trace.distractors)
    # a trace written before the field existed loads with none
    older = save_trace(
        dataclasses.replace(trace, distractors=np.zeros((0, 2), np.float32)), tmp_path / "o.npz"
    )
    with np.load(older) as data:
        np.savez_compressed(tmp_path / "old.npz", **{k: data[k] for k in data.files if k != "distractors"})
    assert load_trace(tmp_path / "old.npz").robot(0).other_targets.shape == (1, 2)


def test_the_map_draws_distractors_without_a_success_circle_or_label(pair):
    from navformer_rl.envs.topdown import draw_topdown

    world = pair[1].episodes[0].world_spec().build()
    robots_only = dataclasses.replace(world, targets=world.targets[:2])
    with_distractors, plain = (draw_topdown(w, px_per_m=48.0, margin_px=0) for w in (world, robots_only))
    rows, cols = np.nonzero(np.any(with_distractors != plain, axis=2))
    assert len(rows)
    # every pixel they change lies on a distractor's body (a 1.5 m circle or a label would reach further)
    centres = np.array(
        [(48.0 * t.position[0], 48.0 * (world.size - t.position[1])) for t in world.distractors]
    )
    reach = np.hypot(cols[:, None] - centres[None, :, 0], rows[:, None] - centres[None, :, 1]).min(axis=1)
    assert reach.max() <= 48.0 * max(t.half_extent for t in world.distractors) * np.sqrt(2) + 2


def test_replace_layout_accepts_distractors_after_the_robots_targets(pair):
    from navformer_rl.envs.world import replace_layout

    world = pair[1].episodes[0].world_spec().build()
    again = replace_layout(world, starts=world.starts, targets=world.targets)
    assert len(again.distractors) == 3 and again.n_robots == 2
    with pytest.raises(ValueError, match="2 starts need one target each, got 1 targets"):
        replace_layout(world, targets=world.targets[:1])


def test_make_episodes_cli_takes_distractors_and_evaluate_refuses_them_with_a_file(tmp_path):
    from .test_cli_and_report import _run

    out = tmp_path / "e.json"
    assert _run(["evaluate", "make-episodes", "--protocol", "smoke", "--trials-per-setup", "1",
                 "--distractors", "2", "--out", str(out)]) == 0  # fmt: skip
    (episode,) = load_episode_set(out).episodes
    assert len(episode.distractors) == 2
    with pytest.raises(ValueError, match="--distractors: only with --protocol"):
        _run(["evaluate", "--method", "vrw", "--episodes", str(out), "--distractors", "1",
              "--out", str(tmp_path / "run")])  # fmt: skip
    with pytest.raises(SystemExit):
        _run(["evaluate", "make-episodes", "--protocol", "smoke", "--distractors", "-1", "--out", str(out)])
    assert TINY_SETUP.distractors == 0


def test_sets_that_differ_only_in_distractors_share_their_robots_hash(pair):
    plain, with_distractors = pair
    assert plain.content_hash() != with_distractors.content_hash()
    assert plain.robots_hash() == with_distractors.robots_hash()
    other = make_episode_set([SETUP], trials_per_setup=2, trials_per_world=2, seed=5, max_steps=10)
    assert other.robots_hash() != plain.robots_hash()


def test_compare_pairs_runs_of_sets_that_differ_only_in_distractors(tmp_path, pair):
    from navformer_rl.evaluation.harness import evaluate
    from navformer_rl.evaluation.paired import pooled_paired_differences

    from .test_cli_and_report import _run

    plain, with_distractors = pair
    other = make_episode_set([SETUP], trials_per_setup=2, trials_per_world=2, seed=5, max_steps=10)
    folders = {}
    for name, episodes in (("plain", plain), ("with", with_distractors), ("other", other)):
        folders[name] = tmp_path / name
        evaluate("vrw", episodes, folders[name], seed=3, maps_per_setup=0, videos_per_setup=0, progress=False)
    with pytest.raises(ValueError, match="ran different episode sets .* or both sets' files"):
        pooled_paired_differences([folders["with"]], [folders["plain"]])
    _, rows = pooled_paired_differences(
        [folders["with"]], [folders["plain"]], episode_sets=[plain, with_distractors]
    )
    assert rows[-1].setup == "all" and rows[-1].n_robot_trials == 4  # 2 trials x 2 robots, matched
    with pytest.raises(ValueError, match="whose robots differ"):
        pooled_paired_differences([folders["other"]], [folders["plain"]], episode_sets=[plain, other])
    files = [save_episode_set(s, tmp_path / f"{n}.json") for n, s in (("p", plain), ("w", with_distractors))]
    out = tmp_path / "compare.md"
    argv = ["evaluate", "compare", str(folders["with"]), str(folders["plain"]), "--out", str(out)]
    assert _run([*argv, "--episodes", *map(str, files)]) == 0
    assert "| all |" in out.read_text()


def test_a_maze_whose_layout_left_pockets_still_takes_its_distractors():
    """Table I 12.5m-6r world 4 trial 49: its six targets leave one-cell pockets in the free space, so the
    free space is not one component before any distractor; distractors then keep every start and target in
    one component (a generated world, one component, keeps the stricter rule D_e's data was made with)."""
    from navformer_rl.evaluation.episodes import _make_episode, _make_world

    (setup,) = [s for s in protocol_setups("table1") if s.name == "12.5m-6r"]
    base = _make_world(setup, 4, 0)
    plain = _make_episode(setup, base, 4, 49).world_spec().build()
    assert plain.occupancy.free_components(plain.config.robot_radius)[1] > 1
    episode = _make_episode(dataclasses.replace(setup, distractors=4), base, 4, 49)
    world = episode.world_spec().build()
    labels, _ = world.occupancy.free_components(world.config.robot_radius)
    points = [t.position for t in world.targets] + list(world.starts[:, :2])
    assert len(world.distractors) == 4
    assert len({int(labels[world.occupancy.snap_to_free(p, world.config.robot_radius)]) for p in points}) == 1


def test_other_target_area_is_the_free_space_near_a_target_not_ones_own(pair):
    from navformer_rl.evaluation.diagnose.trace import other_target_area

    plain, with_distractors = pair
    without, with_them = (other_target_area(s.episodes[0]) for s in (plain, with_distractors))
    assert without.shape == with_them.shape == (2,)
    assert np.all((0 < without) & (without < with_them) & (with_them < 1))
    # known answer: a robot alone in its world has no other target to end near
    (alone,) = make_episode_set(
        [Setup("7.5m-1r", 7.5, ("jackal",), (True,))], trials_per_setup=1, max_steps=5
    ).episodes
    assert other_target_area(alone).tolist() == [0.0]
