"""recipes/paper_scale/run_queue.sh: the queue of long jobs runs each job once, in order, skips a failed one,
stops on STOP, leaves a job killed by a signal to the next start, and the committed study queue is well
formed; publish_record.sh copies a finished run into the committed records."""

from __future__ import annotations

import gzip
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RUNNER = ROOT / "recipes" / "paper_scale" / "run_queue.sh"
STUDY = ROOT / "recipes" / "paper_scale" / "seeds_and_ablations.tsv"


def write_queue(path: Path, jobs: list[tuple[str, str]]) -> Path:
    path.write_text("# NAME\tCODE\tCOMMAND\n" + "".join(f"{name}\t-\t{command}\n" for name, command in jobs))
    return path


def run(queue: Path, run_dir: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(RUNNER), str(queue), str(run_dir)], capture_output=True, text=True, timeout=60)


def test_jobs_run_once_in_order_and_a_failed_one_is_skipped(tmp_path):
    out = tmp_path / "out.txt"
    queue = write_queue(
        tmp_path / "q.tsv",
        [
            ("first", f"echo first >> {out}"),
            ("broken", "exit 3"),
            ("last", f"echo $OMP_NUM_THREADS >> {out}"),
        ],
    )
    assert run(queue, tmp_path / "run").returncode == 0
    assert out.read_text().split() == ["first", "2"]
    assert (tmp_path / "run/failed/broken").read_text().strip() == "exit 3"
    assert sorted(p.name for p in (tmp_path / "run/done").iterdir()) == ["first", "last"]
    assert run(queue, tmp_path / "run").returncode == 0  # everything done or failed: nothing reruns
    assert out.read_text().split() == ["first", "2"]
    (tmp_path / "run/failed/broken").unlink()  # deleting the mark retries the job
    write_queue(queue, [("first", "true"), ("broken", f"echo retried >> {out}"), ("last", "true")])
    assert run(queue, tmp_path / "run").returncode == 0
    assert out.read_text().split() == ["first", "2", "retried"]


def test_stop_file_and_a_job_killed_by_a_signal_resume_at_the_next_start(tmp_path):
    out, started = tmp_path / "out.txt", tmp_path / "started"
    queue = write_queue(
        tmp_path / "q.tsv",
        [("slow", f"echo run >> {out}; touch {started}; sleep 30; echo end >> {out}"), ("next", "true")],
    )
    runner = subprocess.Popen([str(RUNNER), str(queue), str(tmp_path / "run")])
    deadline = time.monotonic() + 20
    while not started.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert run(queue, tmp_path / "run").returncode == 1  # one runner per run folder
    os.kill(runner.pid, signal.SIGTERM)
    assert runner.wait(timeout=20) == 143
    assert not (tmp_path / "run/done/slow").exists() and not (tmp_path / "run/failed/slow").exists()
    write_queue(queue, [("slow", f"echo rerun >> {out}"), ("next", f"echo next >> {out}")])
    (tmp_path / "run/STOP").touch()
    assert run(queue, tmp_path / "run").returncode == 0  # STOP: nothing starts
    (tmp_path / "run/STOP").unlink()
    assert run(queue, tmp_path / "run").returncode == 0
    assert out.read_text().split() == ["run", "rerun", "next"]
    assert "stopped by a signal" in (tmp_path / "run/runner.log").read_text()


@pytest.mark.parametrize(
    "line", [line for line in STUDY.read_text().splitlines() if line and not line.startswith("#")]
)
def test_the_study_queue_names_committed_code_and_known_commands(line):
    name, code, command = line.split("\t")
    assert name.isidentifier()
    if name.startswith("pub_"):  # copies records in the working tree: test_each_study_publish_job_...
        assert code == "-" and command.startswith("recipes/paper_scale/publish_record.sh ")
        return
    assert command.startswith("navformer ")
    shallow = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--is-shallow-repository"], capture_output=True, text=True
    )
    if shallow.returncode != 0 or shallow.stdout.strip() != "false":
        pytest.skip("not a full git clone: the queue's revisions cannot be checked")
    assert subprocess.run(["git", "-C", str(ROOT), "cat-file", "-e", f"{code}^{{commit}}"]).returncode == 0


PUBLISH = ROOT / "recipes" / "paper_scale" / "publish_record.sh"


def study_jobs() -> list[tuple[str, str, str]]:
    return [
        tuple(line.split("\t"))
        for line in STUDY.read_text().splitlines()
        if line and not line.startswith("#")
    ]


def test_each_study_publish_job_copies_the_evaluation_before_it_into_its_label():
    jobs = study_jobs()
    published = 0
    for before, (name, code, command) in zip(jobs, jobs[1:]):
        if not name.startswith("pub_"):
            continue
        published += 1
        assert code == "-" and name == f"pub_{before[0]}"
        script, eval_dir, record, *train = command.split()
        assert script == "recipes/paper_scale/publish_record.sh"
        words = before[2].split()
        assert eval_dir == words[words.index("--out") + 1]
        assert record.startswith("docs/results/") and record.endswith("/" + words[words.index("--label") + 1])
        checkpoint = words[words.index("--checkpoint") + 1]
        assert train == (
            [checkpoint.split("/checkpoints/")[0]]
            if before[0].startswith("t1_") and "/train/" in checkpoint
            else []
        )
    assert published == sum(1 for name, _, _ in jobs if name.startswith("pub_")) > 0


