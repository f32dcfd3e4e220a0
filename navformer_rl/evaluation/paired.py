"""Paired differences between two evaluations of the same episodes (e.g. NavFormer - DT on Table I's trials).

Two methods run on one episode set meet the same mazes, starts, targets and obstacle robots, so their
difference is measured far more precisely than the two separate intervals suggest: a trial that is hard for
one is usually hard for the other. :func:`paired_differences` matches the robot-trials of two evaluation
folders by ``(episode_id, robot)`` and, per setup and pooled (``all``), gives the mean difference ``A - B`` of
success (SR, in points of the rate), SPL and CR with a cluster-bootstrap interval: whole trials (or whole
mazes, ``cluster="world"``) are resampled with replacement, each resample's statistic being the mean of the
per-robot differences of the drawn clusters (:func:`~navformer_rl.evaluation.measures.bootstrap_mean_interval`,
seeded). An interval that excludes zero says the difference holds on these episodes beyond the trial-to-trial
noise; it does not cover the spread between training seeds (``navformer evaluate seeds``).

Only robots measured in both folders count (Table III's unseen obstacle robots are not measured).

:func:`unseen_obstacle_differences` pairs within one folder instead: Table III's ``-unseen`` setup replays
the ``-seen`` setup's mazes, starts and targets with other obstacle robots, so each measured robot of an
unseen trial is matched with the same robot of the same seen trial (unseen - seen: the drop in §VII.C).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from navformer_rl.evaluation.episodes import SEEN_SUFFIX, UNSEEN_SUFFIX
from navformer_rl.evaluation.measures import (
    RobotTrial,
    bootstrap_mean_interval,
    check_cluster,
    min_trials_for_interval,
)
from navformer_rl.evaluation.tables import ALL_SETUPS, read_records, read_run, setup_order_key

PAIRED_METRICS: tuple[str, ...] = ("sr", "spl", "cr")
"""The compared metrics: success (SR), SPL and the collision rate (CR) of each robot-trial."""


@dataclass(frozen=True)
class PairedDifference:
    """``A - B`` on one setup (or ``all``): each metric's mean for A and B over the paired robot-trials, the
    mean difference and its ``(low, high)`` interval (``(nan, nan)`` with fewer clusters than
    :func:`~navformer_rl.evaluation.measures.min_trials_for_interval`)."""

    setup: str
    n_robot_trials: int
    n_trials: int
    n_clusters: int
    a: dict[str, float]
    b: dict[str, float]
    difference: dict[str, float]
    interval: dict[str, tuple[float, float]]

    def excludes_zero(self, metric: str) -> bool:
        """Whether ``metric``'s interval lies wholly on one side of zero."""
        low, high = self.interval[metric]
        return not math.isnan(low) and (low > 0 or high < 0)


def _metric_values(record: RobotTrial) -> dict[str, float]:
    return {"sr": float(record.success), "spl": record.spl, "cr": record.collision_rate}


def _paired(
    a: Sequence[RobotTrial], b: Sequence[RobotTrial], names: tuple[str, str]
) -> list[tuple[RobotTrial, RobotTrial]]:
    """The measured robot-trials of ``a`` and ``b`` matched by ``(episode_id, robot)``; ValueError naming the
    first unmatched one unless both cover the same measured robot-trials."""
    keyed = [{(r.episode_id, r.robot): r for r in records if r.measured} for records in (a, b)]
    for (mine, other), (name, other_name) in zip(
        ((keyed[0], keyed[1]), (keyed[1], keyed[0])), (names, names[::-1])
    ):
        missing = [key for key in mine if key not in other]
        if missing:
            episode, robot = missing[0]
            raise ValueError(
                f"{name} has robot {robot} of episode {episode!r} (and {len(missing) - 1} more) that {other_name} "
                "lacks: a paired comparison needs both evaluations finished on the same episodes"
            )
    return [(keyed[0][key], keyed[1][key]) for key in keyed[0]]


