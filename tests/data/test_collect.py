"""Tiny real collections through the simulator and the experts (seeded), resume, and the CLI."""

import ast
import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from navformer_rl.data import collect as collect_module
from navformer_rl.data import expert_episodes, open_dataset
from navformer_rl.data.cli import main as cli_main
from navformer_rl.data.collect import collect, settings_for
from navformer_rl.data.schema import DatasetKind
from navformer_rl.data.versions import DATA_VERSIONS, KIND_VERSIONS, VERSIONS_KEY, data_versions
from navformer_rl.data.writer import DatasetWriter

REPO = Path(__file__).resolve().parents[2]


def _stored_target_names(ds, task, settings):
    """``(shape, colour)`` of each stored trajectory's target, found by its position among the targets of
    the dataset's units' worlds (regenerated from the seeded settings: cheap, nothing simulated)."""
    names = {}
    for unit in range(ds.metadata["counts"]["units"]):
        if task == 0:
            episodes = range(settings.episodes_per_unit)
            worlds = [expert_episodes.exploration_world(settings, unit, k)[0] for k in episodes]
        else:
            worlds = [expert_episodes.collision_avoidance_world(settings, unit)[0]]
        for world in worlds:
            for target in world.targets:
                position = tuple(np.float32(target.position).tolist())
                names.setdefault(position, set()).add((target.shape, target.color))
    stored = []
    for start in ds.episodes.start.tolist():
        position = tuple(ds.rows["privileged", "target_position"][start].numpy().tolist())
        (name,) = names[position]  # a target of one of the units' worlds, unambiguous
        stored.append(name)
    return stored


def _check_trajectories(ds, task, settings):
    from navformer_rl.envs.target_image import render_target_image

    rows, ep = ds.rows, ds.episodes
    assert (rows["task"] == task).all()
    ends = ep.start + ep.length - 1
    # every stored trajectory succeeded: reward 1 exactly on its last step, RTG (eq. 3) 1 everywhere
    assert rows["next", "reward"][:, 0].sum() == len(ep)
    assert (rows["next", "reward"][ends] == 1).all() and (rows["next", "terminated"][ends]).all()
    assert torch.equal(rows["return_to_go"], torch.ones_like(rows["return_to_go"]))
    assert not rows["next", "truncated"].any()
    assert rows["action"].abs().max() <= 1.0
    # the last pose plus the last action's motion ends within the success radius of the target
    final_dist = (rows["privileged", "pose"][ends, :2] - rows["privileged", "target_position"][ends]).norm(
        dim=-1
    )
    assert (final_dist < 1.5 + 0.25).all()
    # frames are real camera images, target images differ between different targets
    assert rows["pixels"].float().std() > 10
    assert ds.targets.shape == (len(ep), 84, 84, 3)
    assert ep.target_id.tolist() == list(range(len(ep)))  # one target image per trajectory, in order
    names = _stored_target_names(ds, task, settings)
    images = [ds.targets[i].numpy() for i in range(len(ep))]
    for name, image in zip(names, images, strict=True):
        assert np.array_equal(image, render_target_image(*name)), name  # the image of its own target
    for i in range(len(ep)):
        for j in range(i):
            assert np.array_equal(images[i], images[j]) == (names[i] == names[j]), (names[i], names[j])


def test_tiny_exploration_collection(tmp_path):
    s = settings_for("e", "small", seed=0, n_trajectories=2, episodes_per_unit=1, world_sizes=(5.0,))
    ds = open_dataset(collect("e", tmp_path / "e", s, workers=1, progress=False), kind="e")
    assert ds.num_trajectories == 2
    _check_trajectories(ds, task=0, settings=s)
    meta = ds.metadata
    assert meta["settings"]["world_sizes"] == [5.0] and meta["counts"]["attempted"] >= 2
    assert meta["settings"][VERSIONS_KEY] == data_versions("e") and "code_sha256" not in meta["settings"]
    assert "worlds" not in meta["settings"]  # the training worlds: the identity plain collections always had
    assert "distractors" not in meta["settings"]
    assert meta["seeds"]["base"] == 0


