"""Table IV's verdicts: ablation - full on one setup, judged against the full model's seed-to-seed spread."""

from __future__ import annotations

import math

import pytest

from navformer_rl.cli.main import main
from navformer_rl.evaluation.ablations import ablation_verdicts, ablations_markdown, verdict
from navformer_rl.evaluation.paired import PairedDifference
from tests.evaluation.test_paired import trials, write

N = 20  # trials per setup, one robot each


def outcomes(successes: int, n: int = N) -> list[list[bool]]:
    return [[t < successes] for t in range(n)]


def folder(tmp_path, name: str, table4_successes: int, other_successes: int = 10):
    """An evaluation of two setups: ``table4_successes`` of 20 on 12.5m-4r, ``other_successes`` on 7.5m-2r."""
    records = trials(outcomes(other_successes), setup="7.5m-2r") + trials(
        outcomes(table4_successes), setup="12.5m-4r"
    )
    return write(tmp_path / name, name, records)


def difference(d: float, low: float, high: float) -> PairedDifference:
    return PairedDifference(
        setup="12.5m-4r", n_robot_trials=60, n_trials=60, n_clusters=60, a={}, b={},
        difference={"sr": d}, interval={"sr": (low, high)},
    )  # fmt: skip


def test_the_verdict_needs_the_interval_and_the_seed_spread():
    assert verdict(difference(-0.20, -0.30, -0.10), seed_spread=0.05) == "holds"
    assert verdict(difference(+0.20, +0.10, +0.30), seed_spread=0.05) == "does not hold"
    # the interval excludes zero but the difference lies within the spread of the full model's seeds
    assert verdict(difference(-0.04, -0.07, -0.01), seed_spread=0.05) == "cannot tell"
    assert verdict(difference(+0.04, +0.01, +0.07), seed_spread=0.05) == "cannot tell"
    assert verdict(difference(-0.20, -0.35, +0.01), seed_spread=0.05) == "cannot tell"
    assert verdict(difference(-0.20, math.nan, math.nan), seed_spread=None) == "cannot tell"
    # one seed of the full model: the interval alone
    assert verdict(difference(-0.04, -0.07, -0.01), seed_spread=None) == "holds"


def test_known_answers_on_table4s_setup(tmp_path):
    """The full model's seeds: 12, 10, 8 successes of 20 on 12.5m-4r (50 %, sd 10 points); one ablation at
    2 / 20, one at 19 / 20, one at 9 / 20."""
    full = [folder(tmp_path, f"full_s{i}", k) for i, k in enumerate((12, 10, 8))]
    ablations = [
        ("no_ssl", [folder(tmp_path, "no_ssl", 2)]),
        ("no_thsc", [folder(tmp_path, "no_thsc", 19)]),
        ("no_fs", [folder(tmp_path, "no_fs", 9)]),
    ]
    rows = ablation_verdicts(full, ablations)
    assert [(r.name, r.setup) for r in rows] == [(n, "12.5m-4r") for n in ("no_ssl", "no_thsc", "no_fs")]
    assert [r.seed_spread for r in rows] == pytest.approx([0.10] * 3)
    assert [r.difference.a["sr"] for r in rows] == pytest.approx([0.10, 0.95, 0.45])
    assert [r.difference.b["sr"] for r in rows] == pytest.approx([0.50] * 3)
    assert [r.difference.difference["sr"] for r in rows] == pytest.approx([-0.40, +0.45, -0.05])
    assert [r.difference.n_seeds for r in rows] == [(1, 3)] * 3
    assert [r.verdict for r in rows] == ["holds", "does not hold", "cannot tell"]
    table = ablations_markdown(rows)
    assert "| no_ssl | 1 | 12.5m-4r | 10.0 % / " in table and "| -40.0 [" in table
    assert "| 10.0 | holds |" in table and "| 10.0 | cannot tell |" in table
    assert "full model (3 seeds)" in table


def test_all_setups_pool_and_one_full_seed_rests_on_the_interval(tmp_path):
    full = [folder(tmp_path, "full", 10, other_successes=10)]
    ablation = folder(tmp_path, "no_de", 0, other_successes=0)
    (row,) = ablation_verdicts(full, [("no_de", [ablation])], setup="all")
    assert row.setup == "all" and row.seed_spread is None
    assert row.difference.difference["sr"] == pytest.approx(-0.50)
    assert row.verdict == "holds"
    assert "| - | holds (one seed) |" in ablations_markdown([row])


def test_bad_input_is_one_line(tmp_path, capsys):
    full = [folder(tmp_path, "full", 10)]
    ablation = folder(tmp_path, "no_fg", 5)
    with pytest.raises(ValueError, match="no ablation given"):
        ablation_verdicts(full, [])
    with pytest.raises(ValueError, match=r"setup '17.5m-6r' is not among .*7.5m-2r, 12.5m-4r, all"):
        ablation_verdicts(full, [("no_fg", [ablation])], setup="17.5m-6r")
    argv = ["evaluate", "ablations", "--full", str(full[0]), "--ablation", "no_fg"]
    assert main(argv) == 2
    assert "--ablation no_fg: give the ablation's evaluation folders" in capsys.readouterr().err


def test_cli_prints_and_writes_the_table(tmp_path, capsys):
    full = [folder(tmp_path, f"full_s{i}", k) for i, k in enumerate((12, 8))]
    ablation = folder(tmp_path, "no_ssl", 1)
    out = tmp_path / "table4.md"
    argv = ["evaluate", "ablations", "--full", *map(str, full), "--ablation", "no_ssl", str(ablation)]
    assert main([*argv, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed == out.read_text()
    assert "| no_ssl | 1 | 12.5m-4r | 5.0 % / " in printed and "| -45.0 [" in printed and "holds |" in printed
