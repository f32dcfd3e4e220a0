"""The evaluation records kept in ``docs/results/`` stay readable by the evaluation tools and still give the
numbers docs/results.md (its tables and sentences), docs/studies.md, the README's caption and the model cards
quote from them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from navformer_rl.evaluation.paired import paired_differences
from navformer_rl.evaluation.seeds import summarize_seed_groups

DATA_SCALING = Path(__file__).resolve().parents[2] / "docs" / "results" / "data_scaling"


@pytest.mark.parametrize(
    ("group", "expected_sr"),
    [
        ("navformer_e350", {0: 0.200, 1: 0.250}),
        ("dt_e350", {0: 0.3417, 1: 0.2917}),
        ("navformer_e1000", {1: 0.300}),
        ("dt_e1000", {1: 0.2667}),
        ("navformer_e3496", {0: 0.175}),
        ("dt_e3496", {0: 0.300}),
    ],
)
def test_data_scaling_records_give_the_quoted_success_rates(
    group: str, expected_sr: dict[int, float]
) -> None:
    folders = [DATA_SCALING / f"{group}_s{seed}" for seed in expected_sr]
    (summary,) = summarize_seed_groups({group: folders})
    assert [run.metrics.sr for run in summary.runs] == pytest.approx(list(expected_sr.values()), abs=5e-5)
    assert summary.mean["sr"] == pytest.approx(sum(expected_sr.values()) / len(expected_sr), abs=5e-5)
    assert all(run.metrics.n_trials == 40 for run in summary.runs)


def test_data_scaling_records_share_one_episode_set() -> None:
    # summarize_seed_groups refuses folders of different episode sets, across groups too
    folders = sorted(p for p in DATA_SCALING.iterdir() if p.is_dir())
    assert len(folders) >= 4
    summaries = summarize_seed_groups({folder.name: [folder] for folder in folders})
    assert {s.runs[0].metrics.n_trials for s in summaries} == {40}


PAPER10K = DATA_SCALING.parent / "paper10k"


@pytest.mark.parametrize(
    ("record", "expected"),
    [
        ("navformer_10k_s0_it01000", {"sr": 0.1667, "cr": 0.7549}),
        ("navformer_10k_s0_it02000", {"sr": 0.3083, "cr": 0.4215}),
        ("navformer_10k_s0_it02500", {"sr": 0.3333, "cr": 0.4834}),
        ("navformer_10k_s0_it03000", {"sr": 0.3000, "cr": 0.3646}),
        ("navformer_10k_s0_runb_it01000", {"sr": 0.1417, "cr": 0.5233}),
        ("navformer_10k_s0_runb_it02000", {"sr": 0.2750, "cr": 0.5513}),
        ("navformer_10k_s0_runb_it02500", {"sr": 0.3500, "cr": 0.4559}),
        ("navformer_10k_s0_runb_it03000", {"sr": 0.3333, "cr": 0.5243}),
        ("navformer_10k_s0_runb_it04000", {"sr": 0.2833, "cr": 0.6126}),
        ("navformer_10k_s0_runb_it05000", {"sr": 0.4083, "cr": 0.4008}),
        ("navformer_10k_s0_runb_it06000", {"sr": 0.3750, "cr": 0.4775}),
        ("navformer_10k_s0_runb_it07000", {"sr": 0.4333, "cr": 0.5635}),
        ("navformer_10k_s0_runb_it08000", {"sr": 0.4083, "cr": 0.4299}),
        ("navformer_10k_s0_runb_it09000", {"sr": 0.4500, "cr": 0.4759}),
        ("navformer_10k_s0_runb_it10000", {"sr": 0.4833, "cr": 0.4432}),
        ("navformer_10k_s0_runb_avg09000-10000", {"sr": 0.5333, "cr": 0.4306}),
        ("navformer_10k_s0_runb_it02500_w16", {"sr": 0.3750, "cr": 0.3689}),
        ("navformer_10k_s0_runb_it04000_w16", {"sr": 0.3000, "cr": 0.5946}),
        ("navformer_10k_s0_runb_it05000_w16", {"sr": 0.3417, "cr": 0.3999}),
        ("navformer_10k_s0_runb_it06000_w16", {"sr": 0.3333, "cr": 0.4404}),
        ("navformer_10k_s0_runb_avg02000-03000", {"sr": 0.3333, "cr": 0.3502}),
        ("navformer_10k_s0_runb_avg03000-04000", {"sr": 0.2667, "cr": 0.5542}),
        ("navformer_10k_s0_runb_avg04000-05000", {"sr": 0.3833, "cr": 0.5249}),
        ("dt_10k_s0_it01000", {"sr": 0.2333, "cr": 0.5128}),
        ("dt_10k_s0_it02000", {"sr": 0.2833, "cr": 0.5644}),
        ("dt_10k_s0_it02500", {"sr": 0.3167, "cr": 0.5326}),
        ("dt_10k_s0_it03000", {"sr": 0.3917, "cr": 0.5297}),
        ("dt_10k_s0_it04000", {"sr": 0.3500, "cr": 0.5184}),
        ("dt_10k_s0_it05000", {"sr": 0.3417, "cr": 0.6025}),
        ("dt_10k_s0_it06000", {"sr": 0.5000, "cr": 0.4928}),
        ("dt_10k_s0_it07000", {"sr": 0.3500, "cr": 0.5942}),
        ("dt_10k_s0_it08000", {"sr": 0.5167, "cr": 0.4443}),
        ("dt_10k_s0_it09000", {"sr": 0.4833, "cr": 0.4700}),
        ("dt_10k_s0_it10000", {"sr": 0.5167, "cr": 0.4634}),
        ("dt_10k_s0_avg09000-10000", {"sr": 0.4667, "cr": 0.4312}),
        ("navformer_tenth_it02500", {"sr": 0.3833, "cr": 0.3342}),
        ("dt_tenth_it02500", {"sr": 0.3250, "cr": 0.5057}),
    ],
)
def test_paper_training_records_give_the_quoted_metrics(record: str, expected: dict[str, float]) -> None:
    (summary,) = summarize_seed_groups({record: [PAPER10K / record]})
    (run,) = summary.runs
    assert run.metrics.n_trials == 40
    assert run.metrics.sr == pytest.approx(expected["sr"], abs=5e-5)
    assert run.metrics.cr == pytest.approx(expected["cr"], abs=5e-5)


def test_paper_training_records_share_the_data_scaling_episodes() -> None:
    records = sorted(p for p in PAPER10K.iterdir() if (p / "run.json").is_file())
    assert len(records) >= 11
    folders = [DATA_SCALING / "navformer_e350_s0", *records]
    summarize_seed_groups({folder.name: [folder] for folder in folders})  # refuses mixed episode sets


def test_paired_difference_of_all_the_data_against_a_tenth_at_2500_iterations() -> None:
    _, rows = paired_differences(
        PAPER10K / "navformer_10k_s0_it02500", PAPER10K / "navformer_tenth_it02500", n_resamples=200
    )
    pooled = rows[-1]
    assert pooled.setup == "all" and pooled.n_robot_trials == 120
    assert pooled.difference["sr"] == pytest.approx(-0.050, abs=5e-5)
    assert pooled.difference["cr"] == pytest.approx(0.149, abs=5e-4)


CONTEXT = DATA_SCALING.parent / "context"


@pytest.mark.parametrize(
    ("record", "baseline", "context_steps", "expected"),
    [
        ("nf10k_it2500_w8", "navformer_10k_s0_it02500", 8, {"sr": 0.4083, "cr": 0.4373}),
        ("nf10k_it2500_w16", "navformer_10k_s0_it02500", 16, {"sr": 0.3917, "cr": 0.3743}),
        ("nf10k_it2500_w32", "navformer_10k_s0_it02500", 32, {"sr": 0.3500, "cr": 0.3370}),
        ("nf10k_it2500_w64", "navformer_10k_s0_it02500", 64, {"sr": 0.3250, "cr": 0.4070}),
        ("nf10k_it2500_w128", "navformer_10k_s0_it02500", 128, {"sr": 0.3833, "cr": 0.3980}),
        ("shipped_navformer_w16", "navformer_tenth_it02500", 16, {"sr": 0.3917, "cr": 0.2020}),
        ("shipped_navformer_w32", "navformer_tenth_it02500", 32, {"sr": 0.3667, "cr": 0.2270}),
        ("shipped_dt_w16", "dt_tenth_it02500", 16, {"sr": 0.3917, "cr": 0.3780}),
        ("shipped_dt_w32", "dt_tenth_it02500", 32, {"sr": 0.3500, "cr": 0.4240}),
    ],
)
def test_context_records_give_the_quoted_metrics_against_the_whole_context(
    record: str, baseline: str, context_steps: int, expected: dict[str, float]
) -> None:
    """The same checkpoint as its whole-context record, only the inference window differs (run.json)."""
    import json

    run, whole = (
        json.loads((folder / "run.json").read_text()) for folder in (CONTEXT / record, PAPER10K / baseline)
    )
    assert run["context_steps"] == context_steps and "context_steps" not in whole
    assert run["checkpoint_sha256"] == whole["checkpoint_sha256"]
    (summary,) = summarize_seed_groups({record: [CONTEXT / record]})
    metrics = summary.runs[0].metrics
    assert metrics.n_trials == 40
    assert metrics.sr == pytest.approx(expected["sr"], abs=5e-5)
    assert metrics.cr == pytest.approx(expected["cr"], abs=5e-4)
    _, rows = paired_differences(CONTEXT / record, PAPER10K / baseline, n_resamples=200)
    assert rows[-1].n_robot_trials == 120  # the same robot-trials: the data-scaling episodes


def test_a_record_kept_gzip_compressed_reads_like_the_plain_one(tmp_path: Path) -> None:
    import gzip
    import shutil

    from navformer_rl.evaluation.tables import read_records

    plain = PAPER10K / "navformer_10k_s0_it02500"
    packed = tmp_path / "packed"
    packed.mkdir()
    shutil.copy(plain / "run.json", packed / "run.json")
    (packed / "episodes.jsonl.gz").write_bytes(gzip.compress((plain / "episodes.jsonl").read_bytes()))
    assert read_records(packed / "episodes.jsonl") == read_records(plain / "episodes.jsonl")
    _, rows = paired_differences(packed, PAPER10K / "navformer_tenth_it02500", n_resamples=200)
    assert rows[-1].difference["sr"] == pytest.approx(-0.050, abs=5e-5)
    (packed / "episodes.jsonl.gz").write_bytes(b"not gzip")
    with pytest.raises(ValueError, match="is not a gzip-compressed JSONL file"):
        read_records(packed / "episodes.jsonl")
    with pytest.raises(FileNotFoundError, match=r"nor episodes.jsonl.gz"):
        read_records(tmp_path / "episodes.jsonl")


TABLE1 = CONTEXT / "table1"


@pytest.mark.parametrize(
    ("record", "baseline", "expected"),
    [
        ("navformer_w16", "navformer", {"sr": 0.060, "cr": -0.176}),
        ("dt_w16", "dt", {"sr": 0.005, "cr": -0.153}),
    ],
)
def test_table1_records_of_the_context_give_the_quoted_paired_differences(
    record: str, baseline: str, expected: dict[str, float]
) -> None:
    """Table I's 540 trials, stored gzip-compressed: each window against the same weights' whole context."""
    import json

    run, whole = (json.loads((TABLE1 / name / "run.json").read_text()) for name in (record, baseline))
    assert run["context_steps"] == 16 and "context_steps" not in whole
    assert run["checkpoint_sha256"] == whole["checkpoint_sha256"]
    _, rows = paired_differences(TABLE1 / record, TABLE1 / baseline, n_resamples=200)
    pooled = rows[-1]
    assert pooled.setup == "all" and pooled.n_robot_trials == 2160
    assert pooled.difference["sr"] == pytest.approx(expected["sr"], abs=5e-4)
    assert pooled.difference["cr"] == pytest.approx(expected["cr"], abs=5e-4)


TABLE3 = CONTEXT / "table3"


@pytest.mark.parametrize(
    ("record", "expected"),
    [("navformer", -0.067), ("navformer_w16", 0.0), ("dt", 0.067), ("dt_w16", -0.017)],
)
def test_table3_records_give_the_quoted_unseen_minus_seen(record: str, expected: float) -> None:
    """Table III's 120 episodes, gzip-compressed: the same Jackal among unseen against seen obstacle
    robots."""
    from navformer_rl.evaluation.paired import unseen_obstacle_differences

    _, difference = unseen_obstacle_differences(TABLE3 / record, n_resamples=200)
    assert difference.n_robot_trials == 60
    assert difference.difference["sr"] == pytest.approx(expected, abs=5e-4)


def test_table3_records_pair_navformer_and_dt_with_16_steps() -> None:
    _, rows = paired_differences(TABLE3 / "navformer_w16", TABLE3 / "dt_w16", n_resamples=200)
    pooled = rows[-1]
    assert pooled.n_robot_trials == 300
    assert pooled.difference["sr"] == pytest.approx(0.020, abs=5e-4)
    assert pooled.difference["cr"] == pytest.approx(-0.181, abs=5e-4)


WINDOW16 = DATA_SCALING.parent / "window16"


def test_window16_records_are_the_short_window_checkpoint_on_its_window_and_on_the_whole_context() -> None:
    """Trained on 16-step windows: recorded attending to 16 steps (the checkpoint's default) and to 256."""
    import json

    short, whole = (
        json.loads((WINDOW16 / name / "run.json").read_text())
        for name in ("navformer_ctx16_it2500", "navformer_ctx16_it2500_w256")
    )
    assert short["context_steps"] == 16 and whole["context_steps"] == 256
    assert short["checkpoint_sha256"] == whole["checkpoint_sha256"]
    summaries = summarize_seed_groups(
        {"w16": [WINDOW16 / "navformer_ctx16_it2500"], "w256": [WINDOW16 / "navformer_ctx16_it2500_w256"]}
    )
    assert [summary.runs[0].metrics.sr for summary in summaries] == pytest.approx([0.4333, 0.2417], abs=5e-5)
    _, rows = paired_differences(
        WINDOW16 / "navformer_ctx16_it2500", PAPER10K / "navformer_10k_s0_it02500", n_resamples=200
    )
    assert rows[-1].n_robot_trials == 120
    assert rows[-1].difference["sr"] == pytest.approx(0.100, abs=5e-5)


@pytest.mark.parametrize(
    ("baseline", "expected"),
    [("navformer_w16", 0.042), ("navformer", 0.102), ("dt", 0.060), ("dt_w16", 0.055)],
)
def test_window16_table1_record_gives_the_quoted_paired_differences(baseline: str, expected: float) -> None:
    _, rows = paired_differences(WINDOW16 / "table1" / "navformer_ctx16", TABLE1 / baseline, n_resamples=200)
    pooled = rows[-1]
    assert pooled.n_robot_trials == 2160
    assert pooled.difference["sr"] == pytest.approx(expected, abs=5e-4)


def test_window16_navformer_and_dt_trained_the_same_way_pair_on_table1_and_table3() -> None:
    import json

    assert json.loads((WINDOW16 / "dt_ctx16_it2500" / "run.json").read_text())["context_steps"] == 16
    _, rows = paired_differences(
        WINDOW16 / "table1" / "navformer_ctx16", WINDOW16 / "table1" / "dt_ctx16", n_resamples=200
    )
    assert rows[-1].n_robot_trials == 2160
    assert rows[-1].difference["sr"] == pytest.approx(0.023, abs=5e-4)
    assert rows[-1].difference["cr"] == pytest.approx(0.146, abs=5e-4)
    from navformer_rl.evaluation.paired import unseen_obstacle_differences

    for record, expected in (("navformer_ctx16", 0.017), ("dt_ctx16", 0.050)):
        _, difference = unseen_obstacle_differences(WINDOW16 / "table3" / record, n_resamples=200)
        assert difference.difference["sr"] == pytest.approx(expected, abs=5e-4)


def test_window16_second_seed_record_gives_the_quoted_difference() -> None:
    _, rows = paired_differences(
        WINDOW16 / "navformer_ctx16_s1_it2500", WINDOW16 / "navformer_ctx16_it2500", n_resamples=200
    )
    assert rows[-1].n_robot_trials == 120
    assert rows[-1].difference["sr"] == pytest.approx(-0.150, abs=5e-4)


EXPERT = DATA_SCALING.parent / "expert"


def test_exploration_expert_records_give_the_quoted_success_rates() -> None:
    for record, expected, trials in (("frontier", 0.775, 40), ("table1/frontier", 0.5495, 540)):
        (summary,) = summarize_seed_groups({record: [EXPERT / record]})
        assert summary.runs[0].metrics.sr == pytest.approx(expected, abs=5e-5)
        assert summary.runs[0].metrics.n_trials == trials
    _, rows = paired_differences(WINDOW16 / "navformer_ctx16_it2500", EXPERT / "frontier", n_resamples=200)
    assert rows[-1].n_robot_trials == 120
    assert rows[-1].difference["sr"] == pytest.approx(-0.342, abs=5e-4)


@pytest.mark.parametrize(
    ("record", "found", "sr_found"),
    [
        ("frontier", 0.817, 0.939),
        ("navformer_ctx16", 0.550, 0.727),
        ("dt_ctx16", 0.483, 0.879),
        ("shipped_navformer", 0.442, 0.830),
        ("dagger_it500", 0.575, 0.797),
        ("control_it500", 0.467, 0.750),
    ],
)
def test_diagnosis_records_split_sr_into_finding_and_reaching(
    record: str, found: float, sr_found: float
) -> None:
    """The quoted decomposition: robot-trials that see their target within 3 m, and the SR of those."""
    from navformer_rl.evaluation.diagnose import load_diagnosis

    summary = load_diagnosis(EXPERT / "diagnosis" / record)["all"]
    three = summary["sightings"][0]
    assert three["range_m"] == 3.0
    assert three["robot_trials_with_sighting_fraction"] == pytest.approx(found, abs=5e-4)
    assert three["robot_trials_with_sighting_success_fraction"] == pytest.approx(sr_found, abs=5e-4)
    # SR = found x SR of those + the successes without such a sighting
    assert summary["success_rate"] >= found * sr_found - 1e-9


def test_window16_dagger_records_give_the_quoted_differences() -> None:
    dagger = WINDOW16 / "dagger" / "dagger_it500"
    for baseline, expected in (
        (WINDOW16 / "dagger" / "control_it500", 0.117),
        (WINDOW16 / "navformer_ctx16_it2500", 0.050),
    ):
        _, rows = paired_differences(dagger, baseline, n_resamples=200)
        assert rows[-1].n_robot_trials == 120
        assert rows[-1].difference["sr"] == pytest.approx(expected, abs=5e-4)


def test_window16_second_seed_of_dt_gives_the_quoted_success_rate() -> None:
    (summary,) = summarize_seed_groups({"dt_s1": [WINDOW16 / "dt_ctx16_s1_it2500"]})
    assert summary.runs[0].metrics.sr == pytest.approx(0.2333, abs=5e-5)


def test_window16_second_seed_on_table1_gives_the_quoted_differences() -> None:
    seed1 = WINDOW16 / "table1" / "navformer_ctx16_s1"
    for baseline, expected in (
        (WINDOW16 / "table1" / "navformer_ctx16", -0.107),
        (TABLE1 / "navformer", -0.006),
        (TABLE1 / "dt", -0.048),
    ):
        _, rows = paired_differences(seed1, baseline, n_resamples=200)
        assert rows[-1].n_robot_trials == 2160
        assert rows[-1].difference["sr"] == pytest.approx(expected, abs=5e-4)


def test_exploration_expert_table3_record_gives_the_quoted_difference() -> None:
    from navformer_rl.evaluation.paired import unseen_obstacle_differences

    _, difference = unseen_obstacle_differences(EXPERT / "table3" / "frontier", n_resamples=200)
    assert difference.difference["sr"] == pytest.approx(0.017, abs=5e-4)


def test_window16_dagger_table1_record_gives_the_quoted_difference() -> None:
    _, rows = paired_differences(
        WINDOW16 / "dagger" / "table1_dagger_it500", WINDOW16 / "table1" / "navformer_ctx16", n_resamples=200
    )
    assert rows[-1].n_robot_trials == 2160
    assert rows[-1].difference["sr"] == pytest.approx(-0.003, abs=5e-4)


def test_window16_navformer_and_dt_of_the_second_seed_pair_on_table1() -> None:
    _, rows = paired_differences(
        WINDOW16 / "table1" / "navformer_ctx16_s1", WINDOW16 / "table1" / "dt_ctx16_s1", n_resamples=200
    )
    assert rows[-1].n_robot_trials == 2160
    assert rows[-1].difference["sr"] == pytest.approx(0.016, abs=5e-4)
    assert rows[-1].difference["cr"] == pytest.approx(-0.026, abs=5e-4)


def test_paired_difference_of_the_two_runs_at_3000_iterations() -> None:
    _, rows = paired_differences(
        PAPER10K / "navformer_10k_s0_runb_it03000", PAPER10K / "navformer_10k_s0_it03000", n_resamples=200
    )
    pooled = rows[-1]
    assert pooled.n_robot_trials == 120
    assert pooled.difference["sr"] == pytest.approx(0.0333, abs=5e-4)
    assert pooled.difference["cr"] == pytest.approx(0.160, abs=5e-4)


def test_the_run_b_diagnosis_at_4000_iterations_gives_the_quoted_contact_and_turns() -> None:
    from navformer_rl.evaluation.diagnose import load_diagnosis

    summary = load_diagnosis(PAPER10K / "diagnosis" / "navformer_10k_s0_runb_it04000")["all"]
    assert summary["success_rate"] == pytest.approx(0.2833, abs=5e-5)
    assert summary["walls"]["contact_fraction"] == pytest.approx(0.733, abs=5e-4)
    assert summary["outcomes"]["stuck"] == pytest.approx(0.617, abs=5e-4)
    assert summary["progress"]["per_step_target_hidden"] == pytest.approx(0.001, abs=5e-4)


def test_two_checkpoints_of_run_b_1000_iterations_apart_differ_beyond_the_interval() -> None:
    _, rows = paired_differences(
        PAPER10K / "navformer_10k_s0_runb_it05000",
        PAPER10K / "navformer_10k_s0_runb_it04000",
        n_resamples=200,
    )
    assert rows[-1].difference["sr"] == pytest.approx(0.125, abs=5e-4)
    assert rows[-1].difference["cr"] == pytest.approx(-0.212, abs=5e-4)


@pytest.mark.parametrize(
    ("window", "expected_sr", "expected_cr"),
    [
        ("02000-03000", 0.0, -0.174),
        ("03000-04000", -0.0167, -0.0584),
        ("04000-05000", -0.025, 0.124),
        ("09000-10000", 0.05, -0.0126),
    ],
)
def test_averaged_checkpoints_against_the_last_one_they_average(
    window: str, expected_sr: float, expected_cr: float
) -> None:
    _, rows = paired_differences(
        PAPER10K / f"navformer_10k_s0_runb_avg{window}",
        PAPER10K / f"navformer_10k_s0_runb_it{window.split('-')[1]}",
        n_resamples=200,
    )
    assert rows[-1].n_robot_trials == 120
    assert rows[-1].difference["sr"] == pytest.approx(expected_sr, abs=5e-4)
    assert rows[-1].difference["cr"] == pytest.approx(expected_cr, abs=5e-4)


# SR, robot-trials with the target in view within 3 m, progress per step while it is hidden, mean |angular|,
# mean angular, |angular| in each trial's main direction, steps in contact, stuck at the end
CHECKPOINT_DIAGNOSES = [
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_it01000",
        (0.1417, 0.2583, -0.0026, 0.3192, 0.0845, 0.8184, 0.5706, 0.4583),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_it02000",
        (0.2750, 0.3667, 0.0001, 0.1431, 0.0760, 0.7583, 0.6520, 0.3750),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_it02500",
        (0.3500, 0.3833, 0.0007, 0.1824, 0.0910, 0.7592, 0.5600, 0.2167),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_it03000",
        (0.3333, 0.4417, 0.0025, 0.1727, 0.0160, 0.7329, 0.6474, 0.4917),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_it04000",
        (0.2833, 0.3750, 0.0007, 0.1227, -0.0256, 0.7117, 0.7330, 0.6167),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_it05000",
        (0.4083, 0.5167, 0.0001, 0.3169, -0.2267, 0.8383, 0.4822, 0.4250),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_it06000",
        (0.3750, 0.4500, 0.0006, 0.2310, -0.1294, 0.8136, 0.5703, 0.5000),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_it08000",
        (0.4083, 0.4917, -0.0006, 0.2276, -0.0492, 0.6925, 0.5429, 0.5000),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_it10000",
        (0.4833, 0.5917, 0.0021, 0.2124, 0.0404, 0.6974, 0.5784, 0.3917),
    ),
    (
        "paper10k/diagnosis/dt_10k_s0_it10000",
        (0.5167, 0.5667, 0.0070, 0.1812, -0.0037, 0.7067, 0.6650, 0.4500),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_avg02000-03000",
        (0.3333, 0.4167, -0.0003, 0.2651, 0.1847, 0.8282, 0.4161, 0.0667),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_avg03000-04000",
        (0.2667, 0.3417, 0.0012, 0.1200, 0.0328, 0.7268, 0.6942, 0.5250),
    ),
    (
        "paper10k/diagnosis/navformer_10k_s0_runb_avg04000-05000",
        (0.3833, 0.4500, 0.0016, 0.1542, -0.0319, 0.6843, 0.6895, 0.5583),
    ),
    ("expert/diagnosis/shipped_navformer", (0.3833, 0.4417, -0.0004, 0.2997, 0.2427, 0.8824, 0.4022, 0.1583)),
    ("expert/diagnosis/shipped_dt", (0.3250, 0.4083, 0.0007, 0.2288, -0.0057, 0.7137, 0.6234, 0.4000)),
    ("expert/diagnosis/frontier", (0.7750, 0.8167, 0.0209, 0.2274, -0.0077, 0.7624, 0.5241, 0.1583)),
    ("expert/diagnosis/fca", (0.9667, 0.9000, 0.0514, 0.4096, 0.1030, 0.7354, 0.0000, 0.0000)),
]


