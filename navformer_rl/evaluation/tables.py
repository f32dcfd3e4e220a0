"""Per-setup aggregates of robot-trial records: JSONL in, CSV and a Table I-layout markdown table out."""

from __future__ import annotations

import csv
import gzip
import io
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from navformer_rl.constants import FURNISHED_FOOTPRINTS
from navformer_rl.evaluation.measures import (
    MetricSummary,
    RobotTrial,
    check_cluster,
    min_trials_for_interval,
    summarize,
)
from navformer_rl.utils.durable import atomic_write_text

ALL_SETUPS = "all"
"""Setup name of the row that pools every setup of a method."""

CSV_COLUMNS: tuple[str, ...] = (
    "method", "setup", "size", "n_robots", "n_worlds", "n_trials", "n_robot_trials", "cluster",
    "sr", "sr_low", "sr_high", "spl", "spl_low", "spl_high", "cr", "cr_low", "cr_high",
    "spl_disc", "spl_disc_low", "spl_disc_high",
)  # fmt: skip


@dataclass(frozen=True)
class SetupSummary:
    """The metrics of one method on one setup (``setup == "all"``: every setup pooled)."""

    method: str
    setup: str
    size: float | None
    n_robots: int | None
    metrics: MetricSummary


def read_records(path: str | os.PathLike) -> list[RobotTrial]:
    """Load robot-trial rows from a per-episode JSONL file (one JSON object per line); where ``path`` is
    missing, its gzip-compressed ``path.gz`` (how a kept record can be stored, e.g. ``docs/results/``)."""
    path = Path(path)
    compressed = path.with_name(path.name + ".gz")
    if path.is_file():
        text = path.read_text()
    elif compressed.is_file():
        try:
            text = gzip.decompress(compressed.read_bytes()).decode()
        except (OSError, EOFError, UnicodeDecodeError) as error:
            raise ValueError(f"{compressed} is not a gzip-compressed JSONL file ({error})") from None
        path = compressed
    else:
        raise FileNotFoundError(f"no per-episode records at {str(path)!r} (nor {compressed.name})")
    records = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            records.append(RobotTrial.from_dict(json.loads(line)))
        except (json.JSONDecodeError, KeyError, TypeError) as error:
            raise ValueError(f"{path}:{number} is not a robot-trial record ({error})") from None
    return records


