"""`navformer evaluate` (make-episodes, run, report) and the markdown report."""

import argparse
import csv
import hashlib
import json
import shutil
from pathlib import Path

import pytest

from navformer_rl.evaluation.cli import register
from navformer_rl.evaluation.episodes import load_episode_set
from navformer_rl.evaluation.harness import evaluate
from navformer_rl.evaluation.report import paper_table1_markdown, write_report


def _run(argv):
    parser = argparse.ArgumentParser(prog="navformer")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.run(args)


def test_make_episodes_then_evaluate_then_report(tmp_path, capsys):
    episodes = tmp_path / "smoke.json"
    common = ["--protocol", "smoke", "--trials-per-setup", "2", "--trials-per-world", "2", "--max-steps", "6"]
    assert _run(["evaluate", "make-episodes", "--out", str(episodes), *common]) == 0
    episode_set = load_episode_set(episodes)
    assert len(episode_set) == 2 and episode_set.max_steps == 6 and episode_set.setups == ["7.5m-2r"]

    out = tmp_path / "vrw"
    argv = ["evaluate", "--method", "vrw", "--episodes", str(episodes), "--out", str(out), "--videos", "0"]
    assert _run([*argv, "--maps", "1", "--cluster-by", "world", "--no-progress"]) == 0
    assert "| 7.5m-2r | 7.5 × 7.5 | 2 |" in capsys.readouterr().out
    assert (out / "maps" / "7.5m-2r_w00t00.png").is_file()
    # intervals over mazes: one maze holds both trials, too few for SPL / CR intervals
    (row,) = csv.DictReader((out / "summary.csv").open())
    assert (row["cluster"], row["n_worlds"], row["n_trials"], row["spl_low"]) == ("world", "1", "2", "")
    assert json.loads((out / "run.json").read_text())["cluster"] == "world"
    assert "fewer than 6 mazes (worlds)" in (out / "summary.md").read_text()

    report = tmp_path / "report" / "README.md"
    assert _run(["evaluate", "report", str(out), "--out", str(report)]) == 0
    text = report.read_text()
    assert "vrw SR" in text and (tmp_path / "report" / "README_metrics.png").is_file()
    # the report follows the folders' own intervals (run.json), unless told otherwise, and then says so
    assert "Intervals: Wilson on the world-clustered" in text and "Note:" not in text
    assert _run(["evaluate", "report", str(out), "--out", str(report), "--cluster-by", "trial"]) == 0
    text = report.read_text()
    assert "Intervals: Wilson on the trial-clustered" in text
    assert f"Note: {out} was evaluated with 95 % intervals over mazes (its own `summary.md`)" in text
    with pytest.raises(SystemExit):
        _run(["evaluate", "report", str(out), "--out", str(report), "--cluster-by", "maze"])
    assert "../vrw/maps/7.5m-2r_w00t00.png" in text
    # generation options with an episode file would be ignored: refused instead
    with pytest.raises(ValueError, match="--max-steps: only with --protocol"):
        _run([*argv, "--max-steps", "50", "--no-progress"])


def test_negative_seeds_are_refused_by_every_command(capsys):
    from navformer_rl import cli

    for argv in (["demo", "--seed", "-1"], ["collect", "e", "--out", "x", "--seed", "-1"],
                 ["evaluate", "make-episodes", "--protocol", "smoke", "--out", "x",
                  "--episode-seed", "-1"]):  # fmt: skip
        with pytest.raises(SystemExit) as exit_info:
            cli.main(argv)
        assert exit_info.value.code == 2
        assert "seed must be a non-negative integer, got -1" in capsys.readouterr().err