@pytest.mark.parametrize(("record", "expected"), CHECKPOINT_DIAGNOSES)
def test_closed_loop_diagnoses_give_the_quoted_search_and_turn_measures(record: str, expected: tuple) -> None:
    from navformer_rl.evaluation.diagnose import load_diagnosis

    summary = load_diagnosis(DATA_SCALING.parent / record)["all"]
    turns = summary["commands"]["angular"]
    measured = (
        summary["success_rate"],
        summary["sightings"][0]["robot_trials_with_sighting_fraction"],
        summary["progress"]["per_step_target_hidden"],
        turns["mean_abs"],
        turns["mean"],
        turns["main_direction_share"],
        summary["walls"]["contact_fraction"],
        summary["outcomes"]["stuck"],
    )
    assert summary["sightings"][0]["range_m"] == 3.0 and summary["robot_trials"] == 120
    assert measured == pytest.approx(expected, abs=5e-5)


def test_only_the_paper_scale_dt_gets_closer_while_its_target_is_hidden() -> None:
    hidden = {record: expected[2] for record, expected in CHECKPOINT_DIAGNOSES}
    paper_dt = hidden.pop("paper10k/diagnosis/dt_10k_s0_it10000")
    learned = [value for record, value in hidden.items() if "frontier" not in record and "fca" not in record]
    assert len(learned) == 14 and max(abs(value) for value in learned) < 0.003
    assert hidden["expert/diagnosis/frontier"] > 0.02 and hidden["expert/diagnosis/fca"] > 0.05
    # DT's paper-scale run is the one learned policy that closes in,
    # by about a third of the exploration expert
    assert 0.005 < paper_dt < hidden["expert/diagnosis/frontier"] / 2


