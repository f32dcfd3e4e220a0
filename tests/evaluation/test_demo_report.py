"""The demo's stage times describe the computation that produced each stage's result, not the last rerun."""

import json
from pathlib import Path

import pytest

from navformer_rl.demo import DemoConfig, StageTimes
from navformer_rl.demo import pipeline as demo
from navformer_rl.demo.report import timings_markdown


@pytest.fixture
def clock(monkeypatch, fake_clock):
    fake = fake_clock
    monkeypatch.setattr(demo, "time", fake)
    return fake


def test_stage_times_keep_the_time_that_computed_a_result(tmp_path, clock):
    result = {"collect": None, "train": None}

    def stage(name, seconds, produces=None, fails=False):
        def work():
            clock.now += seconds
            if produces is not None:
                result[name] = produces
            if fails:
                raise KeyboardInterrupt
            return name

        return lambda: result[name], work

    times = StageTimes(tmp_path)
    assert times.run("collect", *stage("collect", 100.0, "data-1")) == "collect"
    assert times.seconds("collect") == 100.0
    # a rerun (a new process) that finds the result finished keeps the first time
    times = StageTimes(tmp_path)
    times.run("collect", *stage("collect", 1.5))
    assert times.seconds("collect") == 100.0 and times.this_invocation["collect"] == 1.5
    # an interrupted stage and the rerun that finishes it add up
    with pytest.raises(KeyboardInterrupt):
        StageTimes(tmp_path).run("train", *stage("train", 30.0, "iter_000010", fails=True))
    times = StageTimes(tmp_path)
    times.run("train", *stage("train", 50.0, "iter_000020"))
    assert times.seconds("train") == 80.0
    # a deleted result starts over instead of adding to the old time
    result["train"] = None
    times = StageTimes(tmp_path)
    times.run("train", *stage("train", 70.0, "iter_000020"))
    assert times.seconds("train") == 70.0
    saved = json.loads((tmp_path / "stage_times.json").read_text())
    assert saved == {
        "collect": {"seconds": 100.0, "result": "data-1"},
        "train": {"seconds": 70.0, "result": "iter_000020"},
    }
    # a finished result that no invocation timed (made before stage_times.json existed): unknown
    (tmp_path / "stage_times.json").unlink()
    times = StageTimes(tmp_path)
    times.run("collect", *stage("collect", 2.0))
    assert times.seconds("collect") is None


def test_a_rerun_of_the_demo_reports_the_first_runs_times(tmp_path, clock, monkeypatch):
    """run_demo with stand-in stages that do their work once (as the real ones resume) and take known time."""
    cfg = DemoConfig.preset("quick", out_dir=tmp_path, methods=("navformer", "vrw"))

    def collect_stage(cfg, progress=True):
        metadata = cfg.out_dir / "data" / "e" / "metadata.json"
        if not metadata.is_file():
            clock.now += 300.0
            metadata.parent.mkdir(parents=True)
            metadata.write_text('{"status": "complete"}')
        clock.now += 1.0  # checking what is there
        return {"e": metadata.parent}

    def train_stage(cfg, data, method, progress=True):
        run_dir = cfg.out_dir / "train" / method
        checkpoint = run_dir / "checkpoints" / "iter_000020"
        if not checkpoint.is_dir():
            clock.now += 600.0
            checkpoint.mkdir(parents=True)
            (checkpoint / "config.json").write_text("{}")
            (run_dir / "checkpoints" / "latest").write_text("iter_000020\n")
        clock.now += 2.0
        return run_dir

    def evaluate_stage(cfg, train_dirs, progress=True):
        folders = []
        for seconds, method in zip((40.0, 60.0), cfg.methods):
            folder = cfg.out_dir / "eval" / method
            if not folder.is_dir():
                clock.now += seconds
                folder.mkdir(parents=True)
                # what the harness writes: the time that computed its episodes, kept on reruns
                (folder / "run.json").write_text(json.dumps({"seconds": seconds}))
            clock.now += 0.5
            folders.append(folder)
        return folders

    reports = []
    monkeypatch.setattr(demo, "collect_stage", collect_stage)
    monkeypatch.setattr(demo, "train_stage", train_stage)
    monkeypatch.setattr(demo, "evaluate_stage", evaluate_stage)
    monkeypatch.setattr(
        "navformer_rl.demo.report.write_demo_report",
        lambda cfg, data, train_dirs, folders, timings: reports.append(timings) or cfg.out_dir / "report.md",
    )
    for _ in range(2):
        demo.run_demo(cfg, progress=False, log=lambda line: None)
    first, rerun = reports
    assert first == {"collect": (301.0, 301.0), "train navformer": (602.0, 602.0), "evaluate": (100.0, 101.0)}
    assert rerun == {"collect": (301.0, 1.0), "train navformer": (602.0, 2.0), "evaluate": (100.0, 1.0)}
    table = "\n".join(timings_markdown(rerun))
    assert "| stage | seconds computing the result | seconds in this invocation |" in table
    assert "| collect | 301 | 1 |" in table and "| evaluate | 100 | 1 |" in table
    assert "| train navformer | - | 2 |" in "\n".join(timings_markdown({"train navformer": (None, 2.0)}))