def test_cli_errors(tmp_path, capsys):
    for argv in (
        ["evaluate", "--method", "random", "--protocol", "smoke", "--out", str(tmp_path)],
        ["evaluate", "make-episodes", "--protocol", "table9", "--out", str(tmp_path / "x.json")],
    ):
        with pytest.raises(SystemExit):
            _run(argv)
    err = capsys.readouterr().err
    assert (
        "argument --method: invalid choice: 'random' (choose from 'navformer', 'dt', 'vrw', "
        "'fca', 'dsac', 'matdn', 'frontier')" in err
    )
    assert "argument --protocol: invalid choice: 'table9'" in err
    with pytest.raises(ValueError, match="--episodes FILE or --protocol"):
        _run(["evaluate", "--method", "vrw", "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="--setups: only with --protocol"):
        _run(
            [
                "evaluate",
                "--method",
                "vrw",
                "--episodes",
                "x.json",
                "--setups",
                "7.5m-2r",
                "--out",
                str(tmp_path),
            ]
        )
    with pytest.raises(ValueError, match=r"device \(--device\)='tpu': expected one of"):
        _run(
            ["evaluate", "--method", "vrw", "--protocol", "smoke", "--device", "tpu", "--out", str(tmp_path)]
        )
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "navformer_rl.dataset", "version": 1}))
    with pytest.raises(ValueError, match="not an episode-set file"):
        _run(["evaluate", "--method", "vrw", "--episodes", str(bad), "--out", str(tmp_path / "o")])
    # output files: a folder is refused; an existing file is replaced only by the same episodes
    make = ["evaluate", "make-episodes", "--protocol", "smoke", "--trials-per-setup", "2", "--max-steps", "5"]
    with pytest.raises(ValueError, match="is a folder; expected the path of a file"):
        _run([*make, "--out", str(tmp_path)])
    with pytest.raises(FileExistsError, match="holds something else"):
        _run([*make, "--out", str(bad)])
    assert json.loads(bad.read_text())["format"] == "navformer_rl.dataset"  # untouched
    episodes = tmp_path / "smoke.json"
    assert _run([*make, "--out", str(episodes)]) == 0 and _run([*make, "--out", str(episodes)]) == 0
    with pytest.raises(ValueError, match="is a folder"):
        _run(["evaluate", "report", str(tmp_path / "o"), "--out", str(tmp_path)])


def test_report_puts_paper_numbers_beside_ours(tmp_path, tiny_episodes, vrw_run):
    a = vrw_run[1]
    b = evaluate(
        "vrw", tiny_episodes, tmp_path / "vrw2", label="vrw-seed1", seed=1,
        maps_per_setup=0, videos_per_setup=0, progress=False,
    )  # fmt: skip
    path = write_report([a.out_dir, b.out_dir], tmp_path / "report.md", title="tiny")
    text = path.read_text()
    # Our two methods side by side, the paper's VRW value for 7.5 m / 2 robots, and the caveat.
    assert "| Setup | Env size (m) | # of robots | vrw SR | vrw SPL | vrw CR | vrw-seed1 SR |" in text
    assert "/ 39.17%" in text and "not directly comparable" in text and "Gazebo" in text
    assert "| Setup | vrw SPL-disc | vrw-seed1 SPL-disc |" in text
    assert paper_table1_markdown() in text
    with pytest.raises(ValueError, match="both hold results labelled 'vrw'.*another --label"):
        write_report([a.out_dir, a.out_dir], tmp_path / "dup.md")
    with pytest.raises(FileNotFoundError, match="not an evaluation folder"):
        write_report([tmp_path], tmp_path / "none.md")


def test_report_warns_only_when_the_episodes_of_a_setup_differ(tmp_path, tiny_episodes, vrw_run):
    """The same episodes under another set name (Table I's 12.5 m / 4-robot episodes are Table IV's) are
    paired; other episodes of the same setup are not, and the warning names that setup."""
    import dataclasses

    from navformer_rl.evaluation.episodes import make_episode_set

    from .conftest import TINY_SETUP

    kwargs = dict(maps_per_setup=0, videos_per_setup=0, progress=False, seed=3)
    renamed = dataclasses.replace(tiny_episodes, name="renamed", generation={"protocol": "other"})
    assert renamed.content_hash() != tiny_episodes.content_hash()
    same = evaluate("vrw", renamed, tmp_path / "same", label="vrw-renamed", **kwargs)
    text = write_report([vrw_run[0], same.out_dir], tmp_path / "paired.md").read_text()
    assert "Warning" not in text
    other_set = make_episode_set([TINY_SETUP], trials_per_setup=2, trials_per_world=2, seed=2, max_steps=12)
    other = evaluate("vrw", other_set, tmp_path / "other", label="vrw-other", **kwargs)
    text = write_report([vrw_run[0], other.out_dir], tmp_path / "unpaired.md").read_text()
    assert "**Warning: the methods ran on different episodes** in 7.5m-2r" in text
    shorter = dataclasses.replace(tiny_episodes, max_steps=4)  # same episodes, shorter trials
    short = evaluate("vrw", shorter, tmp_path / "short", label="vrw-short", **kwargs)
    text = write_report([vrw_run[0], short.out_dir], tmp_path / "short.md").read_text()
    assert "**Warning: the methods ran on different episodes** in 7.5m-2r" in text


