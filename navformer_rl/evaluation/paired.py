"""Paired differences between two evaluations of the same episodes (e.g. NavFormer - DT on Table I's trials).

Two methods run on one episode set meet the same mazes, starts, targets and obstacle robots, so their
difference is measured far more precisely than the two separate intervals suggest: a trial that is hard for
one is usually hard for the other. :func:`paired_differences` matches the robot-trials of two evaluation
folders by ``(episode_id, robot)`` and, per setup and pooled (``all``), gives the mean difference ``A - B`` of
success (SR, in points of the rate), SPL and CR with a cluster-bootstrap interval: whole trials (or whole
mazes, ``cluster="world"``) are resampled with replacement, each resample's statistic being the mean of the
per-robot differences of the drawn clusters
(:func:`~navformer_rl.evaluation.measures.bootstrap_mean_interval`, seeded). An interval that excludes zero
says the difference holds on these episodes beyond the trial-to-trial noise; it does not cover the spread
between training seeds (``navformer evaluate seeds``).

:func:`pooled_paired_differences` compares two *models* trained with several seeds each (one evaluation
folder per seed, all on one episode set): each robot-trial's value is its mean over a side's seeds, and the
interval resamples the seeds of each side with replacement as well as the trials (a two-level bootstrap), so
it widens with the seed-to-seed spread. With one folder per side it is :func:`paired_differences`.

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

from navformer_rl.evaluation.episodes import SEEN_SUFFIX, UNSEEN_SUFFIX, EpisodeSet
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
    """``A - B`` on one setup (or ``all``): each metric's mean for A and B over the paired robot-trials (and
    over each side's ``n_seeds`` training seeds), the mean difference and its ``(low, high)`` interval
    (``(nan, nan)`` with fewer clusters than
    :func:`~navformer_rl.evaluation.measures.min_trials_for_interval`)."""

    setup: str
    n_robot_trials: int
    n_trials: int
    n_clusters: int
    a: dict[str, float]
    b: dict[str, float]
    difference: dict[str, float]
    interval: dict[str, tuple[float, float]]
    n_seeds: tuple[int, int] = (1, 1)

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
                f"{name} has robot {robot} of episode {episode!r} (and {len(missing) - 1} more) that "
                f"{other_name} lacks: a paired comparison needs both evaluations "
                "finished on the same episodes"
            )
    return [(keyed[0][key], keyed[1][key]) for key in keyed[0]]


def _difference(
    setup: str,
    records: Sequence[Sequence[RobotTrial]],
    n_seeds: tuple[int, int],
    cluster: str,
    confidence: float,
    seed: int,
    n_resamples: int,
) -> PairedDifference:
    """``records``: per matched robot-trial, A's seeds' records then B's (``n_seeds`` of each)."""
    k_a, k_b = n_seeds
    values = np.array([[[_metric_values(r)[m] for r in row] for m in PAIRED_METRICS] for row in records])
    a_seeds, b_seeds = values[:, :, :k_a], values[:, :, k_a:]  # [robot-trial, metric, seed]
    a, b = a_seeds.mean(axis=2), b_seeds.mean(axis=2)
    first = [row[0] for row in records]
    keys = (
        [x.episode_id for x in first] if cluster == "trial" else [f"{x.setup}/{x.world_seed}" for x in first]
    )
    _, groups = np.unique(np.array(keys), return_inverse=True)
    if n_seeds == (1, 1):
        interval = {
            m: bootstrap_mean_interval(a[:, i] - b[:, i], groups, confidence, n_resamples, seed)
            for i, m in enumerate(PAIRED_METRICS)
        }
    else:
        interval = {
            m: _two_level_interval(a_seeds[:, i], b_seeds[:, i], groups, confidence, n_resamples, seed)
            for i, m in enumerate(PAIRED_METRICS)
        }
    return PairedDifference(
        setup=setup,
        n_robot_trials=len(records),
        n_trials=len({x.episode_id for x in first}),
        n_clusters=int(groups.max()) + 1,
        a={m: float(a[:, i].mean()) for i, m in enumerate(PAIRED_METRICS)},
        b={m: float(b[:, i].mean()) for i, m in enumerate(PAIRED_METRICS)},
        difference={m: float((a[:, i] - b[:, i]).mean()) for i, m in enumerate(PAIRED_METRICS)},
        interval=interval,
        n_seeds=n_seeds,
    )


