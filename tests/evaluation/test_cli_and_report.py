"""`navformer evaluate` (make-episodes, run, report) and the markdown report."""

import argparse
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
    assert _run([*argv, "--maps", "1", "--no-progress"]) == 0
    assert "| 7.5m-2r | 7.5 × 7.5 | 2 |" in capsys.readouterr().out
    assert (out / "maps" / "7.5m-2r_w00t00.png").is_file()

    report = tmp_path / "report" / "README.md"
    assert _run(["evaluate", "report", str(out), "--out", str(report)]) == 0
    text = report.read_text()
    assert "vrw SR" in text and (tmp_path / "report" / "README_metrics.png").is_file()
    assert "../vrw/maps/7.5m-2r_w00t00.png" in text
    # generation options with an episode file would be ignored: refused instead
    with pytest.raises(ValueError, match="--max-steps: only with --protocol"):
        _run([*argv, "--max-steps", "50", "--no-progress"])


def test_negative_seeds_are_refused_by_every_command(capsys):
    from navformer_rl import cli

    for argv in (["demo", "--seed", "-1"], ["collect", "e", "--out", "x", "--seed", "-1"],
                 ["evaluate", "make-episodes", "--protocol", "smoke", "--out", "x", "--episode-seed", "-1"]):  # fmt: skip
        with pytest.raises(SystemExit) as exit_info:
            cli.main(argv)
        assert exit_info.value.code == 2
        assert "expected a non-negative integer seed, got -1" in capsys.readouterr().err


def test_cli_errors(tmp_path):
    with pytest.raises(ValueError, match="expected one of navformer, dt, vrw, fca"):
        _run(["evaluate", "--method", "random", "--protocol", "smoke", "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="--episodes FILE or --protocol"):
        _run(["evaluate", "--method", "vrw", "--out", str(tmp_path)])
    with pytest.raises(ValueError, match="unknown protocol"):
        _run(["evaluate", "make-episodes", "--protocol", "table2", "--out", str(tmp_path / "x.json")])
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
    with pytest.raises(ValueError, match="same method label"):
        write_report([a.out_dir, a.out_dir], tmp_path / "dup.md")
    with pytest.raises(FileNotFoundError, match="not an evaluation folder"):
        write_report([tmp_path], tmp_path / "none.md")


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
        for setup, size, n in (("12.5m-4r", 12.5, 4), ("7.5m-2r", 7.5, 2))
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