def test_report_never_replaces_other_files(tmp_path, vrw_run):
    out_dir = Path(shutil.copytree(vrw_run[0], tmp_path / "vrw"))  # the fixture's folder stays as it is
    own_plot = (out_dir / "metrics.png").read_bytes()
    # a report inside the evaluation folder keeps that folder's own plot
    inside = write_report([out_dir], out_dir / "report.md")
    assert (out_dir / "metrics.png").read_bytes() == own_plot and (out_dir / "report_metrics.png").is_file()
    assert write_report([out_dir], inside) == inside  # an earlier report is replaced
    notes = tmp_path / "notes.md"
    notes.write_text("# my notes\n")
    with pytest.raises(FileExistsError, match="not a report written by navformer_rl"):
        write_report([out_dir], notes)
    assert notes.read_text() == "# my notes\n"
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "run.json").write_text("{truncated")
    with pytest.raises(ValueError, match="run.json is not valid JSON"):
        write_report([broken], tmp_path / "r.md")


def test_ablation_labels_are_compared_with_their_table4_row():
    import dataclasses

    from navformer_rl.evaluation.measures import RobotTrial
    from navformer_rl.evaluation.report import paper_comparison_markdown
    from navformer_rl.evaluation.tables import summarize_by_setup

    base = RobotTrial(
        method="", episode_id="", setup="", size=0.0, n_robots=0, world_seed=0, trial=0, robot=0,
        robot_style="jackal", measured=True, success=True, success_step=10, steps=10, collisions=0,
        path_length=5.0, shortest_path=4.0, shortest_path_to_disc=3.0, final_distance=0.5,
    )  # fmt: skip
    records = [
        dataclasses.replace(
            base, method=method, episode_id=f"{setup}-{i}", setup=setup, size=size, n_robots=n
        )
        for method in ("navformer-no_thsc", "navformer-seed1")
        for setup, size, n in (("12.5m-4r", 12.5, 4), ("7.5m-2r", 7.5, 2), ("12.5m-4r-unseen", 12.5, 4))
        for i in range(2)
    ]
    table = paper_comparison_markdown(summarize_by_setup(records), ["navformer-no_thsc", "navformer-seed1"])
    header, _, *rows = table.strip().splitlines()
    by_setup = {row.split(" | ")[0].strip("| "): row for row in rows}
    assert "navformer-no_thsc SR (ours / paper NavFormer w/o THSC)" in header
    assert "navformer-seed1 SR (ours / paper NavFormer)" in header
    # Table IV (12.5 m, 4 robots): w/o THSC is 32.08 % / 0.261 / 0.500
    assert by_setup["12.5m-4r"].startswith("| 12.5m-4r | 100.00% / 32.08% | 0.800 / 0.261 | 0.000 / 0.500 |")
    # Table IV has no 7.5 m row: no paper value for the ablation there, Table I's for the full model
    assert by_setup["7.5m-2r"] == "| 7.5m-2r | - | - | - | 100.00% / 80.83% | 0.800 / 0.562 | 0.000 / 0.228 |"
    # Table IV measured four Jackals: not the unseen-obstacle setup (one Jackal, three TurtleBot3s), which
    # has Table III's full-model row only
    assert by_setup["12.5m-4r-unseen"].startswith("| 12.5m-4r-unseen | - | - | - | 100.00% / ")


def test_cli_refuses_a_label_naming_another_ablation_before_generating_episodes(
    tmp_path, checkpoint_factory, monkeypatch
):
    from navformer_rl.evaluation import episodes
    from navformer_rl.modules import NavFormerConfig

    full = checkpoint_factory(tmp_path / "full", NavFormerConfig(), {"ablation": "none"})

    def no_generation(*args, **kwargs):
        raise AssertionError("episodes generated before the label was checked")

    monkeypatch.setattr(episodes, "make_protocol_episodes", no_generation)
    argv = ["evaluate", "--method", "navformer", "--checkpoint", str(full), "--protocol", "table1"]
    with pytest.raises(
        ValueError, match=r"'navformer-no_thsc' names the training ablation 'no_thsc'.*ablation=none"
    ):
        _run([*argv, "--label", "navformer-no_thsc", "--out", str(tmp_path / "out")])
    assert not (tmp_path / "out").exists()


def _relabel(source: Path, target: Path, label: str, **run_changes) -> Path:
    """A copy of an evaluation folder as an earlier version wrote it under another label (no `ablation`
    and no timing beyond `seconds` in run.json)."""
    shutil.copytree(source, target)
    run = json.loads((target / "run.json").read_text())
    for key in ("ablation", "invocation_seconds", "episode_seconds", "episodes_computed", "episodes_reused"):
        run.pop(key, None)
    run.update(label=label, **run_changes)
    (target / "run.json").write_text(json.dumps(run))
    rows = [json.loads(line) for line in (target / "episodes.jsonl").read_text().splitlines()]
    (target / "episodes.jsonl").write_text("".join(json.dumps({**r, "method": label}) + "\n" for r in rows))
    return target