@pytest.mark.parametrize(
    ("iteration", "expected_sr", "expected_cr"),
    [
        ("02500", 0.025, -0.087),
        ("04000", 0.0167, -0.018),
        ("05000", -0.0667, -0.0009),
        ("06000", -0.0417, -0.0371),
    ],
)
def test_run_b_with_a_16_step_context_against_its_whole_context(
    iteration: str, expected_sr: float, expected_cr: float
) -> None:
    _, rows = paired_differences(
        PAPER10K / f"navformer_10k_s0_runb_it{iteration}_w16",
        PAPER10K / f"navformer_10k_s0_runb_it{iteration}",
        n_resamples=200,
    )
    assert rows[-1].difference["sr"] == pytest.approx(expected_sr, abs=5e-4)
    assert rows[-1].difference["cr"] == pytest.approx(expected_cr, abs=5e-4)


def test_run_b_at_5000_keeps_turning_as_its_context_fills() -> None:
    from navformer_rl.evaluation.diagnose import load_diagnosis

    phases = load_diagnosis(PAPER10K / "diagnosis" / "navformer_10k_s0_runb_it05000")["all"]["phases"]
    turns = {phase["first_step"]: phase["free_median_abs_turn"] for phase in phases}
    expected = {0: 0.4356, 25: 0.2777, 50: 0.3364, 100: 0.4584, 200: 0.6525}
    assert {step: turns[step] for step in expected} == pytest.approx(expected, abs=5e-5)


@pytest.mark.parametrize(
    ("iteration", "expected_sr", "expected_cr", "against_tenth"),
    [
        ("05000", 0.2523, 0.4604, {"navformer": (0.0764, 0.0718), "dt": (0.0343, -0.1031)}),
        ("10000", 0.2917, 0.5333, {"navformer": (0.1157, 0.1447), "dt": (0.0736, -0.0302)}),
    ],
)
def test_run_b_on_table1_against_the_tenth_scale_weights(
    iteration: str, expected_sr: float, expected_cr: float, against_tenth: dict[str, tuple[float, float]]
) -> None:
    """Iterations 5,000 and 10,000 (``pretrained:navformer``) paired with ``navformer_tenth`` and
    ``dt_tenth``."""
    record = PAPER10K / "table1" / f"navformer_10k_s0_runb_it{iteration}"
    (summary,) = summarize_seed_groups({"run B": [record]})
    assert summary.runs[0].metrics.n_trials == 540
    assert summary.runs[0].metrics.sr == pytest.approx(expected_sr, abs=5e-5)
    assert summary.runs[0].metrics.cr == pytest.approx(expected_cr, abs=5e-5)
    table1 = DATA_SCALING.parent / "context" / "table1"
    for tenth, (sr_difference, cr_difference) in against_tenth.items():
        _, rows = paired_differences(record, table1 / tenth, n_resamples=200)
        assert rows[-1].n_robot_trials == 2160
        assert rows[-1].difference["sr"] == pytest.approx(sr_difference, abs=5e-4)
        assert rows[-1].difference["cr"] == pytest.approx(cr_difference, abs=5e-4)


def test_run_b_at_6000_on_table1_against_5000() -> None:
    record = PAPER10K / "table1" / "navformer_10k_s0_runb_it06000"
    (summary,) = summarize_seed_groups({"run B": [record]})
    assert summary.runs[0].metrics.sr == pytest.approx(0.2032, abs=5e-5)
    assert summary.runs[0].metrics.cr == pytest.approx(0.5442, abs=5e-5)
    _, rows = paired_differences(
        record, PAPER10K / "table1" / "navformer_10k_s0_runb_it05000", n_resamples=200
    )
    assert rows[-1].difference["sr"] == pytest.approx(-0.0491, abs=5e-4)
    assert rows[-1].difference["cr"] == pytest.approx(0.0838, abs=5e-4)


def test_run_b_at_7000_on_table1() -> None:
    record = PAPER10K / "table1" / "navformer_10k_s0_runb_it07000"
    (summary,) = summarize_seed_groups({"run B": [record]})
    assert summary.runs[0].metrics.sr == pytest.approx(0.2579, abs=5e-4)
    _, rows = paired_differences(record, DATA_SCALING.parent / "context" / "table1" / "dt", n_resamples=200)
    assert rows[-1].difference["sr"] == pytest.approx(0.040, abs=5e-4)
    assert rows[-1].difference["cr"] == pytest.approx(0.063, abs=5e-4)


def test_navformer_against_dt_at_the_papers_scale_on_table1() -> None:
    """Both final checkpoints of the paper's training (``pretrained:navformer``, ``pretrained:dt``)
    on Table I: DT is ahead in every setup and touches less."""
    navformer = PAPER10K / "table1" / "navformer_10k_s0_runb_it10000"
    dt = PAPER10K / "table1" / "dt_10k_s0_it10000"
    (summary,) = summarize_seed_groups({"DT": [dt]})
    assert summary.runs[0].metrics.n_trials == 540
    assert summary.runs[0].metrics.sr == pytest.approx(0.3694, abs=5e-5)
    assert summary.runs[0].metrics.cr == pytest.approx(0.5032, abs=5e-5)
    _, rows = paired_differences(navformer, dt, n_resamples=200)
    assert [row.setup for row in rows][-1] == "all" and len(rows) == 10
    assert all(row.difference["sr"] < 0 for row in rows)
    assert rows[-1].difference["sr"] == pytest.approx(-0.0778, abs=5e-4)
    assert rows[-1].difference["cr"] == pytest.approx(0.0302, abs=5e-4)
    _, rows = paired_differences(dt, DATA_SCALING.parent / "context" / "table1" / "dt", n_resamples=200)
    assert rows[-1].difference["sr"] == pytest.approx(0.1514, abs=5e-4)
    assert rows[-1].difference["cr"] == pytest.approx(-0.0604, abs=5e-4)


@pytest.mark.parametrize(
    ("record", "expected_sr_difference"),
    [("navformer_10k_s0_runb_it10000", -0.0333), ("dt_10k_s0_it10000", -0.1000)],
)
def test_the_shipped_policies_on_table3(record: str, expected_sr_difference: float) -> None:
    """The final checkpoints of the paper's training (``pretrained:navformer``, ``pretrained:dt``): the same
    Jackal among unseen against seen robots."""
    from navformer_rl.evaluation.paired import unseen_obstacle_differences

    _, difference = unseen_obstacle_differences(PAPER10K / "table3" / record, n_resamples=200)
    assert difference.n_robot_trials == 60
    assert difference.difference["sr"] == pytest.approx(expected_sr_difference, abs=5e-4)


# ----------------------------------------------------------------------------------------------------------
# The pages: every number of ours in results.md's tables, the README's caption and the model cards' result
# tables is recomputed from the committed records (the paper's from paper_results), so a page that drifts from
# its records fails here.

ROOT = DATA_SCALING.parents[2]
RESULTS_PAGE = ROOT / "docs" / "results.md"
BASELINES = DATA_SCALING.parent / "baselines"


def _shipped_and_baselines(table: str) -> dict[str, Path]:
    """One paper table's records: the shipped NavFormer and DT (seed 0, iteration 10,000), VRW, FCA."""
    return {
        "navformer": PAPER10K / table / "navformer_10k_s0_runb_it10000",
        "dt": PAPER10K / table / "dt_10k_s0_it10000",
        "vrw": BASELINES / table / "vrw",
        "fca": BASELINES / table / "fca",
    }


T1, T2, T3 = (_shipped_and_baselines(table) for table in ("table1", "table2", "table3"))

PAPER_NAMES = {
    "navformer": "NavFormer",
    "dt": "DT",
    "vrw": "VRW",
    "fca": "FCA",
    "dsac": "DSAC",
    "matdn": "MA-TDN",
}


def _page_tables(path: Path) -> list[tuple[str, list[list[str]]]]:
    """``(heading, rows)`` of every markdown table of ``path`` in order: ``heading`` the last ``#`` line above
    it ("" before the first), ``rows`` the cells of each row after the separator, bold and escapes removed."""
    tables: list[tuple[str, list[list[str]]]] = []
    heading, rows, in_table = "", None, False
    for line in path.read_text().splitlines():
        if line.startswith("#") and not in_table:
            heading = line.lstrip("#").strip()
        if line.startswith("|"):
            cells = [
                c.strip().replace("**", "").replace("\\*", "*") for c in line.strip().strip("|").split("|")
            ]
            if not in_table:
                rows, in_table = [], True
                tables.append((heading, rows))
            elif not all(set(c) <= set("-: ") for c in cells):
                rows.append(cells)
        else:
            in_table = False
    return tables


def _table_under(heading: str, index: int = 0) -> list[list[str]]:
    found = [rows for title, rows in _page_tables(RESULTS_PAGE) if title == heading]
    assert len(found) > index, f"results.md has no table {index} under {heading!r}"
    return found[index]


def _summaries(folder: Path) -> dict:
    from navformer_rl.evaluation.tables import read_records, summarize_by_setup

    return {s.setup: s.metrics for s in summarize_by_setup(read_records(folder / "episodes.jsonl"))}


def _ours(m) -> str:
    """SR [95 % interval] / SPL / CR, as results.md writes a measured cell."""
    return f"{100 * m.sr:.1f} % [{100 * m.sr_ci[0]:.1f}, {100 * m.sr_ci[1]:.1f}] / {m.spl:.2f} / {m.cr:.2f}"


def _paired(row, metric: str = "sr") -> str:
    """A paired difference with its interval (SR in points), ``*`` where the interval excludes zero."""
    low, high = row.interval[metric]
    scale, digits = (100, 1) if metric == "sr" else (1, 3)
    difference, low, high = (f"{scale * x:+.{digits}f}" for x in (row.difference[metric], low, high))
    text = f"{difference} [{low}, {high}]"
    return text + (" *" if row.excludes_zero(metric) else "")