def read_run(folder: str | os.PathLike) -> dict[str, Any]:
    """The ``run.json`` of an evaluation folder written by ``evaluate``.

    Raises:
        FileNotFoundError: ``folder`` has no ``run.json``.
        ValueError: the file is not valid JSON.
    """
    run_file = Path(folder) / "run.json"
    if not run_file.is_file():
        raise FileNotFoundError(f"{folder} is not an evaluation folder (no run.json)")
    try:
        return json.loads(run_file.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(
            f"{run_file} is not valid JSON ({error}); rerun `navformer evaluate` there"
        ) from None


def records_to_jsonl(records: Sequence[RobotTrial]) -> str:
    """One JSON object per robot-trial, newline-terminated."""
    return "".join(json.dumps(r.to_dict(), sort_keys=True) + "\n" for r in records)


def setup_order_key(size: float | None, n_robots: int | None, setup: str) -> tuple:
    """Rows sort by size, then robot count, then name; the pooled row goes last."""
    if setup == ALL_SETUPS:
        return (1, 0.0, 0, setup)
    return (0, size or 0.0, n_robots or 0, setup)


def ordered_setups(summaries: Sequence[SetupSummary]) -> list[tuple[float | None, int | None, str]]:
    """Every setup of ``summaries`` once, as ``(size, robots, name)`` in the order of every table and plot
    (:func:`setup_order_key`: size, robot count, name; the pooled ``all`` last), whichever methods have it."""
    first: dict[str, tuple[float | None, int | None, str]] = {}
    for s in summaries:
        first.setdefault(s.setup, (s.size, s.n_robots, s.setup))
    return sorted(first.values(), key=lambda k: setup_order_key(*k))


def interval_method(cluster: str = "trial", confidence: float = 0.95) -> str:
    """How the tables' intervals are computed, for the notes beside them (``cluster``: what they resample,
    :data:`~navformer_rl.evaluation.measures.CLUSTER_LEVELS`)."""
    units = {"trial": "trials", "world": "mazes (worlds)"}[check_cluster(cluster)]
    fewest = min_trials_for_interval(confidence)
    return (
        f"Wilson on the {cluster}-clustered effective sample size for SR - robots of one trial are not "
        f"independent{', nor are trials in one maze' if cluster == 'world' else ''} - and when every outcome "
        f"is equal or a row has fewer than {fewest} {units} the number of {units} is the sample size; "
        f"bootstrap over {units} for SPL and CR, n/a with fewer {units} than that"
        + (
            "; the intervals describe these mazes "
            "(`--cluster-by world` widens them to the variation between mazes)"
            if cluster == "trial"
            else ""
        )
    )


def summarize_by_setup(
    records: Sequence[RobotTrial], confidence: float = 0.95, seed: int = 0, cluster: str = "trial"
) -> list[SetupSummary]:
    """One :class:`SetupSummary` per (method, setup), plus a pooled ``"all"`` row per method that ran more
    than one setup (with a single setup it would repeat that setup's row).

    Only ``measured`` robot-trials count; ``cluster`` chooses what the intervals resample (see
    :func:`~navformer_rl.evaluation.measures.summarize`).
    """
    measured = [r for r in records if r.measured]
    if not measured:
        raise ValueError("no measured robot-trials to summarise")
    out: list[SetupSummary] = []
    for method in sorted({r.method for r in measured}):
        mine = [r for r in measured if r.method == method]
        setups = sorted({(r.size, r.n_robots, r.setup) for r in mine}, key=lambda s: setup_order_key(*s))
        for size, n_robots, setup in setups:
            rows = [r for r in mine if r.setup == setup]
            out.append(
                SetupSummary(method, setup, size, n_robots, summarize(rows, confidence, seed, cluster))
            )
        if len(setups) > 1:
            out.append(
                SetupSummary(method, ALL_SETUPS, None, None, summarize(mine, confidence, seed, cluster))
            )
    return out


def summaries_to_csv(summaries: Sequence[SetupSummary]) -> str:
    """CSV text with :data:`CSV_COLUMNS` (SR as a fraction; an interval end that is NaN, no interval, is
    an empty cell)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for s in summaries:
        m = s.metrics
        writer.writerow(
            [s.method, s.setup, "" if s.size is None else s.size, "" if s.n_robots is None else s.n_robots,
             m.n_worlds, m.n_trials, m.n_robot_trials, m.cluster,
             _cell(m.sr), _cell(m.sr_ci[0]), _cell(m.sr_ci[1]),
             _cell(m.spl), _cell(m.spl_ci[0]), _cell(m.spl_ci[1]),
             _cell(m.cr), _cell(m.cr_ci[0]), _cell(m.cr_ci[1]),
             _cell(m.spl_disc), _cell(m.spl_disc_ci[0]), _cell(m.spl_disc_ci[1])]
        )  # fmt: skip
    return buffer.getvalue()


def _cell(x: float) -> str:
    return "" if math.isnan(x) else f"{x:.6f}"


def _has_interval(ci: tuple[float, float] | None) -> bool:
    return ci is not None and not (math.isnan(ci[0]) or math.isnan(ci[1]))


def format_sr(value: float, ci: tuple[float, float] | None = None) -> str:
    """``39.17%``, ``39.17% [30.9, 48.1]`` (percent) or ``39.17% [n/a]`` (``ci`` NaN: no interval)."""
    text = f"{100 * value:.2f}%"
    if ci is None:
        return text
    return f"{text} [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]" if _has_interval(ci) else f"{text} [n/a]"


def format_ratio(value: float, ci: tuple[float, float] | None = None) -> str:
    """``0.287``, ``0.287 [0.25, 0.32]`` or ``0.287 [n/a]`` (``ci`` NaN: too few trials for an interval)."""
    text = f"{value:.3f}"
    if ci is None:
        return text
    return f"{text} [{ci[0]:.2f}, {ci[1]:.2f}]" if _has_interval(ci) else f"{text} [n/a]"


def _env_size(setup: str, size: float | None) -> str:
    """The "Env size (m)" cell: a maze's side twice, a Table II world's footprint,
    ``all`` for the pooled row."""
    if size is None:
        return "all"
    footprint = FURNISHED_FOOTPRINTS.get(setup)
    return f"{footprint[0]:g} × {footprint[1]:g}" if footprint else f"{size:g} × {size:g}"


def table_markdown(summaries: Sequence[SetupSummary], methods: Sequence[str] | None = None) -> str:
    """Markdown table in the paper's Table I layout: one row per setup (size x robots), and for each
    method three columns SR / SPL / CR, each ``value [95 % CI]``."""
    if methods is None:
        methods = list(dict.fromkeys(s.method for s in summaries))
    by_key = {(s.method, s.setup): s for s in summaries}
    rows = ordered_setups(summaries)
    header = ["Setup", "Env size (m)", "# of robots"]
    for method in methods:
        header += [f"{method} SR", f"{method} SPL", f"{method} CR"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for size, n_robots, setup in rows:
        cells = [
            setup,
            _env_size(setup, size),
            "-" if n_robots is None else str(n_robots),
        ]
        for method in methods:
            s = by_key.get((method, setup))
            if s is None:
                cells += ["-", "-", "-"]
                continue
            m = s.metrics
            cells += [format_sr(m.sr, m.sr_ci), format_ratio(m.spl, m.spl_ci), format_ratio(m.cr, m.cr_ci)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_summary_files(
    records: Sequence[RobotTrial],
    out_dir: str | os.PathLike,
    confidence: float = 0.95,
    seed: int = 0,
    cluster: str = "trial",
) -> list[SetupSummary]:
    """Write ``summary.csv`` and ``summary.md`` (Table I layout) for ``records`` into ``out_dir``."""
    out_dir = Path(out_dir)
    summaries = summarize_by_setup(records, confidence, seed, cluster)
    atomic_write_text(out_dir / "summary.csv", summaries_to_csv(summaries))
    note = (
        f"SR / SPL / CR with {100 * confidence:g} % confidence intervals in brackets "
        f"({interval_method(cluster, confidence)}).\n\n"
    )
    atomic_write_text(out_dir / "summary.md", note + table_markdown(summaries))
    return summaries