def fake_runs(tmp_path: Path) -> tuple[Path, Path]:
    evaluation = tmp_path / "eval"
    evaluation.mkdir()
    (evaluation / "run.json").write_text('{"label": "x"}\n')
    (evaluation / "summary.md").write_text("| SR |\n")
    (evaluation / "episodes.jsonl").write_text('{"success": true}\n{"success": false}\n')
    train = tmp_path / "train"
    scalars = train / "logs" / "navformer" / "scalars"
    (scalars / "validation").mkdir(parents=True)
    (train / "train_config.json").write_text('{"seed": 1}\n')
    (scalars / "loss_dt.csv").write_text("10,0.5\n")
    (scalars / "lr.csv").write_text("10,0.0002\n")
    (scalars / "validation" / "loss_dt_exploration.csv").write_text("1000,0.1\n")
    return evaluation, train


def test_publish_record_copies_the_evaluation_and_the_training_losses(tmp_path):
    evaluation, train = fake_runs(tmp_path)
    record = tmp_path / "docs" / "label"
    done = subprocess.run(
        [str(PUBLISH), str(evaluation), str(record), str(train)], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert (record / "run.json").read_text() == '{"label": "x"}\n'
    assert (record / "summary.md").read_text() == "| SR |\n"
    assert (
        gzip.decompress((record / "episodes.jsonl.gz").read_bytes())
        == (evaluation / "episodes.jsonl").read_bytes()
    )
    copied = sorted(
        str(p.relative_to(record / "training")) for p in (record / "training").rglob("*") if p.is_file()
    )
    assert copied == [
        "scalars/loss_dt.csv",
        "scalars/validation/loss_dt_exploration.csv",
        "train_config.json",
    ]
    assert not list(record.rglob("*.tmp"))


@pytest.mark.parametrize("missing", ["eval/episodes.jsonl", "train/train_config.json"])
def test_publish_record_refuses_an_unfinished_folder_in_one_line(tmp_path, missing):
    evaluation, train = fake_runs(tmp_path)
    (tmp_path / missing).unlink()
    done = subprocess.run(
        [str(PUBLISH), str(evaluation), str(tmp_path / "record"), str(train)], capture_output=True, text=True
    )
    assert done.returncode == 2 and not (tmp_path / "record").exists()
    assert done.stderr.count("\n") == 1 and missing.split("/")[1] in done.stderr


STATUS = ROOT / "recipes" / "paper_scale" / "queue_status.py"


def queue_status(*args: Path | str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(STATUS), *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=30
    )


def test_queue_status_reads_each_jobs_state_and_the_running_ones_progress(tmp_path):
    (tmp_path / "episodes.json").write_text('{"episodes": [{"n_robots": 2}, {"n_robots": 4}]}')
    queue = tmp_path / "q.tsv"
    queue.write_text(
        "# NAME\tCODE\tCOMMAND\n"
        "collect\t-\tnavformer collect e --n 3 --out data/e\n"
        "broken\t-\texit 3\n"
        "train\tabc123\tnavformer train seed=1 output_dir=$PWD/runs/t resume=true optim.iterations=1000\n"
        "evaluate\t-\tnavformer evaluate --method dt --episodes episodes.json --out runs/ev --label x\n"
    )
    run_dir = tmp_path / "run"
    for folder in ("done", "failed", "logs"):
        (run_dir / folder).mkdir(parents=True)
    (run_dir / "done/collect").write_text("95\n")
    (run_dir / "failed/broken").write_text("exit 3\n")
    for step in (250, 500):
        (tmp_path / f"runs/t/checkpoints/iter_{step:06d}").mkdir(parents=True)
    (tmp_path / "runs/ev/per_episode").mkdir(parents=True)  # the evaluation's finished episodes
    (tmp_path / "runs/ev/per_episode/w00t00.json").write_text("{}")
    (run_dir / "runner.log").write_text(
        "2026-12-01T10:00:00Z start collect (code -)\n2026-12-01T10:01:35Z done collect in 95 s\n"
        "2026-12-01T10:02:00Z start train (code abc123)\n"
    )
    (run_dir / "runner.pid").write_text(f"{os.getpid()}\n")  # a live process stands in for the runner

    done = queue_status(queue, run_dir, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[1].split() == ["done", "collect", "95", "s"]
    assert lines[2].split()[:3] == ["failed", "broken", "exit"]
    assert "running  train     checkpoint 500 of 1,000 (50 %), started 2026-12-01T10:02:00Z" in lines[3]
    assert lines[4].split() == ["waiting", "evaluate"]
    assert lines[-1] == "1 of 4 done (0.0 h), 1 running, 1 waiting, 1 failed"

    # the evaluation running, the runner stopped by a signal before: only the last start counts
    with (run_dir / "runner.log").open("a") as log:
        log.write("2026-12-01T11:00:00Z stopped by a signal\n2026-12-01T11:05:00Z start evaluate (code -)\n")
    lines = queue_status(queue, run_dir, cwd=tmp_path).stdout.splitlines()
    assert lines[3].split()[:2] == ["waiting", "train"]
    assert "running  evaluate  1 of 2 episodes (50 %), started 2026-12-01T11:05:00Z" in lines[4]

    (run_dir / "runner.pid").unlink()  # no runner: nothing is running
    assert (
        "runner not running" in (lines := queue_status(queue, run_dir, cwd=tmp_path).stdout.splitlines())[0]
    )
    assert lines[-1].endswith("0 running, 2 waiting, 1 failed")


def test_queue_status_refuses_a_missing_run_folder_in_one_line(tmp_path):
    done = queue_status(STUDY, tmp_path / "nowhere", cwd=ROOT)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "nowhere" in done.stderr
