"""Training seeds side by side: SR / SPL / CR of several checkpoints of one configuration, as mean ± std.

One training run is one draw of the training's randomness (initial weights, batches, dropout); at the
small budgets a CPU affords, two seeds of the same configuration can differ by more than two
configurations do. ``summarize_seed_groups({"navformer": [eval_s0, eval_s1], "dt": [...]})`` reads
evaluation folders written by :func:`~navformer_rl.evaluation.harness.evaluate` (one per trained seed,
every folder on the same episode set) and gives, per group:

- each seed's SR / SPL / CR over all its measured robot-trials (every setup pooled);
- their mean and sample standard deviation over seeds (``ddof = 1``; ``nan`` with one seed): the spread
  a new seed of that configuration can be expected to land in;
- the pooled estimate over every robot-trial of every seed, with the harness's trial-clustered intervals
  (Wilson for SR, bootstrap for SPL / CR; a trial of seed 0 and the same trial of seed 1 are different
  clusters). This interval describes these checkpoints on these episodes; it does not include the
  between-seed variance, which the standard deviation shows.

Folders of one group may share a label (``navformer evaluate --label``), but not a checkpoint: the same
weights evaluated twice are not two seeds (for VRW / FCA, which have no checkpoint, the folders need
different ``--seed``). All folders, across groups too, must have run the same
episode set (``run.json``'s ``content_sha256``), so that the groups face the same mazes.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from navformer_rl.evaluation.measures import MetricSummary, RobotTrial, summarize
from navformer_rl.evaluation.tables import format_ratio, format_sr, read_records, read_run

METRICS: tuple[str, ...] = ("sr", "spl", "cr")
"""The metrics summarised over seeds (see :mod:`navformer_rl.evaluation.measures`)."""


@dataclass(frozen=True)
class SeedRun:
    """One evaluated checkpoint: its folder, ``run.json`` label and checkpoint, and its metrics over every
    measured robot-trial (all setups pooled)."""

    folder: str
    label: str
    checkpoint: str | None
    metrics: MetricSummary


@dataclass(frozen=True)
class SeedGroupSummary:
    """One configuration over its seeds.

    Attributes:
        name: the group's name (a column label of your choosing).
        runs: one :class:`SeedRun` per seed, in the order given.
        mean, std: ``{"sr", "spl", "cr"} -> float`` over the seeds' values (``std``: sample standard
            deviation, ``nan`` with one seed).
        pooled: every robot-trial of every seed in one :class:`MetricSummary` (trials of different seeds are
            different clusters).
    """

    name: str
    runs: tuple[SeedRun, ...]
    mean: dict[str, float]
    std: dict[str, float]
    pooled: MetricSummary

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (intervals as ``[low, high]``, ``nan`` as ``None``)."""
        return _json_ready(dataclasses.asdict(self))


