"""Episode sets: deterministic generation, protocol layout, round trip and refusal of bad files."""

import json

import numpy as np
import pytest

from navformer_rl.evaluation.episodes import (
    FORMAT_VERSION,
    Episode,
    Setup,
    load_episode_set,
    make_episode_set,
    protocol_setups,
    save_episode_set,
)

SETUP = Setup("7.5m-2r", 7.5, ("jackal", "jackal"), (True, True))


@pytest.fixture(scope="module")
def small_set():
    return make_episode_set([SETUP], trials_per_setup=3, trials_per_world=2, seed=5, name="t", max_steps=30)


def test_generation_is_deterministic_and_groups_trials_by_world(small_set):
    again = make_episode_set([SETUP], trials_per_setup=3, trials_per_world=2, seed=5, name="t", max_steps=30)
    assert again == small_set
    assert [e.episode_id for e in small_set.episodes] == [
        "7.5m-2r/w00t00",
        "7.5m-2r/w00t01",
        "7.5m-2r/w01t02",
    ]
    a, b, c = small_set.episodes
    # Trials 0 and 1 share a maze, with new starts and targets; trial 2 is in a new maze.
    assert a.world_seed == b.world_seed != c.world_seed
    assert a.starts != b.starts and a.targets != b.targets
    other = make_episode_set([SETUP], trials_per_setup=3, trials_per_world=2, seed=6)
    assert other.episodes[0].world_seed != a.world_seed


def test_worker_processes_make_the_same_set(small_set):
    """Two spawned workers build the two mazes; the set is the one made in this process."""
    parallel = make_episode_set(
        [SETUP], trials_per_setup=3, trials_per_world=2, seed=5, name="t", max_steps=30, workers=2
    )
    assert parallel == small_set and parallel.content_hash() == small_set.content_hash()
    with pytest.raises(ValueError, match="workers must be an integer >= 1, got 0"):
        make_episode_set([SETUP], trials_per_setup=1, workers=0)


def test_episode_content_is_consistent_with_the_world(small_set):
    for episode in small_set.episodes:
        world = episode.world_spec().build()
        episode.check_world(world)
        np.testing.assert_allclose(world.starts, np.array(episode.starts, dtype=np.float32))
        for i in range(episode.n_robots):
            xy = np.array(episode.starts[i][:2])
            # l: start -> target on the map inflated by the Jackal radius; the disc path is shorter.
            assert world.shortest_path_length(xy, i, clearance=0.30, reach=5) == pytest.approx(
                episode.shortest_paths[i]
            )
            # the 8-connected grid's moves are reach-5 moves too: its path is never shorter
            assert episode.shortest_paths[i] <= world.shortest_path_length(xy, i, clearance=0.30)
            assert episode.shortest_paths_to_disc[i] < episode.shortest_paths[i]
            assert np.hypot(*(xy - world.targets[i].position)) > 1.5
        assert len({(t["shape"], t["color"]) for t in episode.targets}) == episode.n_robots


def test_round_trip(tmp_path, small_set):
    path = save_episode_set(small_set, tmp_path / "set.json")
    loaded = load_episode_set(path)
    assert loaded == small_set
    assert loaded.max_steps == 30


def _write(path, document):
    path.write_text(json.dumps(document))
    return path


def test_refuses_corrupt_foreign_and_wrong_version(tmp_path, small_set):
    path = save_episode_set(small_set, tmp_path / "set.json")
    document = json.loads(path.read_text())

    edited = json.loads(json.dumps(document))
    edited["episodes"][0]["starts"][0][0] += 0.5
    with pytest.raises(ValueError, match="corrupt or was edited"):
        load_episode_set(_write(tmp_path / "edited.json", edited))

    truncated = tmp_path / "truncated.json"
    truncated.write_text(path.read_text()[:200])
    with pytest.raises(ValueError, match="not JSON"):
        load_episode_set(truncated)

    with pytest.raises(ValueError, match="format"):
        load_episode_set(_write(tmp_path / "foreign.json", {"format": "something.else", "episodes": []}))

    old = dict(document, version=FORMAT_VERSION + 1)
    with pytest.raises(ValueError, match="version"):
        load_episode_set(_write(tmp_path / "old.json", old))

    with pytest.raises(FileNotFoundError):
        load_episode_set(tmp_path / "missing.json")


@pytest.mark.parametrize(
    "edit, message",
    [
        (
            lambda row: row["shortest_paths_to_disc"].__setitem__(0, 0.0),
            "shortest_paths_to_disc must be finite and > 0",
        ),
        (
            lambda row: row["shortest_paths"].__setitem__(1, float("nan")),
            "shortest_paths must be finite and > 0",
        ),
        (
            lambda row: row["shortest_paths_to_disc"].__setitem__(0, row["shortest_paths"][0] + 1.0),
            "longer than",
        ),
        (
            lambda row: row["world"]["config"].__setitem__("n_robots", 5),
            "n_robots=2 disagrees with its world config",
        ),
        (lambda row: row.__setitem__("size", 12.5), "size=12.5 disagrees with its world config"),
    ],
)
def test_episode_rows_are_checked_beyond_the_hash(small_set, edit, message):
    # a file edited with its hash recomputed must still be refused before any episode runs
    row = json.loads(json.dumps(small_set.episodes[0].to_json()))
    assert Episode.from_json(row) == small_set.episodes[0]
    edit(row)
    with pytest.raises(ValueError, match=message):
        Episode.from_json(row)