def _two_level_interval(
    a: np.ndarray, b: np.ndarray, groups: np.ndarray, confidence: float, n_resamples: int, seed: int
) -> tuple[float, float]:
    """Percentile interval of ``mean(A) - mean(B)`` over robot-trials, ``a`` float ``[N, seeds of A]`` and
    ``b`` ``[N, seeds of B]``: each resample draws each side's seeds with replacement, then whole groups
    (``groups`` int ``[N]``) with replacement, and takes the mean over the drawn groups' robot-trials of the
    drawn A seeds' mean minus the drawn B seeds' mean. ``(nan, nan)`` with too few groups."""
    n_groups = int(groups.max()) + 1
    if n_groups < min_trials_for_interval(confidence):
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    counts = np.bincount(groups, minlength=n_groups).astype(np.float64)
    # each resample's seed weights (how often each seed is drawn, over the side's size) and group draws
    weights_a = (
        rng.multinomial(a.shape[1], np.full(a.shape[1], 1 / a.shape[1]), size=n_resamples) / a.shape[1]
    )
    weights_b = (
        rng.multinomial(b.shape[1], np.full(b.shape[1], 1 / b.shape[1]), size=n_resamples) / b.shape[1]
    )
    drawn = rng.multinomial(n_groups, np.full(n_groups, 1 / n_groups), size=n_resamples)  # [resamples, G]
    group_sums = [
        np.stack([np.bincount(groups, weights=v[:, k], minlength=n_groups) for k in range(v.shape[1])], 1)
        for v in (a, b)
    ]  # [G, seeds] per side
    sums = group_sums[0] @ weights_a.T - group_sums[1] @ weights_b.T  # [G, resamples]
    stats = (drawn * sums.T).sum(axis=1) / (drawn @ counts)
    alpha = (1.0 - confidence) / 2.0
    low, high = np.quantile(stats, [alpha, 1.0 - alpha])
    return float(low), float(high)


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
    return pooled_paired_differences([folder_a], [folder_b], None, cluster, confidence, seed, n_resamples)


