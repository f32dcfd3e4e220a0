"""Table IV's verdicts (paper §VII.D): each ablation against the full model on the same robot-trials, judged
against the full model's seed-to-seed spread.

The paper's Table IV claims that removing each part of NavFormer lowers its success rate. For each ablation,
given as one ``navformer evaluate`` folder per training seed, :func:`ablation_verdicts` gives on one setup
(Table IV's is ``12.5m-4r``) or pooled over every setup (``all``):

- the ablation's SR / SPL / CR on the paired robot-trials (each averaged over its seeds);
- ablation - full, paired on the same robot-trials and pooled over each side's seeds
  (:func:`~navformer_rl.evaluation.paired.pooled_paired_differences`: a two-level bootstrap when a side has
  several seeds);
- the full model's seed-to-seed spread: the sample standard deviation over its seeds of SR on those
  robot-trials (None with one seed). An ablation trained with one seed could land anywhere within that
  spread of its own mean, so a difference inside it says nothing about the part;
- the verdict on the paper's sign, from SR: ``holds`` (the interval lies below zero and the difference is
  larger than the spread), ``does not hold`` (the interval lies above zero and the difference is larger
  than the spread: removing the part helps here), ``cannot tell`` otherwise. With one seed of the full model
  the spread is unknown: the verdict rests on the paired interval alone and says ``(one seed)``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from navformer_rl.evaluation.paired import PairedDifference, pooled_paired_differences
from navformer_rl.evaluation.tables import ALL_SETUPS, read_records

TABLE4_SETUP = "12.5m-4r"
"""Table IV's setting: 12.5 m mazes with 4 robots (Table I's 12.5m-4r trials)."""

VERDICTS = ("holds", "does not hold", "cannot tell")
"""The verdicts on the paper's sign (module docstring)."""


@dataclass(frozen=True)
class AblationVerdict:
    """One ablation on one setup (or ``all``): ``difference`` is ablation - full (its ``a`` the ablation's
    means, ``b`` the full model's), ``seed_spread`` the full model's SR standard deviation over its seeds
    (a fraction; None with one seed), ``verdict`` one of :data:`VERDICTS`."""

    name: str
    difference: PairedDifference
    seed_spread: float | None
    verdict: str

    @property
    def setup(self) -> str:
        return self.difference.setup


def verdict(difference: PairedDifference, seed_spread: float | None) -> str:
    """The paper's claim "removing the part lowers SR" judged from ``difference`` (ablation - full) and the
    full model's seed-to-seed spread of SR (module docstring)."""
    low, high = difference.interval["sr"]
    d = difference.difference["sr"]
    beyond_spread = seed_spread is None or abs(d) > seed_spread
    if not math.isnan(low) and high < 0 and beyond_spread:
        return "holds"
    if not math.isnan(low) and low > 0 and beyond_spread:
        return "does not hold"
    return "cannot tell"


def _seed_spread(full: Sequence[Path], setup: str) -> float | None:
    """Sample standard deviation over the full model's seeds of its SR on ``setup`` (None with one seed)."""
    if len(full) < 2:
        return None
    rates = []
    for folder in full:
        records = [r for r in read_records(folder / "episodes.jsonl") if r.measured]
        rates.append(np.mean([r.success for r in records if setup in (ALL_SETUPS, r.setup)]))
    return float(np.std(rates, ddof=1))


def ablation_verdicts(
    full: Sequence[str | os.PathLike],
    ablations: Sequence[tuple[str, Sequence[str | os.PathLike]]],
    setup: str = TABLE4_SETUP,
    cluster: str = "trial",
    confidence: float = 0.95,
    seed: int = 0,
    n_resamples: int = 10_000,
) -> list[AblationVerdict]:
    """Each ablation against the full model on ``setup`` (``all``: every setup pooled).

    Args:
        full: the full model's evaluation folders, one per training seed.
        ablations: ``(name, folders)`` per ablation, one folder per training seed; every folder ran the same
            episode set.
        setup: a setup of those episodes (Table IV's ``12.5m-4r`` by default) or ``all``.
        cluster, confidence, seed, n_resamples: as :func:`~navformer_rl.evaluation.paired.paired_differences`.

    Raises:
        FileNotFoundError: a folder that is not a finished evaluation.
        ValueError: no ablation, a setup the episodes do not have, or folders that cannot be paired.
    """
    if not ablations:
        raise ValueError("no ablation given: name at least one ablation and its evaluation folders")
    full_folders = [Path(f) for f in full]
    differences = []
    for name, folders in ablations:
        _, rows = pooled_paired_differences(
            [Path(f) for f in folders], full_folders, (name, "full"), cluster, confidence, seed, n_resamples
        )
        by_setup = {row.setup: row for row in rows}
        if setup not in by_setup:
            raise ValueError(
                f"setup {setup!r} is not among the evaluated episodes' setups ({', '.join(by_setup)}); "
                "name one of them"
            )
        differences.append((name, by_setup[setup]))
    spread = _seed_spread(full_folders, setup)  # the full model's, the same for every ablation
    return [AblationVerdict(name, d, spread, verdict(d, spread)) for name, d in differences]


def ablations_markdown(rows: Sequence[AblationVerdict], confidence: float = 0.95) -> str:
    """Markdown table of :func:`ablation_verdicts` (one row per ablation), then how it is computed."""
    lines = [
        "| ablation | seeds | setup | SR / SPL / CR | - full (SR points) | full's seed sd (points) "
        "| verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        d = row.difference
        low, high = d.interval["sr"]
        interval = "[n/a]" if math.isnan(low) else f"[{100 * low:+.1f}, {100 * high:+.1f}]"
        spread = "-" if row.seed_spread is None else f"{100 * row.seed_spread:.1f}"
        note = " (one seed)" if row.seed_spread is None else ""
        lines.append(
            f"| {row.name} | {d.n_seeds[0]} | {d.setup} | {100 * d.a['sr']:.1f} % / {d.a['spl']:.3f} / "
            f"{d.a['cr']:.3f} | {100 * d.difference['sr']:+.1f} {interval} | {spread} | "
            f"{row.verdict}{note} |"
        )
    n_full = max((row.difference.n_seeds[1] for row in rows), default=1)
    lines += [
        "",
        f"Paired with the full model ({n_full} seed{'s' if n_full > 1 else ''}) on the same robot-trials, "
        f"{100 * confidence:g} % bootstrap intervals. The paper's claim, removing the part lowers SR: holds "
        "when the interval lies below zero and the difference exceeds the full model's seed-to-seed standard "
        "deviation; does not hold when it lies above zero and exceeds it; cannot tell otherwise (one seed: "
        "the interval alone).",
    ]
    return "\n".join(lines) + "\n"