def test_distractor_targets_join_the_mazes_and_the_expert_still_seeks_its_own(tmp_path, capsys):
    s = settings_for(
        "e", "small", seed=0, n_trajectories=2, episodes_per_unit=1, world_sizes=(7.5,), distractors=3
    )
    ds = open_dataset(collect("e", tmp_path / "e", s, workers=1, progress=False), kind="e")
    _check_trajectories(
        ds, task=0, settings=s
    )  # each ends at its own target and holds its own target's image
    assert ds.metadata["settings"]["distractors"] == 3
    plain = dataclasses.replace(s, distractors=0)
    for unit in range(ds.metadata["counts"]["units"]):
        with_them, _ = expert_episodes.exploration_world(s, unit, 0)
        without, _ = expert_episodes.exploration_world(plain, unit, 0)
        assert len(with_them.targets) == 4 and len(without.targets) == 1
        assert np.array_equal(with_them.walls, without.walls) and np.array_equal(
            with_them.starts, without.starts
        )
        mine, plain_own = with_them.targets[0], without.targets[0]
        assert np.array_equal(mine.position, plain_own.position) and (mine.shape, mine.color) == (
            plain_own.shape,
            plain_own.color,
        )
    with pytest.raises(ValueError, match="e distractors=10: expected at most 9"):
        settings_for("e", "small", distractors=10)
    with pytest.raises(ValueError, match="unknown ca collection setting"):
        settings_for("ca", "small", distractors=1)
    assert cli_main(["collect", "ca", "--distractors", "2", "--out", str(tmp_path / "ca")]) == 2
    assert "--distractors applies to e, not to 'ca'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli_main(["collect", "e", "--distractors", "-1", "--out", str(tmp_path / "x")])
    assert "--distractors" in capsys.readouterr().err


def test_tiny_collision_avoidance_collection(tmp_path):
    s = settings_for("ca", "small", seed=1, n_trajectories=4, other_robots=(2, 3))
    ds = open_dataset(collect("ca", tmp_path / "ca", s, workers=1, progress=False), kind="ca")
    assert ds.num_trajectories == 4
    _check_trajectories(ds, task=1, settings=s)
    # several robots of one arena episode: distinct targets, each trajectory with its own image
    assert len({ds.targets[i].numpy().tobytes() for i in range(4)}) >= 3
    # the counts describe the robots up to the last stored trajectory, not the whole last episode
    counts = ds.metadata["counts"]
    assert counts["attempted"] - counts["failed"] == counts["items"] == 4
    assert counts["robot_steps"] >= counts["rows"]


def test_noisy_collision_avoidance_collection_records_its_noise(tmp_path):
    s = settings_for("ca", "small", seed=1, n_trajectories=3, other_robots=(2, 2), action_noise=0.2)
    ds = open_dataset(collect("ca", tmp_path / "ca", s, workers=1, progress=False), kind="ca")
    assert ds.num_trajectories == 3 and ds.metadata["settings"]["action_noise"] == 0.2
    _check_trajectories(ds, task=1, settings=s)
    plain = settings_for("ca", "small", seed=1, n_trajectories=3, other_robots=(2, 2))
    quiet = open_dataset(collect("ca", tmp_path / "quiet", plain, workers=1, progress=False))
    # the same arenas and starts, other paths
    assert torch.equal(ds.targets.as_subclass(torch.Tensor), quiet.targets.as_subclass(torch.Tensor))
    assert not torch.equal(
        ds.rows["action"][:20].as_subclass(torch.Tensor), quiet.rows["action"][:20].as_subclass(torch.Tensor)
    )


def test_counts_describe_the_stored_trajectories_only(tmp_path):
    """The dataset ends after the first trajectory of a 2-episode unit: the metadata counts the attempts up
    to it (as the dataset card's success rate does), not the unit's second episode."""
    s = settings_for("e", "small", seed=0, n_trajectories=1, episodes_per_unit=2, world_sizes=(5.0,))
    ds = open_dataset(collect("e", tmp_path / "e", s, workers=1, progress=False), kind="e")
    counts = ds.metadata["counts"]
    assert counts["items"] == 1 and counts["units"] == 1
    assert counts["attempted"] - counts["failed"] == 1
    steps_of_failures = counts["robot_steps"] - counts["rows"]
    assert steps_of_failures >= 0 and (steps_of_failures > 0) == (counts["failed"] > 0)


