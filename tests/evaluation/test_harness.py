"""The harness end to end on tiny episodes: outputs, numbers recomputed from the JSONL, env agreement."""

import csv
import json

import cv2
import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModuleBase

from navformer_rl.baselines.random_walk import RandomWalkPolicy
from navformer_rl.evaluation import harness
from navformer_rl.evaluation.episodes import load_episode_set
from navformer_rl.evaluation.harness import evaluate, make_eval_env
from navformer_rl.evaluation.measures import clustered_wilson_interval, collision_rate, spl
from navformer_rl.modules import NavFormerConfig
from navformer_rl.modules.decoding.native import native_status
from navformer_rl.training.checkpoint import training_context_steps


def test_writes_every_output(vrw_run, tiny_episodes):
    out, result = vrw_run
    for name in (
        "episodes.jsonl",
        "summary.csv",
        "summary.md",
        "metrics.png",
        "run.json",
        "episode_set.json",
    ):
        assert (out / name).is_file(), name
    assert result.files["maps"] == ["maps/7.5m-2r_w00t00.png"]
    assert result.files["videos"] == ["videos/7.5m-2r_w00t00.mp4"]
    assert load_episode_set(out / "episode_set.json") == tiny_episodes
    run = json.loads((out / "run.json").read_text())
    assert run["method"] == "vrw" and run["episode_set"]["content_sha256"] == tiny_episodes.content_hash()
    image = cv2.imread(str(out / "maps/7.5m-2r_w00t00.png"))
    assert image is not None and image.shape[0] > 400
    plot = cv2.imread(str(out / "metrics.png"))
    assert plot is not None
    capture = cv2.VideoCapture(str(out / "videos/7.5m-2r_w00t00.mp4"))
    frames = 0
    while capture.read()[0]:
        frames += 1
    rows = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    first = [r for r in rows if r["episode_id"] == "7.5m-2r/w00t00"]
    assert frames == 1 + max(r["steps"] for r in first)  # the reset frame + one per step


def test_summary_matches_a_recomputation_from_the_jsonl(vrw_run, tiny_episodes):
    out, _ = vrw_run
    rows = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert len(rows) == 4  # 2 trials x 2 robots
    assert [(r["episode_id"], r["robot"]) for r in rows] == [
        (e.episode_id, i) for e in tiny_episodes.episodes for i in range(e.n_robots)
    ]
    success = np.array([r["success"] for r in rows])
    shortest = np.array([r["shortest_path"] for r in rows])
    driven = np.array([r["path_length"] for r in rows])
    collisions = np.array([r["collisions"] for r in rows])
    steps = np.array([r["steps"] for r in rows])
    for r, episode_row in zip(rows, [e for e in tiny_episodes.episodes for _ in range(e.n_robots)]):
        assert r["shortest_path"] == episode_row.shortest_paths[r["robot"]]
        assert r["steps"] == (r["success_step"] if r["success"] else 12)
    table = list(csv.DictReader((out / "summary.csv").open()))
    assert len(table) == 1 and table[0]["setup"] == "7.5m-2r"
    row = table[0]
    assert float(row["sr"]) == pytest.approx(success.mean(), abs=1e-6)
    assert float(row["spl"]) == pytest.approx(spl(success, shortest, driven), abs=1e-6)
    assert float(row["cr"]) == pytest.approx(collision_rate(collisions, steps), abs=1e-6)
    low, high = clustered_wilson_interval(success, np.array([r["episode_id"] for r in rows]))
    assert float(row["sr_low"]) == pytest.approx(low, abs=1e-6) and float(row["sr_high"]) == pytest.approx(
        high, abs=1e-6
    )
    assert int(row["n_trials"]) == 2 and int(row["n_robot_trials"]) == 4
    markdown = (out / "summary.md").read_text()
    assert "| 7.5m-2r | 7.5 × 7.5 | 2 |" in markdown and "vrw SR" in markdown


