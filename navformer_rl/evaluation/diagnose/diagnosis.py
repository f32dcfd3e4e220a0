"""Diagnosing how a policy fails: run it on an episode set with per-step records, then measure the failures.

``diagnose(method, episode_set, out_dir, ...)`` plays every episode as ``navformer evaluate`` does (same
methods, checkpoint forms and seeds: :class:`~navformer_rl.evaluation.policy_spec.PolicySpec`), records
every robot's every step (:mod:`~navformer_rl.evaluation.diagnose.trace`) and writes into ``out_dir``:

- ``traces/<episode>.npz``: one per episode, written as soon as it ends (atomic); a rerun reuses the traces
  computed with the same method, checkpoint weights, seed, trial length and package version (``resume``);
- ``robot_trials.jsonl``: one row per measured robot-trial (episode, robot, outcome - success, stuck,
  circling or other failure -, first contact, steps to free, first sighting, geodesic at start and end), to
  find the episodes worth watching (``navformer evaluate --videos``);
- ``diagnosis.json``: the failure measures (:mod:`~navformer_rl.evaluation.diagnose.measures`) over every
  measured robot-trial (``all``) and per setup (``by_setup``), the experts' command distribution
  (``expert_commands``, with ``expert_data``) and the teacher-forced turns on held-out trajectories
  (``teacher_forced``, with ``held_out``; ``navformer`` / ``dt`` only);
- ``diagnosis.md``: the same as tables, with the folders of ``compare`` (other diagnoses of the same
  episodes, e.g. FCA and VRW) as further columns.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from navformer_rl import __version__
from navformer_rl.evaluation.diagnose.runner import TraceRunner, TraceTask, _init_worker, _run_in_worker
from navformer_rl.evaluation.diagnose.trace import TRACE_VERSION, load_trace, save_trace
from navformer_rl.evaluation.episodes import EpisodeSet, load_episode_set
from navformer_rl.evaluation.policy_spec import CHECKPOINT_METHODS, PolicySpec
from navformer_rl.utils.backends import LocalPool, run_units
from navformer_rl.utils.checks import check_int
from navformer_rl.utils.devices import resolve_device
from navformer_rl.utils.durable import atomic_write_json, atomic_write_text, folder_lock

FORMAT = "navformer_rl.diagnosis"
FORMAT_VERSION = 1
LOCK_FILENAME = ".diagnose.lock"
TRACES_DIRNAME = "traces"
SUMMARY_JSON = "diagnosis.json"
SUMMARY_MD = "diagnosis.md"
ROBOT_TRIALS = "robot_trials.jsonl"


def diagnose(
    method: str,
    episode_set: EpisodeSet | str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    checkpoint: str | os.PathLike | None = None,
    workers: int = 1,
    label: str | None = None,
    seed: int = 0,
    device: str = "cpu",
    expert_data: Mapping[str, str | os.PathLike] | None = None,
    held_out: Mapping[str, str | os.PathLike] | None = None,
    compare: Sequence[str | os.PathLike] = (),
    progress: bool = True,
    resume: bool = True,
    context_steps: int | None = None,
) -> dict[str, Any]:
    """Record ``method`` on every episode of ``episode_set`` and write the diagnosis (module docstring).

    Args:
        method: ``navformer``, ``dt``, ``vrw`` or ``fca``
            (:data:`~navformer_rl.evaluation.policy_spec.METHODS`).
        episode_set: an :class:`EpisodeSet` or the path of an episode-set file.
        out_dir: output folder (one diagnosis at a time: a second is refused while one runs).
        checkpoint: for ``navformer`` / ``dt``: run dir, checkpoint folder, ``model.safetensors`` or
            ``pretrained:NAME`` (resolved once to one checkpoint folder).
        workers: processes (1 runs here); the traces do not depend on it.
        label: the method's name in the tables (default ``method``).
        seed: base seed of stochastic policies, as ``navformer evaluate --seed``.
        device: where ``navformer`` / ``dt`` run their model (as in ``evaluate``).
        expert_data: ``{"e": folder, "ca": folder}`` (either or both): the expert datasets whose actions are
            set beside the policy's commands.
        held_out: ``{"e": folder, "ca": folder}``: held-out expert datasets for the teacher-forced turns
            (``navformer`` / ``dt`` only).
        compare: other diagnosis folders of the same episode set, shown as further columns of
            ``diagnosis.md`` (ValueError when one ran other episodes).
        progress: show a progress bar.
        resume: reuse stored traces of the same work; False recomputes every episode.
        context_steps: ``navformer`` / ``dt`` only: the timesteps the policy attends to (as in ``evaluate``;
            None: the window the checkpoint was trained on, else the model's whole context). Teacher-forced
            measures use the training windows regardless.

    Returns:
        The content of ``diagnosis.json``.
    """
    from navformer_rl.evaluation.diagnose.report import diagnosis_markdown

    if isinstance(episode_set, str | os.PathLike):
        episode_set = load_episode_set(episode_set)
    if not isinstance(episode_set, EpisodeSet) or len(episode_set) == 0:
        raise ValueError("episode_set must be a non-empty EpisodeSet or the path of an episode-set file")
    workers = check_int(workers, "workers")
    for name, datasets in (("expert_data (--expert-data)", expert_data), ("held_out (--held-out)", held_out)):
        for kind, path in (datasets or {}).items():
            if not Path(path).exists():
                raise FileNotFoundError(f"{name}: the {kind} dataset {str(path)!r} does not exist")
    if held_out and method not in CHECKPOINT_METHODS:
        raise ValueError(
            f"held_out (--held-out) needs a model to teacher-force: method navformer or dt, not {method!r}"
        )
    episode_hash = episode_set.content_hash()
    others = [_load_comparison(Path(folder), episode_hash) for folder in compare]
    if checkpoint is not None and method in CHECKPOINT_METHODS:
        from navformer_rl.training.checkpoint import resolve_checkpoint

        checkpoint = resolve_checkpoint(checkpoint)
    spec = PolicySpec(
        method,
        None if checkpoint is None else str(checkpoint),
        int(seed),
        device=device,
        context_steps=context_steps,
    )
    label = label or method
    description = spec.validate(label)
    identity: dict[str, Any] = {
        "method": method,
        "seed": int(seed),
        "max_steps": episode_set.max_steps,
        "checkpoint_sha256": description.get("checkpoint_sha256"),
        "trace_version": TRACE_VERSION,
        "package_version": __version__,
    }
    if method in CHECKPOINT_METHODS:
        if resolve_device(device).type != "cpu":
            identity["device"] = resolve_device(device).type
        native = description.get("transformer_step") == "native"
        identity["transformer_step"] = description.get("transformer_step")
        spec = dataclasses.replace(spec, native=native)
        if description.get("context_steps") is not None:
            identity["context_steps"] = description["context_steps"]

    out_dir = Path(out_dir)
    started = time.perf_counter()
    with folder_lock(out_dir, LOCK_FILENAME, "diagnosed"):
        traces_dir = out_dir / TRACES_DIRNAME
        traces_dir.mkdir(parents=True, exist_ok=True)
        tasks = [
            TraceTask(
                episode.to_json(),
                str(traces_dir / f"{_file_stem(episode.episode_id)}.npz"),
                _key(identity, episode.to_json()),
            )
            for episode in episode_set.episodes
        ]
        _remove_leftovers(traces_dir, tasks)
        computed = _run_tasks(tasks, spec, episode_set.max_steps, workers, progress, label, resume)
        traces = [load_trace(task.path) for task in tasks]
        atomic_write_text(out_dir / ROBOT_TRIALS, _robot_rows(traces))
        summary = {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "method": method,
            "label": label,
            "checkpoint": spec.checkpoint,
            "checkpoint_sha256": description.get("checkpoint_sha256"),
            "context_steps": description.get("context_steps"),
            "seed": int(seed),
            "episode_set": {
                "name": episode_set.name,
                "content_sha256": episode_hash,
                "episodes": len(episode_set),
                "max_steps": episode_set.max_steps,
                "setups": episode_set.setups,
            },
            "package_version": __version__,
            **_measure(traces),
            "expert_commands": None,
            "teacher_forced": None,
            "episodes_computed": computed,
        }
        if expert_data:
            from navformer_rl.evaluation.diagnose.actions import expert_command_statistics

            summary["expert_commands"] = expert_command_statistics(expert_data)
        if held_out:
            from navformer_rl.evaluation.diagnose.actions import teacher_forced_turns

            summary["teacher_forced"] = teacher_forced_turns(spec.checkpoint, held_out, device=device)
        summary["seconds"] = round(time.perf_counter() - started, 3)
        atomic_write_json(out_dir / SUMMARY_JSON, summary)
        atomic_write_text(out_dir / SUMMARY_MD, diagnosis_markdown([summary, *others]))
    return summary


def _measure(traces) -> dict[str, Any]:
    """``{"all": ..., "by_setup": {setup: ...}}`` of :func:`summarize_robots` over the measured robots."""
    from navformer_rl.evaluation.diagnose.measures import summarize_robots

    by_setup: dict[str, list] = {}
    for trace in traces:
        robots = by_setup.setdefault(trace.setup, [])
        robots.extend(trace.robot(i) for i in range(trace.n_robots) if trace.measured[i])
    every = [robot for robots in by_setup.values() for robot in robots]
    return {
        "all": summarize_robots(every),
        "by_setup": {setup: summarize_robots(robots) for setup, robots in by_setup.items()},
    }


def _robot_rows(traces) -> str:
    """``robot_trials.jsonl``: one :func:`robot_row` per measured robot-trial, with its episode and robot."""
    from navformer_rl.evaluation.diagnose.measures import robot_row

    rows = [
        {"episode_id": trace.episode_id, "setup": trace.setup, "robot": i, **robot_row(trace.robot(i))}
        for trace in traces
        for i in range(trace.n_robots)
        if trace.measured[i]
    ]
    return "".join(json.dumps(row, sort_keys=True) + "\n" for row in rows)


def load_diagnosis(folder: str | os.PathLike) -> dict[str, Any]:
    """The ``diagnosis.json`` of a diagnosis folder; FileNotFoundError / ValueError naming it otherwise."""
    path = Path(folder) / SUMMARY_JSON
    if not path.is_file():
        raise FileNotFoundError(
            f"{folder}: no {SUMMARY_JSON}; expected a folder written by `evaluate diagnose`"
        )
    try:
        summary = json.loads(path.read_text())
    except ValueError as error:
        raise ValueError(f"{path}: not JSON ({error})") from None
    if not isinstance(summary, dict) or summary.get("format") != FORMAT:
        raise ValueError(f"{path}: not a diagnosis summary (format {FORMAT!r} expected)")
    if summary.get("version") != FORMAT_VERSION:
        raise ValueError(f"{path}: diagnosis version {summary.get('version')!r}, expected {FORMAT_VERSION}")
    return summary


def _load_comparison(folder: Path, episode_hash: str) -> dict[str, Any]:
    summary = load_diagnosis(folder)
    if summary["episode_set"]["content_sha256"] != episode_hash:
        raise ValueError(
            f"compare folder {folder} diagnosed another episode set ({summary['episode_set']['name']!r}); "
            "compare diagnoses of the same episodes"
        )
    return summary


def _key(identity: Mapping[str, Any], episode: Mapping[str, Any]) -> str:
    content = json.dumps({**identity, "episode": episode}, sort_keys=True)
    return hashlib.sha256(content.encode()).hexdigest()


def _file_stem(episode_id: str) -> str:
    return episode_id.replace("/", "_").replace(" ", "_")


def _stored(task: TraceTask) -> bool:
    """Whether ``task``'s trace exists with its key."""
    try:
        return load_trace(task.path).key == task.key
    except (ValueError, FileNotFoundError):
        return False


def _remove_leftovers(traces_dir: Path, tasks: list[TraceTask]) -> None:
    """Delete temporary files of killed writers and the traces of episodes this set does not hold (warning
    with their count), so the folder holds what ``diagnosis.json`` describes. Called under the lock."""
    for leftover in traces_dir.glob(".*.tmp.npz"):
        leftover.unlink(missing_ok=True)
    keep = {Path(task.path) for task in tasks}
    stale = [path for path in sorted(traces_dir.glob("*.npz")) if path not in keep]
    for path in stale:
        path.unlink()
    if stale:
        warnings.warn(
            f"{traces_dir}: removed {len(stale)} traces of episodes this diagnosis does not hold",
            stacklevel=3,
        )


def _run_tasks(
    tasks: list[TraceTask],
    spec: PolicySpec,
    max_steps: int,
    workers: int,
    progress: bool,
    label: str,
    resume: bool,
) -> int:
    """Record every task whose trace is not stored (all when not ``resume``); returns how many ran."""
    from tqdm.auto import tqdm

    todo = [task for task in tasks if not (resume and _stored(task))]
    bar = tqdm(
        total=len(tasks), initial=len(tasks) - len(todo), desc=f"diagnose {label}", unit="episode",
        disable=not progress,
    )  # fmt: skip
    try:
        if not todo:
            pass
        elif workers == 1:
            import torch

            threads = torch.get_num_threads()
            torch.set_num_threads(1)  # as in the workers, so the worker count cannot change float results
            runner = TraceRunner(spec, max_steps)
            try:
                for task in todo:
                    save_trace(runner.run(task.episode, task.key), task.path)
                    bar.update(1)
            finally:
                runner.close()
                torch.set_num_threads(threads)
        else:  # on an error or Ctrl-C the pool stops the rest; finished traces are stored
            with LocalPool(min(workers, len(todo)), _init_worker, (spec, max_steps)) as pool:
                for _ in run_units(pool, _run_in_worker, ((task, (task,)) for task in todo)):
                    bar.update(1)
    finally:
        bar.close()
    return len(todo)