def pooled_paired_differences(
    folders_a: Sequence[str | os.PathLike],
    folders_b: Sequence[str | os.PathLike],
    names: tuple[str, str] | None = None,
    cluster: str = "trial",
    confidence: float = 0.95,
    seed: int = 0,
    n_resamples: int = 10_000,
    episode_sets: Sequence[EpisodeSet] = (),
) -> tuple[tuple[str, str], list[PairedDifference]]:
    """``A - B`` per setup and pooled (``all``, last) for two models, each given as the evaluation folders of
    its training seeds on one episode set (module docstring: each robot-trial's mean over a side's seeds; a
    two-level bootstrap over seeds and trials when a side has several).

    Args:
        folders_a, folders_b: one ``navformer evaluate`` folder per training seed of A and of B.
        names: ``(name of A, name of B)``; None: the folders' labels (one folder per side) or
            ``"label + N seeds"``.
        cluster, confidence, seed, n_resamples: as :func:`paired_differences`.
        episode_sets: the episode sets of folders that ran different sets, which then pair when the sets
            hold the same robots (:meth:`EpisodeSet.robots_hash`: they differ only in their distractors,
            e.g. ``--distractors 0`` against a protocol's default); empty: every folder ran one set.

    Raises:
        FileNotFoundError: a folder that is not a finished evaluation.
        ValueError: a side with no folder or the same folder twice, folders of different episode sets (unless
            ``episode_sets`` shows they hold the same robots), or one lacking robot-trials of another.
    """
    check_cluster(cluster)
    sides = [[Path(f) for f in folders_a], [Path(f) for f in folders_b]]
    for side, folders in zip("AB", sides, strict=True):
        if not folders:
            raise ValueError(f"side {side} has no evaluation folder; give at least one per side")
        if len(set(folders)) != len(folders):
            raise ValueError(
                f"side {side} names a folder twice ({[str(f) for f in folders]}); give each seed once"
            )
    folders = [*sides[0], *sides[1]]
    runs = [read_run(folder) for folder in folders]
    digests = [(run.get("episode_set") or {}).get("content_sha256") for run in runs]
    robots = {episode_set.content_hash(): episode_set.robots_hash() for episode_set in episode_sets}
    for folder, digest in zip(folders[1:], digests[1:], strict=True):
        if digests[0] is not None and digest == digests[0]:
            continue
        if digests[0] in robots and digest in robots:
            if robots[digest] == robots[digests[0]]:
                continue
            raise ValueError(
                f"{folders[0]} and {folder} ran episode sets ({digests[0][:12]}, {digest[:12]}) whose robots "
                "differ (other worlds, starts or targets); only sets that differ in their distractors pair"
            )
        raise ValueError(
            f"{folders[0]} and {folder} ran different episode sets (content_sha256 "
            f"{str(digests[0])[:12]} vs {str(digest)[:12]}); a paired comparison needs every evaluation "
            "run with the same --episodes file, or both sets' files (compare --episodes) when they differ "
            "only in their distractors"
        )
    labels = [str(run.get("label")) for run in runs]
    if names is None:
        k_a = len(sides[0])
        names = tuple(  # type: ignore[assignment]
            side_labels[0] if len(side_labels) == 1 else f"{side_labels[0]} + {len(side_labels) - 1} seeds"
            for side_labels in (labels[:k_a], labels[k_a:])
        )
    described = [f"{folder} ({label})" for folder, label in zip(folders, labels, strict=True)]
    records = [read_records(folder / "episodes.jsonl") for folder in folders]
    matched = [_paired(records[0], other, (described[0], described[i])) for i, other in enumerate(records)]
    rows = [[pairs[j][1] for pairs in matched] for j in range(len(matched[0]))]
    if not rows:
        raise ValueError(f"{', '.join(map(str, folders))} hold no measured robot-trials to compare")
    n_seeds = (len(sides[0]), len(sides[1]))
    first = [row[0] for row in rows]
    setups = sorted({(x.size, x.n_robots, x.setup) for x in first}, key=lambda key: setup_order_key(*key))
    out = [
        _difference(
            setup,
            [row for row in rows if row[0].setup == setup],
            n_seeds,
            cluster,
            confidence,
            seed,
            n_resamples,
        )
        for _, _, setup in setups
    ]
    out.append(_difference(ALL_SETUPS, rows, n_seeds, cluster, confidence, seed, n_resamples))
    return names, out


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
                f"{folder}: robot {robot} of {record.episode_id!r} has no seen partner {episode!r}; evaluate "
                "the whole table3 episode set (make-episodes --protocol table3)"
            )
        if (
            partner.world_seed != record.world_seed
            or abs(partner.shortest_path - record.shortest_path) > 1e-3
        ):
            raise ValueError(
                f"{folder}: {record.episode_id!r} and {partner.episode_id!r} are not the same maze, start "
                "and target; the seen and unseen setups must come from one "
                "make-episodes --protocol table3 call"
            )
        pairs.append((record, partner))
    if not pairs:
        raise ValueError(
            f"{folder}: no measured robot-trials in a '*{UNSEEN_SUFFIX}' setup (Table III's episodes)"
        )
    return label, _difference(label, pairs, (1, 1), "trial", confidence, seed, n_resamples)


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
        f"| {row_header} | trials | robot-trials | {a} SR | {b} SR | SR {a} - {b} (points) | SPL difference "
        "| CR difference |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row.setup} | {row.n_trials} | {row.n_robot_trials} | {100 * row.a['sr']:.1f} % | "
            f"{100 * row.b['sr']:.1f} % | {_cell(row, 'sr')} | {_cell(row, 'spl')} | {_cell(row, 'cr')} |"
        )
    units = {"trial": "trials", "world": "mazes"}[cluster]
    seeds = max((row.n_seeds for row in rows), default=(1, 1))
    resampled = f"whole {units}" if seeds == (1, 1) else f"each side's training seeds and whole {units}"
    pooled = (
        ""
        if seeds == (1, 1)
        else f"each robot-trial's value is its mean over {seeds[0]} seeds of {a} and {seeds[1]} of {b}; "
    )
    lines += [
        "",
        f"Paired on the same robot-trials; {pooled}{100 * confidence:g} % percentile-bootstrap intervals "
        f"resampling {resampled} (n/a with fewer than {min_trials_for_interval(confidence)} {units}); * : "
        "the interval excludes zero.",
    ]
    return "\n".join(lines) + "\n"