def test_measures_agree_with_the_env_counters(vrw_run, tiny_episodes):
    """Replay episode 0 by hand with the same seeded VRW: the env's own path length and collision counters
    equal the harness's p and N_c."""
    out, _ = vrw_run
    rows = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()][:2]
    episode = tiny_episodes.episodes[0]
    env = make_eval_env(episode.robots, tiny_episodes.max_steps)
    try:
        env.set_next_episode(episode.world_spec())
        policy = RandomWalkPolicy()
        with torch.no_grad():
            td = env.reset()
            policy.bind(env, episode.seed ^ 3)
            for _ in range(tiny_episodes.max_steps):
                td = env.step(policy(td))
                if td["next", "done"].all():
                    break
                td = td["next"]
        final = td["next", "privileged"]
        np.testing.assert_allclose(
            final["path_length"].reshape(-1).numpy(), [r["path_length"] for r in rows], atol=1e-4
        )
        np.testing.assert_array_equal(
            final["collisions"].reshape(-1).numpy(), [r["collisions"] for r in rows]
        )
    finally:
        env.close()


def test_vrw_is_deterministic(tmp_path, vrw_run, tiny_episodes):
    out, _ = vrw_run
    again = evaluate(
        "vrw", tiny_episodes, tmp_path / "again", maps_per_setup=0, videos_per_setup=0, progress=False, seed=3
    )
    assert (tmp_path / "again" / "episodes.jsonl").read_text() == (out / "episodes.jsonl").read_text()
    assert not (tmp_path / "again" / "maps").exists() and again.files["videos"] == []


@pytest.mark.slow
@pytest.mark.parametrize("method", ["vrw", "navformer"])
def test_worker_count_does_not_change_results(tmp_path, tiny_episodes, checkpoints, method):
    """Spawned workers (one torch thread each) give byte-identical rows to the in-process run."""
    checkpoint = checkpoints.get(method) if method == "navformer" else None
    kwargs = dict(checkpoint=checkpoint, maps_per_setup=0, videos_per_setup=0, progress=False, seed=3)
    evaluate(method, tiny_episodes, tmp_path / "one", workers=1, **kwargs)
    evaluate(method, tiny_episodes, tmp_path / "two", workers=2, **kwargs)
    assert (tmp_path / "two" / "episodes.jsonl").read_text() == (
        tmp_path / "one" / "episodes.jsonl"
    ).read_text()


def test_resume_reuses_finished_episodes(tmp_path, tiny_episodes, monkeypatch):
    out = tmp_path / "resume"
    evaluate("vrw", tiny_episodes, out, maps_per_setup=0, videos_per_setup=0, progress=False)
    first = (out / "episodes.jsonl").read_text()
    # Mark episode 0's stored rows: a resumed run must take them as they are, not recompute them.
    partial = out / "per_episode" / "7.5m-2r_w00t00.json"
    document = json.loads(partial.read_text())
    document["records"][0]["path_length"] = 123.0
    partial.write_text(json.dumps(document))
    (out / "per_episode" / "7.5m-2r_w00t01.json").unlink()
    evaluate("vrw", tiny_episodes, out, maps_per_setup=0, videos_per_setup=0, progress=False)
    rows = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert rows[0]["path_length"] == 123.0
    assert [json.dumps(r, sort_keys=True) for r in rows[1:]] == first.splitlines()[1:]
    # Another seed, or another package version, is other work: the marked row is not reused
    evaluate("vrw", tiny_episodes, out, maps_per_setup=0, videos_per_setup=0, progress=False, seed=3)
    assert json.loads((out / "episodes.jsonl").read_text().splitlines()[0])["path_length"] != 123.0
    partial.write_text(json.dumps(document))  # marked again, under seed 0
    monkeypatch.setattr(harness, "__version__", "0.0.0-older")
    evaluate("vrw", tiny_episodes, out, maps_per_setup=0, videos_per_setup=0, progress=False)
    assert (out / "episodes.jsonl").read_text() == first
    # resume=False recomputes everything
    partial.write_text(json.dumps(document))
    evaluate("vrw", tiny_episodes, out, maps_per_setup=0, videos_per_setup=0, progress=False, resume=False)
    assert (out / "episodes.jsonl").read_text() == first


@pytest.fixture
def clock(monkeypatch, fake_clock):
    """Fake time: building a runner takes 0.5 s, an episode 2 s, writing the summary files 0.25 s."""
    from navformer_rl.evaluation import runner

    fake = fake_clock
    monkeypatch.setattr(harness, "time", fake)
    monkeypatch.setattr(runner, "time", fake)

    def taking(seconds, function):
        def timed(*args, **kwargs):
            fake.now += seconds
            return function(*args, **kwargs)

        return timed

    monkeypatch.setattr(runner.EpisodeRunner, "__init__", taking(0.5, runner.EpisodeRunner.__init__))
    monkeypatch.setattr(runner.EpisodeRunner, "run", taking(2.0, runner.EpisodeRunner.run))
    monkeypatch.setattr(harness, "write_summary_files", taking(0.25, harness.write_summary_files))
    return fake