def test_tiny_ssl_collection_pairs_share_the_pose(tmp_path):
    s = settings_for("ssl", "small", seed=2, n_worlds=2, pairs_per_world=5, robots=(4, 5), world_sizes=(5.0,))
    ds = open_dataset(collect("ssl", tmp_path / "ssl", s, workers=1, progress=False), kind="ssl")
    assert len(ds) == 10 and ds.rows["world"].tolist() == [0] * 5 + [1] * 5
    static, dynamic = ds.rows["pixels_static"], ds.rows["pixels_dynamic"]
    diff = (static != dynamic).flatten(1).any(1)
    assert ds.metadata["counts"]["pairs_with_visible_robot"] == int(diff.sum())
    # same pose: apart from the robots, most pixels are identical in every pair
    same = (static == dynamic).all(-1).flatten(1).float().mean(1)
    assert (same > 0.5).all()


def test_collections_in_furnished_worlds(tmp_path, capsys):
    """``worlds=`` collects each kind in Table II's furnished worlds: the experts succeed there, the worlds
    are the drawn kinds at their footprints, and the setting is part of the dataset's identity."""
    s = settings_for("e", "small", seed=4, n_trajectories=2, episodes_per_unit=1, worlds="furnished")
    kinds = {expert_episodes.exploration_world(s, u, 0)[0].kind for u in range(12)}
    assert kinds == {"bookstore", "cafe", "house"}  # 'furnished' draws the kind per world
    ds = open_dataset(collect("e", tmp_path / "e", s, workers=1, progress=False), kind="e")
    assert ds.num_trajectories == 2 and ds.metadata["settings"]["worlds"] == "furnished"
    _check_trajectories(ds, task=0, settings=s)
    # CLI: two-robot D_ca in cafes, as the fine-tuning protocol of paper §VIII asks
    out = tmp_path / "ca"
    args = ["collect", "ca", "--worlds", "cafe", "--robots", "2", "--n", "2", "--seed", "1", "--workers", "1"]
    assert cli_main([*args, "--out", str(out), "--no-progress"]) == 0
    ca = open_dataset(out, kind="ca")
    settings = ca.metadata["settings"]
    assert settings["worlds"] == "cafe" and settings["other_robots"] == [1, 1]
    ca_settings = settings_for("ca", "small", seed=1, n_trajectories=2, other_robots=(1, 1), worlds="cafe")
    world = expert_episodes.collision_avoidance_world(ca_settings, 0)[0]
    assert world.kind == "cafe" and len(world.starts) == 2
    _check_trajectories(ca, task=1, settings=ca_settings)
    ssl = settings_for("ssl", "small", seed=2, n_worlds=1, pairs_per_world=4, robots=(3, 3), worlds="house")
    pairs = open_dataset(collect("ssl", tmp_path / "ssl", ssl, workers=1, progress=False), kind="ssl")
    assert len(pairs) == 4 and expert_episodes.ssl_world(ssl, 0)[0].kind == "house"
    # another worlds setting is another dataset: resuming into the folder is refused
    other = settings_for("e", "small", seed=4, n_trajectories=2, episodes_per_unit=1, worlds="cafe")
    with pytest.raises(ValueError, match="worlds"):
        collect("e", tmp_path / "e", other, workers=1, progress=False)
    capsys.readouterr()
    assert cli_main(["collect", "e", "--robots", "2", "--out", str(tmp_path / "x")]) == 2
    assert "--robots applies to ca and ssl" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli_main(["collect", "ca", "--robots", "0", "--out", str(tmp_path / "x")])
    assert "'0': expected N or LO-HI robots with 1 <= LO <= HI" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"e worlds='arena': expected one of \('maze'"):
        settings_for("e", worlds="arena")
    with pytest.raises(ValueError, match="ca other_robots=\\(2, 1\\): expected"):
        settings_for("ca", other_robots=(2, 1))


def test_failed_episodes_are_dropped_and_counted():
    # 3 steps are never enough to reach a target in a 5 m maze: every episode fails
    s = settings_for("e", "small", seed=0, episodes_per_unit=2, world_sizes=(5.0,), max_steps=3)
    by_item: dict[str, list[int]] = {}
    rows, targets, counters = expert_episodes.exploration_unit(s, 0, by_item)
    assert rows == [] and targets == [] and by_item == {}
    assert counters == {"attempted": 2, "failed": 2, "collision_steps": 0, "robot_steps": 6}