def _percent(fraction: float) -> str:
    """A paper SR (published to two decimals of a percent) to one decimal, halves rounded up."""
    from decimal import ROUND_HALF_UP, Decimal

    return str(Decimal(f"{100 * fraction:.2f}").quantize(Decimal("0.1"), rounding=ROUND_HALF_UP))


def _paper(sr: float, spl: float, cr: float) -> str:
    return f"{_percent(sr)} % / {spl:.2f} / {cr:.2f}"


def _paper_table1_pooled(method: str) -> tuple[float, float, float]:
    """Table I's nine rows pooled as ours are: each setup weighted by its robot-trials (60 x robots)."""
    from navformer_rl.evaluation.paper_results import TABLE1

    weight = sum(robots for _, robots in TABLE1)
    return tuple(
        sum(robots * TABLE1[(size, robots)][method][k] for size, robots in TABLE1) / weight for k in range(3)
    )


def _setup_key(setup: str) -> tuple[float, int]:
    size, robots = setup.split("m-")
    return float(size), int(robots.rstrip("r"))


def test_the_headline_table_is_the_records_beside_the_paper() -> None:
    """results.md's first table: per paper table, the paper's NavFormer and DT, ours, and NavFormer - DT."""
    from navformer_rl.evaluation.paper_results import TABLE2, TABLE3, TABLE4

    (title, rows), *_ = _page_tables(RESULTS_PAGE)
    assert title == "Results" and [row[0].split(":")[0] for row in rows] == [
        "[I](#table-i-unseen-mazes-viia)", "[II](#table-ii-furnished-worlds-viib)",
        "[III](#table-iii-unseen-obstacle-robots-viic)", "[III](#table-iii-unseen-obstacle-robots-viic)",
        "[IV](#table-iv-ablations-viid)",
    ]  # fmt: skip
    paper_rows = [
        (_paper_table1_pooled("NavFormer"), _paper_table1_pooled("DT")),
        (TABLE2["NavFormer"], TABLE2["DT"]),
        (TABLE3["seen"]["NavFormer"], TABLE3["seen"]["DT"]),
        (TABLE3["unseen"]["NavFormer"], TABLE3["unseen"]["DT"]),
    ]
    ours = [(T1, "all"), (T2, "all"), (T3, "12.5m-4r-seen"), (T3, "12.5m-4r-unseen")]
    for row, (paper_nf, paper_dt), (table, setup) in zip(rows, paper_rows, ours):
        nf, dt = _summaries(table["navformer"])[setup], _summaries(table["dt"])[setup]
        pairs = {r.setup: r for r in paired_differences(table["navformer"], table["dt"])[1]}
        paper_difference = f"{100 * (paper_nf[0] - paper_dt[0]):+.1f}"
        expected = [_paper(*paper_nf).replace(" ¹", ""), _ours(nf), _paper(*paper_dt), _ours(dt)]
        assert [cell.replace(" ¹", "") for cell in row[1:5]] == expected, row[0]
        assert row[5] == f"{paper_difference} / {_paired(pairs[setup])}", row[0]
    table4 = rows[4]
    assert table4[1] == _paper(*TABLE4["NavFormer"]) + " (full model)" and table4[2] == "running"


def test_table1_section_is_the_records_per_setup() -> None:
    """Table I's per-setup table: NavFormer, DT, their paired difference, VRW and FCA from the records; the
    paper's six columns from paper_results; DSAC and MA-TDN marked as not re-measured."""
    from navformer_rl.evaluation.paper_results import TABLE1

    rows = _table_under("Table I: unseen mazes (§VII.A)")
    summaries = {name: _summaries(folder) for name, folder in T1.items()}
    pairs = {r.setup: r for r in paired_differences(T1["navformer"], T1["dt"])[1]}
    setups = list(summaries["navformer"])
    assert [row[0] for row in rows] == setups[:-1] + ["all 540 trials"] and len(setups) == 10
    for row, setup in zip(rows, setups):
        expected = [_ours(summaries[name][setup]) for name in ("navformer", "dt")] + [_paired(pairs[setup])]
        expected += [_ours(summaries["vrw"][setup]), _ours(summaries["fca"][setup]), "not re-measured"]
        paper = (
            ""
            if setup == "all"
            else " / ".join(
                _percent(TABLE1[_setup_key(setup)][PAPER_NAMES[m]][0])
                for m in ("navformer", "dt", "vrw", "fca", "dsac", "matdn")
            )
        )
        assert row[1:] == expected + [paper], setup


def test_table1_verdicts_follow_from_the_records() -> None:
    """The verdicts of 'What the numbers say', recomputed: DT ahead everywhere (significantly in six setups),
    the paper's DT inside or below our DT's interval, the paper's NavFormer above our NavFormer's, SR falling
    with world size at every robot count, NavFormer's CR above DT's."""
    from navformer_rl.evaluation.paper_results import TABLE1

    nf, dt = _summaries(T1["navformer"]), _summaries(T1["dt"])
    rows = paired_differences(T1["navformer"], T1["dt"])[1]
    assert all(r.difference["sr"] < 0 for r in rows)
    assert sorted(r.setup for r in rows[:-1] if not r.excludes_zero("sr")) == [
        "12.5m-4r",
        "12.5m-6r",
        "7.5m-2r",
    ]
    below_dt = []
    for setup in list(nf)[:-1]:
        paper = TABLE1[_setup_key(setup)]
        assert paper["DT"][0] <= dt[setup].sr_ci[1], setup  # inside or below our interval
        if paper["DT"][0] < dt[setup].sr_ci[0]:
            below_dt.append(setup)
        assert paper["NavFormer"][0] > nf[setup].sr_ci[1], setup  # above our interval
    assert below_dt == ["7.5m-2r", "12.5m-2r", "12.5m-4r", "17.5m-4r"]
    for summaries in (nf, dt):
        for robots in (2, 4, 6):
            srs = [summaries[f"{size}m-{robots}r"].sr for size in ("7.5", "12.5", "17.5")]
            assert srs == sorted(srs, reverse=True), robots
    assert _paired(rows[-1], "cr") == "+0.030 [+0.014, +0.046] *"
    text = RESULTS_PAGE.read_text()
    world = paired_differences(T1["navformer"], T1["dt"], cluster="world")[1][-1]
    low, high = world.interval["sr"]
    assert f"resampling whole mazes\n  instead of trials: [{100 * low:.1f}, {100 * high:.1f}]" in text


def test_table3_seen_row_is_table1s_12_5m_4r_setup() -> None:
    """Table III's seen trials are Table I's 12.5m-4r robot-trials: the same outcomes, robot by robot."""
    from navformer_rl.evaluation.tables import read_records

    for name in ("navformer", "dt"):
        seen = {
            (r.episode_id.split("/", 1)[1], r.robot): (r.success, r.spl, r.collision_rate, r.world_seed)
            for r in read_records(T3[name] / "episodes.jsonl")
            if r.setup == "12.5m-4r-seen"
        }
        table1 = {
            (r.episode_id.split("/", 1)[1], r.robot): (r.success, r.spl, r.collision_rate, r.world_seed)
            for r in read_records(T1[name] / "episodes.jsonl")
            if r.setup == "12.5m-4r"
        }
        assert len(seen) == 240 and seen == table1, name


CARDS = ROOT / "navformer_rl" / "pretrained" / "weights"
CONTEXT_T1, CONTEXT_T3, WINDOW16_T1, WINDOW16_T3 = (
    CONTEXT / "table1",
    CONTEXT / "table3",
    WINDOW16 / "table1",
    WINDOW16 / "table3",
)
CARD_RECORDS = {
    "navformer": [PAPER10K / "navformer_10k_s0_runb_it10000", T1["navformer"], T3["navformer"]],
    "dt": [PAPER10K / "dt_10k_s0_it10000", T1["dt"], T3["dt"]],
    "navformer_tenth": [
        PAPER10K / "navformer_tenth_it02500",
        CONTEXT_T1 / "navformer",
        CONTEXT_T1 / "navformer_w16",
        CONTEXT_T3 / "navformer",
    ],
    "dt_tenth": [PAPER10K / "dt_tenth_it02500", CONTEXT_T1 / "dt", CONTEXT_T3 / "dt"],
    "navformer_window16": [
        WINDOW16 / "navformer_ctx16_it2500",
        WINDOW16_T1 / "navformer_ctx16",
        WINDOW16_T3 / "navformer_ctx16",
    ],
    "dt_window16": [WINDOW16 / "dt_ctx16_it2500", WINDOW16_T1 / "dt_ctx16", WINDOW16_T3 / "dt_ctx16"],
}
"""Each shipped model's card result sections, in order, and the committed record each one reports."""


def _card_sections(text: str) -> list[tuple[str, list[list[str]]]]:
    """``(the line under the heading, table rows)`` of every ``### ... on `protocol``` section of a card."""
    sections = []
    for block in text.split("\n### ")[1:]:
        lines = block.splitlines()
        rows = [
            [c.strip() for c in line.strip().strip("|").split("|")]
            for line in lines
            if line.startswith("|") and not line.startswith("|---")
        ][1:]
        sections.append((lines[2], rows))
    return sections


@pytest.mark.parametrize("name", sorted(CARD_RECORDS))
def test_every_model_card_result_table_is_a_committed_record(name: str) -> None:
    """A card's result tables (written from run folders outside git) equal the committed records, row by
    row: the same episode set, trial counts, SR, SPL and CR with their intervals."""
    import json

    from navformer_rl.evaluation.tables import format_ratio, format_sr

    card = (CARDS / name / "MODEL_CARD.md").read_text()
    sections = _card_sections(card.split("## Results", 1)[1].split("\n## ", 1)[0])
    assert len(sections) == len(CARD_RECORDS[name])
    for (header, rows), record in zip(sections, CARD_RECORDS[name]):
        digest = json.loads((record / "run.json").read_text())["episode_set"]["content_sha256"]
        assert f"episode set sha256 {digest[:16]}..." in header, record
        summaries = _summaries(record)
        assert [row[0] for row in rows] == list(summaries), record
        for row in rows:
            m = summaries[row[0]]
            expected = [str(m.n_trials), str(m.n_robot_trials), format_sr(m.sr, m.sr_ci),
                        format_ratio(m.spl, m.spl_ci), format_ratio(m.cr, m.cr_ci)]  # fmt: skip
            assert row[1:] == expected, (record, row[0])
        assert f"`{record.relative_to(ROOT)}`" in card, (
            f"the card names its record {record.relative_to(ROOT)}"
        )


def test_the_readme_caption_quotes_the_records() -> None:
    """The README's three caption lines: the shipped NavFormer's and DT's Table I SR, the paper's range."""
    from navformer_rl.evaluation.paper_results import TABLE1

    caption = (ROOT / "README.md").read_text().split("\n\n*The shipped", 1)[1].split("*\n", 1)[0]
    assert len(caption.splitlines()) == 3
    nf, dt = _summaries(T1["navformer"])["all"].sr, _summaries(T1["dt"])["all"].sr
    paper = [TABLE1[setup]["NavFormer"][0] for setup in TABLE1]
    assert f"it reaches {100 * nf:.1f} % SR over Table I" in caption
    assert f"DT trained the same way {100 * dt:.1f} %" in caption
    dt_s1 = _summaries(PAPER10K / "table1" / "dt_10k_s1")["all"].sr
    assert f"(training seed 0; seed 1: {100 * dt_s1:.1f} %)" in caption
    assert f"{100 * min(paper):.0f}-{100 * max(paper):.0f} % per setup" in caption
    assert "steps 0, 167, 333 and 500\n(0-100 s of the trial)" in caption  # 0.2 s per step