def test_run_json_times_the_computation_not_the_rerun(tmp_path, tiny_episodes, clock):
    """A rerun that reuses finished episodes reports the time that computed them, not its own."""
    from navformer_rl.evaluation.report import write_report

    out = tmp_path / "timed"
    kwargs = dict(maps_per_setup=0, videos_per_setup=0, progress=False)
    evaluate("vrw", tiny_episodes, out, **kwargs)
    first = json.loads((out / "run.json").read_text())
    stored = {p.name: json.loads(p.read_text()) for p in sorted((out / "per_episode").glob("*.json"))}
    # each episode ran 2 s; the wall time from the start also holds the runner's 0.5 s build (first episode)
    assert len(stored) == 2 and all(d["seconds"] == 2.0 for d in stored.values())
    assert sorted(d["wall_seconds"] for d in stored.values()) == [2.0, 2.5]
    assert (first["seconds"], first["episode_seconds"], first["invocation_seconds"]) == (4.5, 4.0, 4.75)
    assert (first["episodes_computed"], first["episodes_reused"]) == (2, 0)

    result = evaluate("vrw", tiny_episodes, out, **kwargs)
    rerun = json.loads((out / "run.json").read_text())
    assert (rerun["seconds"], rerun["episode_seconds"]) == (4.5, 4.0)
    assert (rerun["episodes_computed"], rerun["episodes_reused"]) == (0, 2)
    assert result.episodes_computed == 0 and result.seconds == 4.5
    # the rerun's own time runs from the call: it builds no runner, runs no episode, writes the summary
    assert rerun["invocation_seconds"] == 0.25

    # one episode reused (with a marked time), one recomputed: their times add up
    reused, redone = (out / "per_episode" / name for name in stored)
    document = json.loads(reused.read_text())
    document["wall_seconds"] = 1000.0
    reused.write_text(json.dumps(document))
    redone.unlink()
    evaluate("vrw", tiny_episodes, out, **kwargs)
    third = json.loads((out / "run.json").read_text())
    assert json.loads(redone.read_text())["wall_seconds"] == 2.5  # runner build + episode
    assert (third["seconds"], third["invocation_seconds"]) == (1002.5, 2.75)
    assert (third["episodes_computed"], third["episodes_reused"]) == (1, 1)
    report = write_report([out], tmp_path / "report.md").read_text()
    assert f"| - | - | {third['seconds']:.0f} |" in report  # checkpoint, ablation, seconds

    # an episode stored without its time (an older version's file) makes the total unknown, not smaller
    del document["wall_seconds"]
    reused.write_text(json.dumps(document))
    evaluate("vrw", tiny_episodes, out, **kwargs)
    assert json.loads((out / "run.json").read_text())["seconds"] is None
    assert "| - | - | - |" in write_report([out], tmp_path / "report.md").read_text()


def test_one_evaluation_per_folder_and_killed_writers_temporaries_are_removed(tmp_path, tiny_episodes):
    import subprocess
    import sys

    from navformer_rl.evaluation.harness import LOCK_FILENAME
    from navformer_rl.utils import durable

    out = tmp_path / "vrw"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom navformer_rl.utils.durable import folder_lock\n"
         f"with folder_lock(sys.argv[1], {LOCK_FILENAME!r}, 'evaluated'):\n"
         "    print('locked', flush=True); time.sleep(60)", str(out)],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(
            durable.FolderLockedError, match=rf"is being evaluated by another process \(pid {holder.pid}"
        ):
            evaluate("vrw", tiny_episodes, out, maps_per_setup=0, videos_per_setup=0, progress=False)
    finally:
        holder.kill()
        holder.wait()
    # a writer killed mid-file leaves its temporary file; the next evaluation of the folder removes it
    (out / "videos").mkdir(parents=True)
    leftover = out / "videos" / ".7.5m-2r_w00t00.abc12345.tmp.mp4"
    leftover.write_bytes(b"partial")
    users_file = out / ".notes.tmpl"  # a hidden file of the user's that merely looks similar
    users_file.write_text("keep")
    with pytest.warns(UserWarning, match="taking over the lock left by process"):  # the killed holder's
        evaluate("vrw", tiny_episodes, out, maps_per_setup=0, videos_per_setup=0, progress=False)
    assert not leftover.exists() and not (out / LOCK_FILENAME).exists()
    assert users_file.read_text() == "keep"