def test_report_warns_about_older_runs_whose_label_names_another_ablation(
    tmp_path, tiny_episodes, checkpoints, checkpoint_factory
):
    from navformer_rl.modules import NavFormerConfig

    kwargs = dict(maps_per_setup=0, videos_per_setup=0, progress=False)
    run = evaluate("navformer", tiny_episodes, tmp_path / "nf", checkpoint=checkpoints["navformer"], **kwargs)
    # The fixture's checkpoint records no training ablation, but its model has THSC: not w/o THSC.
    old = _relabel(run.out_dir, tmp_path / "old", "navformer-no_thsc")
    text = write_report([old], tmp_path / "report.md").read_text()
    assert f"**Warning: {old}**: the label 'navformer-no_thsc' names the training ablation 'no_thsc'" in text
    assert "its rows are not compared with the paper." in text
    assert "navformer-no_thsc SR (ours / paper" not in text
    assert "| navformer-no_thsc |" in text and "†" in text  # the older run.json's seconds are marked
    # The same weights, now in a checkpoint that records ablation=none: compared with the full model's row.
    full = checkpoint_factory(tmp_path / "full", NavFormerConfig(), {"ablation": "none"})
    sha256 = hashlib.sha256(next(full.rglob("model.safetensors")).read_bytes()).hexdigest()
    old2 = _relabel(
        run.out_dir, tmp_path / "old2", "navformer-no_thsc", checkpoint=str(full), checkpoint_sha256=sha256
    )
    text = write_report([old2], tmp_path / "report.md").read_text()
    assert "but checkpoint" in text and "was trained with ablation=none" in text
    assert "compared with the paper's NavFormer instead." in text
    assert "navformer-no_thsc SR (ours / paper NavFormer)" in text and "/ 80.83%" in text
    # ... but only while the checkpoint at the recorded path has the weights that were evaluated
    (full / "checkpoints" / "iter_000001" / "model.safetensors").write_bytes(b"other weights")
    assert "its rows are not compared with the paper." in write_report([old2], tmp_path / "r.md").read_text()
    # A run of this version is not warned about; its checkpoint's ablation is listed.
    text = write_report([run.out_dir], tmp_path / "report.md").read_text()
    assert "Warning" not in text and "navformer SR (ours / paper NavFormer)" in text and "†" not in text


def test_the_recorded_ablation_decides_the_paper_column():
    from navformer_rl.evaluation.report import _paper_column
    from navformer_rl.tasks import label_ablation

    assert _paper_column("navformer", "no_thsc") == "NavFormer w/o THSC"
    assert _paper_column("navformer-seed1", "none") == "NavFormer"
    assert _paper_column("dt", "dt") == "DT" and _paper_column("vrw") == "VRW"
    assert _paper_column("navformer_resnet18") == "NavFormer w ResNet18"
    labels = (
        "navformer-no_de",
        "navformer-seed1",
        "dt-no_thsc",
        "vrw",
        "navformer-no_fs-seed1",
        "navformer-byol_w0.1",
    )
    assert [label_ablation(x) for x in labels] == ["no_de", None, None, None, "no_fs", None]
    # words, not substrings: a label that merely contains an ablation's name names none
    assert label_ablation("navformer-no_fsx") is None and label_ablation("navformer-dt") is None


def _records(methods_and_setups):
    import dataclasses

    from navformer_rl.evaluation.measures import RobotTrial

    base = RobotTrial(
        method="", episode_id="", setup="", size=0.0, n_robots=0, world_seed=0, trial=0, robot=0,
        robot_style="jackal", measured=True, success=True, success_step=10, steps=10, collisions=0,
        path_length=5.0, shortest_path=4.0, shortest_path_to_disc=3.0, final_distance=0.5,
    )  # fmt: skip
    return [
        dataclasses.replace(
            base, method=method, episode_id=f"{setup}-{i}", setup=setup, size=size, n_robots=n
        )
        for method, setups in methods_and_setups.items()
        for setup, size, n in setups
        for i in range(2)
    ]