# --------------------------------------------------------------------------------- data versions
PACKAGE = REPO / "navformer_rl"
COLLECTION_ROOTS = ("data/collect.py", "data/expert_episodes.py")
NOT_SHAPING_DATA = {
    "__init__.py",
    "utils/__init__.py",
    "utils/durable.py",
    "utils/interrupts.py",
    "utils/backends.py",
    "utils/mp4.py",
    "data/writer.py",
    "data/versions.py",
}
"""Package modules imported by the collection code that only move bytes, draw, handle Ctrl-C, schedule the
work units, or give the version."""


def _package_imports(file: Path) -> set[str]:
    """Package files (relative to ``navformer_rl/``) that ``file`` imports, at any depth of its code."""
    found = set()
    for node in ast.walk(ast.parse(file.read_text())):
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            modules = [f"{node.module}.{alias.name}" for alias in node.names] + [node.module]
        else:
            continue
        for module in modules:
            parts = module.split(".")
            if parts[0] != "navformer_rl":
                continue
            inner = parts[1:]
            candidates = [Path(*inner[:-1], f"{inner[-1]}.py")] if inner else []
            for candidate in (*candidates, Path(*inner, "__init__.py")):
                if (PACKAGE / candidate).is_file():
                    found.add(candidate.as_posix())
                    break
    return found


def test_data_versions_cover_every_module_that_shapes_the_data():
    """Each package module the collection code reaches (imports, transitively) is covered by a version of
    DATA_VERSIONS (which a change of its behaviour bumps) or known not to change the data."""
    covered = {name for version in DATA_VERSIONS.values() for name in version.covers}
    assert all((PACKAGE / name).is_file() for name in covered), sorted(covered)
    reached, todo = set(), list(COLLECTION_ROOTS)
    while todo:
        name = todo.pop()
        if name in reached or name in NOT_SHAPING_DATA:
            continue
        reached.add(name)
        todo.extend(_package_imports(PACKAGE / name))
    assert {"envs/sim.py", "experts/dwa.py", "experts/nh_orca.py", "constants.py"} <= reached
    assert reached - covered == set(), sorted(reached - covered)


def test_every_kind_records_its_data_versions():
    for kind in DatasetKind:
        versions = data_versions(kind)
        assert {"world", "simulator", "renderer"} <= set(versions) == set(KIND_VERSIONS[kind])
        assert all(isinstance(n, int) and n >= 1 for n in versions.values())
    assert "exploration_expert" in data_versions("e") and "exploration_expert" not in data_versions("ca")
    assert "collision_avoidance_expert" in data_versions("ca") and "ssl_pairs" in data_versions("ssl")


def test_collection_is_deterministic_and_resumes_identically(tmp_path, folder_bytes):
    s = settings_for("ca", "small", seed=5, n_trajectories=5, other_robots=(2, 2))
    ref = collect("ca", tmp_path / "ref", s, workers=1, progress=False)
    # crash after the first unit (its shard is complete), then resume
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