def test_summary_intervals_do_not_depend_on_the_policy_seed(tmp_path, tiny_episodes, monkeypatch):
    """summary.csv's bootstrap is seeded like the report's (0), not with the policy seed, so the same rows
    get the same intervals in both."""
    from navformer_rl.evaluation import tables

    seeds = []
    summarize = tables.summarize_by_setup

    def recording(records, confidence=0.95, seed=0, cluster="trial"):
        seeds.append(seed)
        return summarize(records, confidence, seed, cluster)

    monkeypatch.setattr(tables, "summarize_by_setup", recording)
    evaluate(
        "vrw", tiny_episodes, tmp_path / "vrw", seed=3, maps_per_setup=0, videos_per_setup=0, progress=False
    )
    assert seeds == [0]


class _ConstantPolicy(TensorDictModuleBase):
    """Every robot commands ``(linear, 0)``: in ``("agents", "pixels")``, out ``("agents", "action")``."""

    in_keys = [("agents", "pixels")]
    out_keys = [("agents", "action")]

    def __init__(self, linear: float) -> None:
        super().__init__()
        self.linear = linear

    def forward(self, tensordict):
        robots = tensordict["agents", "pixels"].shape[0]
        action = torch.zeros(robots, 2)
        action[:, 0] = self.linear
        return tensordict.set(("agents", "action"), action)


def standing_policy():
    return _ConstantPolicy(0.0)


def driving_policy():
    return _ConstantPolicy(1.0)


driving_policy.__name__ = "standing_policy"  # the same label as standing_policy, another policy


def test_resume_tells_apart_your_own_policies_that_share_a_label(tmp_path, tiny_episodes):
    out = tmp_path / "mine"
    common = dict(maps_per_setup=0, videos_per_setup=0, progress=False)
    trials = sum(episode.n_robots for episode in tiny_episodes.episodes)
    assert (len(tiny_episodes), trials) == (2, 4)  # two episodes of two robots
    standing = evaluate(standing_policy, tiny_episodes, out, **common)
    assert len(standing.records) == trials and standing.episodes_computed == 2
    assert all(r.path_length == 0.0 for r in standing.records)
    driving = evaluate(driving_policy, tiny_episodes, out, **common)
    assert driving.episodes_computed == len(tiny_episodes)  # not the standing policy's rows
    assert len(driving.records) == trials
    assert all(r.path_length > 0.0 for r in driving.records)
    assert json.loads((out / "run.json").read_text())["factory"].endswith(".driving_policy")


def test_a_new_video_frame_rate_recomputes_only_the_episodes_with_a_video(tmp_path, tiny_episodes):
    out = tmp_path / "vrw"
    common = dict(maps_per_setup=0, videos_per_setup=1, progress=False, seed=3)
    evaluate("vrw", tiny_episodes, out, video_fps=10.0, **common)
    again = evaluate("vrw", tiny_episodes, out, video_fps=5.0, **common)
    assert again.episodes_computed == 1  # the first episode of the setup has the video; the other is reused
    capture = cv2.VideoCapture(str(out / again.files["videos"][0]))
    assert capture.get(cv2.CAP_PROP_FPS) == 5.0
    capture.release()


@pytest.mark.skipif(not native_status().available, reason=native_status().reason)
def test_the_transformer_path_is_recorded_and_part_of_the_resume_key(
    tmp_path, tiny_episodes, checkpoints, monkeypatch
):
    """The compiled kernel and the torch path agree only to float rounding: results of one are never
    reused for the other."""
    out = tmp_path / "navformer"
    kwargs = dict(checkpoint=checkpoints["navformer"], maps_per_setup=0, videos_per_setup=0, progress=False)
    evaluate("navformer", tiny_episodes, out, workers=1, **kwargs)
    assert json.loads((out / "run.json").read_text())["transformer_step"] == "native"
    partial = out / "per_episode" / "7.5m-2r_w00t00.json"
    document = json.loads(partial.read_text())
    document["records"][0]["path_length"] = 123.0  # a marked row: reused on resume, gone if recomputed
    partial.write_text(json.dumps(document))
    evaluate("navformer", tiny_episodes, out, workers=1, **kwargs)
    assert json.loads((out / "episodes.jsonl").read_text().splitlines()[0])["path_length"] == 123.0
    monkeypatch.setenv("NAVFORMER_NATIVE", "0")  # the workers inherit it
    evaluate("navformer", tiny_episodes, out, workers=1, **kwargs)
    assert json.loads((out / "run.json").read_text())["transformer_step"] == "torch"
    assert json.loads((out / "episodes.jsonl").read_text().splitlines()[0])["path_length"] != 123.0


