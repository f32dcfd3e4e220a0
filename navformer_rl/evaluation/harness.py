"""The evaluation harness: run one method on every episode of an episode set and write the results.

``evaluate(method, episode_set, out_dir, workers=...)`` runs each episode in a ``MultiRobotNavEnv`` with
every robot driven by the evaluated method (paper §VII.A), measures each robot-trial
(:mod:`navformer_rl.evaluation.measures`) and writes into ``out_dir``:

- ``episodes.jsonl``: one row per robot-trial (:class:`~navformer_rl.evaluation.measures.RobotTrial`);
- ``summary.csv`` / ``summary.md``: SR, SPL, CR per setup with 95 % intervals (Table I layout);
- ``metrics.png``: bar plots per setup;
- ``maps/<episode>.png``: top-down maps with every robot's trajectory (first ``maps_per_setup`` episodes
  of each setup); ``videos/<episode>.mp4``: the robots' cameras beside the top-down map (first
  ``videos_per_setup`` episodes of each setup);
- ``episode_set.json``: the episode set that was run; ``run.json``: method, label, checkpoint (its weights'
  sha256, model config and training ``ablation``), settings, hashes and timing: ``seconds`` is the
  wall-clock time that computed the results (each episode stores its share, so a resumed run keeps the
  time of the episodes it reused), ``episode_seconds`` the sum of the episodes' own run times (about
  ``seconds`` x workers), ``invocation_seconds`` this call's wall time, ``episodes_computed`` /
  ``episodes_reused`` what this call ran or reused;
- ``per_episode/<episode>.json``: each finished episode's rows, written as soon as it ends, so that an
  interrupted run resumes where it stopped (``resume=True``, the default, reuses the rows whose method,
  label, checkpoint weights, seed, trial length, episode and visuals are the same).

Episodes run in ``workers`` spawned processes (one env per robot line-up and one policy per process), or
with ``backend="ray"`` as Ray tasks (:mod:`navformer_rl.utils.backends`): each task runs its episode in a
scratch folder of the machine that runs it and returns its rows and the bytes of its map and video, which
this process writes where a local worker would have. Each episode's result depends only on the episode (its
world, layout and seed) and the method, never on which worker or backend ran it or in which order, so any
worker count and either backend give the same records (and resume each other's runs).

This module orchestrates: it checks the arguments, makes the tasks, reuses stored episode results, runs
the rest (here or in the worker pool), removes stale outputs and writes the files above. The policy recipe
and its checks live in :mod:`navformer_rl.evaluation.policy_spec`, the episode loop and its visuals in
:mod:`navformer_rl.evaluation.runner`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import re
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from navformer_rl import __version__
from navformer_rl.evaluation.episodes import EpisodeSet, load_episode_set, save_episode_set
from navformer_rl.evaluation.measures import RobotTrial, check_cluster
from navformer_rl.evaluation.policy_spec import (
    CHECKPOINT_METHODS,
    METHODS,
    ONLINE_METHODS,
    PolicySpec,
    checkpoint_ablation,
    label_ablation_problem,
)
from navformer_rl.evaluation.runner import (
    EpisodeRunner,
    EpisodeTask,
    _file_stem,
    _init_worker,
    _run_in_worker,
    _timed_run,
    make_eval_env,
)
from navformer_rl.evaluation.tables import SetupSummary, records_to_jsonl, write_summary_files
from navformer_rl.utils.backends import check_backend, open_backend, run_units
from navformer_rl.utils.checks import check_int
from navformer_rl.utils.devices import resolve_device
from navformer_rl.utils.durable import atomic_path, atomic_write_text, folder_lock
from navformer_rl.utils.mp4 import ffmpeg_executable

__all__ = [
    "LOCK_FILENAME",
    "PARTIAL_DIRNAME",
    "EvaluateConfig",
    "EvaluationResult",
    "evaluate",
    # re-exported for the CLI, the report, recipes and tests
    "METHODS",
    "EpisodeTask",
    "PolicySpec",
    "checkpoint_ablation",
    "label_ablation_problem",
    "make_eval_env",
]

LOCK_FILENAME = ".evaluate.lock"
"""Held (``flock`` + pid) in the output folder while an evaluation writes there: a second one is refused."""
PARTIAL_DIRNAME = "per_episode"
"""Sub-folder of the output folder holding one result file per finished episode (for resuming)."""


@dataclass
class EvaluationResult:
    """What :func:`evaluate` produced."""

    out_dir: Path
    records: list[RobotTrial]
    summaries: list[SetupSummary]
    files: dict[str, Any] = field(default_factory=dict)
    episodes_computed: int = 0
    """Episodes run by this call (the others were reused from ``per_episode/``)."""
    seconds: float | None = None
    """Wall-clock seconds that computed these results (``run.json`` ``seconds``), reused episodes included."""


@dataclass(frozen=True)
class EvaluateConfig:
    """How :func:`evaluate` runs: every option, documented once (CleanRL's ``Args``). ``navformer evaluate``,
    the evaluation recipe and the demo build one; ``evaluate(..., **options)`` takes the same fields as
    keywords."""

    checkpoint: str | os.PathLike | None = None
    """For ``navformer`` / ``dt``: run dir, checkpoint folder or ``model.safetensors`` (or
    ``pretrained:NAME``); resolved once, at the start, to one checkpoint folder (a run dir: its latest), which
    ``run.json`` names (a run still training with ``checkpoint.keep_last`` may delete that folder before the
    workers load it: they then fail; evaluate a finished run or a copied checkpoint)."""
    workers: int = 1
    """Processes (>= 1; 1 runs in this process), or Ray tasks at once with ``backend="ray"``."""
    label: str | None = None
    """Method name in tables (default the method; e.g. ``navformer-no_thsc`` for an ablation). A label naming
    a training ablation must match the checkpoint's (ValueError before any episode runs, see
    :func:`label_ablation_problem`); other labels (``navformer-seed1``) are free."""
    seed: int = 0
    """Base seed of stochastic policies."""
    maps_per_setup: int = 2
    """How many episodes per setup (the first ones) get a top-down map PNG."""
    videos_per_setup: int = 1
    """How many episodes per setup (the first ones) get an mp4 video."""
    video_fps: float = 10.0
    """Frames per second of the videos (one frame per 0.2 s step)."""
    confidence: float = 0.95
    """Level of the intervals."""
    cluster: str = "trial"
    """What the intervals resample: whole trials (``"trial"``, intervals for these mazes) or whole mazes
    (``"world"``, also the variation between mazes; needs 6 mazes per setup at 95 %), see
    :data:`~navformer_rl.evaluation.measures.CLUSTER_LEVELS`."""
    device: str = "cpu"
    """Where ``navformer`` / ``dt`` run their model in every worker: ``cpu``, ``cuda``, ``cuda:N`` or ``auto``
    (ValueError for a device torch cannot use here). Episodes still simulate and render on the CPU; results on
    a GPU differ from the CPU's in the last float bits, so resuming reuses only episodes computed on the same
    kind of device. The other methods have no model to place (an unusable device is refused for them too)."""
    progress: bool = True
    """Show a tqdm progress bar."""
    resume: bool = True
    """Reuse the per-episode results already in ``out_dir/per_episode/`` that were computed with the same
    method (your own policy: the same factory), label, checkpoint weights, seed, trial length, video_fps and
    package version (an interrupted run picks up where it stopped); False recomputes everything."""
    backend: str = "local"
    """Where episodes run: ``local`` (``workers`` processes here) or ``ray`` (Ray tasks, ``pip install
    "navformer_rl[distributed]"``; the model on the CPU only); ValueError otherwise."""
    ray_address: str | None = None
    """With ``ray``: the cluster to join (``auto``, ``ray://host:10001``; default ``$RAY_ADDRESS``, else a
    local Ray instance with ``workers`` CPUs, shut down at the end). Every node needs navformer_rl installed
    and, for ``navformer`` / ``dt``, the checkpoint at the same path."""
    context_steps: int | None = None
    """``navformer`` / ``dt`` only: the timesteps the policy attends to (an inference option, not the paper's,
    ``NavFormerPolicy(context_steps=)``); None: the window the checkpoint was trained on
    (``data.context_steps``) when set, else the model's whole context. Recorded in ``run.json`` when not the
    whole; results of another context are never reused."""


def evaluate(
    method: str | Callable[[], Any],
    episode_set: EpisodeSet | str | os.PathLike,
    out_dir: str | os.PathLike,
    config: EvaluateConfig | None = None,
    **options: Any,
) -> EvaluationResult:
    """Run ``method`` on every episode of ``episode_set`` and write the outputs (module docstring).

    Args:
        method: one of :data:`METHODS` (ValueError listing them otherwise), or your own policy as a picklable
            zero-argument factory returning a ``TensorDictModuleBase`` that reads the ``MultiRobotNavEnv``
            tensordict and writes ``("agents", "action")`` (a ``bind(env, seed)`` method, if present, is
            called after every reset); its label defaults to the factory's name.
        episode_set: an :class:`EpisodeSet` or the path of an episode-set file.
        out_dir: output folder (created; this run's files in it are overwritten, but a folder holding
            another label's finished results is refused with ``FileExistsError``).
        config: the :class:`EvaluateConfig` (default: its defaults).
        options: :class:`EvaluateConfig` fields as keywords, replacing ``config``'s (TypeError for another
            name).
    """
    cfg = _evaluate_config(config, options)
    invoked = time.perf_counter()
    episode_set = _checked_episode_set(episode_set)
    workers = _check_options(
        cfg.workers, cfg.maps_per_setup, cfg.videos_per_setup, cfg.video_fps, cfg.confidence, cfg.cluster
    )
    check_backend(cfg.backend)
    if callable(method):
        factory, method = method, getattr(method, "__name__", "custom")
    else:
        factory = None
    checkpoint = _resolved_checkpoint(method, factory, cfg.checkpoint)
    spec = PolicySpec(
        method,
        None if checkpoint is None else str(checkpoint),
        int(cfg.seed),
        factory,
        cfg.device,
        context_steps=cfg.context_steps,
    )
    label = cfg.label or method
    description = spec.validate(label)
    model_device = _model_device(method, factory, cfg.device)
    if cfg.backend == "ray" and model_device not in (None, "cpu"):
        raise ValueError(
            f"device={cfg.device!r} with backend='ray': Ray tasks run the model on the CPU; use "
            "device='cpu', or the local backend for a GPU"
        )
    out_dir = Path(out_dir)
    with folder_lock(out_dir, LOCK_FILENAME, "evaluated"):  # one evaluation per folder at a time
        _prepare_folder(out_dir, label, episode_set)
        identity = _resume_identity(
            method, label, int(cfg.seed), episode_set.max_steps, description, model_device
        )
        spec = _with_transformer_step(spec, description)
        tasks = _make_tasks(
            episode_set, out_dir, label, cfg.maps_per_setup, cfg.videos_per_setup, cfg.video_fps, identity
        )
        outputs, computed = _run_tasks(
            tasks,
            spec,
            episode_set.max_steps,
            cfg.video_fps,
            workers,
            cfg.progress,
            label,
            cfg.resume,
            cfg.backend,
            cfg.ray_address,
        )
        _remove_stale_outputs(out_dir, tasks, outputs)
        records, summaries, files = _write_results(
            out_dir, label, episode_set, outputs, cfg.confidence, cfg.cluster
        )
        run = {
            "method": method,
            "label": label,
            "checkpoint": spec.checkpoint,
            "seed": int(cfg.seed),
            "workers": workers,
            "backend": cfg.backend,
            "episode_set": _episode_set_entry(episode_set),
            "confidence": cfg.confidence,
            "cluster": cfg.cluster,
            "device": model_device,
            **_timing(outputs, computed, time.perf_counter() - invoked),
            "package_version": __version__,
            "files": files,
            **description,
        }
        atomic_write_text(out_dir / "run.json", json.dumps(run, indent=2, sort_keys=True, default=str) + "\n")
        return EvaluationResult(
            out_dir=out_dir,
            records=records,
            summaries=summaries,
            files=files,
            episodes_computed=computed,
            seconds=run["seconds"],
        )


def _evaluate_config(config: EvaluateConfig | None, options: dict[str, Any]) -> EvaluateConfig:
    """``config`` (default: the defaults) with ``options`` replacing its fields (TypeError naming an unknown
    one, as for an unknown keyword argument)."""
    fields = {f.name for f in dataclasses.fields(EvaluateConfig)}
    unknown = sorted(set(options) - fields)
    if unknown:
        raise TypeError(
            f"evaluate() got unexpected keyword arguments {unknown}; expected EvaluateConfig fields"
        )
    return dataclasses.replace(config or EvaluateConfig(), **options)


def _checked_episode_set(episode_set: EpisodeSet | str | os.PathLike) -> EpisodeSet:
    """``episode_set``, loaded when it is a path, after checking it is non-empty with distinct episode ids."""
    if isinstance(episode_set, str | os.PathLike):
        episode_set = load_episode_set(episode_set)
    if not isinstance(episode_set, EpisodeSet) or len(episode_set) == 0:
        raise ValueError("episode_set must be a non-empty EpisodeSet or the path of an episode-set file")
    _check_episode_ids(episode_set)
    return episode_set


def _check_options(
    workers: int,
    maps_per_setup: int,
    videos_per_setup: int,
    video_fps: float,
    confidence: float,
    cluster: str,
) -> int:
    """Check :func:`evaluate`'s counts, levels and video settings (ValueError naming the bad one; a missing
    video encoder is reported here, not by a worker at its first video); returns ``workers``."""
    workers = check_int(workers, "workers")
    check_int(maps_per_setup, "maps_per_setup (--maps)", minimum=0)
    check_int(videos_per_setup, "videos_per_setup (--videos)", minimum=0)
    if videos_per_setup > 0:
        ffmpeg_executable()
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence={confidence!r}: expected a level in (0, 1), e.g. 0.95")
    check_cluster(cluster)
    if not (isinstance(video_fps, int | float) and math.isfinite(video_fps) and video_fps > 0):
        raise ValueError(f"video_fps={video_fps!r}: expected a number of frames per second > 0")
    return workers


def _resolved_checkpoint(
    method: str, factory: Callable[[], Any] | None, checkpoint: str | os.PathLike | None
) -> str | os.PathLike | None:
    """For ``navformer`` / ``dt`` / ``dsac`` / ``matdn``: one concrete checkpoint folder for the checks,
    ``run.json`` and every worker (a run directory's latest, fixed now even while that run keeps training);
    else ``checkpoint``."""
    if checkpoint is None or factory is not None or method not in (*CHECKPOINT_METHODS, *ONLINE_METHODS):
        return checkpoint
    from navformer_rl.training.checkpoint import resolve_checkpoint

    return resolve_checkpoint(checkpoint)


def _prepare_folder(out_dir: Path, label: str, episode_set: EpisodeSet) -> None:
    """Clear writers' leftovers from ``out_dir``, refuse another label's results, save the episode set."""
    _remove_temporaries(out_dir)
    _refuse_other_runs_results(out_dir, label)
    out_dir.mkdir(parents=True, exist_ok=True)
    save_episode_set(episode_set, out_dir / "episode_set.json")


def _model_device(method: str, factory: Callable[[], Any] | None, device: str) -> str | None:
    """The device type (``"cpu"``, ``"cuda"``) a ``navformer`` / ``dt`` model runs on; None for the others."""
    return resolve_device(device).type if method in CHECKPOINT_METHODS and factory is None else None


def _resume_identity(
    method: str,
    label: str,
    seed: int,
    max_steps: int,
    description: dict[str, Any],
    model_device: str | None,
) -> dict[str, Any]:
    """What a stored episode result must have been computed with to be reused (hashed into each task's key).

    ``device`` is present only off the CPU and ``transformer_step`` only for the native kernel, so results
    computed on the CPU with the torch step match whatever else the identity holds.
    """
    identity = {
        "method": method,
        "label": label,
        "seed": seed,
        "max_steps": max_steps,
        "checkpoint_sha256": description.get("checkpoint_sha256"),
        "record_fields": sorted(RobotTrial.__dataclass_fields__),
        # results of another release (simulator or policy fixes) are recomputed, never mixed in
        "package_version": __version__,
    }
    if "factory" in description:  # your own policy: its module.qualname, not only its label
        identity["factory"] = description["factory"]
    if model_device not in (None, "cpu"):
        identity["device"] = model_device
    if description.get("transformer_step") == "native":
        identity["transformer_step"] = "native"
    if description.get("context_steps") is not None:
        identity["context_steps"] = description["context_steps"]
    return identity


def _with_transformer_step(spec: PolicySpec, description: dict[str, Any]) -> PolicySpec:
    """``spec`` running the transformer step the policy described (native kernel or torch),
    when it names one."""
    step = description.get("transformer_step")
    if step == "native":
        return dataclasses.replace(spec, native=True)
    if step == "torch":
        return dataclasses.replace(spec, native=False)
    return spec


def _write_results(
    out_dir: Path,
    label: str,
    episode_set: EpisodeSet,
    outputs: list[dict[str, Any]],
    confidence: float,
    cluster: str,
) -> tuple[list[RobotTrial], list[SetupSummary], dict[str, Any]]:
    """Write ``episodes.jsonl``, the summary tables and ``metrics.png``; returns the records, the summaries
    and the ``files`` entry of ``run.json`` (those names, the maps and the videos)."""
    records = [record for output in outputs for record in output["records"]]
    atomic_write_text(out_dir / "episodes.jsonl", records_to_jsonl(records))
    # the bootstrap seed is not the policy seed: the same rows get the same intervals here and in reports
    summaries = write_summary_files(records, out_dir, confidence, cluster=cluster)
    from navformer_rl.evaluation.plots import plot_setup_bars

    plot = plot_setup_bars(summaries, out_dir / "metrics.png", title=f"{label} on {episode_set.name}")
    files = {
        "episodes": "episodes.jsonl",
        "summary_csv": "summary.csv",
        "summary_md": "summary.md",
        "plot": plot.name,
        "maps": [m for o in outputs for m in o["maps"]],
        "videos": [v for o in outputs for v in o["videos"]],
    }
    return records, summaries, files


def _episode_set_entry(episode_set: EpisodeSet) -> dict[str, Any]:
    """The ``episode_set`` entry of ``run.json``: name, content hash, size, trial length, setups."""
    return {
        "name": episode_set.name,
        "content_sha256": episode_set.content_hash(),
        "episodes": len(episode_set),
        "max_steps": episode_set.max_steps,
        "setups": episode_set.setups,
    }


_TEMPORARY_NAME = re.compile(r"^\..+\.[a-z0-9_]{8}\.tmp(\.[A-Za-z0-9]+)?$")
"""The names ``durable.atomic_path`` gives its temporary files:
``.<stem>.<mkstemp's 8 characters>.tmp<suffix>``."""


def _remove_temporaries(out_dir: Path) -> None:
    """Delete the temporary files that writers killed mid-write left in ``out_dir`` (only files named as
    ``atomic_path`` names them; called while holding the folder's lock, so none is in use)."""
    for folder in (out_dir, out_dir / "videos", out_dir / "maps", out_dir / PARTIAL_DIRNAME):
        for leftover in folder.glob(".*.tmp*"):
            if _TEMPORARY_NAME.match(leftover.name) and leftover.is_file():
                leftover.unlink(missing_ok=True)


def _timing(outputs: list[dict[str, Any]], computed: int, elapsed: float) -> dict[str, Any]:
    """The timing entries of ``run.json`` (see :func:`evaluate`): the time that computed the results, summed
    from what each episode stored when it was computed, beside this invocation's own wall time."""

    def total(key: str) -> float | None:
        values = [o.get(key) for o in outputs]
        # an episode stored without its time makes the total unknown, not smaller
        return None if any(v is None for v in values) else round(sum(values), 3)

    return {
        "seconds": total("wall_seconds"),
        "episode_seconds": total("seconds"),
        "invocation_seconds": round(elapsed, 3),
        "episodes_computed": computed,
        "episodes_reused": len(outputs) - computed,
    }


def _refuse_other_runs_results(out_dir: Path, label: str) -> None:
    """FileExistsError if ``out_dir`` holds the finished results of another label (they would be replaced)."""
    run_file = out_dir / "run.json"
    if not run_file.is_file():
        return
    try:
        previous = json.loads(run_file.read_text()).get("label")
    except (ValueError, AttributeError):
        previous = None
    if previous != label:
        raise FileExistsError(
            f"{out_dir} holds the results of {previous!r}; evaluating {label!r} there would replace them. "
            "Use another output folder (one per method or label), or delete that one"
        )


def _remove_stale_outputs(out_dir: Path, tasks: list[EpisodeTask], outputs: list[dict[str, Any]]) -> None:
    """Delete the maps, videos and per-episode results of episodes this run does not hold - left by an
    earlier evaluation of other episodes (or with more ``--maps`` / ``--videos``) under the same label - so
    that the folder shows only what its ``run.json`` and tables describe; warns with the count."""
    keep = {out_dir / name for output in outputs for name in output["maps"] + output["videos"]}
    keep |= {_partial_path(task) for task in tasks}
    stale = [
        path
        for folder, pattern in (("maps", "*.png"), ("videos", "*.mp4"), (PARTIAL_DIRNAME, "*.json"))
        for path in sorted((out_dir / folder).glob(pattern))
        if path not in keep
    ]
    for path in stale:
        path.unlink(missing_ok=True)
    if stale:
        warnings.warn(
            f"{out_dir}: removed {len(stale)} maps / videos / per-episode results of episodes this "
            "evaluation does not hold (an earlier evaluation of other episodes in this folder)",
            stacklevel=3,
        )


def _check_episode_ids(episode_set: EpisodeSet) -> None:
    """Every episode gets its own result file: refuse ids that repeat or map to the same file name."""
    stems: dict[str, str] = {}
    for episode in episode_set.episodes:
        episode_id = episode.episode_id
        other = stems.get(_file_stem(episode_id))
        if other is not None:
            problem = "appears twice" if other == episode_id else f"and {other!r} share a result file name"
            raise ValueError(f"episode id {episode_id!r} {problem} in episode set {episode_set.name!r}")
        stems[_file_stem(episode_id)] = episode_id


def _make_tasks(
    episode_set: EpisodeSet,
    out_dir: Path,
    label: str,
    maps_per_setup: int,
    videos_per_setup: int,
    video_fps: float,
    identity: dict[str, Any],
) -> list[EpisodeTask]:
    """One task per episode; its resume key hashes ``identity``, the episode, whether it saves a map and a
    video, and the video's frame rate only when it saves one (a result without a video does not depend
    on it)."""
    seen: dict[str, int] = {}
    tasks = []
    for index, episode in enumerate(episode_set.episodes):
        rank = seen.get(episode.setup, 0)
        seen[episode.setup] = rank + 1
        save_map, save_video = rank < maps_per_setup, rank < videos_per_setup
        content = {**identity, "episode": episode.to_json(), "map": save_map, "video": save_video}
        if save_video:
            content["video_fps"] = float(video_fps)
        key = hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()
        tasks.append(EpisodeTask(index, episode.to_json(), save_map, save_video, str(out_dir), label, key))
    return tasks


def _partial_path(task: EpisodeTask) -> Path:
    return Path(task.out_dir) / PARTIAL_DIRNAME / f"{_file_stem(task.episode['episode_id'])}.json"


def _store_partial(task: EpisodeTask, output: dict[str, Any]) -> None:
    document = {
        "key": task.key,
        "records": [r.to_dict() for r in output["records"]],
        "maps": output["maps"],
        "videos": output["videos"],
        "seconds": output.get("seconds"),
        "wall_seconds": output.get("wall_seconds"),
    }
    atomic_write_text(_partial_path(task), json.dumps(document, sort_keys=True) + "\n")


def _load_partial(task: EpisodeTask) -> dict[str, Any] | None:
    """The stored output of ``task`` when its key matches and its visuals still exist (non-empty),
    else None."""
    path = _partial_path(task)
    try:
        document = json.loads(path.read_text())
        if document["key"] != task.key:
            return None
        output = {
            "records": [RobotTrial.from_dict(r) for r in document["records"]],
            "maps": list(document["maps"]),
            "videos": list(document["videos"]),
            # the times it took when it was computed (None when the file holds none)
            "seconds": document.get("seconds"),
            "wall_seconds": document.get("wall_seconds"),
        }
    except (OSError, ValueError, KeyError, TypeError):
        return None
    for name in output["maps"] + output["videos"]:
        visual = Path(task.out_dir) / name
        if not visual.is_file() or visual.stat().st_size == 0:
            return None
    return output


def _run_tasks(
    tasks: list[EpisodeTask],
    spec: PolicySpec,
    max_steps: int,
    video_fps: float,
    workers: int,
    progress: bool,
    label: str,
    resume: bool,
    backend: str = "local",
    ray_address: str | None = None,
) -> tuple[list[dict[str, Any]], int]:
    """Every task's output (stored ones reused when ``resume``) and how many tasks were run.

    Each output run here gets ``seconds`` (the episode's own run time, in the process that ran it) and
    ``wall_seconds`` (wall-clock time from the previous episode's finish, or the start, to its own: summed
    over the episodes of a run, the run's wall time without what an interruption discarded); both are stored
    with the episode, so a resumed run still reports the time that computed a reused one. On an error or a
    Ctrl-C the episodes not started are dropped (finished ones are already stored for resuming) and the
    running ones end before this returns, so nothing writes into the folder once its lock is released.
    """
    from tqdm.auto import tqdm

    results: list[dict[str, Any] | None] = [None] * len(tasks)
    if resume:
        for task in tasks:
            results[task.index] = _load_partial(task)
    todo = [task for task in tasks if results[task.index] is None]
    bar = tqdm(
        total=len(tasks),
        initial=len(tasks) - len(todo),
        desc=f"evaluate {label}",
        unit="episode",
        disable=not progress,
    )

    last_finish = time.perf_counter()

    def finish(task: EpisodeTask, output: dict[str, Any]) -> None:
        nonlocal last_finish
        now = time.perf_counter()
        output["wall_seconds"] = round(now - last_finish, 3)
        last_finish = now
        _store_partial(task, output)
        results[task.index] = output
        bar.update(1)

    try:
        if not todo:
            pass
        elif workers == 1 and backend == "local":
            import torch

            threads = torch.get_num_threads()
            torch.set_num_threads(1)  # as in the workers, so the worker count cannot change float results
            runner = EpisodeRunner(spec, max_steps, video_fps)
            try:
                for task in todo:
                    finish(task, _timed_run(runner, task))
            finally:
                runner.close()
                torch.set_num_threads(threads)
        else:
            with open_backend(
                backend,
                min(workers, len(todo)),
                # local workers build their runner once (and end quietly on Ctrl-C); Ray tasks: _run_remotely
                initializer=_init_worker,
                initargs=(spec, max_steps, video_fps),
                address=ray_address,
            ) as pool:
                if pool.remote:
                    units = ((task, (spec, max_steps, video_fps, task)) for task in todo)
                    for task, (output, visuals) in run_units(pool, _run_remotely, units):
                        _write_visuals(Path(task.out_dir), visuals)
                        finish(task, output)
                else:
                    for task, output in run_units(pool, _run_in_worker, ((task, (task,)) for task in todo)):
                        finish(task, output)
    finally:
        bar.close()
    return [r for r in results if r is not None], len(todo)


_REMOTE_RUNNER: tuple[tuple[Any, ...], EpisodeRunner] | None = None
"""The :class:`EpisodeRunner` of this Ray worker process, with the arguments that built it."""


def _run_remotely(
    spec: PolicySpec, max_steps: int, video_fps: float, task: EpisodeTask
) -> tuple[dict[str, Any], dict[str, bytes]]:
    """A Ray task: run ``task`` in a scratch folder on the machine that runs it; returns the output of
    :func:`_timed_run` and the bytes of its maps and videos by their names in the output folder. The
    runner is built once per worker process (one torch thread, as the local workers) and reused."""
    global _REMOTE_RUNNER
    key = (spec, max_steps, video_fps)
    if _REMOTE_RUNNER is None or _REMOTE_RUNNER[0] != key:
        import torch

        if _REMOTE_RUNNER is not None:
            _REMOTE_RUNNER[1].close()
            _REMOTE_RUNNER = None
        torch.set_num_threads(1)
        _REMOTE_RUNNER = (key, EpisodeRunner(spec, max_steps, video_fps))
    with tempfile.TemporaryDirectory(prefix="navformer-evaluate-") as scratch:
        output = _timed_run(_REMOTE_RUNNER[1], dataclasses.replace(task, out_dir=scratch))
        visuals = {name: (Path(scratch) / name).read_bytes() for name in output["maps"] + output["videos"]}
    return output, visuals


def _write_visuals(out_dir: Path, visuals: dict[str, bytes]) -> None:
    """Write the maps and videos a Ray task returned (name relative to ``out_dir`` -> bytes), atomically."""
    for name, data in visuals.items():
        path = out_dir / name
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)
