"""The end-to-end demo (``navformer demo``) and the world demo (``navformer world-demo``).

``run_demo`` is the whole NavFormer pipeline at a small scale, in one run folder:

1. collect D_e, D_ca and D_ssl with the experts (``<out>/data/{e,ca,ssl}``), and small held-out D_e / D_ca
   from other mazes (``<out>/data/held_out_{e,ca}``; resumable);
2. train NavFormer and the DT baseline on them (``<out>/train/{navformer,dt}``; checkpoints), scoring the
   action loss on the held-out trajectories as they train (``validation.*``);
3. evaluate NavFormer, DT, VRW and FCA on the same fixed episodes (``<out>/eval/<method>``);
4. write ``<out>/report.md`` with tables (the paper's numbers beside ours), plots, maps and videos.

Every stage is resumable: rerunning the same command after an interruption reuses what is finished.
``DemoConfig`` holds the knobs; ``DemoConfig.preset("quick" | "default")`` gives the two sizes we ship.

The report's stage times are the wall-clock time that computed each stage's result, across invocations
(an interrupted run plus the rerun that finished it), beside this invocation's own time: a rerun that
reuses everything leaves the first ones unchanged. Collection and training keep theirs in
``<out>/stage_times.json`` (:class:`StageTimes`); evaluation's is the sum of the methods' ``run.json``
``seconds``, which each evaluation keeps with its finished episodes. The demo ends by printing both times
per stage (:func:`stage_time_table`).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from navformer_rl import cli_args
from navformer_rl.durable import atomic_write_text

BASELINES = ("vrw", "fca")
HELD_OUT_SEED_OFFSET = 1000
"""The held-out D_e / D_ca are collected with ``seed + HELD_OUT_SEED_OFFSET``: mazes the training never saw."""
TRAINED_METHODS = ("navformer", "dt")
STAGE_TIMES_FILENAME = "stage_times.json"
"""File of the run folder keeping the seconds that computed each stage's result (:class:`StageTimes`)."""
T = TypeVar("T")