def test_the_evaluation_report_is_nested_under_the_demo_reports_heading(tmp_path, vrw_run):
    from navformer_rl.demo.report import nested_report
    from navformer_rl.evaluation.report import REPORT_MARKER, write_report

    text = write_report([vrw_run[0]], tmp_path / "evaluation.md", title="Evaluation").read_text()
    assert text.startswith(REPORT_MARKER + "\n# Evaluation\n")
    nested = nested_report(text)
    assert REPORT_MARKER not in nested and "# Evaluation" not in nested.splitlines()[:3]
    headings = [line for line in nested.splitlines() if line.startswith("#")]
    assert headings and all(line.startswith("### ") or line.startswith("#### ") for line in headings)


def test_time_spent_before_a_stage_had_any_result_is_kept(tmp_path, clock):
    """Training interrupted before its first checkpoint, then finished by a rerun: both times count."""
    state = {"result": None}

    def fingerprint():
        return state["result"]

    def interrupted():
        clock.now += 40.0
        raise KeyboardInterrupt

    def finishes():
        clock.now += 60.0
        state["result"] = "iter_000020"

    with pytest.raises(KeyboardInterrupt):
        StageTimes(tmp_path).run("train", fingerprint, interrupted)
    times = StageTimes(tmp_path)
    times.run("train", fingerprint, finishes)
    assert times.seconds("train") == 100.0


def test_a_failing_time_file_does_not_hide_the_stages_error(tmp_path, clock, monkeypatch):
    def fails():
        raise ValueError("the stage's own error")

    def no_disk(path, payload):
        raise OSError("disk full")

    monkeypatch.setattr(demo, "write_json", no_disk)
    with pytest.raises(ValueError, match="the stage's own error"):
        StageTimes(tmp_path).run("collect", lambda: None, fails)


def test_the_training_section_tables_the_last_validation_of_each_model(tmp_path):
    from navformer_rl.demo.report import _training_section

    logged = {
        "navformer": {"loss_dt_exploration": [(5, 0.5), (10, 0.4)], "train_loss_dt_exploration": [(10, 0.1)]},
        "dt": {},  # trained without held-out data: no row
    }
    train_dirs = {}
    for method, metrics in logged.items():
        scalars = tmp_path / method / "logs" / "navformer" / "scalars"
        (scalars / "validation").mkdir(parents=True)
        (scalars / "loss_dt.csv").write_text("1,1.0\n10,0.2\n")
        for name, rows in metrics.items():
            (scalars / "validation" / f"{name}.csv").write_text("".join(f"{s},{v}\n" for s, v in rows))
        train_dirs[method] = tmp_path / method
    text = "\n".join(_training_section(train_dirs, tmp_path))
    assert "| model | iteration | D_e, training data | D_e, held-out mazes | D_ca, training data |" in text
    assert "| navformer | 10 | 0.100 | 0.400 | - | - |" in text
    assert "| dt |" not in text
    assert (tmp_path / "figures" / "training_losses.png").is_file()
    # the study the table points to for the demo's plateau exists under that title
    studies = (Path(__file__).resolve().parents[2] / "docs" / "studies.md").read_text()
    title = "The encoders' optimiser at the demo's scale"
    assert f"'{title}'" in text.replace("\n", " ") and f"## {title}\n" in studies


