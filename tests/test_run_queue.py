"""recipes/paper_scale/run_queue.sh: the queue of long jobs runs each job once, in order, skips a failed one,
stops on STOP, leaves a job killed by a signal to the next start, and the committed study queue is well
formed."""

from __future__ import annotations

import os
import signal
import subprocess
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
    assert name.isidentifier() and command.startswith("navformer ")
    shallow = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--is-shallow-repository"], capture_output=True, text=True
    )
    if shallow.returncode != 0 or shallow.stdout.strip() != "false":
        pytest.skip("not a full git clone: the queue's revisions cannot be checked")
    assert subprocess.run(["git", "-C", str(ROOT), "cat-file", "-e", f"{code}^{{commit}}"]).returncode == 0