@dataclass(frozen=True)
class DemoConfig:
    """Sizes of the small end-to-end run (the paper-scale values are in ``docs/reproduce.md``).

    Attributes:
        out_dir: run folder.
        seed: base seed of collection, training and evaluation.
        workers: processes for collection and evaluation.
        exploration_trajectories, collision_trajectories: D_e / D_ca trajectories (paper: 3,496 / 7,467).
        ssl_worlds, ssl_pairs_per_world: D_ssl size (paper: 1,000 x 98).
        held_out_exploration, held_out_collision: held-out D_e / D_ca trajectories for validation (0: none).
        iterations: training iterations of NavFormer and of DT (paper: 10,000).
        exploration_batch, collision_batch, ssl_batch: trajectories / pairs per iteration (paper: 25/150/512).
        setups: evaluation protocol (a name of ``navformer_rl.evaluation.episodes.PROTOCOLS``).
        trials_per_setup, trials_per_world: evaluation trials (paper: 60 per setup, new world every 10).
        max_steps: steps per evaluation trial (paper: 500).
        videos_per_setup: episodes recorded as mp4 per setup and method.
    """

    out_dir: Path = Path("runs/demo")
    seed: int = 0
    workers: int = 2
    exploration_trajectories: int = 48
    collision_trajectories: int = 96
    ssl_worlds: int = 8
    ssl_pairs_per_world: int = 64
    held_out_exploration: int = 16
    held_out_collision: int = 32
    iterations: int = 200
    exploration_batch: int = 8
    collision_batch: int = 24
    ssl_batch: int = 128
    setups: str = "smoke"
    trials_per_setup: int = 6
    trials_per_world: int = 3
    max_steps: int = 500
    videos_per_setup: int = 1
    methods: tuple[str, ...] = field(default=TRAINED_METHODS + BASELINES)

    @staticmethod
    def preset(name: str, **overrides) -> DemoConfig:
        """``default`` (8-15 minutes on 2 CPU cores, README.md) or ``quick`` (a few minutes: a smoke check)."""
        presets = {
            "default": {},
            "quick": {
                "exploration_trajectories": 6,
                "collision_trajectories": 12,
                "ssl_worlds": 2,
                "ssl_pairs_per_world": 32,
                "held_out_exploration": 2,
                "held_out_collision": 4,
                "iterations": 20,
                "exploration_batch": 4,
                "collision_batch": 8,
                "ssl_batch": 32,
                "trials_per_setup": 2,
                "trials_per_world": 2,
                "max_steps": 120,
            },
        }
        if name not in presets:
            raise ValueError(f"unknown demo preset {name!r}; expected one of {sorted(presets)}")
        return dataclasses.replace(DemoConfig(), **{**presets[name], **overrides})

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first bad field."""
        positive = (
            "workers exploration_trajectories collision_trajectories ssl_worlds ssl_pairs_per_world "
            "iterations exploration_batch collision_batch ssl_batch trials_per_setup trials_per_world "
            "max_steps"
        ).split()
        for name in positive:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"demo setting {name}={value!r}: expected a positive integer")
        for name in ("held_out_exploration", "held_out_collision"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"demo setting {name}={value!r}: expected an integer >= 0 (0: none)")
        unknown = sorted(set(self.methods) - set(TRAINED_METHODS + BASELINES))
        if unknown or not self.methods:
            raise ValueError(
                f"demo methods {list(self.methods)!r}: expected a non-empty subset of "
                f"{list(TRAINED_METHODS + BASELINES)}"
            )
        if self.exploration_batch > self.exploration_trajectories:
            raise ValueError(
                f"exploration_batch={self.exploration_batch} exceeds exploration_trajectories="
                f"{self.exploration_trajectories}"
            )
        if self.collision_batch > self.collision_trajectories:
            raise ValueError(
                f"collision_batch={self.collision_batch} exceeds collision_trajectories="
                f"{self.collision_trajectories}"
            )


def collect_stage(cfg: DemoConfig, progress: bool = True) -> dict[str, Path]:
    """Stage 1: the datasets under ``<out>/data`` (resumes a partial collection).

    Returns ``{name: folder}``: ``e``, ``ca``, ``ssl`` and, unless their size is 0, ``held_out_e`` /
    ``held_out_ca`` (collected with ``seed + HELD_OUT_SEED_OFFSET``)."""
    from navformer_rl.data.collect import collect, settings_for
    from navformer_rl.data.schema import DatasetKind

    data_dir = cfg.out_dir / "data"
    sizes = {
        DatasetKind.EXPLORATION: {"n_trajectories": cfg.exploration_trajectories},
        DatasetKind.COLLISION_AVOIDANCE: {"n_trajectories": cfg.collision_trajectories},
        DatasetKind.SSL: {"n_worlds": cfg.ssl_worlds, "pairs_per_world": cfg.ssl_pairs_per_world},
    }
    jobs = [(kind.value, kind, cfg.seed, overrides) for kind, overrides in sizes.items()]
    held_out = {
        DatasetKind.EXPLORATION: cfg.held_out_exploration,
        DatasetKind.COLLISION_AVOIDANCE: cfg.held_out_collision,
    }
    jobs += [
        (f"held_out_{kind.value}", kind, cfg.seed + HELD_OUT_SEED_OFFSET, {"n_trajectories": n})
        for kind, n in held_out.items()
        if n > 0
    ]
    paths = {}
    for name, kind, seed, overrides in jobs:
        settings = settings_for(kind, "small", seed, **overrides)
        paths[name] = collect(kind, data_dir / name, settings, workers=cfg.workers, progress=progress)
    return paths


def train_stage(cfg: DemoConfig, data: dict[str, Path], method: str, progress: bool = True) -> Path:
    """Stage 2: train ``method`` (``navformer`` or the ``dt`` baseline); returns its run folder."""
    from navformer_rl.data.schema import DatasetKind
    from navformer_rl.training import load_train_config, train

    run_dir = cfg.out_dir / "train" / method
    overrides = [
        f"ablation={'dt' if method == 'dt' else 'none'}",
        f"seed={cfg.seed}",
        f"output_dir={run_dir}",
        "resume=true",
        f"data.exploration_path={data[DatasetKind.EXPLORATION.value]}",
        f"data.collision_path={data[DatasetKind.COLLISION_AVOIDANCE.value]}",
        f"data.ssl_path={data[DatasetKind.SSL.value]}",
        f"data.exploration_batch_trajs={cfg.exploration_batch}",
        f"data.collision_batch_trajs={cfg.collision_batch}",
        f"data.ssl_batch_pairs={cfg.ssl_batch}",
        f"optim.iterations={cfg.iterations}",
        f"checkpoint.interval={max(1, cfg.iterations // 4)}",
        "model.autocast_dtype=bfloat16",
        "model.encoder_micro_batch=512",
        f"logger.progress={str(progress).lower()}",
        f"validation.interval={max(1, cfg.iterations // 4)}",
    ]
    for kind, key in (("e", "exploration_path"), ("ca", "collision_path")):
        if f"held_out_{kind}" in data:
            overrides.append(f"validation.{key}={data[f'held_out_{kind}']}")
    result = train(load_train_config(overrides))
    return result.run_dir


def evaluate_stage(cfg: DemoConfig, train_dirs: dict[str, Path], progress: bool = True) -> list[Path]:
    """Stage 3: every method on one fixed episode set; returns the evaluation folders."""
    from navformer_rl.evaluation.episodes import make_protocol_episodes, save_episode_set
    from navformer_rl.evaluation.harness import evaluate

    eval_dir = cfg.out_dir / "eval"
    episodes = make_protocol_episodes(
        cfg.setups,
        cfg.trials_per_setup,
        cfg.trials_per_world,
        seed=cfg.seed,
        max_steps=cfg.max_steps,
        workers=cfg.workers,
    )
    save_episode_set(episodes, eval_dir / "episode_set.json")
    folders = []
    for method in cfg.methods:
        result = evaluate(
            method,
            episodes,
            eval_dir / method,
            checkpoint=train_dirs.get(method),
            workers=cfg.workers,
            seed=cfg.seed,
            videos_per_setup=cfg.videos_per_setup,
            progress=progress,
        )
        folders.append(result.out_dir)
    return folders


class StageTimes:
    """The wall-clock seconds that computed each stage's current result, kept in ``<out>/stage_times.json``.

    :meth:`run` times a stage and reads a fingerprint of its result before and after it: a stage that ended
    normally with the fingerprint unchanged computed nothing (it found its result finished), so the time
    recorded for that result stays as it was; otherwise this invocation's time is added to it (an
    interrupted run and the rerun that finishes it add up). When the result is not the one recorded (none
    yet, deleted, or made without this file) its time counts from zero, and is unknown (None) when this
    invocation found it finished.

    Args:
        out_dir: the demo's run folder.
    """

    def __init__(self, out_dir: Path) -> None:
        self.path = Path(out_dir) / STAGE_TIMES_FILENAME
        self.saved: dict[str, dict[str, Any]] = {}
        try:
            loaded = json.loads(self.path.read_text())
        except (OSError, ValueError):
            loaded = {}
        if isinstance(loaded, dict):
            self.saved = {k: v for k, v in loaded.items() if isinstance(v, dict)}
        self.this_invocation: dict[str, float] = {}
        """Seconds each stage took in this invocation."""

    def run(self, stage: str, fingerprint: Callable[[], str | None], work: Callable[[], T]) -> T:
        """``work()``, timed as ``stage``; ``fingerprint()`` identifies the stage's result (None: none)."""
        before = fingerprint()
        entry = self.saved.get(stage, {})
        # the recorded time belongs to this result; with no result yet, to the unfinished work towards it
        same = "result" in entry and entry["result"] == before
        carried = entry.get("seconds") if same else None
        started = time.perf_counter()
        finished = False
        try:
            value = work()
            finished = True
            return value
        finally:
            elapsed = time.perf_counter() - started
            self.this_invocation[stage] = elapsed
            try:
                after = fingerprint()
            except Exception:  # a half-written result after an error: time it as new work
                after = None
            if finished and before is not None and after == before:
                seconds = carried  # found finished: its time is the one recorded (None: not recorded)
            else:
                seconds = round((carried or 0.0) + elapsed, 3)
            self.saved[stage] = {"seconds": seconds, "result": after}
            try:
                write_json(self.path, self.saved)
            except OSError:
                if finished:
                    raise
                # the stage's own error is the one to report; its time is lost with this file

    def seconds(self, stage: str) -> float | None:
        """The seconds that computed ``stage``'s current result (None: not known)."""
        return self.saved.get(stage, {}).get("seconds")