@pytest.mark.parametrize(
    ("name", "phrases"),
    [
        (
            "navformer",
            (
                "It reaches {nf:.1f} % SR over Table I's nine setups",
                "({nf75:.1f} % at 7.5 m with 2 robots",
                "{nf_tenth:.1f} points above pretrained:navformer_tenth",
                "{nf_dt_tenth:.1f} above pretrained:dt_tenth",
                "but {dt_nf:.1f} points below pretrained:dt",
            ),
        ),
        (
            "dt",
            (
                "It reaches {dt:.1f} % SR over Table I's nine setups",
                "({dt75:.1f} % at 7.5 m with 2 robots",
                "{dt_nf:.1f} points above pretrained:navformer and {dt_tenth:.1f} above pretrained:dt_tenth",
            ),
        ),
    ],
)
def test_the_model_card_summaries_quote_the_records(name: str, phrases: tuple[str, ...]) -> None:
    nf, dt = _summaries(T1["navformer"]), _summaries(T1["dt"])

    def pooled(a: Path, b: Path) -> float:
        return 100 * paired_differences(a, b, n_resamples=200)[1][-1].difference["sr"]

    values = {
        "nf": 100 * nf["all"].sr,
        "nf75": 100 * nf["7.5m-2r"].sr,
        "dt": 100 * dt["all"].sr,
        "dt75": 100 * dt["7.5m-2r"].sr,
        "nf_tenth": pooled(T1["navformer"], CONTEXT_T1 / "navformer"),
        "nf_dt_tenth": pooled(T1["navformer"], CONTEXT_T1 / "dt"),
        "dt_nf": pooled(T1["dt"], T1["navformer"]),
        "dt_tenth": pooled(T1["dt"], CONTEXT_T1 / "dt"),
    }
    summary = (CARDS / name / "MODEL_CARD.md").read_text().split("\n\n")[1]
    for phrase in phrases:
        assert phrase.format(**values) in summary, phrase.format(**values)


def test_table2_section_is_the_records_per_world_kind() -> None:
    """Table II's table: each method over all 90 trials and per world kind, NavFormer - DT paired, the paper's
    pooled row beside; DSAC and MA-TDN not re-measured."""
    from navformer_rl.evaluation.paper_results import TABLE2

    rows = _table_under("Table II: furnished worlds (§VII.B)")
    summaries = {name: _summaries(folder) for name, folder in T2.items()}
    kinds = ["all", "bookstore", "house", "cafe"]  # the records' order: by the world's side
    assert all(list(s) == kinds[1:] + ["all"] for s in summaries.values())
    labels = ["NavFormer", "DT", "VRW", "FCA", "DSAC", "MA-TDN", "NavFormer - DT, paired (points)"]
    assert [row[0] for row in rows] == labels
    for row, name in zip(rows, ("navformer", "dt", "vrw", "fca")):
        s = summaries[name]
        expected = [_ours(s["all"])] + [f"{100 * s[kind].sr:.1f} %" for kind in kinds[1:]]
        assert row[1:] == expected + [_paper(*TABLE2[PAPER_NAMES[name]])], name
    for row, name in zip(rows[4:6], ("DSAC", "MA-TDN")):
        assert row[1:] == ["not re-measured", "", "", "", _paper(*TABLE2[name])], name
    pairs = {r.setup: r for r in paired_differences(T2["navformer"], T2["dt"])[1]}
    paper_difference = f"{100 * (TABLE2['NavFormer'][0] - TABLE2['DT'][0]):+.1f}"
    assert rows[6][1:] == [_paired(pairs[kind]) for kind in kinds] + [paper_difference]


def test_table3_section_is_the_records_seen_and_unseen() -> None:
    """Table III's two tables: each method among seen and unseen obstacle robots, and unseen - seen for the
    same robot, maze, start and target (`navformer evaluate unseen`) beside the paper's unpaired ones."""
    from navformer_rl.evaluation.paired import unseen_obstacle_differences
    from navformer_rl.evaluation.paper_results import TABLE3

    rows = _table_under("Table III: unseen obstacle robots (§VII.C)")
    summaries = {name: _summaries(folder) for name, folder in T3.items()}
    assert [row[0] for row in rows] == ["seen", "unseen"]
    for row, kind in zip(rows, ("seen", "unseen")):
        expected = [_ours(summaries[name][f"12.5m-4r-{kind}"]) for name in T3] + ["not re-measured"]
        paper = " / ".join(
            _percent(TABLE3[kind][PAPER_NAMES[m]][0])
            for m in ("navformer", "dt", "vrw", "fca", "dsac", "matdn")
        )
        assert row[1:] == expected + [paper], kind
    rows = _table_under("Table III: unseen obstacle robots (§VII.C)", 1)
    assert [row[0] for row in rows] == ["NavFormer", "DT", "VRW", "FCA", "paper NavFormer / DT (unpaired)"]
    for row, name in zip(rows, T3):
        _, d = unseen_obstacle_differences(T3[name])
        assert d.n_robot_trials == 60
        seen_unseen = f"{100 * d.b['sr']:.1f} % -> {100 * d.a['sr']:.1f} %"
        assert row[1:] == [seen_unseen, _paired(d), _paired(d, "spl"), _paired(d, "cr")], name
    both_rows = paired_differences(T3["navformer"], T3["dt"])[1][-1]
    assert f"both rows {_paired(both_rows)}" in " ".join(RESULTS_PAGE.read_text().split())
    paper = {m: [TABLE3[k][m] for k in ("seen", "unseen")] for m in ("NavFormer", "DT")}
    assert rows[4][1:] == [
        " / ".join(f"{_percent(seen[0])} % -> {_percent(unseen[0])} %" for seen, unseen in paper.values()),
        " / ".join(f"{100 * (unseen[0] - seen[0]):+.1f}" for seen, unseen in paper.values()),
        " / ".join(f"{unseen[1] - seen[1]:+.3f}" for seen, unseen in paper.values()),
        " / ".join(f"{unseen[2] - seen[2]:+.3f}" for seen, unseen in paper.values()),
    ]


def test_table4_section_lays_out_every_ablation_beside_the_paper() -> None:
    """Table IV's rows in the paper's order with its numbers; ours: the full NavFormer's 12.5m-4r row of
    Table I (Table IV's trials), the ablations marked as running until their records land."""
    from navformer_rl.evaluation.paper_results import ABLATION_TO_TABLE4, TABLE4

    rows = _table_under("Table IV: ablations (§VII.D)")
    assert [row[1].strip("`") for row in rows] == ["-", *ABLATION_TO_TABLE4]
    for row, paper_row in zip(rows, TABLE4):
        sr, spl, cr = TABLE4[paper_row]
        assert row[2] == f"{_percent(sr)} % / {spl:.3f} / {cr:.3f}", paper_row
    assert rows[0][3] == _ours(_summaries(T1["navformer"])["12.5m-4r"])
    assert {row[3] for row in rows[1:]} == {"running"}
    pairs = {r.setup: r for r in paired_differences(T1["dt"], T1["navformer"])[1]}
    text = " ".join(RESULTS_PAGE.read_text().split())
    assert f"DT - NavFormer is {_paired(pairs['12.5m-4r'])} points" in text


def test_the_prose_of_results_md_quotes_the_records() -> None:
    """The numbers in results.md's sentences, each recomputed from its record."""
    from navformer_rl.evaluation.diagnose import load_diagnosis

    text = " ".join(RESULTS_PAGE.read_text().split())
    nf, dt = _summaries(T1["navformer"]), _summaries(T1["dt"])
    rows = {r.setup: r for r in paired_differences(T1["navformer"], T1["dt"])[1]}
    assert f"SPL is lower too ({_paired(rows['all'], 'spl')})" in text.replace("\\*", "*")

    def span(summaries: dict, size: str) -> str:
        srs = [100 * summaries[f"{size}m-{robots}r"].sr for robots in (2, 4, 6)]
        return f"{int(min(srs) + 0.5)}-{int(max(srs) + 0.5)} %"  # halves rounded up

    assert (
        f"NavFormer {span(nf, '7.5')} at 7.5 m, {span(nf, '12.5')} at 12.5 m, {span(nf, '17.5')} at 17.5 m; "
        f"DT {span(dt, '7.5')[:-2]} %, {span(dt, '12.5')[:-2]} %, {span(dt, '17.5')[:-2]} %)" in text
    )
    assert f"{100 * nf['7.5m-2r'].sr:.1f} % against its 80.8 % at 7.5m-2r" in text
    vrw, fca = _summaries(T1["vrw"]), _summaries(T1["fca"])
    setups = [setup for setup in nf if setup != "all"]
    spans = {}
    for name, summaries in (("FCA", fca), ("VRW", vrw)):
        srs = [100 * summaries[setup].sr for setup in setups]
        spans[name] = f"{int(min(srs) + 0.5)}-{int(max(srs) + 0.5)} %"
    assert f"(FCA {spans['FCA']}, VRW {spans['VRW']} per setup;" in text
    assert f"reaches {spans['FCA']} per setup ({100 * fca['all'].sr:.1f} % overall)" in text
    assert f"VRW reaches {spans['VRW']} ({100 * vrw['all'].sr:.1f} %)" in text
    for setup in setups:  # FCA above both learned policies, VRW below, in every setup
        assert fca[setup].sr > max(nf[setup].sr, dt[setup].sr) and vrw[setup].sr < min(
            nf[setup].sr, dt[setup].sr
        )
    checkpoints = [
        _summaries(PAPER10K / "table1" / f"navformer_10k_s0_runb_it{i}")["all"].sr
        for i in ("05000", "06000", "07000")
    ]
    assert "reach {:.1f} / {:.1f} / {:.1f} %".format(*(100 * sr for sr in checkpoints)) in text
    window = PAPER10K / "table1" / "dt_10k_s0_it10000_w256"
    w256 = paired_differences(window, T1["dt"])[1][-1]
    assert f"reaches {100 * w256.a['sr']:.1f} % on Table I, paired {_paired(w256)}" in text
    diagnoses = {
        name: load_diagnosis(PAPER10K / "diagnosis" / f"{name}_it10000")["all"]
        for name in ("dt_10k_s0", "navformer_10k_s0_runb")
    }
    dt_d, nf_d = diagnoses["dt_10k_s0"], diagnoses["navformer_10k_s0_runb"]
    hidden = f"DT gets {dt_d['progress']['per_step_target_hidden']:.3f} m closer per step"
    assert hidden in text and f"NavFormer {nf_d['progress']['per_step_target_hidden']:.3f}" in text
    sight = [d["sightings"][0] for d in (dt_d, nf_d)]
    assert (
        "about as often ({:.0f} and {:.0f} % of robot-trials)".format(
            *(100 * s["robot_trials_with_sighting_fraction"] for s in sight)
        )
        in text
    )
    assert (
        "about as often once they have ({:.0f} and {:.0f} %)".format(
            *(100 * s["robot_trials_with_sighting_success_fraction"] for s in sight)
        )
        in text
    )
    (expert,) = summarize_seed_groups({"frontier": [EXPERT / "table1" / "frontier"]})
    m = expert.runs[0].metrics
    assert (
        f"reaches {100 * m.sr:.1f} % [{100 * m.sr_ci[0]:.1f}, {100 * m.sr_ci[1]:.1f}] on the same 540 trials"
        in text
    )
    table2 = paired_differences(T2["navformer"], T2["dt"])[1][-1]
    assert f"DT collides more (CR {_paired(table2, 'cr')}, NavFormer - DT)" in text.replace("\\*", "*")
    t2 = {name: _summaries(folder)["all"].sr for name, folder in T2.items()}
    assert (
        f"NavFormer falls from {100 * nf['all'].sr:.1f} % on Table I to {100 * t2['navformer']:.1f} %" in text
    )
    assert f"DT from {100 * dt['all'].sr:.1f} % to {100 * t2['dt']:.1f} %" in text
    assert (
        f"solves {100 * t2['fca']:.1f} % of these trials" in text
        and f"VRW reaches {100 * t2['vrw']:.1f} %" in text
    )
    cr = {name: _summaries(folder)["all"].cr for name, folder in T2.items()}
    learned = sorted((cr["navformer"], cr["dt"]))
    assert f"(CR {cr['vrw']:.2f} against their {learned[0]:.2f}-{learned[1]:.2f};" in text
    t3 = {name: _summaries(folder) for name, folder in T3.items()}
    seen_unseen = [
        100 * t3[name][f"12.5m-4r-{kind}"].sr for name in ("fca", "vrw") for kind in ("seen", "unseen")
    ]
    assert (
        "above both rows ({:.1f} and {:.1f} %), VRW below ({:.1f} and {:.1f} %)".format(*seen_unseen) in text
    )


def test_the_records_table_names_existing_folders_of_the_named_episode_sets() -> None:
    import json
    import re

    rows = _table_under("Records")
    assert len(rows) >= 9
    for row in rows:
        digest = re.search(r"\(`([0-9a-f]{12})`\)", row[2]).group(1)
        for folder in re.findall(r"`([a-z0-9_/.-]+)`", row[1]):
            path = DATA_SCALING.parent / folder
            run = json.loads(
                next(f for f in (path / "run.json", path / "diagnosis.json") if f.is_file()).read_text()
            )
            assert run["episode_set"]["content_sha256"].startswith(digest), folder