def _difference(
    setup: str,
    pairs: Sequence[tuple[RobotTrial, RobotTrial]],
    cluster: str,
    confidence: float,
    seed: int,
    n_resamples: int,
) -> PairedDifference:
    values = [(_metric_values(x), _metric_values(y)) for x, y in pairs]
    a = {m: np.array([va[m] for va, _ in values]) for m in PAIRED_METRICS}
    b = {m: np.array([vb[m] for _, vb in values]) for m in PAIRED_METRICS}
    if cluster == "trial":
        keys = [x.episode_id for x, _ in pairs]
    else:
        keys = [f"{x.setup}/{x.world_seed}" for x, _ in pairs]
    _, groups = np.unique(np.array(keys), return_inverse=True)
    interval = {
        m: bootstrap_mean_interval(a[m] - b[m], groups, confidence, n_resamples, seed) for m in PAIRED_METRICS
    }
    return PairedDifference(
        setup=setup,
        n_robot_trials=len(pairs),
        n_trials=len({x.episode_id for x, _ in pairs}),
        n_clusters=int(groups.max()) + 1,
        a={m: float(a[m].mean()) for m in PAIRED_METRICS},
        b={m: float(b[m].mean()) for m in PAIRED_METRICS},
        difference={m: float((a[m] - b[m]).mean()) for m in PAIRED_METRICS},
        interval=interval,
    )


def paired_differences(
    folder_a: str | os.PathLike,
    folder_b: str | os.PathLike,
    cluster: str = "trial",
    confidence: float = 0.95,
    seed: int = 0,
    n_resamples: int = 10_000,
) -> tuple[tuple[str, str], list[PairedDifference]]:
    """``A - B`` per setup and pooled (``all``, last) for two evaluation folders of one episode set.

    Args:
        folder_a, folder_b: ``navformer evaluate`` output folders (``run.json``, ``episodes.jsonl``).
        cluster: what the bootstrap resamples, ``trial`` or ``world`` (the mazes).
        confidence: the intervals' level; seed, n_resamples: the seeded bootstrap.

    Returns:
        ``((label A, label B), [PairedDifference, ...])`` in the tables' setup order.

    Raises:
        FileNotFoundError: a folder that is not a finished evaluation.
        ValueError: the folders ran different episode sets, or one lacks robot-trials of the other.
    """
    check_cluster(cluster)
    folders = (Path(folder_a), Path(folder_b))
    runs = [read_run(folder) for folder in folders]
    digests = [(run.get("episode_set") or {}).get("content_sha256") for run in runs]
    if digests[0] is None or digests[0] != digests[1]:
        raise ValueError(
            f"{folders[0]} and {folders[1]} ran different episode sets (content_sha256 {str(digests[0])[:12]} vs "
            f"{str(digests[1])[:12]}); a paired comparison needs both evaluated with the same --episodes file"
        )
    labels = (str(runs[0].get("label")), str(runs[1].get("label")))
    names = (f"{folders[0]} ({labels[0]})", f"{folders[1]} ({labels[1]})")
    pairs = _paired(*(read_records(folder / "episodes.jsonl") for folder in folders), names)
    if not pairs:
        raise ValueError(f"{folders[0]} and {folders[1]} hold no measured robot-trials to compare")
    setups = sorted({(x.size, x.n_robots, x.setup) for x, _ in pairs}, key=lambda key: setup_order_key(*key))
    out = [
        _difference(setup, [p for p in pairs if p[0].setup == setup], cluster, confidence, seed, n_resamples)
        for _, _, setup in setups
    ]
    out.append(_difference(ALL_SETUPS, pairs, cluster, confidence, seed, n_resamples))
    return labels, out


def _seen_partner(record: RobotTrial) -> tuple[str, int]:
    """``(episode_id, robot)`` of the seen trial an unseen robot-trial replays."""
    setup, trial = record.episode_id.split("/", 1)
    return f"{setup.removesuffix(UNSEEN_SUFFIX)}{SEEN_SUFFIX}/{trial}", record.robot


