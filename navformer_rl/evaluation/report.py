"""A markdown report over one or more methods' evaluation folders, with the paper's numbers beside ours.

``write_report([dir_vrw, dir_fca, dir_navformer], "report/README.md")`` reads each folder written by
:func:`navformer_rl.evaluation.harness.evaluate` (``episodes.jsonl`` + ``run.json``), recomputes the
aggregates from the per-robot-trial rows, and writes:

- the combined table in the paper's Table I layout (values with 95 % intervals);
- a combined bar plot (``<report stem>_metrics.png`` next to the report);
- for setups that appear in the paper's Table I / III / IV, the paper's numbers beside ours, labelled as
  measured in another simulator (Gazebo) on other worlds with the authors' models;
- links to each method's top-down maps and videos, and the episode-set hash each method ran on;
- a warning for an evaluation whose label names a training ablation (``navformer-no_thsc``) that its
  checkpoint was not trained with (``evaluate`` refuses such labels; a folder may still hold one it did
  not check): its rows are compared with the paper's row of the checkpoint's actual ablation when ``run.json``
  or the checkpoint tells it, and with no paper row otherwise.

Every table and the plot list the setups in one order
(:func:`~navformer_rl.evaluation.tables.ordered_setups`).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from navformer_rl.constants import FURNISHED_FOOTPRINTS
from navformer_rl.evaluation.harness import checkpoint_ablation, label_ablation_problem
from navformer_rl.evaluation.measures import RobotTrial, check_cluster
from navformer_rl.evaluation.paper_results import (
    ABLATION_TO_TABLE4,
    METHOD_TO_PAPER_COLUMN,
    PAPER_SOURCE,
    TABLE1,
    TABLE2,
    TABLE3,
    TABLE4,
    TABLE4_SETUP,
)
from navformer_rl.evaluation.plots import plot_setup_bars
from navformer_rl.evaluation.tables import (
    ALL_SETUPS,
    SetupSummary,
    format_ratio,
    format_sr,
    interval_method,
    ordered_setups,
    read_records,
    read_run,
    summarize_by_setup,
    table_markdown,
)
from navformer_rl.tasks import label_ablation
from navformer_rl.utils.durable import atomic_write_text
from navformer_rl.utils.mp4 import video_codec

PAPER_CAVEAT = (
    "Paper numbers come from {source}: other worlds, other robot models and the authors' fully trained "
    "models. Ours come from this package's pybullet mazes with whatever training budget produced the "
    "checkpoint. The two are **not directly comparable**; the paper's columns are there for orientation "
    "(ordering of methods, rough magnitudes)."
)


def _paper_column(label: str, ablation: str | None = None) -> str | None:
    """The paper column or Table IV row matching one of our method labels.

    ``vrw``, ``dt``, ``fca``, ``navformer`` (and ``navformer-<anything>``) -> the Table I / III column; a
    NavFormer label naming a training ablation (``navformer-no_thsc``, ``navformer_resnet18``) -> its
    Table IV row (``ABLATION_TO_TABLE4``), compared only on Table IV's setup. ``ablation``, the training
    ablation ``run.json`` records for the evaluated checkpoint, decides over the label when given:
    ``none`` -> NavFormer, ``dt`` -> DT, a Table IV ablation -> its row.
    """
    if ablation is not None:
        return ABLATION_TO_TABLE4.get(ablation) or {"none": "NavFormer", "dt": "DT"}.get(ablation)
    named = label_ablation(label)
    if named is not None:
        return ABLATION_TO_TABLE4[named]
    return METHOD_TO_PAPER_COLUMN.get(label.lower().split("-")[0].split("_")[0])


def _recorded_ablation(run: dict[str, Any]) -> str | None:
    """The training ablation of the checkpoint an evaluation ran: ``run.json``'s ``ablation``; for a
    ``run.json`` without one, read from the checkpoint when it is still at the recorded
    path with the same weights (sha256); None when unknown or not a checkpoint method."""
    if "ablation" in run:
        return run["ablation"]
    checkpoint, sha256 = run.get("checkpoint"), run.get("checkpoint_sha256")
    if not checkpoint or not sha256:
        return None
    from navformer_rl.training.checkpoint import WEIGHTS_FILENAME, resolve_checkpoint

    try:
        folder = resolve_checkpoint(checkpoint)
        if hashlib.sha256((folder / WEIGHTS_FILENAME).read_bytes()).hexdigest() != sha256:
            return None
        return checkpoint_ablation(folder)
    except (OSError, ValueError):
        return None


def _paper_numbers(
    summary: SetupSummary, column: str, table2: bool = False
) -> tuple[float, float, float] | None:
    """The paper's (SR, SPL, CR) for ``summary``'s setup in ``column``; ``table2``: the setups are Table II's
    world kinds, whose pooled row is compared with the paper's one Table II row."""
    if summary.setup == ALL_SETUPS:
        return TABLE2.get(column) if table2 else None
    if column in ABLATION_TO_TABLE4.values():
        # Table IV: four measured Jackals, not the unseen-obstacle setup
        same_setup = (summary.size, summary.n_robots) == TABLE4_SETUP
        return TABLE4[column] if same_setup and not summary.setup.endswith("-unseen") else None
    if summary.setup.endswith("-unseen"):
        return TABLE3["unseen"].get(column)
    if summary.setup.endswith("-seen"):
        return TABLE3["seen"].get(column)
    return TABLE1.get((summary.size, summary.n_robots), {}).get(column)