def test_the_training_figure_gives_each_curve_one_colour_and_no_hidden_duplicate(tmp_path, monkeypatch):
    """A curve has the same colour in every model's panel; a run without BYOL (DT) draws no ``loss`` curve,
    which would lie exactly on its ``loss_dt``."""
    from matplotlib.axes import Axes

    from navformer_rl.demo.report import _training_section

    drawn: list[tuple[int, str, str]] = []
    plot = Axes.plot

    def recording_plot(ax, *args, **kwargs):
        drawn.append((id(ax), kwargs["label"], kwargs["color"]))
        return plot(ax, *args, **kwargs)

    monkeypatch.setattr(Axes, "plot", recording_plot)
    curves = {"navformer": ["loss_dt", "loss_byol", "loss"], "dt": ["loss_dt", "loss"]}
    train_dirs = {}
    for method, names in curves.items():
        scalars = tmp_path / method / "logs" / "navformer" / "scalars"
        (scalars / "validation").mkdir(parents=True)
        for name in [*names, "validation/loss_dt_exploration", "validation/loss_dt_collision_avoidance"]:
            (scalars / f"{name}.csv").write_text("1,1.0\n10,0.2\n")
        train_dirs[method] = tmp_path / method
    _training_section(train_dirs, tmp_path)
    panels = list(dict.fromkeys(ax for ax, _, _ in drawn))
    labels = [[label for ax, label, _ in drawn if ax == panel] for panel in panels]
    held_out = ["loss_dt, held-out D_e (eval mode)", "loss_dt, held-out D_ca (eval mode)"]
    assert labels == [["loss_dt", "loss_byol", "loss", *held_out], ["loss_dt", *held_out]]
    colours = {}
    for _, label, colour in drawn:
        assert colours.setdefault(label, colour) == colour, label
    assert len(set(colours.values())) == len(colours)  # and different curves differ


@pytest.mark.parametrize("value", [-1, 1.5, True])
def test_held_out_sizes_must_be_counts(tmp_path, value):
    with pytest.raises(ValueError, match=r"held_out_collision=.*expected an integer >= 0 \(0: none\)"):
        DemoConfig.preset("quick", out_dir=tmp_path, held_out_collision=value).validate()
    DemoConfig.preset("quick", out_dir=tmp_path, held_out_collision=0).validate()


def test_held_out_sets_come_from_other_mazes_and_validate_the_training(tmp_path, monkeypatch):
    """collect_stage adds held-out D_e / D_ca collected with another seed (none when their size is 0);
    train_stage scores them through validation.* every quarter of the run."""
    import navformer_rl.data.collect as collect_module
    import navformer_rl.training as training_module

    calls = []

    def fake_collect(kind, out, settings, workers, progress):
        calls.append((kind.value, out.name, settings.seed, getattr(settings, "n_trajectories", None)))
        return out

    monkeypatch.setattr(collect_module, "collect", fake_collect)
    cfg = DemoConfig.preset("quick", out_dir=tmp_path, seed=3)
    data = demo.collect_stage(cfg, progress=False)
    assert sorted(data) == ["ca", "e", "held_out_ca", "held_out_e", "ssl"]
    held = {name: (kind, seed, n) for kind, name, seed, n in calls if name.startswith("held_out_")}
    assert held == {"held_out_e": ("e", 1003, 2), "held_out_ca": ("ca", 1003, 4)}
    assert {seed for _, name, seed, _ in calls if not name.startswith("held_out_")} == {3}

    configs = []
    monkeypatch.setattr(
        training_module, "train", lambda cfg: configs.append(cfg) or type("R", (), {"run_dir": None})
    )
    demo.train_stage(cfg, data, "navformer", progress=False)
    validation = configs[-1].validation
    assert (
        validation.exploration_path == str(data["held_out_e"]) and validation.interval == cfg.iterations // 4
    )
    assert validation.collision_path == str(data["held_out_ca"])

    calls.clear()
    without = DemoConfig.preset("quick", out_dir=tmp_path, held_out_exploration=0, held_out_collision=0)
    data = demo.collect_stage(without, progress=False)
    assert sorted(data) == ["ca", "e", "ssl"] and len(calls) == 3
    demo.train_stage(without, data, "dt", progress=False)
    assert configs[-1].validation.exploration_path is None and not configs[-1].validation.enabled


@pytest.mark.parametrize("native", [True, False])
def test_the_demo_trains_in_bf16_only_where_the_cpu_has_it(tmp_path, monkeypatch, native):
    """bf16 autocast where the hardware computes it; fp32 on a CPU that would emulate bf16 (several times
    slower there, docs/training.md)."""
    import navformer_rl.training as training_module
    from navformer_rl.utils import devices

    monkeypatch.setattr(devices, "cpu_has_native_bfloat16", lambda: native)
    configs = []
    monkeypatch.setattr(
        training_module, "train", lambda cfg: configs.append(cfg) or type("R", (), {"run_dir": None})
    )
    cfg = DemoConfig.preset("quick", out_dir=tmp_path)
    data = {"e": tmp_path / "e", "ca": tmp_path / "ca", "ssl": tmp_path / "ssl"}
    demo.train_stage(cfg, data, "navformer", progress=False)
    on_gpu = devices.resolve_device("auto").type == "cuda"
    expected = "bfloat16" if native or on_gpu else None
    assert configs[-1].model.get("autocast_dtype") == expected