def test_a_shorter_context_is_recorded_and_never_mixed_with_the_whole_contexts_results(
    tmp_path, tiny_episodes, checkpoints
):
    """``context_steps`` runs the policy on that window (other actions past it), is written to run.json, and
    is part of the resume key; other methods and windows longer than the model's are refused by name."""
    out = tmp_path / "navformer"
    kwargs = dict(checkpoint=checkpoints["navformer"], maps_per_setup=0, videos_per_setup=0, progress=False)
    whole = evaluate("navformer", tiny_episodes, out, **kwargs)
    assert "context_steps" not in json.loads((out / "run.json").read_text())
    short = evaluate("navformer", tiny_episodes, out, context_steps=2, **kwargs)
    assert short.episodes_computed == len(tiny_episodes)  # none reused from the whole context
    assert json.loads((out / "run.json").read_text())["context_steps"] == 2
    paths = [[r.path_length for r in result.records] for result in (whole, short)]
    assert paths[0] != paths[1]
    assert evaluate("navformer", tiny_episodes, out, context_steps=2, **kwargs).episodes_computed == 0
    with pytest.raises(ValueError, match=r"context_steps=3 \(--context-steps\) applies to navformer and dt"):
        evaluate("vrw", tiny_episodes, tmp_path / "vrw", context_steps=3, progress=False)
    with pytest.raises(
        ValueError,
        match=r"context_steps \(--context-steps\)=257: expected a whole number of timesteps from 1 to 256",
    ):
        evaluate("navformer", tiny_episodes, tmp_path / "long", context_steps=257, **kwargs)


def test_a_checkpoint_trained_on_short_windows_attends_to_them_unless_told_otherwise(
    tmp_path, tiny_episodes, checkpoints, checkpoint_factory
):
    """A checkpoint trained with ``data.context_steps=W`` evaluates on its last W steps by default (the same
    results as ``context_steps=W`` on the same weights, recorded in run.json); ``context_steps`` overrides it;
    the loaders and the shipped-weights path give the policy that window."""
    from navformer_rl.baselines.dt import load_dt_policy
    from navformer_rl.baselines.navformer import load_navformer_policy

    windowed = checkpoint_factory(tmp_path / "windowed", NavFormerConfig(), {"data": {"context_steps": 2}})
    assert training_context_steps(windowed) == 2 and training_context_steps(checkpoints["navformer"]) is None
    assert load_navformer_policy(windowed)[0].context_steps == 2
    assert load_navformer_policy(checkpoints["navformer"])[0].context_steps is None
    dt = checkpoint_factory(tmp_path / "dt", NavFormerConfig.dt_baseline(), {"data": {"context_steps": 3}})
    assert load_dt_policy(dt)[0].context_steps == 3
    kwargs = dict(maps_per_setup=0, videos_per_setup=0, progress=False)
    default = evaluate("navformer", tiny_episodes, tmp_path / "default", checkpoint=windowed, **kwargs)
    assert json.loads((tmp_path / "default" / "run.json").read_text())["context_steps"] == 2
    given = evaluate(
        "navformer",
        tiny_episodes,
        tmp_path / "given",
        checkpoint=checkpoints["navformer"],
        context_steps=2,
        **kwargs,
    )
    paths = [[r.path_length for r in result.records] for result in (default, given)]
    assert paths[0] == paths[1]  # the same weights (seeded) on the same window
    whole = evaluate(
        "navformer", tiny_episodes, tmp_path / "default", checkpoint=windowed, context_steps=256, **kwargs
    )
    assert whole.episodes_computed == len(tiny_episodes)  # another window: nothing reused
    assert json.loads((tmp_path / "default" / "run.json").read_text())["context_steps"] == 256
    assert [r.path_length for r in whole.records] != paths[0]