def test_every_table_and_the_plot_order_setups_alike(tmp_path, monkeypatch):
    import matplotlib.axes

    from navformer_rl.evaluation.plots import plot_setup_bars
    from navformer_rl.evaluation.report import paper_comparison_markdown, spl_disc_markdown
    from navformer_rl.evaluation.tables import summarize_by_setup, table_markdown

    table3 = [("12.5m-4r-seen", 12.5, 4), ("12.5m-4r-unseen", 12.5, 4)]
    summaries = summarize_by_setup(_records({"fca": table3, "vrw": [("7.5m-2r", 7.5, 2)]}))
    expected = ["7.5m-2r", "12.5m-4r-seen", "12.5m-4r-unseen", "all"]

    def setups(table):
        return [row.split(" | ")[0].strip("| ") for row in table.strip().splitlines()[2:]]

    assert setups(table_markdown(summaries, ["fca", "vrw"])) == expected
    assert setups(spl_disc_markdown(summaries, ["fca", "vrw"])) == expected
    assert setups(paper_comparison_markdown(summaries, ["fca", "vrw"])) == expected[:-1]
    ticks = []
    original = matplotlib.axes.Axes.set_xticks
    monkeypatch.setattr(
        matplotlib.axes.Axes,
        "set_xticks",
        lambda self, positions, labels=None, **kw: (
            ticks.append(list(labels)) or original(self, positions, labels, **kw)
        ),
    )
    plot_setup_bars(summaries, tmp_path / "plot.png", methods=["fca", "vrw"])
    assert ticks == [expected[:-1]]


def test_the_pooled_row_exists_only_with_more_than_one_setup(vrw_run):
    import csv

    from navformer_rl.evaluation.tables import summarize_by_setup

    out, _ = vrw_run  # one setup: its row only (an `all` row would repeat it)
    assert [r["setup"] for r in csv.DictReader((out / "summary.csv").open())] == ["7.5m-2r"]
    two = summarize_by_setup(_records({"vrw": [("7.5m-2r", 7.5, 2), ("12.5m-4r", 12.5, 4)]}))
    assert [s.setup for s in two] == ["7.5m-2r", "12.5m-4r", "all"]


def test_report_names_folders_whose_videos_are_not_h264(tmp_path, vrw_run):
    import cv2
    import numpy as np

    out_dir = Path(shutil.copytree(vrw_run[0], tmp_path / "vrw"))
    text = write_report([out_dir], tmp_path / "report.md").read_text()
    assert "Videos are H.264" in text and "Not H.264" not in text
    # an episode reused from a version that wrote OpenCV's mp4v
    video = out_dir / json.loads((out_dir / "run.json").read_text())["files"]["videos"][0]
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 5, (32, 32))
    writer.write(np.zeros((32, 32, 3), dtype=np.uint8))
    writer.release()
    text = write_report([out_dir], tmp_path / "report.md").read_text()
    assert "Not H.264: the videos of vrw (mpeg4)" in text


def test_table2_worlds_are_compared_with_the_papers_single_table2_row():
    import dataclasses

    from navformer_rl.evaluation.measures import RobotTrial
    from navformer_rl.evaluation.report import paper_comparison_markdown
    from navformer_rl.evaluation.tables import summarize_by_setup

    base = RobotTrial(
        method="fca", episode_id="", setup="", size=0.0, n_robots=3, world_seed=0, trial=0, robot=0,
        robot_style="jackal", measured=True, success=True, success_step=10, steps=10, collisions=0,
        path_length=5.0, shortest_path=4.0, shortest_path_to_disc=3.0, final_distance=0.5,
    )  # fmt: skip
    records = [
        dataclasses.replace(base, episode_id=f"{kind}-{i}", setup=kind, size=size)
        for kind, size in (("bookstore", 15.6), ("cafe", 23.1), ("house", 19.0))
        for i in range(2)
    ]
    header, _, *rows = paper_comparison_markdown(summarize_by_setup(records), ["fca"]).strip().splitlines()
    by_setup = {row.split(" | ")[0].strip("| "): row for row in rows}
    assert list(by_setup) == ["bookstore", "house", "cafe", "all"]  # by world size
    assert by_setup["bookstore"] == "| bookstore | - | - | - |"  # the paper gives one row for the three
    # Table II, FCA: 82.22 % / 0.612 / 0.092
    assert by_setup["all"] == "| all | 100.00% / 82.22% | 0.800 / 0.612 | 0.000 / 0.092 |"
    # our table gives each world's footprint, not a square of its longer side
    from navformer_rl.evaluation.tables import table_markdown

    sizes = {
        row.split(" | ")[0].strip("| "): row.split(" | ")[1]
        for row in table_markdown(summarize_by_setup(records)).splitlines()[2:]
    }
    assert sizes == {"bookstore": "14.3 × 15.6", "house": "19 × 11", "cafe": "9.3 × 23.1", "all": "all"}