def test_the_demo_ends_with_a_table_of_its_stage_times(tmp_path, clock, monkeypatch):
    cfg = DemoConfig.preset("quick", out_dir=tmp_path, methods=("navformer", "vrw"))

    def takes(seconds, value):
        def stage(*args, **kwargs):
            clock.now += seconds
            return value

        return stage

    monkeypatch.setattr(demo, "collect_stage", takes(61.0, {}))
    monkeypatch.setattr(demo, "train_stage", takes(600.0, tmp_path / "train" / "navformer"))
    monkeypatch.setattr(demo, "evaluate_stage", takes(30.0, []))
    monkeypatch.setattr(
        "navformer_rl.demo.report.write_demo_report",
        lambda *args: takes(4.0, tmp_path / "report.md")(),
    )
    printed = []
    demo.run_demo(cfg, progress=False, log=printed.append)
    assert printed[-1].splitlines() == [
        "stage            this run  computing the result",
        "collect              1:01                  1:01",
        "train navformer     10:00                 10:00",
        "evaluate             0:30                  0:00",  # no evaluation folder recorded a time
        "report               0:04                     -",
        "total               11:35",
    ]


def test_stage_times_read_as_minutes_and_seconds():
    table = demo.stage_time_table({"collect": (4000.0, 0.4), "evaluate": (None, 59.6)})
    assert table.splitlines()[1:] == [
        "collect       0:00               1:06:40",
        "evaluate      1:00                     -",
        "total         1:00",
    ]


def _trial(robot, **fields):
    row = {
        "episode_id": "smoke/7.5m-2r/w000/t001",
        "size": 7.5,
        "n_robots": 2,
        "robot": robot,
        "measured": True,
        "success": False,
        "success_step": None,
        "steps": 500,
        "collisions": 0,
        "final_distance": 3.21,
    }
    return {**row, **fields}


def test_the_video_captions_say_what_happens_from_the_episode_records(tmp_path):
    from navformer_rl.demo.report import robot_outcome, video_captions

    folder = tmp_path / "eval" / "navformer"
    folder.mkdir(parents=True)
    video = "videos/smoke_7.5m-2r_w000_t001.mp4"
    (folder / "run.json").write_text(json.dumps({"label": "navformer", "files": {"videos": [video]}}))
    rows = [
        _trial(1, collisions=400),
        _trial(0, success=True, success_step=123, steps=123, collisions=2, final_distance=1.2),
        {**_trial(0), "episode_id": "smoke/7.5m-2r/w000/t002"},  # another episode, without a video
    ]
    (folder / "episodes.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    lines = video_captions([folder], tmp_path)
    assert lines[0] == "### What the videos show\n"
    assert lines[2] == (
        f"- [navformer, episode smoke/7.5m-2r/w000/t001](eval/navformer/{video}) (7.5 m maze, 2 robots): "
        "robot 0 reaches its target at step 123 (in contact on 2 of its steps); robot 1 does not reach its "
        "target in 500 steps: it ends 3.2 m from it, in contact on 400 of its 500 steps."
    )
    assert len(lines) == 4  # one video, one caption
    obstacle = _trial(1, measured=False, steps=80, collisions=0)
    assert (
        robot_outcome(obstacle) == "robot 1 is a scripted moving obstacle (in contact on 0 of its 80 steps)"
    )


def test_the_video_captions_of_a_real_evaluation_name_its_method_and_robots(tmp_path, vrw_run):
    from navformer_rl.demo.report import video_captions

    folder, result = vrw_run
    lines = video_captions([folder], folder.parent)
    videos = result.files["videos"]
    assert videos and len(lines) == 3 + len(videos)
    assert all(line.startswith("- [vrw, episode ") for line in lines[2 : 2 + len(videos)])
    assert "robot 0 " in lines[2]


def test_the_report_describes_shipped_weights_from_their_checkpoint(tmp_path, monkeypatch):
    from navformer_rl.demo.report import _shipped_note
    from navformer_rl.training.checkpoint import read_checkpoint_config
    from navformer_rl.training.pretrained_registry import PRETRAINED_DIR_ENV

    monkeypatch.delenv(PRETRAINED_DIR_ENV, raising=False)
    assert _shipped_note([tmp_path / "navformer", tmp_path / "vrw"]) == []
    (note,) = _shipped_note([tmp_path / "navformer", tmp_path / "pretrained_navformer"])
    iterations = read_checkpoint_config("pretrained:navformer")["iteration"]
    assert note.startswith(
        f"`pretrained:navformer` ({iterations:,} training iterations): the shipped weights"
    )
    assert "MODEL_CARD.md" in note and "paper's scale" not in note