def _alive(pid: int) -> bool:
    """Whether process ``pid`` still runs (an exited, not yet reaped zombie does not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _wait_until(condition, seconds: float, poll: float = 0.05) -> bool:
    """Poll ``condition`` until it holds or ``seconds`` (a generous deadline, not a timing check) passed."""
    deadline = time.monotonic() + seconds
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(poll)
    return True


@pytest.mark.slow
def test_killed_cli_process_resumes_to_identical_dataset(tmp_path, folder_bytes):
    """SIGKILL a real `collect` process with 2 workers after its first shard; rerun; compare bytes."""
    import json

    cmd = [sys.executable, "-m", "navformer_rl.data.cli", "collect", "e", "--n", "6", "--seed", "3"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    out = tmp_path / "killed"
    proc = subprocess.Popen([*cmd, "--out", str(out), "--workers", "2", "--no-progress"], cwd=REPO, env=env)
    workers: list[int] = []

    def shards():
        return list((out / "shards").glob("unit-*"))

    try:
        assert _wait_until(lambda: shards() or proc.poll() is not None, 300), "no shard written"
        # freeze the collection (parent, then its workers) so the state checked below is the one killed
        proc.send_signal(signal.SIGSTOP)
        children = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout
        workers += [int(pid) for pid in children.split()]
        for pid in workers:
            os.kill(pid, signal.SIGSTOP)
        # the first shard is committed, the dataset is not complete: the kill lands mid-collection
        assert proc.poll() is None, "collection finished before it could be killed"
        assert shards() and len(workers) >= 2
        assert json.loads((out / "metadata.json").read_text()).get("status") != "complete"
        assert not (out / "consolidated").exists()
        proc.send_signal(signal.SIGKILL)  # the parent only: its workers must notice and exit by themselves
        proc.wait()
        for pid in workers:
            os.kill(pid, signal.SIGCONT)
        assert _wait_until(lambda: not any(_alive(pid) for pid in workers), 60), "orphaned collection workers"
    finally:  # after a failed check: leave nothing of this collection running
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for pid in workers:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
    subprocess.run(
        [*cmd, "--out", str(out), "--workers", "2", "--no-progress"], cwd=REPO, env=env, check=True
    )
    ref = tmp_path / "ref"
    subprocess.run(
        [*cmd, "--out", str(ref), "--workers", "1", "--no-progress"], cwd=REPO, env=env, check=True
    )
    assert folder_bytes(out) == folder_bytes(ref)
    assert open_dataset(out).num_trajectories == 6


def test_cli_help_and_errors(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli_main(["collect", "--help"])
    assert exit_info.value.code == 0
    assert "--scale" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_info:
        cli_main(["collect", "e", "--out", str(tmp_path / "x"), "--workers", "0"])
    assert exit_info.value.code == 2
    assert "argument --workers: expected an integer >= 1, got 0" in capsys.readouterr().err
    assert cli_main(["collect", "all", "--out", str(tmp_path / "x"), "--n", "3"]) == 2
    assert "not to 'all'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli_main(["collect", "xyz", "--out", str(tmp_path)])
    # a folder holding another dataset is refused with a clear message
    DatasetWriter(tmp_path / "other", "e", {"something": "else"}, 1)
    assert cli_main(["collect", "e", "--out", str(tmp_path / "other"), "--no-progress"]) == 2
    assert "already holds a dataset" in capsys.readouterr().err


def test_settings_overrides_are_checked():
    with pytest.raises(ValueError, match="unknown e collection setting"):
        settings_for("e", "small", bogus=1)
    with pytest.raises(ValueError, match="unknown scale 'huge'"):
        settings_for("e", "huge")
    paper = settings_for("ssl", "paper")
    assert paper.n_worlds * paper.pairs_per_world == 98_000
    assert settings_for("e", "paper").n_trajectories == 3496
    assert settings_for("ca", "paper").n_trajectories == 7467
    assert np.isclose(min(settings_for("e").world_sizes), 5.0)


def test_deferred_rendering_equals_live_cameras():
    """run_episode renders after the episode (restoring poses);
    the frames equal live rendering at each step."""
    from navformer_rl.envs.robots import JACKAL
    from navformer_rl.envs.sim import Simulator
    from navformer_rl.experts.policies import NHORCAExpert

    s = settings_for("ca", "small", seed=1, other_robots=(2, 2))

    def episode():
        world, rng = expert_episodes.collision_avoidance_world(s, 0)
        sim = Simulator(world, JACKAL)
        expert = NHORCAExpert()
        expert.reset(world, sim, rng)
        return world, sim, expert

    world, sim, expert = episode()
    live = []
    active = ~expert_episodes.reached_targets(sim, world)
    while active.any() and len(live) < 200:
        live.append(sim.render_all(active))
        actions = expert.act(sim, active)
        sim.step(np.where(active[:, None], actions, 0.0), active)
        active &= ~expert_episodes.reached_targets(sim, world) & ~expert.failed
    sim.close()
    world, sim, expert = episode()
    trajs = expert_episodes.run_episode(world, sim, expert, 200)
    sim.close()
    assert world.n_robots == 3 and len(trajs) == world.n_robots  # the ego robot and its 2 others
    assert all(t.succeeded for t in trajs)
    compared = 0
    for i, traj in enumerate(trajs):
        assert len(traj.frames) == len(traj.actions) > 0
        for t, frame in enumerate(traj.frames):
            assert np.array_equal(frame, live[t][i])
            compared += 1
    assert compared == sum(len(t.frames) for t in trajs) > 0
    assert len(live) == max(len(t.frames) for t in trajs)  # live ran until the last robot arrived


def test_paper_ssl_unit_that_overfills_its_maze_gets_fewer_robots():
    """Paper unit 26 draws 25 robots for a 5 m maze, which random placement cannot hold: the unit is
    retried with fewer robots (deterministically) instead of aborting the whole collection."""
    s = settings_for("ssl", "paper")
    world, n_drawn, rng = expert_episodes.ssl_world(s, 26)
    assert (world.size, n_drawn) == (5.0, 25)
    layouts = expert_episodes.ssl_layouts(s, 26, world, n_drawn, rng)
    n = len(layouts[0])
    assert 4 <= n < 25 and len(layouts) == -(-s.pairs_per_world // n)
    assert all(layout.shape == (n, 3) for layout in layouts)
    world, n_drawn, rng = expert_episodes.ssl_world(s, 26)
    again = expert_episodes.ssl_layouts(s, 26, world, n_drawn, rng)
    assert all(np.array_equal(a, b) for a, b in zip(layouts, again, strict=True))


def test_overfull_ssl_worlds_complete_deterministically(tmp_path, folder_bytes):
    s = settings_for(
        "ssl", "small", seed=0, n_worlds=2, pairs_per_world=3, robots=(25, 25), world_sizes=(5.0,)
    )
    ref = collect("ssl", tmp_path / "ref", s, workers=1, progress=False)
    ds = open_dataset(ref, kind="ssl")
    assert len(ds) == 6
    counts = ds.metadata["counts"]
    assert counts["robots_drawn"] == 50 and counts["worlds_with_fewer_robots"] == 2
    assert 8 <= counts["robots_total"] < 50
    assert "one robot fewer" in ds.metadata["robot_placement"]
    again = collect("ssl", tmp_path / "again", s, workers=1, progress=False)
    assert folder_bytes(again) == folder_bytes(ref)


class _ConstantExpert:
    """Drives straight ahead at half speed, never fails."""

    def __init__(self, n):
        self.failed = np.zeros(n, dtype=bool)

    def act(self, sim, active):
        return np.tile(np.float32([0.5, 0.0]), (sim.n_robots, 1))


def test_action_noise_perturbs_the_executed_actions_and_keeps_the_labels(capsys):
    """DART: the simulator drives clip(a + noise); the stored action is the expert's a."""
    from navformer_rl.envs.robots import JACKAL
    from navformer_rl.envs.sim import Simulator
    from navformer_rl.envs.world import WorldConfig, generate_world

    world = generate_world(WorldConfig(size=12.5, kind="arena", n_robots=1, robot_radius=JACKAL.radius), 3)

    def drive(noise, seed=0):
        sim = Simulator(world, JACKAL)
        try:
            (traj,) = expert_episodes.run_episode(
                world, sim, _ConstantExpert(1), 6, False, noise, np.random.default_rng(seed)
            )
        finally:
            sim.close()
        return traj

    plain, noisy, again = drive(0.0), drive(0.3), drive(0.3)
    assert all(np.array_equal(a, [0.5, 0.0]) for a in noisy.actions)  # labels: the expert's actions
    headings = [p[2] for p in noisy.poses]
    assert len(set(np.round(headings, 6))) > 1  # the executed turn rates were perturbed
    assert len({round(float(p[2]), 6) for p in plain.poses}) == 1  # without noise: straight ahead
    assert all(np.array_equal(a, b) for a, b in zip(noisy.poses, again.poses))  # seeded
    with pytest.raises(ValueError, match="needs a noise_rng"):
        expert_episodes.run_episode(world, None, _ConstantExpert(1), 6, False, 0.3)
    with pytest.raises(ValueError, match=r"e action_noise must be .*<= 1"):
        settings_for("e", action_noise=2.0)
    from navformer_rl.data.cli import main

    assert main(["collect", "ssl", "--out", "/tmp/never", "--action-noise", "0.1"]) == 2
    assert "--action-noise applies to e and ca" in capsys.readouterr().err