def test_deviations_quote_dts_window_from_the_records() -> None:
    """docs/deviations.md's DT-window row: DT at 256 steps against its own 341 and against NavFormer."""
    text = " ".join((ROOT / "docs" / "deviations.md").read_text().split())
    window = PAPER10K / "table1" / "dt_10k_s0_it10000_w256"
    own = paired_differences(window, T1["dt"])[1][-1]
    navformer = paired_differences(window, T1["navformer"])[1][-1]

    def bracket(row) -> str:
        return _paired(row).removesuffix(" *")

    assert (
        f"scores {100 * own.a['sr']:.1f} % on Table I's {own.n_robot_trials:,} robot-trials against "
        f"{100 * own.b['sr']:.1f} % with 341, paired {bracket(own)} points"
    ) in text
    assert f"still {bracket(navformer)} above `pretrained:navformer`" in text


STUDIES_PAGE = ROOT / "docs" / "studies.md"
DEMO_OPTIMISER = ROOT / "docs" / "results" / "demo_optimiser"


def _final_validation_loss(record: str, task: str) -> float:
    """The held-out action loss at a training record's last validation (iteration 200)."""
    rows = (DEMO_OPTIMISER / record / "validation" / f"loss_dt_{task}.csv").read_text().split()
    iteration, loss = rows[-1].split(",")
    assert int(iteration) == 200
    return float(loss)


def test_the_demo_scale_optimiser_table_quotes_its_training_records() -> None:
    """studies.md's table of the encoders' optimiser at the demo's scale: each row's records (named in the
    row) give its held-out losses, and each record trained with the setting its row names."""
    (rows,) = [
        r for title, r in _page_tables(STUDIES_PAGE) if title == "The encoders' optimiser at the demo's scale"
    ]
    assert len(rows) == 6
    for setting, records, exploration, collision in rows:
        names = [name.strip(" `") for name in records.split(",")]
        for task, cell in (("exploration", exploration), ("collision_avoidance", collision)):
            assert cell == ", ".join(f"{_final_validation_loss(n, task):.3f}" for n in names), (setting, task)
        for name in names:
            config = json.loads((DEMO_OPTIMISER / name / "train_config.json").read_text())
            assert config["optim"]["iterations"] == 200
            assert config["seed"] == int(name.rsplit("_s", 1)[1])
            expected = {
                "adam": ("none", "adam", 0.0004, 0.0004),
                "adam_wd0": ("none", "adam", 0.0004, 0.0),
                "adam_lr2e-4": ("none", "adam", 0.0002, 0.0004),
                "adamw": ("none", "adamw", 0.0004, 0.0004),
                "no_ssl": ("no_ssl", "adam", 0.0004, 0.0004),
                "dt": ("dt", "adamw", 0.0004, 0.0004),
            }[name.rsplit("_s", 1)[0]]
            optim = config["optim"]
            got = (config["ablation"], optim["encoder_optimizer"], optim["dve_lr"], optim["dve_weight_decay"])
            assert got == expected, name


PROBE_RECORDS = ROOT / "docs" / "results" / "probe"


def _probe_cells(record: str, features: str, quantity: str) -> tuple[str, str]:
    """``("NavFormer / DT", "DT - NavFormer [interval]")`` of a committed probe record."""
    probe = json.loads((PROBE_RECORDS / record / "probe.json").read_text())
    reference = probe["reference"]
    (other,) = [label for label in probe["results"] if label != reference]
    own = probe["results"][reference]["probes"][features][quantity]
    # DT's rows that repeat another are left out: its "all" is its one encoder, its "h_o" its head
    theirs = probe["results"][other]["probes"][{"all": "general", "h_o": "head"}.get(features, features)][
        quantity
    ]
    paired = probe["results"][other]["paired"][features][quantity]
    return (
        f"{own:.3f} / {theirs:.3f}",
        f"{paired['difference']:+.3f} [{paired['low']:+.3f}, {paired['high']:+.3f}]",
    )


def test_the_probe_table_quotes_its_records() -> None:
    """studies.md's probe table: every cell is its record's probe (NavFormer the reference, DT paired on the
    same frames), and the records probed the shipped weights on the same held-out frames."""
    (rows,) = [
        r
        for title, r in _page_tables(STUDIES_PAGE)
        if title == "What the encoders and the action head keep of a frame"
    ]
    expected = [
        ("paper10k", "all"),
        ("paper10k", "head"),
        ("tenth", "all"),
        ("tenth", "head"),
    ]
    assert len(rows) == len(expected)
    for row, (record, features) in zip(rows, expected, strict=True):
        cells = [
            c
            for quantity in ("linear", "in_view", "bearing")
            for c in _probe_cells(record, features, quantity)
        ]
        assert row[1] == {"all": "frames", "head": "head"}[features]
        assert row[2:] == cells, (record, features)
    for record, names in (("paper10k", ["navformer", "dt"]), ("tenth", ["navformer_tenth", "dt_tenth"])):
        probe = json.loads((PROBE_RECORDS / record / "probe.json").read_text())
        assert list(probe["checkpoints"].values()) == [f"pretrained:{n}" for n in names]
        assert probe["exploration"] == "data/paper_val/e" and probe["context_steps"] == 256
        frames = {label: r["frames"] for label, r in probe["results"].items()}
        assert all(f == {"fit": 16386, "test": 14245, "in_view_test": 1153} for f in frames.values())
    studies = " ".join(STUDIES_PAGE.read_text().split())  # line breaks as spaces
    alone = [_probe_cells(record, "h_o", "bearing") for record in ("paper10k", "tenth")]
    own = [cells[0].split(" / ")[0] for cells in alone]
    assert (
        f"NavFormer's h^ca_o gives the same (bearing R² {own[0]}, tenth scale {own[1]}; DT - NavFormer "
        f"{alone[0][1]} and {alone[1][1]})" in studies
    )
    results = RESULTS_PAGE.read_text()
    _, paired = _probe_cells("paper10k", "head", "bearing")
    own_and_dt = _probe_cells("paper10k", "head", "bearing")[0].split(" / ")
    assert f"(bearing R² {own_and_dt[0]} against {own_and_dt[1]}, paired {paired} for DT;" in results


def _target_reading(record: str, label: str) -> dict:
    probe = json.loads((PROBE_RECORDS / record / "probe.json").read_text())
    (result,) = [r for name, r in probe["results"].items() if name.split(",")[0] == label]
    return result["target_reading"]


def test_the_target_swap_sentences_quote_their_records() -> None:
    """studies.md's and results.md's "neither uses its target image": every number is a probe record's
    ``target_swap`` (held-out D_e at both scales, held-out D_ca)."""

    def pair(values: list[float], digits: int = 3) -> str:
        return "(" + ", ".join(f"{v:.{digits}f}" for v in values) + ")"

    def swap(record: str, label: str) -> dict:
        return _target_reading(record, label)["target_swap"]

    studies = " ".join(STUDIES_PAGE.read_text().split())
    nf, dt = swap("paper10k", "NavFormer"), swap("paper10k", "DT")
    assert (
        f"change NavFormer's action by a mean of {pair(nf['change'])} (linear, angular) and DT's by "
        f"{pair(dt['change'])}, against standard deviations of {pair(nf['own_sd'])} and {pair(dt['own_sd'])}"
        in studies
    )

    def share(value: float) -> str:
        return f"{100 * value:.1f} %"

    assert (
        f"(NavFormer {share(nf['own_toward'])} and {share(nf['swapped_toward'])}, "
        f"DT {share(dt['own_toward'])} and {share(dt['swapped_toward'])}; "
        f"the expert {share(nf['expert_toward'])})" in studies
    )
    nf_ca, dt_ca = swap("paper10k_ca", "NavFormer"), swap("paper10k_ca", "DT")
    nf_tenth, dt_tenth = swap("tenth", "NavFormer"), swap("tenth", "DT")
    assert (
        f"the same: {pair(nf_ca['change'])} and {pair(dt_ca['change'])} against {pair(nf_ca['own_sd'])} and "
        f"{pair(dt_ca['own_sd'])}; at the tenth scale {pair(nf_tenth['change'])} and "
        f"{pair(dt_tenth['change'])}." in studies
    )
    swaps = [nf, dt, nf_ca, dt_ca]
    assert max(max(s["change"]) for s in swaps) <= 0.003 + 5e-4  # "at most 0.003" in results.md
    sds = [v for s in swaps for v in s["own_sd"]]
    results = " ".join(RESULTS_PAGE.read_text().split())
    assert (
        f"changes by at most 0.003 (standard deviation over frames {min(sds):.2f}-{max(sds):.2f})" in results
    )
    assert all(s["swapped_toward"] >= s["own_toward"] - 0.005 for s in swaps)  # "not ... any less"
    terms = _target_reading("paper10k", "NavFormer")["head_terms"]
    assert (
        f"(sd {terms['target_term_sd'][0]:.4f} between targets, against "
        f"{terms['observation_term_sd'][0]:.3f} for the observation's term between frames), and with its "
        "target image swapped for another target's neither model changes its action by more than 0.003"
        in results
    )
    ca = json.loads((PROBE_RECORDS / "paper10k_ca" / "probe.json").read_text())
    assert ca["kind"] == "ca" and ca["exploration"] == "data/paper_val/ca"
    assert list(ca["checkpoints"].values()) == ["pretrained:navformer", "pretrained:dt"]


def test_the_target_reading_sentences_quote_their_records() -> None:
    """studies.md's THSC-term and attention bullets and results.md's THSC sentence: every number is the probe
    record's ``target_reading`` of the shipped weights."""

    def pair(values: list[float], digits: int) -> str:
        return "(" + ", ".join(f"{v:.{digits}f}" for v in values) + ")"

    studies = " ".join(STUDIES_PAGE.read_text().split())
    terms = {r: _target_reading(r, "NavFormer")["head_terms"] for r in ("paper10k", "tenth")}
    paper, tenth = terms["paper10k"], terms["tenth"]
    assert (
        f"it is {pair(paper['target_term_mean'], 3)} on (linear, angular) and varies between targets by a "
        f"standard deviation of {pair(paper['target_term_sd'], 4)}, against "
        f"{pair(paper['observation_term_sd'], 3)} for W_o h^ca_o between frames (tenth scale: "
        f"{pair(tenth['target_term_mean'], 3)}, {pair(tenth['target_term_sd'], 4)} against "
        f"{pair(tenth['observation_term_sd'], 3)})" in studies
    )
    navformer, dt = (_target_reading("paper10k", m)["attention_to_target"] for m in ("NavFormer", "DT"))

    def blocks(values: list[float]) -> str:
        return f"{values[0]:.3f}, {values[1]:.3f} and {values[2]:.3f}"

    assert (
        f"puts {blocks(navformer['all'])} of its attention on the target token in the three blocks, DT's "
        f"{blocks(dt['all'])}, and neither more when the target is in view (NavFormer "
        f"{navformer['in_view'][0]:.3f}, DT {dt['in_view'][0]:.3f} in the first block)" in studies
    )
    assert navformer["in_view"][0] <= navformer["out_of_view"][0] and dt["in_view"][0] <= dt["out_of_view"][0]
    assert navformer["all"][0] > dt["all"][0]
    results = " ".join(RESULTS_PAGE.read_text().split())
    assert (
        f"varies between targets by {paper['target_term_sd'][0]:.4f} (linear command) against "
        f"{paper['observation_term_sd'][0]:.3f} for the observation's term between frames" in results
    )


def test_the_other_target_sentence_quotes_its_diagnoses() -> None:
    """studies.md's closed-loop stays at other robots' targets: the 40-trial diagnoses of the shipped weights
    and of the exploration expert, on the same episodes."""
    records = {
        "navformer": PAPER10K / "diagnosis" / "navformer_10k_s0_runb_it10000",
        "dt": PAPER10K / "diagnosis" / "dt_10k_s0_it10000",
        "frontier": EXPERT / "diagnosis" / "frontier",
    }
    diagnoses = {k: json.loads((v / "diagnosis.json").read_text()) for k, v in records.items()}
    assert len({json.dumps(d["episode_set"], sort_keys=True) for d in diagnoses.values()}) == 1
    stay = {k: d["all"]["other_targets"]["lingered_fraction"] for k, d in diagnoses.items()}
    studies = " ".join(STUDIES_PAGE.read_text().split())
    assert (
        f"in {100 * stay['navformer']:.1f} % and {100 * stay['dt']:.1f} % of their robot-trials, the "
        f"exploration expert, which detects only its own target, in {100 * stay['frontier']:.1f} %" in studies
    )
    excess = [100 * (stay[k] - stay["frontier"]) for k in ("navformer", "dt")]
    assert f"the excess over the expert ({excess[0]:.1f} and {excess[1]:.1f} points)" in studies