def test_walls_check_detects_another_maze(small_set):
    a, _, c = small_set.episodes
    with pytest.raises(ValueError, match="different maze"):
        a.check_world(c.world_spec().build())


def test_protocols():
    table1 = protocol_setups("table1")
    assert [(s.size, s.n_robots) for s in table1] == [(z, n) for z in (7.5, 12.5, 17.5) for n in (2, 4, 6)]
    seen, unseen = protocol_setups("table3")
    assert unseen.robots == ("jackal", "turtlebot3", "turtlebot3", "turtlebot3")
    assert unseen.measured == (True, False, False, False) and all(seen.measured)
    with pytest.raises(ValueError, match="unknown protocol"):
        protocol_setups("table9")


def test_a_protocols_setups_can_be_chosen_and_keep_their_episodes():
    from navformer_rl.evaluation.episodes import make_protocol_episodes

    common = dict(trials_per_setup=1, seed=3, max_steps=20)
    chosen = make_protocol_episodes("table1", **common, setups=["12.5m-4r", "7.5m-2r"])
    assert chosen.setups == ["7.5m-2r", "12.5m-4r"]  # the protocol's order
    alone = make_protocol_episodes("table4", **common)  # table4's one setup is table1's 12.5m-4r
    assert chosen.episodes[1].starts == alone.episodes[0].starts
    assert chosen.episodes[1].targets == alone.episodes[0].targets
    with pytest.raises(
        ValueError, match=r"setups \['7.5m-3r'\]: expected a non-empty list of setups of protocol"
    ):
        make_protocol_episodes("table1", **common, setups=["7.5m-3r"])
    with pytest.raises(ValueError, match="non-empty"):
        make_protocol_episodes("table1", **common, setups=[])


def test_same_size_and_robot_count_share_episodes_across_protocols():
    seen, unseen = protocol_setups("table3")
    a = make_episode_set([seen], trials_per_setup=1, seed=0)
    b = make_episode_set([unseen], trials_per_setup=1, seed=0)
    c = make_episode_set(protocol_setups("table4"), trials_per_setup=1, seed=0)
    ea, eb, ec = a.episodes[0], b.episodes[0], c.episodes[0]
    assert ea.starts == eb.starts == ec.starts and ea.targets == eb.targets == ec.targets
    # Robot 0 is a Jackal in both; the TurtleBot3s' paths use their own (smaller) clearance.
    assert ea.shortest_paths[0] == eb.shortest_paths[0]
    assert ea.shortest_paths[1:] != eb.shortest_paths[1:]


def test_table2_protocol():
    from navformer_rl.evaluation.episodes import protocol_trials

    setups = protocol_setups("table2")
    assert [(s.name, s.kind, s.size) for s in setups] == [
        ("bookstore", "bookstore", 15.6),
        ("cafe", "cafe", 23.1),
        ("house", "house", 19.0),
    ]
    assert all(s.robots == ("jackal",) * 3 and s.measured == (True,) * 3 for s in setups)
    assert protocol_trials("table2") == (30, 10) and protocol_trials("table1") == (60, 10)
    with pytest.raises(ValueError, match="unknown protocol"):
        protocol_trials("table9")


def test_table2_episodes_carry_their_world_kind(tmp_path):
    """A furnished episode rebuilds its world (kind in the record) for the harness like a maze episode."""
    from navformer_rl.evaluation.episodes import make_protocol_episodes

    made = make_protocol_episodes("table2", trials_per_setup=1, seed=2, setups=["house"])
    assert made.generation["setups"][0]["kind"] == "house"
    assert "kind" not in make_episode_set([SETUP], trials_per_setup=1).generation["setups"][0]
    (episode,) = load_episode_set(save_episode_set(made, tmp_path / "t2.json")).episodes
    assert episode.episode_id == "house/w00t00" and episode.size == 19.0 and episode.n_robots == 3
    assert episode.world_config["kind"] == "house"
    world = episode.world_spec().build()
    episode.check_world(world)
    assert world.kind == "house" and world.style is not None
    np.testing.assert_allclose(world.starts, np.array(episode.starts, dtype=np.float32))
    for i in range(3):
        xy = np.array(episode.starts[i][:2])
        assert world.shortest_path_length(xy, i, clearance=0.30, reach=5) == pytest.approx(
            episode.shortest_paths[i]
        )
        assert np.hypot(*(xy - world.targets[i].position)) > 1.5
    assert len({(t["shape"], t["color"]) for t in episode.targets}) == 3


def test_a_gzipped_episode_file_loads_like_the_plain_one(tmp_path, small_set):
    import gzip

    plain = save_episode_set(small_set, tmp_path / "set.json")
    packed = tmp_path / "set.json.gz"
    packed.write_bytes(gzip.compress(plain.read_bytes()))
    assert load_episode_set(packed) == small_set
    packed.write_bytes(packed.read_bytes()[:40])
    with pytest.raises(ValueError, match="not a valid episode-set file"):
        load_episode_set(packed)
