"""``paired_robot_trial_shares``: two diagnoses' yes/no robot-trial measures paired, with known answers and
one-line errors for folders that do not pair."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from navformer_rl.evaluation.diagnose.paired import paired_robot_trial_shares

RECORDS = (
    Path(__file__).resolve().parents[2] / "docs" / "results" / "paper10k" / "diagnosis" / "table1_2r_large"
)


def write_diagnosis(folder: Path, rows: list[dict], content_sha256: str = "a" * 64) -> Path:
    """A diagnosis folder with the committed record's ``diagnosis.json`` (its episode-set hash replaced)
    and ``rows`` as ``robot_trials.jsonl``."""
    folder.mkdir(parents=True)
    summary = json.loads((RECORDS / "dt_10k_s0" / "diagnosis.json").read_text())
    summary["episode_set"]["content_sha256"] = content_sha256
    (folder / "diagnosis.json").write_text(json.dumps(summary))
    (folder / "robot_trials.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    return folder


def row(episode: str, robot: int, outcome: str, sighting: int | None, setup: str = "7.5m-2r") -> dict:
    return {
        "episode_id": episode,
        "robot": robot,
        "outcome": outcome,
        "first_sighting_step": sighting,
        "setup": setup,
    }


def test_shares_and_differences_are_the_robot_trial_means(tmp_path):
    a_rows = [
        row(f"e{i}", r, "success" if r == 0 else "stuck", 5 if r == 0 else None)
        for i in range(8)
        for r in (0, 1)
    ]
    b_rows = [row(f"e{i}", r, "stuck", None) for i in range(8) for r in (0, 1)]
    a, b = write_diagnosis(tmp_path / "a", a_rows), write_diagnosis(tmp_path / "b", b_rows)
    shares = paired_robot_trial_shares(a, b, n_resamples=500)
    assert set(shares) == {"success", "stuck", "sighted"}
    assert (shares["success"].a, shares["success"].b, shares["success"].difference) == (0.5, 0.0, 0.5)
    assert shares["stuck"].difference == -0.5 and shares["sighted"].difference == 0.5
    # every trial holds one success and one stuck robot: every resample gives the same mean
    assert shares["success"].interval == pytest.approx((0.5, 0.5))
    assert shares["success"].excludes_zero() and shares["success"].n_trials == 8
    assert shares["success"].n_robot_trials == 16
    swapped = paired_robot_trial_shares(b, a, n_resamples=500)
    assert swapped["sighted"].difference == -0.5


def test_the_committed_diagnoses_pair_and_a_setup_filter_keeps_its_trials():
    folders = RECORDS / "navformer_10k_s0", RECORDS / "dt_10k_s0"
    every = paired_robot_trial_shares(*folders, n_resamples=200)
    one = paired_robot_trial_shares(*folders, setups=("12.5m-2r",), n_resamples=200)
    assert every["success"].n_robot_trials == 240 and one["success"].n_robot_trials == 120
    summary = json.loads((folders[0] / "diagnosis.json").read_text())
    assert one["success"].a == pytest.approx(summary["by_setup"]["12.5m-2r"]["success_rate"])


def test_folders_that_do_not_pair_are_refused_in_one_line(tmp_path):
    rows = [row(f"e{i}", 0, "success", 1) for i in range(6)]
    a = write_diagnosis(tmp_path / "a", rows)
    other_set = write_diagnosis(tmp_path / "other_set", rows, content_sha256="b" * 64)
    with pytest.raises(ValueError, match="diagnosed different episode sets"):
        paired_robot_trial_shares(a, other_set)
    fewer = write_diagnosis(tmp_path / "fewer", rows[:-1])
    with pytest.raises(ValueError, match="robot 0 of episode 'e5' is measured in only one of"):
        paired_robot_trial_shares(a, fewer)
    with pytest.raises(ValueError, match=r"setups=\('17.5m-6r',\): no robot-trial"):
        paired_robot_trial_shares(a, a, setups=("17.5m-6r",))
    no_rows = tmp_path / "no_rows"
    shutil.copytree(a, no_rows)
    (no_rows / "robot_trials.jsonl").unlink()
    with pytest.raises(FileNotFoundError, match="no robot_trials.jsonl"):
        paired_robot_trial_shares(a, no_rows)


def test_the_diagnose_pair_command_prints_the_paired_table(tmp_path, capsys):
    import argparse

    from navformer_rl.evaluation.cli import register

    parser = argparse.ArgumentParser(prog="navformer")
    register(parser.add_subparsers(dest="command", required=True))
    out = tmp_path / "pair.md"
    argv = [
        "evaluate",
        "diagnose-pair",
        str(RECORDS / "navformer_10k_s0"),
        str(RECORDS / "dt_10k_s1"),
        "--setups",
        "12.5m-2r",
    ]
    args = parser.parse_args([*argv, "--out", str(out)])
    assert args.run(args) == 0
    printed = capsys.readouterr().out
    assert printed == out.read_text()
    lines = printed.splitlines()
    assert lines[0] == (
        "| robot-trials (120 in 60 trials) | navformer_10k_s0 | dt_10k_s1 | "
        "navformer_10k_s0 - dt_10k_s1 (points) |"
    )
    shares = paired_robot_trial_shares(
        RECORDS / "navformer_10k_s0", RECORDS / "dt_10k_s1", setups=("12.5m-2r",)
    )
    sighted = shares["sighted"]
    low, high = sighted.interval
    assert lines[3] == (
        f"| sees its target within 3 m | {100 * sighted.a:.1f} % | {100 * sighted.b:.1f} % | "
        f"{100 * sighted.difference:+.1f} [{100 * low:+.1f}, {100 * high:+.1f}] * |"
    )