def _digest(parts: list[str]) -> str:
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _collect_fingerprint(cfg: DemoConfig) -> str | None:
    """The collection's state: the datasets' ``metadata.json`` (status, settings, counts)."""
    from navformer_rl.data.writer import METADATA_FILE

    texts = []
    for name in ("e", "ca", "ssl", "held_out_e", "held_out_ca"):
        path = cfg.out_dir / "data" / name / METADATA_FILE
        try:  # bytes: a damaged file is the collection's to report (it names the file and the fix)
            texts.append(hashlib.sha256(path.read_bytes()).hexdigest())
        except FileNotFoundError:
            texts.append("-")
        except OSError:
            texts.append("unreadable")
    return None if set(texts) == {"-"} else _digest(texts)


def _train_fingerprint(cfg: DemoConfig, method: str) -> str | None:
    """The training run's state: the name of its latest checkpoint."""
    from navformer_rl.checkpoint import latest_checkpoint

    try:
        latest = latest_checkpoint(cfg.out_dir / "train" / method)
    except (OSError, ValueError):
        return None
    return None if latest is None else latest.name


def _evaluation_seconds(folders: list[Path]) -> float | None:
    """The sum of the evaluations' ``run.json`` ``seconds`` (None when one is unknown)."""
    total = 0.0
    for folder in folders:
        try:
            seconds = json.loads((folder / "run.json").read_text()).get("seconds")
        except (OSError, ValueError, AttributeError):
            seconds = None
        if not isinstance(seconds, int | float):
            return None
        total += seconds
    return round(total, 3)


