"""Two diagnoses of the same episodes compared robot-trial by robot-trial: the share of robot-trials that
succeed, end stuck, or ever see their target within 3 m, and A - B with a 95 % interval from resampling
whole trials (as ``navformer evaluate compare`` pairs SR).

    >>> from navformer_rl.evaluation.diagnose.paired import paired_robot_trial_shares
    >>> rows = paired_robot_trial_shares("runs/diagnosis/navformer", "runs/diagnosis/dt")  # doctest: +SKIP
    >>> rows["sighted"].difference, rows["sighted"].interval                               # doctest: +SKIP

``navformer evaluate diagnose-pair A B`` prints :func:`paired_shares_markdown` of the same.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from navformer_rl.evaluation.diagnose.diagnosis import ROBOT_TRIALS, load_diagnosis
from navformer_rl.evaluation.measures import bootstrap_mean_interval

SHARE_NAMES = {
    "success": "succeeds",
    "sighted": "sees its target within 3 m",
    "stuck": "ends stuck",
}
"""How the markdown table names each measure of :data:`ROBOT_TRIAL_SHARES`."""

ROBOT_TRIAL_SHARES = {
    "success": lambda row: row["outcome"] == "success",
    "sighted": lambda row: row["first_sighting_step"] is not None,
    "stuck": lambda row: row["outcome"] == "stuck",
}
"""Per-robot-trial yes/no measures of ``robot_trials.jsonl``: it succeeded; its target was ever in view within
3 m (``first_sighting_step`` set); it ended stuck."""


@dataclass(frozen=True)
class PairedShare:
    """One measure's share of robot-trials in A and in B, and A - B with its interval (fractions)."""

    measure: str
    a: float
    b: float
    difference: float
    interval: tuple[float, float]
    n_robot_trials: int
    n_trials: int

    def excludes_zero(self) -> bool:
        """Whether the interval lies wholly on one side of zero."""
        low, high = self.interval
        return low > 0 or high < 0


def _rows(folder: Path) -> dict[tuple[str, int], dict[str, Any]]:
    path = folder / ROBOT_TRIALS
    if not path.is_file():
        raise FileNotFoundError(
            f"{folder}: no {ROBOT_TRIALS}; expected a folder written by `evaluate diagnose`"
        )
    rows = (json.loads(line) for line in path.read_text().splitlines() if line.strip())
    return {(row["episode_id"], row["robot"]): row for row in rows}


def paired_robot_trial_shares(
    folder_a: str | os.PathLike,
    folder_b: str | os.PathLike,
    setups: tuple[str, ...] | None = None,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int = 0,
) -> dict[str, PairedShare]:
    """``{measure: PairedShare}`` over :data:`ROBOT_TRIAL_SHARES` for two diagnosis folders.

    Args:
        folder_a, folder_b: ``navformer evaluate diagnose`` output folders of the same episode set (a
            ValueError names them otherwise, or names the first robot-trial one of them lacks).
        setups: only these setups' robot-trials (None: all).
        confidence, n_resamples, seed: the percentile bootstrap over whole trials (``episode_id``).
    """
    folders = [Path(folder_a), Path(folder_b)]
    hashes = [load_diagnosis(folder)["episode_set"]["content_sha256"] for folder in folders]
    if hashes[0] != hashes[1]:
        raise ValueError(
            f"{folders[0]} and {folders[1]} diagnosed different episode sets ({hashes[0][:12]}... and "
            f"{hashes[1][:12]}...): compare diagnoses of the same episodes"
        )
    a_rows, b_rows = (_rows(folder) for folder in folders)
    if set(a_rows) != set(b_rows):
        episode, robot = sorted(set(a_rows) ^ set(b_rows))[0]
        raise ValueError(
            f"robot {robot} of episode {episode!r} is measured in only one of {folders[0]} and {folders[1]}"
        )
    keys = sorted(key for key in a_rows if setups is None or a_rows[key]["setup"] in setups)
    if not keys:
        raise ValueError(f"setups={setups!r}: no robot-trial of {folders[0]} is in these setups")
    _, groups = np.unique(np.array([episode for episode, _ in keys]), return_inverse=True)
    out = {}
    for measure, test in ROBOT_TRIAL_SHARES.items():
        a = np.array([test(a_rows[key]) for key in keys], dtype=np.float64)
        b = np.array([test(b_rows[key]) for key in keys], dtype=np.float64)
        out[measure] = PairedShare(
            measure=measure,
            a=float(a.mean()),
            b=float(b.mean()),
            difference=float((a - b).mean()),
            interval=bootstrap_mean_interval(a - b, groups, confidence, n_resamples, seed),
            n_robot_trials=len(keys),
            n_trials=int(groups.max()) + 1,
        )
    return out


def paired_shares_markdown(names: tuple[str, str], shares: dict[str, PairedShare]) -> str:
    """A markdown table of :func:`paired_robot_trial_shares`: per measure A's and B's shares and A - B in
    points with its interval, ``*`` where it excludes zero."""
    first = next(iter(shares.values()))
    lines = [
        f"| robot-trials ({first.n_robot_trials} in {first.n_trials} trials) | {names[0]} | {names[1]} | "
        f"{names[0]} - {names[1]} (points) |",
        "|---|---|---|---|",
    ]
    for measure, share in shares.items():
        low, high = share.interval
        star = " *" if share.excludes_zero() else ""
        lines.append(
            f"| {SHARE_NAMES[measure]} | {100 * share.a:.1f} % | {100 * share.b:.1f} % | "
            f"{100 * share.difference:+.1f} [{100 * low:+.1f}, {100 * high:+.1f}]{star} |"
        )
    note = (
        "\nPaired on the same robot-trials; 95 % percentile-bootstrap intervals resampling whole trials; "
        "* : the interval excludes zero.\n"
    )
    return "\n".join(lines) + "\n" + note