@pytest.mark.parametrize("name, label", [("navformer", "NavFormer"), ("dt", "DT")])
def test_the_model_cards_target_image_failure_quotes_the_probe(name: str, label: str) -> None:
    """The shipped cards' "does not use its target image" failure mode: every number is the paper-scale
    probe record's."""
    card = (CARDS / name / "MODEL_CARD.md").read_text()
    failures = card.split("## Known failure modes", 1)[1].split("\n## ", 1)[0]
    reading = _target_reading("paper10k", label)
    swap = reading["target_swap"]
    change, sd = swap["change"], swap["own_sd"]
    assert (
        f"its action changes by {change[0]:.3f} (linear) and {change[1]:.3f} (angular) on average against "
        f"standard deviations of {sd[0]:.3f} and {sd[1]:.3f} over held-out frames" in failures
    )
    assert (
        f"({100 * swap['own_toward']:.1f} % with its own image, "
        f"{100 * swap['swapped_toward']:.1f} % with the other)" in failures
    )
    if "target_term_sd" in reading["head_terms"]:
        assert f"(sd {reading['head_terms']['target_term_sd'][0]:.4f} between targets)" in failures
    with_distractors = DATA_SCALING.parent / "distractors" / "table1_d4" / T1[name].name
    sr, sr_d4 = (_summaries(folder)["all"].sr for folder in (T1[name], with_distractors))
    assert f"take it from {100 * sr:.1f} % to {100 * sr_d4:.1f} % on Table I's trials" in failures


EPISODE_FILES = DATA_SCALING.parent / "episodes"
T2_NAMES = {"navformer": "NavFormer", "dt": "DT", "vrw": "VRW", "fca": "FCA"}
T2_ONE_TARGET = {
    "navformer": PAPER10K / "table2_one_target" / "navformer_10k_s0_runb_it10000",
    "dt": PAPER10K / "table2_one_target" / "dt_10k_s0_it10000",
    "vrw": BASELINES / "table2_one_target" / "vrw",
    "fca": BASELINES / "table2_one_target" / "fca",
}


@pytest.mark.parametrize(
    "name, records",
    [
        ("table1_60", T1),
        (
            "table1_60_d4",
            {n: DATA_SCALING.parent / "distractors" / "table1_d4" / T1[n].name for n in ("navformer", "dt")},
        ),
        ("table2", T2),
        ("table2_one_target", T2_ONE_TARGET),
        ("table3", T3),
    ],
)
def test_the_committed_episode_files_are_the_ones_the_records_ran(name: str, records: dict) -> None:
    from navformer_rl.evaluation.episodes import load_episode_set

    episode_set = load_episode_set(EPISODE_FILES / f"{name}.json.gz")
    for folder in records.values():
        run = json.loads((folder / "run.json").read_text())
        assert run["episode_set"]["content_sha256"] == episode_set.content_hash(), folder
    assert f"`{name}.json.gz`" in (EPISODE_FILES / "README.md").read_text()
    assert f"`{episode_set.content_hash()[:12]}...`" in (EPISODE_FILES / "README.md").read_text()


def test_table2_distractor_table_is_each_method_paired_with_its_one_target_run() -> None:
    """What the five distractors cost: each method on Table II's eight-target trials against the same robots
    with their own three targets only (two episode sets with one robots_hash)."""
    from navformer_rl.evaluation.episodes import load_episode_set
    from navformer_rl.evaluation.paired import pooled_paired_differences

    sets = [load_episode_set(EPISODE_FILES / f"{name}.json.gz") for name in ("table2", "table2_one_target")]
    assert sets[0].robots_hash() == sets[1].robots_hash()
    rows = _table_under("Table II: furnished worlds (§VII.B)", 1)
    assert [row[0] for row in rows] == list(T2_NAMES.values())
    for row, name in zip(rows, T2_NAMES):
        _, pairs = pooled_paired_differences([T2[name]], [T2_ONE_TARGET[name]], episode_sets=sets)
        d = pairs[-1]
        assert d.setup == "all" and d.n_robot_trials == 270
        expected = [f"{100 * d.b['sr']:.1f} % -> {100 * d.a['sr']:.1f} %"]
        expected += [_paired(d), _paired(d, "spl"), _paired(d, "cr")]
        assert row[1:] == expected, name


def test_studies_distractor_table_is_each_policy_paired_with_its_table1_run() -> None:
    """studies.md "What other targets cost in closed loop": each shipped policy on Table I with four
    distractors against its Table I record (the same robots), and NavFormer - DT without and with them."""
    from navformer_rl.evaluation.episodes import load_episode_set
    from navformer_rl.evaluation.paired import pooled_paired_differences

    sets = [load_episode_set(EPISODE_FILES / f"{name}.json.gz") for name in ("table1_60_d4", "table1_60")]
    assert sets[0].robots_hash() == sets[1].robots_hash()
    folders = {
        name: DATA_SCALING.parent / "distractors" / "table1_d4" / T1[name].name
        for name in ("navformer", "dt")
    }
    (rows,) = [
        r for title, r in _page_tables(STUDIES_PAGE) if title == "What other targets cost in closed loop"
    ]
    assert [row[0] for row in rows] == [
        "NavFormer (`pretrained:navformer`)", "DT (`pretrained:dt`)", "NavFormer - DT, paired",
    ]  # fmt: skip
    for row, name in zip(rows, ("navformer", "dt")):
        run = json.loads((folders[name] / "run.json").read_text())
        assert run["episode_set"]["content_sha256"] == sets[0].content_hash()
        _, pairs = pooled_paired_differences([folders[name]], [T1[name]], episode_sets=sets)
        by_setup = {d.setup: d for d in pairs}
        d = by_setup.pop("all")
        worst = min(by_setup.values(), key=lambda x: x.difference["sr"])
        expected = [f"{100 * d.b['sr']:.1f} % -> {100 * d.a['sr']:.1f} %"]
        expected += [_paired(d), _paired(d, "spl"), _paired(d, "cr"), f"{worst.setup}: {_paired(worst)}"]
        assert row[1:] == expected, name
    without = paired_differences(T1["navformer"], T1["dt"])[1][-1]
    with_them = paired_differences(folders["navformer"], folders["dt"])[1][-1]
    assert rows[2][1] == f"{_paired(without)} -> {_paired(with_them)}"


def test_results_md_quotes_the_distractor_study() -> None:
    """The "Why DT leads here" bullet on the target image quotes the Table I distractor records."""
    text = " ".join(RESULTS_PAGE.read_text().split())
    folders = {n: DATA_SCALING.parent / "distractors" / "table1_d4" / T1[n].name for n in ("navformer", "dt")}
    sr = {n: _summaries(T1[n])["all"].sr for n in folders}
    sr_d4 = {n: _summaries(folders[n])["all"].sr for n in folders}
    with_them = paired_differences(folders["navformer"], folders["dt"])[1][-1]
    assert (
        f"take NavFormer from {100 * sr['navformer']:.1f} % to {100 * sr_d4['navformer']:.1f} % and DT from "
        f"{100 * sr['dt']:.1f} % to {100 * sr_d4['dt']:.1f} %" in text
    )
    assert f"NavFormer's deficit shrinks to {_paired(with_them).removesuffix(' *')}." in text


def test_studies_distractor_diagnosis_quotes_its_records() -> None:
    """The "They stop at the objects that are not theirs" bullet: the four diagnoses' other-target measures
    and the chance level from the committed episode files."""
    import numpy as np

    from navformer_rl.evaluation.diagnose.trace import other_target_area
    from navformer_rl.evaluation.episodes import load_episode_set

    text = " ".join(STUDIES_PAGE.read_text().split())
    found = {}
    for suffix in ("", "_d4"):
        episodes = load_episode_set(EPISODE_FILES / f"table1_7.5m-2r{suffix}.json.gz")
        found[f"chance{suffix}"] = np.mean(np.concatenate([other_target_area(e) for e in episodes.episodes]))
        for name in ("navformer", "dt"):
            record = DATA_SCALING.parent / "distractors" / "diagnosis" / f"{name}_7.5m-2r{suffix}"
            diagnosis = json.loads((record / "diagnosis.json").read_text())
            assert diagnosis["episode_set"]["content_sha256"] == episodes.content_hash()
            found[f"{name}{suffix}"] = diagnosis["all"]["other_targets"]

    def pct(x: float) -> str:
        return f"{100 * x:.1f} %"

    nf, dt, nf4, dt4 = (found[k] for k in ("navformer", "dt", "navformer_d4", "dt_d4"))
    assert (
        f"rise from {pct(nf['lingered_fraction'])} to {pct(nf4['lingered_fraction'])} (NavFormer) and from "
        f"{pct(dt['lingered_fraction'])} to {pct(dt4['lingered_fraction'])} (DT), and "
        f"{pct(nf4['failures_ending_near_fraction'])} and {pct(dt4['failures_ending_near_fraction'])} of "
        f"their failures end there ({pct(nf['failures_ending_near_fraction'])} and "
        f"{pct(dt['failures_ending_near_fraction'])} without)" in text
    )
    assert f"{pct(found['chance_d4'])} of it with the distractors, {pct(found['chance'])} without" in text
    evaluation = " ".join((ROOT / "docs" / "evaluation.md").read_text().split())
    chance = f"7.5 m mazes with 2 robots: {pct(found['chance'])}, with four distractors "
    assert chance + pct(found["chance_d4"]) in evaluation


def test_dt_seed_1_on_table1_against_seed_0_and_navformer() -> None:
    """results.md "Three training seeds per model": DT seed 1's cells and the sentences under the table, each
    recomputed from the records (DT seeds 0 and 1, NavFormer seed 0)."""
    from navformer_rl.evaluation.paired import pooled_paired_differences

    table1 = PAPER10K / "table1"
    dt_s0, dt_s1 = table1 / "dt_10k_s0_it10000", table1 / "dt_10k_s1"
    navformer = table1 / "navformer_10k_s0_runb_it10000"
    (summary,) = summarize_seed_groups({"DT": [dt_s0, dt_s1]})
    assert [run.metrics.n_trials for run in summary.runs] == [540, 540]
    rows = {row[0]: row for row in _table_under("Three training seeds per model (running)")}
    seed1 = summary.runs[1].metrics
    assert rows["DT"][2] == f"{100 * seed1.sr:.1f} % [{100 * seed1.sr_ci[0]:.1f}, {100 * seed1.sr_ci[1]:.1f}]"
    assert rows["DT"][4] == f"seeds 0-1: {100 * summary.mean['sr']:.1f} ± {100 * summary.std['sr']:.1f} %"
    _, pooled_rows = pooled_paired_differences([navformer], [dt_s0, dt_s1])
    pooled = {row.setup: row for row in pooled_rows}
    cell = rows["NavFormer - DT, paired (points)"][4].replace("\\*", "*")
    assert cell == f"NavFormer seed 0 - DT seeds 0-1: {_paired(pooled['all'])}"
    seed_gap, against_s0, against_s1 = (
        paired_differences(a, b)[1][-1] for a, b in ((dt_s1, dt_s0), (navformer, dt_s0), (navformer, dt_s1))
    )
    assert seed_gap.n_robot_trials == against_s1.n_robot_trials == 2160
    text = " ".join(RESULTS_PAGE.read_text().split()).replace("\\*", "*")
    assert f"**The seed moves DT by {-100 * seed_gap.difference['sr']:.1f} points**" in text
    assert f"seed 1 - seed 0 is {_paired(seed_gap)} on the same robot-trials" in text
    assert f"{_paired(against_s0)} against seed 0, {_paired(against_s1)} against seed 1" in text
    assert f"12.5m-2r ({_paired(pooled['12.5m-2r'])} against both seeds)" in text
    assert f"17.5m-2r ({_paired(pooled['17.5m-2r'])})" in text
    assert f"({_paired(pooled['all'], 'spl')} pooled)" in text
    assert all(row.difference["spl"] < 0 for row in pooled_rows)
    assert sum(row.excludes_zero("spl") for row in pooled_rows if row.setup != "all") == 8


