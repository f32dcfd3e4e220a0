"""The learning curve: the policy on a small fixed episode set (:func:`fixed_episode_eval`), the log
(:class:`ProgressLog`, ``progress.csv``) and its plot (:func:`plot_learning_curves`, one run or several).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from navformer_rl.envs.world import EpisodeSpec
from navformer_rl.utils.durable import atomic_path, atomic_write_text

PROGRESS_FILENAME = "progress.csv"
CURVE_FILENAME = "learning_curve.png"
PROGRESS_COLUMNS = (
    "iteration",
    "frames",
    "robot_frames",
    "episodes",
    "train_return",
    "train_success_rate",
    "eval_return",
    "eval_success_rate",
    "loss_objective",
    "loss_critic",
    "loss_entropy",
    "entropy",
    "kl_approx",
    "clip_fraction",
    "grad_norm",
    "lr",
    "collect_seconds",
    "update_seconds",
    "frames_per_second",
)
"""One row per PPO batch: counters after the batch (``frames``: env steps, ``robot_frames``: steps of
robots still searching, ``episodes``: finished), the finished episodes' mean per-robot shaped return and
success rate, the fixed-episode evaluation (NaN when it did not run), the update's mean loss terms, and
timing (``frames_per_second``: env steps over collection + update)."""


def fixed_episode_eval(
    policy,
    env,
    episodes: int,
    sizes: Sequence[float],
    seed: int,
    max_steps: int,
) -> dict[str, float]:
    """Run ``policy`` (deterministic: an :class:`~navformer_rl.baselines.online.OnlinePolicy`) on
    ``episodes`` fixed episodes of the PPO env ``env`` (:func:`~navformer_rl.online.envs.make_env`): episode
    ``k`` is the world of seed ``seed + k`` with side ``sizes[k % len(sizes)]``, its own starts and targets,
    ``max_steps`` steps at most.

    Returns ``{"return": mean per-robot shaped return, "success_rate": share of robots that reached their
    target}``.
    """
    base = env.base_env
    returns: list[float] = []
    successes: list[float] = []
    with torch.no_grad():
        for k in range(episodes):
            config = dataclasses.replace(base.config, size=float(sizes[k % len(sizes)]))
            base.set_next_episode(EpisodeSpec(config=config, world_seed=seed + k))
            rollout = env.rollout(max_steps, policy, break_when_any_done=True)
            last = rollout[-1]["next"]
            returns.extend(last.get(("agents", "episode_reward")).reshape(-1).tolist())
            successes.extend(last.get(("privileged", "success")).reshape(-1).float().tolist())
    return {
        "return": sum(returns) / len(returns),
        "success_rate": sum(successes) / len(successes),
    }


class ProgressLog:
    """``<run_dir>/progress.csv`` (:data:`PROGRESS_COLUMNS`), rewritten atomically after every row.

    Resuming at iteration ``k`` keeps the rows up to ``k`` (rows written after the checkpoint are dropped,
    since those batches are trained again).
    """

    def __init__(self, run_dir: str | os.PathLike, resume_iteration: int = 0) -> None:
        self.path = Path(run_dir) / PROGRESS_FILENAME
        self.rows: list[dict[str, Any]] = []
        if resume_iteration and self.path.is_file():
            with open(self.path, newline="") as handle:
                self.rows = [r for r in csv.DictReader(handle) if int(r["iteration"]) <= resume_iteration]

    def append(self, row: dict[str, Any]) -> None:
        self.rows.append({k: row.get(k, math.nan) for k in PROGRESS_COLUMNS})
        out = io.StringIO()
        writer = csv.DictWriter(out, fieldnames=PROGRESS_COLUMNS, lineterminator="\n")
        writer.writeheader()
        for r in self.rows:
            writer.writerow({k: _fmt(v) for k, v in r.items()})
        atomic_write_text(self.path, out.getvalue())


def _fmt(value: Any) -> Any:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.6g}"
    return value


def read_progress(path: str | os.PathLike) -> list[dict[str, float]]:
    """The rows of a ``progress.csv`` as floats."""
    with open(path, newline="") as handle:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(handle)]


def running_mean(values: Sequence[float], window: int) -> list[float]:
    """Mean of the last ``window`` non-NaN values at each position (NaN until one exists)."""
    out: list[float] = []
    recent: list[float] = []
    for value in values:
        if not math.isnan(value):
            recent = (recent + [value])[-window:]
        out.append(sum(recent) / len(recent) if recent else math.nan)
    return out


def plot_learning_curves(
    runs: Mapping[str, str | os.PathLike], path: str | os.PathLike, title: str = "", window: int = 10
) -> Path:
    """PNG with two panels against env frames, one colour per run (``{label: progress.csv}``): the mean
    per-robot shaped return and the success rate of the training episodes (each batch faint, the running
    mean over ``window`` batches solid) and of the fixed evaluation episodes (markers); written atomically."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(7, 6), sharex=True, layout="constrained")
    for index, (label, progress_csv) in enumerate(runs.items()):
        rows = read_progress(progress_csv)
        frames = [r["frames"] for r in rows]
        color = f"C{index}"
        name = f"{label}: " if label else ""
        for ax, train_key, eval_key in (
            (axes[0], "train_return", "eval_return"),
            (axes[1], "train_success_rate", "eval_success_rate"),
        ):
            train = [r[train_key] for r in rows]
            ax.plot(frames, train, ".", color=color, alpha=0.25, markersize=3)
            ax.plot(frames, running_mean(train, window), "-", color=color,
                    label=f"{name}training episodes ({window}-batch mean)")  # fmt: skip
            evaluated = [(f, r[eval_key]) for f, r in zip(frames, rows) if not math.isnan(r[eval_key])]
            if evaluated:
                ax.plot(*zip(*evaluated), "o--", color=color, label=f"{name}fixed episodes (mean action)")
    for ax, label in zip(axes, ("return per robot", "SR")):
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=8)
    axes[1].set_xlabel("env frames")
    if title:
        fig.suptitle(title)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return path