def paper_comparison_markdown(
    summaries: Sequence[SetupSummary],
    methods: Sequence[str],
    columns: Mapping[str, str | None] | None = None,
) -> str:
    """Side-by-side table: per setup and method, ``ours / paper`` for SR, SPL and CR (paper's Table I, or
    Table III for the ``-seen`` / ``-unseen`` setups, or for Table II's world kinds the pooled ``all`` row
    beside the paper's single Table II row); empty when no method/setup has a paper value.

    ``columns`` maps a method label to the paper column or Table IV row it is compared with (None: not
    compared); a label it leaves out gets the column its name implies (``_paper_column``).
    """
    columns = {m: (columns[m] if columns is not None and m in columns else _paper_column(m)) for m in methods}
    by_key = {(s.method, s.setup): s for s in summaries}
    compared = [m for m in methods if columns[m] is not None]
    setups = [setup for _, _, setup in ordered_setups(summaries) if setup != ALL_SETUPS]
    table2 = bool(setups) and set(setups) <= set(FURNISHED_FOOTPRINTS)  # Table II: one row over its 3 worlds
    if table2:
        setups.append(ALL_SETUPS)
    header = ["Setup"]
    for method in compared:
        header += [f"{method} SR (ours / paper {columns[method]})", "SPL (ours / paper)", "CR (ours / paper)"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    any_value = False
    for setup in setups:
        cells = [setup]
        for method in compared:
            s = by_key.get((method, setup))
            paper = None if s is None else _paper_numbers(s, columns[method], table2)
            if s is None or paper is None:
                cells += ["-", "-", "-"]
                continue
            any_value = True
            m = s.metrics
            cells += [
                f"{format_sr(m.sr)} / {format_sr(paper[0])}",
                f"{format_ratio(m.spl)} / {format_ratio(paper[1])}",
                f"{format_ratio(m.cr)} / {format_ratio(paper[2])}",
            ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n" if any_value else ""


def spl_disc_markdown(summaries: Sequence[SetupSummary], methods: Sequence[str]) -> str:
    """Table of the secondary SPL-disc measure: one row per setup, one column per method."""
    by_key = {(s.method, s.setup): s.metrics for s in summaries}
    setups = [setup for _, _, setup in ordered_setups(summaries)]
    lines = [
        "| Setup | " + " | ".join(f"{m} SPL-disc" for m in methods) + " |",
        "|" + "---|" * (len(methods) + 1),
    ]
    for setup in setups:
        cells = [setup]
        for method in methods:
            m = by_key.get((method, setup))
            cells.append("-" if m is None else format_ratio(m.spl_disc, m.spl_disc_ci))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def paper_table1_markdown() -> str:
    """The paper's Table I, as published (all six methods)."""
    methods = list(next(iter(TABLE1.values())))
    header = ["Env size (m)", "# of robots"] + [f"{m} {k}" for m in methods for k in ("SR", "SPL", "CR")]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for (size, n), row in TABLE1.items():
        cells = [f"{size:g} × {size:g}", str(n)]
        for m in methods:
            sr, spl, cr = row[m]
            cells += [format_sr(sr), format_ratio(spl), format_ratio(cr)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def paper_table4_markdown() -> str:
    """The paper's Table IV (ablations, 12.5 m, 4 robots)."""
    lines = ["| Variant | SR | SPL | CR |", "|---|---|---|---|"]
    for name, (sr, spl, cr) in TABLE4.items():
        lines.append(f"| {name} | {format_sr(sr)} | {format_ratio(spl)} | {format_ratio(cr)} |")
    return "\n".join(lines) + "\n"


REPORT_MARKER = "<!-- written by navformer_rl.evaluation.report.write_report -->"
"""First line of every report: an existing file is replaced only if it is a report (this line, or, in a
report without it, the measures sentence near its top)."""
_MEASURES_SENTENCE = "Measures as defined in the paper (§VII.A): SR = mean success over robot-trials"


def _check_replaceable(out_path: Path) -> None:
    """Refuse an ``out_path`` that is a folder, or an existing file that is not one of our reports."""
    if out_path.is_dir():
        raise ValueError(f"{out_path} is a folder; expected the path of the report's .md file")
    if out_path.exists():
        with open(out_path, encoding="utf-8", errors="replace") as handle:
            head = handle.read(4096)
        if not (head.startswith(REPORT_MARKER + "\n") or _MEASURES_SENTENCE in head):
            raise FileExistsError(
                f"{out_path} exists and is not a report written by navformer_rl; choose another path or "
                "delete it"
            )


def _video_codec_note(runs: Sequence[tuple[Path, dict[str, Any]]]) -> str:
    """Lines naming the folders whose videos are not H.264 (e.g. OpenCV's ``mp4v``, in reused episodes) or
    could not be probed, from each folder's first video; empty when there are none."""
    not_h264, unreadable = [], []
    for folder, run in runs:
        videos = run["files"].get("videos", [])
        if videos and (folder / videos[0]).is_file():
            try:
                codec = video_codec(folder / videos[0])
            except (OSError, RuntimeError, StopIteration, KeyError) as error:
                unreadable.append(f"{run['label']} ({type(error).__name__})")
                continue
            if codec != "h264":
                not_h264.append(f"{run['label']} ({codec})")
    lines = []
    if not_h264:
        lines.append(
            f"Not H.264: the videos of {', '.join(not_h264)}, reused from an earlier version (`mpeg4` is "
            "OpenCV's `mp4v`: VLC and mpv play it, browsers do not; to re-encode, rerun that evaluation with "
            "`--fresh` or delete its folder).\n"
        )
    if unreadable:
        lines.append(f"Could not read the first video of {', '.join(unreadable)} to check its codec.\n")
    return "".join(lines)


def _setup_digests(folder: Path) -> dict[str, str] | None:
    """``{setup: sha256 of its episodes and the trial length}`` from an evaluation folder's
    ``episode_set.json`` (read as plain JSON, whatever its format version), or None when the file is missing
    or unreadable. Two sets with other names, protocols or package versions can hold the very same episodes
    of a setup (Table I's 12.5 m / 4-robot episodes are Table IV's): those are paired comparisons."""
    try:
        document = json.loads((folder / "episode_set.json").read_text())
        by_setup: dict[str, list] = {}
        for episode in document["episodes"]:
            by_setup.setdefault(str(episode["setup"]), []).append(episode)
        max_steps = document["max_steps"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return {
        setup: hashlib.sha256(json.dumps([max_steps, episodes], sort_keys=True).encode()).hexdigest()
        for setup, episodes in by_setup.items()
    }


def _unpaired_warning(runs: Sequence[tuple[Path, dict[str, Any]]]) -> str | None:
    """A warning naming the setups whose episodes differ between the methods that ran them (None if none
    do); without every folder's episode file, the whole episode sets' hashes are compared."""
    digests = {run["label"]: _setup_digests(folder) for folder, run in runs}
    if any(d is None for d in digests.values()):
        hashes = {run["episode_set"]["content_sha256"] for _, run in runs}
        if len(hashes) == 1:
            return None
        return (
            "**Warning: these methods ran on different episode sets** (hashes "
            + ", ".join(sorted(h[:12] for h in hashes))
            + "), so their rows are not paired comparisons.\n"
        )
    setups = dict.fromkeys(setup for d in digests.values() for setup in d)
    differ = [s for s in setups if len({d[s] for d in digests.values() if s in d}) > 1]
    if not differ:
        return None
    return (
        "**Warning: the methods ran on different episodes** in "
        + ", ".join(differ)
        + " (other worlds, starts, targets, shortest paths or trial lengths), so those rows are not paired "
        "comparisons.\n"
    )


_UNITS = {"trial": "trials", "world": "mazes"}
"""What each :data:`~navformer_rl.evaluation.measures.CLUSTER_LEVELS` value resamples,
as the report names it."""


def _interval_settings(
    runs: Sequence[tuple[Path, Mapping[str, Any]]], confidence: float | None, cluster: str | None
) -> tuple[float, str, list[str]]:
    """The report's interval level and clusters (the folders' shared ones where not given) and a phrase per
    folder whose own ``summary.md`` used other ones (``run.json``; 0.95 and trials where it records none)."""
    recorded = {folder: (run.get("confidence", 0.95), run.get("cluster", "trial")) for folder, run in runs}
    if confidence is None:
        levels = {level for level, _ in recorded.values()}
        confidence = levels.pop() if len(levels) == 1 else 0.95
    if cluster is None:
        clusters = {units for _, units in recorded.values()}
        cluster = clusters.pop() if len(clusters) == 1 else "trial"
    differing = [
        f"{folder} was evaluated with {100 * level:g} % intervals over {_UNITS[units]} (its own `summary.md`)"
        for folder, (level, units) in recorded.items()
        if (level, units) != (confidence, cluster)
    ]
    return confidence, cluster, differing


def write_report(
    result_dirs: Sequence[str | os.PathLike],
    out_path: str | os.PathLike,
    title: str = "NavFormer evaluation",
    confidence: float | None = None,
    seed: int = 0,
    cluster: str | None = None,
) -> Path:
    """Write the markdown report (module docstring) to ``out_path``; returns its path.

    Args:
        result_dirs: folders written by ``evaluate`` (one per method/label); order = column order.
        out_path: the ``.md`` file; ``<stem>_metrics.png`` is written beside it. An existing file is
            replaced only if it is a report written here (FileExistsError otherwise).
        confidence, seed: level and bootstrap seed of the intervals; ``confidence=None``: the level the
            folders were evaluated with (``run.json``), 0.95 when they differ.
        cluster: what the intervals resample, whole trials or whole mazes
            (:data:`~navformer_rl.evaluation.measures.CLUSTER_LEVELS`); ``None``: the folders' own choice
            (``run.json``), ``"trial"`` when they differ. The report says when a folder's own
            ``summary.md`` used other intervals.
    """
    if cluster is not None:
        check_cluster(cluster)
    if confidence is not None and not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence={confidence!r}: expected a level in (0, 1), e.g. 0.95")
    if not result_dirs:
        raise ValueError("write_report needs at least one evaluation folder")
    out_path = Path(out_path)
    _check_replaceable(out_path)
    report_dir = out_path.parent
    records, runs, labels = _read_runs(result_dirs)
    confidence, cluster, differing = _interval_settings(runs, confidence, cluster)
    summaries = summarize_by_setup(records, confidence, seed, cluster)
    plot_path = report_dir / f"{out_path.stem}_metrics.png"  # not metrics.png: an evaluation folder's own
    plot = plot_setup_bars(summaries, plot_path, methods=labels, title=title)
    columns, ablations, label_warnings = _paper_columns(runs)
    parts = [REPORT_MARKER, f"# {title}\n"]
    parts.append(
        f"{_MEASURES_SENTENCE} (success: within "
        "1.5 m of the target before the trial ends); SPL = mean of S·ℓ/max(℘, ℓ) (eq. 12) with ℓ the "
        "shortest collision-free path from start to target on the true map; CR = mean over robot-trials of "
        "collision steps / active steps. See `docs/evaluation.md`.\n"
    )
    unpaired = _unpaired_warning(runs)
    if unpaired is not None:
        parts.append(unpaired)
    parts += label_warnings
    parts += _methods_section(runs, ablations)
    parts += _results_section(summaries, labels, confidence, cluster, differing, plot.name)
    parts += _paper_section(summaries, labels, columns)
    parts += _episodes_section(runs, report_dir)
    atomic_write_text(out_path, "\n".join(parts) + "\n")
    return out_path


def _read_runs(
    result_dirs: Sequence[str | os.PathLike],
) -> tuple[list[RobotTrial], list[tuple[Path, dict[str, Any]]], list[str]]:
    """``(records, [(folder, run.json)], labels)`` of the evaluation folders, in order; ValueError when
    two hold the same label (a report has one column per label)."""
    records, runs, labels = [], [], []
    for folder in map(Path, result_dirs):
        run = read_run(folder)
        mine = read_records(folder / "episodes.jsonl")
        if run["label"] in labels:
            first = runs[labels.index(run["label"])][0]
            raise ValueError(
                f"{first} and {folder} both hold results labelled {run['label']!r}; a report needs one label "
                "per column: evaluate one of them again with another --label, into another folder"
            )
        labels.append(run["label"])
        records += mine
        runs.append((folder, run))
    return records, runs, labels


def _paper_columns(
    runs: Sequence[tuple[Path, dict[str, Any]]],
) -> tuple[dict[str, str | None], dict[str, str | None], list[str]]:
    """Per label: the paper column its rows are compared with and its training ablation, and a warning
    paragraph for each folder whose label names another ablation than its checkpoint's (its rows are then
    compared with the checkpoint's column, or with none)."""
    columns, ablations, warnings = {}, {}, []
    for folder, run in runs:
        ablations[run["label"]] = ablation = _recorded_ablation(run)
        columns[run["label"]] = _paper_column(run["label"], ablation)
        problem = label_ablation_problem(
            run["label"], run.get("method", ""), ablation, run.get("model_config"), run.get("checkpoint")
        )
        if problem is not None and "factory" not in run:
            column = columns[run["label"]] if ablation is not None else None
            columns[run["label"]] = column
            warnings.append(
                f"**Warning: {folder}**: {problem}. That evaluation predates the check that now refuses "
                "such a label; its rows are "
                + (
                    f"compared with the paper's {column} instead."
                    if column
                    else "not compared with the paper."
                )
                + "\n"
            )
    return columns, ablations, warnings


def _methods_section(
    runs: Sequence[tuple[Path, dict[str, Any]]], ablations: dict[str, str | None]
) -> list[str]:
    """The "Methods" table (episode set, checkpoint, training ablation, seconds per label) and its note."""
    parts = ["## Methods\n"]
    parts.append(
        "| Method | Episode set | Episodes | Max steps | Checkpoint | Training ablation | Seconds |\n"
        "|---|---|---|---|---|---|---|"
    )
    last_invocation_seconds = False
    for _, run in runs:
        es = run["episode_set"]
        seconds = run.get("seconds")
        if "invocation_seconds" not in run and seconds is not None:  # seconds of the last invocation only
            last_invocation_seconds = True
            seconds_cell = f"{seconds:.0f}†"
        else:
            seconds_cell = "-" if seconds is None else f"{seconds:.0f}"
        ablation = ablations[run["label"]]
        parts.append(
            f"| {run['label']} | {es['name']} (`{es['content_sha256'][:12]}`) | {es['episodes']} | "
            f"{es['max_steps']} | {run.get('checkpoint') or '-'} | {ablation or '-'} | {seconds_cell} |"
        )
    parts.append("")
    parts.append(
        "Seconds: the wall-clock time that computed the results, whatever the number of invocations: each "
        "episode stores the time it took, so an evaluation resumed or rerun over finished episodes keeps "
        "the time that computed them (`run.json`: `seconds`; `invocation_seconds` is the last invocation's "
        "own time)."
        + (
            " † `run.json` of an earlier version: the wall time of the last invocation only, which is too "
            "small when that invocation reused finished episodes."
            if last_invocation_seconds
            else ""
        )
        + "\n"
    )
    return parts


def _results_section(
    summaries: Sequence[SetupSummary],
    labels: Sequence[str],
    confidence: float,
    cluster: str,
    differing: Sequence[str],
    plot_name: str,
) -> list[str]:
    """The "Results" section: the interval method, the SR / SPL / CR table, the bar plot ``plot_name`` and
    the SPL measured to the success disc."""
    parts = [f"## Results (ours, {100 * confidence:g} % confidence intervals in brackets)\n"]
    parts.append(f"Intervals: {interval_method(cluster, confidence)}.\n")
    if differing:
        parts.append(
            "Note: "
            + "; ".join(differing)
            + f"; this report recomputes every interval at {100 * confidence:g} % over {_UNITS[cluster]} "
            "from the per-episode rows.\n"
        )
    parts.append(table_markdown(summaries, labels))
    parts.append(f"![SR, SPL and CR per setup]({plot_name})\n")
    parts.append(
        "SPL with ℓ measured to the 1.5 m success disc instead of the target (not in the paper; it removes "
        "the 1.5 m of slack that eq. 12's ℓ gives a robot that stops at the disc's edge):\n"
    )
    parts.append(spl_disc_markdown(summaries, labels))
    return parts


def _paper_section(
    summaries: Sequence[SetupSummary], labels: Sequence[str], columns: dict[str, str | None]
) -> list[str]:
    """The "Beside the paper" section: the caveat, our rows beside the paper's columns, Table I, and Table
    IV when an ablation was evaluated on the 12.5 m / 4-robot setup."""
    comparison = paper_comparison_markdown(summaries, labels, columns)
    parts = ["## Beside the paper\n"]
    parts.append(PAPER_CAVEAT.format(source=PAPER_SOURCE) + "\n")
    if comparison:
        parts.append(comparison)
    parts.append("### The paper's Table I (Gazebo, for reference)\n")
    parts.append(paper_table1_markdown())
    ablation_rows = any(column in ABLATION_TO_TABLE4.values() for column in columns.values())
    if any(s.setup == "12.5m-4r" for s in summaries) and (
        ablation_rows or any("-" in label for label in labels)
    ):
        parts.append("### The paper's Table IV (ablations, Gazebo, for reference)\n")
        parts.append(paper_table4_markdown())
    return parts


def _episodes_section(runs: Sequence[tuple[Path, dict[str, Any]]], report_dir: Path) -> list[str]:
    """The "Episodes" section: per label, links (relative to ``report_dir``) to its per-robot-trial rows,
    maps and videos, then each label's first map shown inline."""
    parts = ["## Episodes\n"]
    parts.append(
        "Videos are H.264 mp4 (browsers, VS Code and VLC play them), one frame per 0.2 s step at the run's "
        "frame rate (10 fps by default: twice real time).\n" + _video_codec_note(runs)
    )
    for folder, run in runs:
        links = []
        for kind, items in (("map", run["files"].get("maps", [])), ("video", run["files"].get("videos", []))):
            for item in items:
                target = os.path.relpath(folder / item, report_dir)
                links.append(f"[{kind} {Path(item).stem}]({target})")
        per_episode = os.path.relpath(folder / "episodes.jsonl", report_dir)
        parts.append(
            f"- **{run['label']}**: [per-robot-trial rows]({per_episode}); "
            + (", ".join(links) or "no visuals")
        )
    parts.append("")
    first_maps = [(folder, run["files"]["maps"][0]) for folder, run in runs if run["files"].get("maps")]
    for folder, item in first_maps:
        parts.append(f"![{Path(item).stem}]({os.path.relpath(folder / item, report_dir)})")
    return parts
