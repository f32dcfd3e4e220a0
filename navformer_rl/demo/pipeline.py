"""The end-to-end demo (``navformer demo``) and the world demo (``navformer world-demo``).

``run_demo`` is the whole NavFormer pipeline at a small scale, in one run folder:

1. collect D_e, D_ca and D_ssl with the experts (``<out>/data/{e,ca,ssl}``), and small held-out D_e / D_ca
   from other mazes (``<out>/data/held_out_{e,ca}``; resumable);
2. train NavFormer and the DT baseline on them (``<out>/train/{navformer,dt}``; checkpoints), scoring the
   action loss on the held-out trajectories as they train (``validation.*``);
3. evaluate NavFormer, DT, VRW and FCA on the same fixed episodes (``<out>/eval/<method>``), and the shipped
   weights of ``DemoConfig.shipped`` when this installation ships them (``<out>/eval/pretrained_<name>``);
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

import hashlib
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from navformer_rl.demo.config import (
    HELD_OUT_SEED_OFFSET,
    STAGE_TIMES_FILENAME,
    TRAINED_METHODS,
    DemoConfig,
    write_json,
)

T = TypeVar("T")


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
    from navformer_rl.utils.devices import fast_autocast_dtype, resolve_device

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
        "model.encoder_micro_batch=512",
        f"logger.progress={str(progress).lower()}",
        f"validation.interval={max(1, cfg.iterations // 4)}",
    ]
    autocast = fast_autocast_dtype(resolve_device("auto"))  # bf16 where the hardware has it, else fp32
    if autocast is not None:
        overrides.append(f"model.autocast_dtype={autocast}")
    for kind, key in (("e", "exploration_path"), ("ca", "collision_path")):
        if f"held_out_{kind}" in data:
            overrides.append(f"validation.{key}={data[f'held_out_{kind}']}")
    result = train(load_train_config(overrides))
    return result.run_dir


def evaluate_stage(cfg: DemoConfig, train_dirs: dict[str, Path], progress: bool = True) -> list[Path]:
    """Stage 3: every method on one fixed episode set; returns the evaluation folders."""
    from navformer_rl.evaluation.episodes import make_protocol_episodes, save_episode_set
    from navformer_rl.evaluation.harness import EvaluateConfig, evaluate

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
    common = EvaluateConfig(
        workers=cfg.workers, seed=cfg.seed, videos_per_setup=cfg.videos_per_setup, progress=progress
    )
    folders = []
    for method in cfg.methods:
        result = evaluate(method, episodes, eval_dir / method, common, checkpoint=train_dirs.get(method))
        folders.append(result.out_dir)
    for name, method in shipped_weights(cfg).items():
        pretrained = f"pretrained:{name}"
        result = evaluate(
            method, episodes, eval_dir / f"pretrained_{name}", common, checkpoint=pretrained, label=pretrained
        )
        folders.append(result.out_dir)
    return folders


def shipped_weights(cfg: DemoConfig) -> dict[str, str]:
    """``{name: method}`` of the names in ``cfg.shipped`` that this installation ships (``navformer pretrained
    list``); the registry records each one's method (``navformer``, ``dt``)."""
    from navformer_rl.training.pretrained_registry import read_registry

    registry = read_registry()
    return {name: registry[name]["method"] for name in cfg.shipped if name in registry}


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
    from navformer_rl.training.checkpoint import latest_checkpoint

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
    shipped = [f"pretrained:{name}" for name in shipped_weights(cfg)]
    log(f"[3/4] evaluating {', '.join([*cfg.methods, *shipped])} on the '{cfg.setups}' episodes")
    for name in sorted(set(cfg.shipped) - set(shipped_weights(cfg))):
        log(f"      pretrained:{name} is not shipped in this installation: not evaluated")
    folders = evaluate_stage(cfg, train_dirs, progress)
    timings["evaluate"] = (_evaluation_seconds(folders), time.perf_counter() - started)

    started = time.perf_counter()
    log("[4/4] writing the report")
    from navformer_rl.demo.report import write_demo_report

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