def run_demo(cfg: DemoConfig, progress: bool = True, log: Callable[[str], None] = print) -> Path:
    """Run the four stages; returns the path of ``report.md``. See the module docstring."""
    cfg.validate()
    cfg.out_dir.mkdir(parents=True, exist_ok=True)
    clock = StageTimes(cfg.out_dir)

    log(f"[1/4] collecting D_e, D_ca, D_ssl and held-out D_e, D_ca into {cfg.out_dir / 'data'}")
    data = clock.run("collect", lambda: _collect_fingerprint(cfg), lambda: collect_stage(cfg, progress))

    train_dirs: dict[str, Path] = {}
    for method in (m for m in TRAINED_METHODS if m in cfg.methods):
        log(f"[2/4] training {method} ({cfg.iterations} iterations)")
        train_dirs[method] = clock.run(
            f"train {method}",
            lambda method=method: _train_fingerprint(cfg, method),
            lambda method=method: train_stage(cfg, data, method, progress),
        )
    timings = {stage: (clock.seconds(stage), seconds) for stage, seconds in clock.this_invocation.items()}

    started = time.perf_counter()
    log(f"[3/4] evaluating {', '.join(cfg.methods)} on the '{cfg.setups}' episodes")
    folders = evaluate_stage(cfg, train_dirs, progress)
    timings["evaluate"] = (_evaluation_seconds(folders), time.perf_counter() - started)

    started = time.perf_counter()
    log("[4/4] writing the report")
    from navformer_rl.demo_report import write_demo_report

    report = write_demo_report(cfg, data, train_dirs, folders, timings)
    log(f"done: {report}")
    log(stage_time_table({**timings, "report": (None, time.perf_counter() - started)}))
    return report


def stage_time_table(timings: dict[str, tuple[float | None, float]]) -> str:
    """The table printed at the end of the demo: per stage (``timings``: ``(seconds that computed its result,
    None when not recorded; seconds in this invocation)``) both times as ``m:ss``, and this invocation's
    total."""
    width = max(len(stage) for stage in [*timings, "total"])
    rows = [f"{'stage':<{width}}  {'this run':>8}  {'computing the result':>20}"]
    for stage, (computed, now) in timings.items():
        rows.append(f"{stage:<{width}}  {_minutes(now):>8}  {_minutes(computed):>20}")
    rows.append(f"{'total':<{width}}  {_minutes(sum(now for _, now in timings.values())):>8}")
    return "\n".join(rows)


