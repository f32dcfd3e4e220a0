#!/usr/bin/env python3
"""Where a queue of run_queue.sh stands: each job's state, and how far the running one has got.

    recipes/paper_scale/queue_status.py QUEUE RUN_DIR [--all]

States: done (with its seconds), failed (its log), running (training: its newest checkpoint of
``optim.iterations``; evaluation: its finished episodes of those in its episode file), waiting. Without --all
only the last three done jobs and the next five waiting ones are listed. It reads the queue file and RUN_DIR
only (the standard library, no navformer_rl), so it runs from any shell while the queue works; run it from
the repository root, as the queue's jobs are.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Job:
    """One line of a queue file: NAME <tab> CODE <tab> COMMAND."""

    name: str
    code: str
    command: str


def read_queue(path: Path) -> list[Job]:
    """The jobs of a queue file, in order ('#' lines and blank lines skipped)."""
    jobs = []
    for line in path.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        name, code, command = (line.split("\t", 2) + ["", ""])[:3]
        jobs.append(Job(name, code, command))
    return jobs


def runner_alive(run_dir: Path) -> int | None:
    """The runner's pid when one works on ``run_dir``, else None."""
    try:
        pid = int((run_dir / "runner.pid").read_text().strip())
        os.kill(pid, 0)
    except (OSError, ValueError):
        return None
    return pid


def running_job(run_dir: Path) -> tuple[str, str] | None:
    """(name, UTC start time) of the job the runner log last started and has not ended, else None."""
    log = run_dir / "runner.log"
    if not log.exists():
        return None
    current = None
    for line in log.read_text().splitlines():
        stamp, _, event = line.partition(" ")
        if event.startswith("start "):
            current = (event.split()[1], stamp)
        elif current and (f" {current[0]} " in f" {event} " or event.startswith("stopped")):
            current = None
    return current


def _arguments(command: str) -> list[str]:
    try:
        return shlex.split(command)
    except ValueError:
        return command.split()


def _value(words: list[str], flag: str) -> str | None:
    """The value of ``--flag VALUE`` or of ``key=VALUE`` among ``words``."""
    for i, word in enumerate(words):
        if flag.startswith("--") and word == flag and i + 1 < len(words):
            return words[i + 1]
        if not flag.startswith("--") and word.startswith(flag + "="):
            return word.split("=", 1)[1]
    return None


def _path(value: str) -> Path:
    return Path(value.replace("$PWD", os.getcwd()))


def progress(command: str) -> str:
    """How far a job's command has got, read from what it writes ('' when it cannot say)."""
    words = _arguments(command)
    if words[:2] == ["navformer", "train"]:
        output, iterations = _value(words, "output_dir"), _value(words, "optim.iterations")
        if output is None:
            return ""
        steps = [
            int(m.group(1))
            for p in (_path(output) / "checkpoints").glob("iter_*")
            if (m := re.fullmatch(r"iter_(\d+)", p.name))
        ]
        newest = max(steps, default=0)
        if iterations is None:
            return f"checkpoint {newest:,}"
        return f"checkpoint {newest:,} of {int(iterations):,} ({100 * newest / int(iterations):.0f} %)"
    if words[:2] == ["navformer", "evaluate"] and len(words) > 2 and words[2].startswith("-"):
        out, episodes = _value(words, "--out"), _value(words, "--episodes")
        if out is None:
            return ""
        finished = len(list((_path(out) / "per_episode").glob("*.json")))
        total = _episode_count(_path(episodes)) if episodes else None
        if total:
            return f"{finished:,} of {total:,} episodes ({100 * finished / total:.0f} %)"
        return f"{finished:,} episodes"
    return ""


def _episode_count(path: Path) -> int | None:
    try:
        return len(json.loads(path.read_text())["episodes"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def status_lines(queue: Path, run_dir: Path, show_all: bool = False) -> list[str]:
    """The report: a header, one line per job shown, and the counts."""
    jobs = read_queue(queue)
    pid = runner_alive(run_dir)
    current = running_job(run_dir) if pid else None
    states, rows = {"done": 0, "failed": 0, "running": 0, "waiting": 0}, []
    done_seconds = 0
    for job in jobs:
        if (run_dir / "done" / job.name).exists():
            mark = (run_dir / "done" / job.name).read_text().strip()
            if mark.isdigit():  # the runner's mark: the job's seconds
                done_seconds += int(mark)
                mark = f"{int(mark):,} s"
            state, detail = "done", mark
        elif (run_dir / "failed" / job.name).exists():
            reason = (run_dir / "failed" / job.name).read_text().strip()
            state, detail = "failed", f"{reason}; log: {run_dir / 'logs' / f'{job.name}.log'}"
        elif current and current[0] == job.name:
            state = "running"
            detail = ", ".join(filter(None, [progress(job.command), f"started {current[1]}"]))
        else:
            state, detail = "waiting", ""
        states[state] += 1
        rows.append((state, job.name, detail))
    done_rows = [row for row in rows if row[0] == "done"]
    waiting_rows = [row for row in rows if row[0] == "waiting"]
    shown = (
        {*rows}
        if show_all
        else {*done_rows[-3:], *waiting_rows[:5], *(r for r in rows if r[0] in ("failed", "running"))}
    )
    runner = f"running (pid {pid})" if pid else "not running"
    lines = [f"queue {queue}, run dir {run_dir}: runner {runner}"]
    hidden_done = sum(row not in shown for row in done_rows)
    if hidden_done:
        lines.append(f"  ... {hidden_done} more done (--all lists them)")
    width = max((len(name) for _, name, _ in rows), default=0)
    lines += [
        f"  {state:<8} {name:<{width}}  {detail}".rstrip()
        for state, name, detail in rows
        if (state, name, detail) in shown
    ]
    hidden_waiting = sum(row not in shown for row in waiting_rows)
    if hidden_waiting:
        lines.append(f"  ... {hidden_waiting} more waiting (--all lists them)")
    lines.append(
        f"{states['done']} of {len(jobs)} done ({done_seconds / 3600:.1f} h), {states['running']} running, "
        f"{states['waiting']} waiting, {states['failed']} failed"
    )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("queue", type=Path, help="the queue file (NAME <tab> CODE <tab> COMMAND lines)")
    parser.add_argument("run_dir", type=Path, help="the run folder the runner was given")
    parser.add_argument("--all", action="store_true", help="list every done job")
    args = parser.parse_args(argv)
    if not args.queue.is_file():
        print(f"queue_status.py: no queue file {args.queue}", file=sys.stderr)
        return 2
    if not args.run_dir.is_dir():
        print(
            f"queue_status.py: no run folder {args.run_dir}: expected the RUN_DIR given to run_queue.sh",
            file=sys.stderr,
        )
        return 2
    print("\n".join(status_lines(args.queue, args.run_dir, args.all)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