def _json_ready(value: Any) -> Any:
    if isinstance(value, float):
        return None if math.isnan(value) else value
    if isinstance(value, Mapping):
        return {key: _json_ready(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_json_ready(item) for item in value]
    return value


def _read_run(folder: Path) -> dict[str, Any]:
    """``run.json`` of ``folder``, checked to be an evaluation's (a label and an episode set)."""
    run = read_run(folder)
    if not isinstance(run, dict) or not isinstance(run.get("episode_set"), dict) or "label" not in run:
        raise ValueError(f"{folder / 'run.json'} is not an evaluation's run.json (no label / episode_set)")
    return run


def _policy_identity(run: Mapping[str, Any]) -> tuple[str, str]:
    """What makes an evaluated policy one seed: its weights' hash, or for a policy without a checkpoint
    (VRW, FCA: stochastic) its method and ``--seed``."""
    weights = run.get("checkpoint_sha256")
    if weights is not None:
        return ("checkpoint", f"checkpoint sha256 {weights[:12]}")
    return ("policy", f"method {run.get('method')!r} with seed {run.get('seed')!r}")


def _as_seed(records: Sequence[RobotTrial], index: int) -> list[RobotTrial]:
    """``records`` with episode ids prefixed by the seed's index,
    so that pooling keeps seeds' trials apart."""
    return [dataclasses.replace(r, episode_id=f"seed{index}/{r.episode_id}") for r in records]


def summarize_seed_groups(
    groups: Mapping[str, Sequence[str | os.PathLike]],
    confidence: float = 0.95,
    seed: int = 0,
    cluster: str = "trial",
) -> list[SeedGroupSummary]:
    """One :class:`SeedGroupSummary` per group of evaluation folders (module docstring).

    Args:
        groups: ``name -> [folder, ...]``, one folder per trained seed of that configuration.
        confidence, seed, cluster: level, bootstrap seed and resampling unit of the pooled intervals
            (:func:`~navformer_rl.evaluation.measures.summarize`).

    Raises:
        ValueError: no group, an empty group, a folder given twice, two folders of one group with the same
            checkpoint (by content hash; without one: the same method and seed), or folders evaluated on
            different episode sets.
        FileNotFoundError: a folder without ``run.json``.
    """
    if not groups:
        raise ValueError("summarize_seed_groups needs at least one group of evaluation folders")
    seen: dict[Path, str] = {}
    episode_set: tuple[str, Path] | None = None
    out = []
    for name, folders in groups.items():
        if not folders:
            raise ValueError(f"group {name!r} has no evaluation folder; give one folder per trained seed")
        runs, pooled_records, checkpoints = [], [], {}
        for index, folder in enumerate(map(Path, folders)):
            resolved = folder.resolve()
            if resolved in seen:
                where = (
                    f"group {name!r}" if seen[resolved] == name else f"groups {seen[resolved]!r} and {name!r}"
                )
                raise ValueError(f"{folder} is given twice ({where})")
            seen[resolved] = name
            run = _read_run(folder)
            digest = run["episode_set"].get("content_sha256")
            if episode_set is None:
                episode_set = (digest, folder)
            elif digest != episode_set[0]:
                raise ValueError(
                    f"{folder} was evaluated on another episode set than {episode_set[1]} (content_sha256 "
                    f"{str(digest)[:12]} vs {str(episode_set[0])[:12]}); seeds and groups are compared on "
                    "the same episodes: evaluate every checkpoint with the same --episodes file"
                )
            identity = _policy_identity(run)
            if identity in checkpoints:
                raise ValueError(
                    f"{checkpoints[identity]} and {folder} evaluated the same policy ({identity[1]}); "
                    f"group {name!r} needs one folder per seed"
                )
            checkpoints[identity] = folder
            records = read_records(folder / "episodes.jsonl")
            metrics = summarize(records, confidence, seed, cluster)
            runs.append(SeedRun(str(folder), run["label"], run.get("checkpoint"), metrics))
            pooled_records += _as_seed(records, index)
        values = {metric: np.array([getattr(r.metrics, metric) for r in runs]) for metric in METRICS}
        out.append(
            SeedGroupSummary(
                name=name,
                runs=tuple(runs),
                mean={metric: float(v.mean()) for metric, v in values.items()},
                std={
                    metric: float(v.std(ddof=1)) if len(v) > 1 else math.nan for metric, v in values.items()
                },
                pooled=summarize(pooled_records, confidence, seed, cluster),
            )
        )
    return out


def _mean_std(value: float, spread: float, percent: bool) -> str:
    scale, digits = (100.0, 1) if percent else (1.0, 3)
    if math.isnan(spread):
        return f"{scale * value:.{digits}f}{'%' if percent else ''}"
    return f"{scale * value:.{digits}f} ± {scale * spread:.{digits}f}{'%' if percent else ''}"


def seed_table_markdown(summaries: Sequence[SeedGroupSummary]) -> str:
    """A markdown table: one row per group with its seeds' SR, mean ± std of SR / SPL / CR over seeds, and
    the pooled SR / CR with their intervals."""
    lines = [
        "| Group | Seeds | SR per seed | SR mean ± std | SPL mean ± std | "
        "CR mean ± std | pooled SR | pooled CR |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in summaries:
        per_seed = ", ".join(f"{100 * r.metrics.sr:.1f}%" for r in s.runs)
        lines.append(
            f"| {s.name} | {len(s.runs)} | {per_seed} | {_mean_std(s.mean['sr'], s.std['sr'], True)} | "
            f"{_mean_std(s.mean['spl'], s.std['spl'], False)} | "
            f"{_mean_std(s.mean['cr'], s.std['cr'], False)} | {format_sr(s.pooled.sr, s.pooled.sr_ci)} | "
            f"{format_ratio(s.pooled.cr, s.pooled.cr_ci)} |"
        )
    return "\n".join(lines) + "\n"