def unseen_obstacle_differences(
    folder: str | os.PathLike,
    confidence: float = 0.95,
    seed: int = 0,
    n_resamples: int = 10_000,
) -> tuple[str, PairedDifference]:
    """Unseen - seen obstacle robots (Table III) for one evaluation folder: every robot measured in a
    ``*-unseen`` trial against the same robot, maze, start and target in the ``*-seen`` trial it replays.

    Returns:
        ``(label, PairedDifference)`` with ``a`` = unseen, ``b`` = seen and whole trials resampled; its
        ``setup`` is the folder's label.

    Raises:
        FileNotFoundError: not a finished evaluation.
        ValueError: no unseen robot-trials, a missing seen partner, or a partner in another maze or with
            another shortest path (not the same episode set layout).
    """
    folder = Path(folder)
    label = str(read_run(folder).get("label"))
    records = read_records(folder / "episodes.jsonl")
    by_key = {(r.episode_id, r.robot): r for r in records}
    pairs = []
    for record in records:
        if not (record.measured and record.setup.endswith(UNSEEN_SUFFIX)):
            continue
        partner = by_key.get(_seen_partner(record))
        if partner is None:
            episode, robot = _seen_partner(record)
            raise ValueError(
                f"{folder}: robot {robot} of {record.episode_id!r} has no seen partner {episode!r}; evaluate the "
                "whole table3 episode set (make-episodes --protocol table3)"
            )
        if (
            partner.world_seed != record.world_seed
            or abs(partner.shortest_path - record.shortest_path) > 1e-3
        ):
            raise ValueError(
                f"{folder}: {record.episode_id!r} and {partner.episode_id!r} are not the same maze, start and "
                "target; the seen and unseen setups must come from one make-episodes --protocol table3 call"
            )
        pairs.append((record, partner))
    if not pairs:
        raise ValueError(
            f"{folder}: no measured robot-trials in a '*{UNSEEN_SUFFIX}' setup (Table III's episodes)"
        )
    return label, _difference(label, pairs, "trial", confidence, seed, n_resamples)


def _signed(value: float, percent: bool) -> str:
    return f"{100 * value:+.1f}" if percent else f"{value:+.3f}"


def _cell(row: PairedDifference, metric: str) -> str:
    percent = metric == "sr"
    low, high = row.interval[metric]
    text = _signed(row.difference[metric], percent)
    if math.isnan(low):
        return f"{text} [n/a]"
    mark = " *" if row.excludes_zero(metric) else ""
    return f"{text} [{_signed(low, percent)}, {_signed(high, percent)}]{mark}"


def paired_markdown(
    labels: tuple[str, str],
    rows: Sequence[PairedDifference],
    cluster: str = "trial",
    confidence: float = 0.95,
    row_header: str = "Setup",
) -> str:
    """Markdown table of :func:`paired_differences`: per setup (its name under ``row_header``) the paired
    counts, both SRs and the differences with intervals (``*``: the interval excludes zero), then a line
    saying how they are computed."""
    a, b = labels
    lines = [
        f"| {row_header} | trials | robot-trials | {a} SR | {b} SR | SR {a} - {b} (points) | SPL difference | "
        "CR difference |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row.setup} | {row.n_trials} | {row.n_robot_trials} | {100 * row.a['sr']:.1f} % | "
            f"{100 * row.b['sr']:.1f} % | {_cell(row, 'sr')} | {_cell(row, 'spl')} | {_cell(row, 'cr')} |"
        )
    units = {"trial": "trials", "world": "mazes"}[cluster]
    lines += [
        "",
        f"Paired on the same robot-trials; {100 * confidence:g} % percentile-bootstrap intervals resampling whole "
        f"{units} (n/a with fewer than {min_trials_for_interval(confidence)} {units}); * : the interval excludes "
        "zero.",
    ]
    return "\n".join(lines) + "\n"