def _minutes(seconds: float | None) -> str:
    """``seconds`` as ``m:ss`` (``h:mm:ss`` from an hour on); ``-`` for None."""
    if seconds is None:
        return "-"
    minutes, secs = divmod(round(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def _demo_config_from_args(args: argparse.Namespace) -> DemoConfig:
    overrides = {
        name: getattr(args, name)
        for name in ("seed", "workers", "iterations")
        if getattr(args, name, None) is not None
    }
    if args.methods:
        overrides["methods"] = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    return DemoConfig.preset(args.preset, out_dir=Path(args.out), **overrides)


def _run_demo_command(args: argparse.Namespace) -> int:
    cfg = _demo_config_from_args(args)
    run_demo(cfg, progress=not args.no_progress)
    return 0


def _run_world_demo_command(args: argparse.Namespace) -> int:
    from navformer_rl.envs.demo import run_world_demo

    paths = run_world_demo(
        args.out,
        size=args.size,
        n_robots=args.robots,
        steps=args.steps,
        seed=args.seed,
        progress=not args.no_progress,
    )
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``demo`` and ``world-demo`` to the ``navformer`` CLI."""
    demo = subparsers.add_parser(
        "demo",
        help="end to end: collect -> train -> evaluate -> report (8-15 min on 2 CPU cores)",
        description="Collect small D_e / D_ca / D_ssl with the experts, train NavFormer and the DT baseline, "
        "evaluate them with VRW and FCA on fixed episodes, and write report.md in --out. Rerun the same "
        "command to resume after an interruption.",
    )
    demo.add_argument(
        "--out", type=cli_args.output_folder, default="runs/demo", help="run folder (default runs/demo)"
    )
    demo.add_argument(
        "--preset",
        default="default",
        choices=("default", "quick"),
        help="default: 8-15 min on 2 cores; quick: a few minutes, a smoke check",
    )
    demo.add_argument("--seed", type=cli_args.seed, help="base seed (default 0)")
    demo.add_argument(
        "--workers", type=cli_args.int_at_least(1), help="processes for collection and evaluation (default 2)"
    )
    demo.add_argument("--iterations", type=cli_args.int_at_least(1), help="training iterations per model")
    demo.add_argument("--methods", help=f"comma-separated subset of {','.join(TRAINED_METHODS + BASELINES)}")
    demo.add_argument("--no-progress", action="store_true", help="no progress bars")
    demo.set_defaults(run=_run_demo_command)

    world = subparsers.add_parser(
        "world-demo",
        help="a seeded maze with moving robots: top-down map + egocentric video",
        description="Generate a seeded maze with several robots, drive them with the goal-seeking obstacle "
        "policy, and write map.png (trajectories) and egocentric.mp4 into --out.",
    )
    world.add_argument(
        "--out",
        type=cli_args.output_folder,
        default="runs/world-demo",
        help="output folder (default runs/world-demo)",
    )
    world.add_argument("--size", type=float, default=12.5, help="maze side in metres, 5-17.5 (default 12.5)")
    world.add_argument(
        "--robots", type=cli_args.int_at_least(1), default=4, help="number of robots (default 4)"
    )
    world.add_argument(
        "--steps", type=cli_args.int_at_least(1), default=200, help="steps of 0.2 s (default 200)"
    )
    world.add_argument("--seed", type=cli_args.seed, default=0, help="world seed (default 0)")
    world.add_argument("--no-progress", action="store_true", help="no progress bar")
    world.set_defaults(run=_run_world_demo_command)


def environment_summary() -> dict[str, str]:
    """Machine facts recorded in the report (threads, torch version, device)."""
    import platform

    import torch

    return {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cpu_count": str(os.cpu_count()),
        "cuda": str(torch.cuda.is_available()),
    }


def write_json(path: Path, payload: dict) -> None:
    """Atomically and durably write ``payload`` as JSON."""
    atomic_write_text(path, json.dumps(payload, indent=2, default=str) + "\n")