def test_the_second_dt_seeds_probe_sentence_quotes_its_record() -> None:
    """studies.md's "A second DT training seed reads the same": DT seed 1's probe beside the shipped pair."""
    probe = json.loads((PROBE_RECORDS / "paper10k_dt_10k_s1" / "probe.json").read_text())
    assert probe["reference"] == "NavFormer"
    assert list(probe["checkpoints"].values())[:2] == ["pretrained:navformer", "pretrained:dt"]
    seed1 = probe["results"]["dt_10k_s1"]
    assert seed1["frames"] == {"fit": 16386, "test": 14245, "in_view_test": 1153}

    def paired(features: str, quantity: str) -> str:
        p = seed1["paired"][features][quantity]
        return f"{p['difference']:+.3f} [{p['low']:+.3f}, {p['high']:+.3f}]"

    swap = seed1["target_reading"]["target_swap"]
    change, sd = ("(" + ", ".join(f"{v:.3f}" for v in swap[k]) + ")" for k in ("change", "own_sd"))
    studies = " ".join(STUDIES_PAGE.read_text().split())
    assert f"better than NavFormer's ({paired('all', 'linear')})" in studies
    assert (
        f"bearing ({seed1['probes']['head']['bearing']:.3f}; {paired('head', 'bearing')}), and a swapped "
        f"target image changes its action by {change} against standard deviations of {sd}" in studies
    )


def test_studies_where_navformer_loses_to_dt_quotes_its_diagnoses() -> None:
    """studies.md "Where NavFormer loses to DT on Table I": the paired shares and every measure of the
    three diagnoses on Table I's 12.5m-2r and 17.5m-2r trials, from the committed records."""
    from navformer_rl.evaluation.diagnose import load_diagnosis, paired_robot_trial_shares
    from navformer_rl.evaluation.episodes import load_episode_set

    folder = PAPER10K / "diagnosis" / "table1_2r_large"
    names = ("navformer_10k_s0", "dt_10k_s0", "dt_10k_s1", "frontier")
    diagnoses = [load_diagnosis(folder / name) for name in names]
    episodes = load_episode_set(EPISODE_FILES / "table1_2r_large.json.gz")
    assert {d["episode_set"]["content_sha256"] for d in diagnoses} == {episodes.content_hash()}
    assert f"content_sha256 `{episodes.content_hash()[:12]}...`" in " ".join(STUDIES_PAGE.read_text().split())
    table1 = {e.episode_id: e for e in load_episode_set(EPISODE_FILES / "table1_60.json.gz").episodes}
    assert all(table1[e.episode_id] == e for e in episodes.episodes)  # Table I's own trials
    first, second = (
        r for title, r in _page_tables(STUDIES_PAGE) if title == "Where NavFormer loses to DT on Table I"
    )

    def pct(x: float) -> str:
        return f"{100 * x:.1f} %"

    def points(share) -> str:
        low, high = share.interval
        star = " *" if share.excludes_zero() else ""
        return f"{100 * share.difference:+.1f} [{100 * low:+.1f}, {100 * high:+.1f}]{star}"

    pairs = [paired_robot_trial_shares(folder / names[0], folder / name) for name in names[1:]]
    assert all(p["success"].n_robot_trials == 240 and p["success"].n_trials == 120 for p in pairs)
    for row, measure in zip(first, ("success", "sighted", "stuck"), strict=True):
        shares = [pairs[0][measure].a, *(p[measure].b for p in pairs)]
        assert row[1:] == [*map(pct, shares), *(points(p[measure]) for p in pairs[:2])], measure
    sightings = [{s["range_m"]: s for s in d["all"]["sightings"]} for d in diagnoses]
    expected = [
        [pct(s[3.0]["robot_trials_with_sighting_success_fraction"]) for s in sightings],
        [pct(s[6.0]["first_sighting_arrive_fraction"]) for s in sightings],
        [f"{d['all']['progress']['per_step_target_hidden']:.3f} m" for d in diagnoses],
        [pct(d["all"]["progress"]["net_fraction_of_l"]) for d in diagnoses],
        [f"{d['all']['progress']['driven_per_step']:.3f} m" for d in diagnoses],
        [pct(d["all"]["other_targets"]["near_step_fraction"]) for d in diagnoses],
    ]
    assert [row[1:] for row in second] == expected
    # the derived numbers of the bullets: SR without a sighting, and NavFormer at DT's sighting rate
    rows = [
        [json.loads(line) for line in (folder / name / "robot_trials.jsonl").read_text().splitlines()]
        for name in names[:3]
    ]
    unseen = [
        sum(r["outcome"] == "success" for r in model if r["first_sighting_step"] is None)
        / sum(r["first_sighting_step"] is None for r in model)
        for model in rows
    ]
    studies = " ".join(STUDIES_PAGE.read_text().split())
    assert f"({100 * min(unseen):.0f}-{100 * max(unseen):.0f} % for all three)" in studies
    own = sightings[0][3.0]["robot_trials_with_sighting_success_fraction"]
    dt_rate = (pairs[0]["sighted"].b + pairs[1]["sighted"].b) / 2
    at_dt_rate = dt_rate * own + (1 - dt_rate) * unseen[0]
    assert f"NavFormer would reach about {100 * at_dt_rate:.0f} %" in studies
    dt_sr = (pairs[0]["success"].b + pairs[1]["success"].b) / 2
    nf_sr = pairs[0]["success"].a
    assert round(3 * (at_dt_rate - nf_sr) / (dt_sr - nf_sr)) == 2  # "two thirds of the way to DT"
    results = " ".join(RESULTS_PAGE.read_text().split()).replace("\\*", "*")
    sighted = [points(p["sighted"]) for p in pairs[:2]]
    assert f"({sighted[0]} against seed 0, {sighted[1]} against seed 1)" in results


def test_studies_two_against_four_robots_at_every_checkpoint() -> None:
    """studies.md's "Not one checkpoint's luck": SR with two robots minus SR with four in the 12.5 m and
    17.5 m mazes, for NavFormer's four Table I checkpoints and both DT seeds."""
    table1 = PAPER10K / "table1"

    def gains(record: str) -> list[float]:
        sr = {setup: m.sr for setup, m in _summaries(table1 / record).items()}
        return [100 * (sr[f"{size}-2r"] - sr[f"{size}-4r"]) for size in ("12.5m", "17.5m")]

    navformer = [gains(f"navformer_10k_s0_runb_it{i:05d}") for i in (5000, 6000, 7000, 10000)]
    dt = [gains(record) for record in ("dt_10k_s0_it10000", "dt_10k_s1")]
    low, high = min(map(min, navformer)), max(map(max, navformer))
    dt_low, dt_high = min(map(min, dt)), max(map(max, dt))
    text = " ".join(STUDIES_PAGE.read_text().split())
    assert f"lies between {low:.1f} and {high:+.1f} points of its SR with four robots" in text
    assert f"DT's lies {dt_low:.1f} to {dt_high:.1f} points above it with either seed" in text


def test_studies_what_the_policies_take_from_frames_and_past_actions_quotes_the_knockouts() -> None:
    """studies.md "What the policies take from their frames and from their past actions" and results.md's
    bullet: every loss and rise from the committed probes' ``encoder_knockout``."""
    heading = "What the policies take from their frames and from their past actions"
    (rows,) = [r for title, r in _page_tables(STUDIES_PAGE) if title == heading]

    def knockout(record: str, label: str) -> dict:
        return json.loads((PROBE_RECORDS / record / "probe.json").read_text())["results"][label][
            "encoder_knockout"
        ]

    def rise(row: dict, share_of: float | None = None) -> str:
        value, low, high = (round(row[k], 4) + 0.0 for k in ("increase", "low", "high"))  # no "-0.0000"
        text = f"{value:+.4f} [{low:+.4f}, {high:+.4f}]"
        return text if share_of is None else f"{text} (+{round(100 * row['increase'] / share_of)} %)"

    expected = {
        "NavFormer (`pretrained:navformer`)": ("paper10k", "NavFormer"),
        "DT (`pretrained:dt`)": ("paper10k", "DT"),
        "DT, seed 1 (`dt_10k_s1`)": ("paper10k_dt_10k_s1", "dt_10k_s1"),
        "NavFormer, tenth scale": ("tenth", "NavFormer, tenth"),
        "DT, tenth scale": ("tenth", "DT, tenth"),
    }
    assert [row[0] for row in rows] == list(expected)
    for row, (record, label) in zip(rows, expected.values(), strict=True):
        k = knockout(record, label)
        encoders = k["encoders"]
        two = "static" in encoders
        assert row[1] == f"{k['loss']:.4f}"
        assert row[2] == (rise(encoders["static"]) if two else "")
        assert row[3] == rise(encoders["general"], k["loss"])
        assert row[4] == (rise(encoders["all"]) if two else "")
        assert row[5] == rise(encoders["past_actions"])
    # the paper10k probe's DT is the same checkpoint on the same frames as paper10k_dt_10k_s1's
    assert knockout("paper10k", "DT") == knockout("paper10k_dt_10k_s1", "DT")
    studies = " ".join(STUDIES_PAGE.read_text().split())
    nf, ca_nf, ca_dt = (
        knockout("paper10k", "NavFormer"),
        knockout("paper10k_ca", "NavFormer"),
        knockout("paper10k_ca", "DT"),
    )
    sd = json.loads((PROBE_RECORDS / "paper10k" / "probe.json").read_text())["results"]["NavFormer"][
        "target_reading"
    ]["target_swap"]["own_sd"]
    change = nf["encoders"]["static"]["change"]
    assert (
        f"moves by a mean of ({change[0]:.3f}, {change[1]:.3f}) (linear, angular; standard deviations over "
        f"frames {sd[0]:.3f}, {sd[1]:.3f})" in studies
    )
    assert f"on held-out D_ca ({rise(ca_nf['encoders']['static'])})" in studies
    assert (
        f"(NavFormer to {nf['encoders']['past_actions']['loss']:.4f}, DT to "
        f"{knockout('paper10k', 'DT')['encoders']['past_actions']['loss']:.4f} and "
        f"{knockout('paper10k_dt_10k_s1', 'dt_10k_s1')['encoders']['past_actions']['loss']:.4f})" in studies
    )
    assert f"level ({rise(ca_nf['encoders']['general'])} and {rise(ca_dt['encoders']['general'])})" in studies
    dt0, dt1 = knockout("paper10k", "DT"), knockout("paper10k_dt_10k_s1", "dt_10k_s1")
    assert (
        f"without both encoders {rise(nf['encoders']['all'])} against {rise(dt0['encoders']['general'])} and "
        f"{rise(dt1['encoders']['general'])} for DT's two seeds" in studies
    )
    results = " ".join(RESULTS_PAGE.read_text().split())
    assert (
        f"NavFormer's action moves by ({change[0]:.3f}, {change[1]:.3f}) and its held-out action loss by "
        f"{rise(nf['encoders']['static'])} (the same at the tenth scale)" in results
    )
    tenth = knockout("tenth", "NavFormer, tenth")["encoders"]["static"]
    assert tenth["low"] < 0 < tenth["high"]  # "the same at the tenth scale": an interval around zero
    assert (
        f"leaves NavFormer's action loss where it is ({rise(nf['encoders']['static'])}; the same at the "
        f"tenth scale); replacing its frame embeddings raises it by {rise(nf['encoders']['all'])}, DT's by "
        f"{rise(dt0['encoders']['general'])} (seed 1: {rise(dt1['encoders']['general'])})" in results
    )


def test_studies_dt_checkpoint_series_of_knockouts_quotes_its_record() -> None:
    """studies.md "Training deepens the reliance on past actions": DT seed 1's checkpoints in the record."""
    record = json.loads((PROBE_RECORDS / "checkpoints" / "dt_10k_s1" / "probe.json").read_text())
    assert record["reference"] == "NavFormer" and record["context_steps"] == 256
    k = {label: r["encoder_knockout"] for label, r in record["results"].items()}
    first, middle, last = (k[f"dt_10k_s1_it{i:05d}"] for i in (1000, 5000, 10000))
    assert (
        last
        == json.loads((PROBE_RECORDS / "paper10k_dt_10k_s1" / "probe.json").read_text())["results"][
            "dt_10k_s1"
        ]["encoder_knockout"]
    )  # the final checkpoint on the same windows reads as in the seed's own record
    studies = " ".join(STUDIES_PAGE.read_text().split())

    def share(row: dict, loss: float) -> str:
        return f"{round(100 * row['increase'] / loss)} %"

    past = (first["encoders"]["past_actions"], last["encoders"]["past_actions"])
    assert (
        f"the held-out loss falls from {first['loss']:.4f} to {last['loss']:.4f} while the rise without the "
        f"past actions grows from {past[0]['increase']:+.4f} to {past[1]['increase']:+.4f} "
        f"({share(past[0], first['loss'])} to {share(past[1], last['loss'])} of the loss); the rise without "
        f"the frames falls from {first['encoders']['general']['increase']:+.4f} to "
        f"{middle['encoders']['general']['increase']:+.4f} at 5,000 and comes back to "
        f"{last['encoders']['general']['increase']:+.4f}" in studies
    )
