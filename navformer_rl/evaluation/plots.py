"""Bar plots of SR / SPL / CR per setup with confidence-interval error bars, and SR over training seeds per
configuration (matplotlib, Agg backend)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from navformer_rl.evaluation.seeds import SeedGroupSummary
from navformer_rl.evaluation.tables import ALL_SETUPS, SetupSummary, ordered_setups
from navformer_rl.utils.durable import atomic_path

_METRICS = (("sr", "SR", "sr_ci"), ("spl", "SPL", "spl_ci"), ("cr", "CR", "cr_ci"))


def plot_setup_bars(
    summaries: Sequence[SetupSummary],
    path: str | os.PathLike,
    methods: Sequence[str] | None = None,
    title: str | None = None,
) -> Path:
    """Write a PNG with one panel per metric (SR, SPL, CR stacked); per setup (x axis) one bar per method,
    with its confidence interval as an error bar and its value written above.

    The legend sits above the panels, outside them, so it never covers a bar or a value; the figure is
    about 0.45 inch per bar wide so the values stay legible. A bar without an interval (NaN: too few trials,
    or mazes, :func:`~navformer_rl.evaluation.measures.min_trials_for_interval`) has no error bar, and a line
    under the panels says so.

    Args:
        summaries: per-(method, setup) summaries (the pooled ``"all"`` rows are skipped).
        path: output ``.png`` (written atomically).
        methods: bar order; default: order of first appearance.
        title: figure title.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    rows = [s for s in summaries if s.setup != ALL_SETUPS]
    if not rows:
        raise ValueError("no per-setup summaries to plot")
    if methods is None:
        methods = list(dict.fromkeys(s.method for s in rows))
    setups = ordered_setups(rows)
    labels = [setup for _, _, setup in setups]
    by_key = {(s.method, s.setup): s.metrics for s in rows}
    x = np.arange(len(setups))
    width = 0.8 / len(methods)
    colors = plt.get_cmap("tab10").colors
    fig_width = max(7.0, 0.45 * len(setups) * max(2, len(methods)) + 2.0)
    legend_columns = max(1, min(len(methods), int(fig_width // 1.6)))
    legend_rows = -(-len(methods) // legend_columns)
    fig, axes = plt.subplots(
        3, 1, figsize=(fig_width, 8.5 + 0.25 * legend_rows), sharex=True, layout="constrained"
    )
    missing_interval = False
    for ax, (attr, name, ci_attr) in zip(axes, _METRICS):
        for k, method in enumerate(methods):
            values, low, high = [], [], []
            for label in labels:
                m = by_key.get((method, label))
                value = np.nan if m is None else getattr(m, attr)
                ci = (np.nan, np.nan) if m is None else getattr(m, ci_attr)
                values.append(value)
                if m is not None and not np.all(np.isfinite(ci)):
                    missing_interval = True  # too few trials for one: no error bar (NaN draws none)
                    low.append(np.nan)
                    high.append(np.nan)
                    continue
                # an interval end ~1e-16 on the wrong side of the estimate (rounding) is a zero-length bar
                low.append(max(value - ci[0], 0.0))
                high.append(max(ci[1] - value, 0.0))
            positions = x + (k - (len(methods) - 1) / 2) * width
            ax.bar(
                positions,
                values,
                width,
                yerr=np.array([low, high]),
                capsize=2,
                ecolor="0.35",
                label=method,
                color=colors[k % len(colors)],
            )
            for position, value, up in zip(positions, values, np.nan_to_num(high)):
                if np.isfinite(value):
                    text = f"{100 * value:.0f}%" if attr == "sr" else f"{value:.2f}"
                    ax.text(position, value + up + 0.02, text, ha="center", va="bottom", fontsize=7)
        ax.set_ylabel(name)
        ax.set_ylim(0, 1.15)
        ax.set_yticks(np.linspace(0, 1, 6))
        ax.grid(axis="y", alpha=0.3)
    axes[-1].set_xticks(x, labels, rotation=30, ha="right", fontsize=8)
    fig.suptitle(title or "SR / SPL / CR per setup", fontsize=11)
    # above the SR panel, outside it (the layout makes room below the title): it cannot cover a bar or a value
    axes[0].legend(
        loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=legend_columns, fontsize=8, frameon=False
    )
    if missing_interval:
        units = "mazes" if any(s.metrics.cluster == "world" for s in summaries) else "trials"
        fig.supxlabel(f"no error bar: too few {units} for a confidence interval", fontsize=8, color="0.35")
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path


SERIES_NAME = r"^(?P<series>.+)@(?P<x>[0-9]+(?:\.[0-9]+)?)$"
"""A seed group named ``SERIES@X`` (e.g. ``navformer@3496``) is point X of the line SERIES."""


X_SCALES = ("auto", "linear", "log")
"""``plot_seed_groups``' x axes: ``auto`` is logarithmic when the largest X is at least 5x the smallest."""


def _labels_collide(ticks: list[float]) -> bool:
    """Whether a label at every X of a linear axis would overlap: two X closer than 6 % of the span.

    Then matplotlib's own round ticks label the axis and the markers show where the measurements are.
    """
    span = ticks[-1] - ticks[0]
    return len(ticks) > 1 and min(b - a for a, b in zip(ticks, ticks[1:])) < 0.06 * span


def plot_seed_groups(
    summaries: Sequence[SeedGroupSummary],
    path: str | os.PathLike,
    x_label: str = "x",
    x_scale: str = "auto",
) -> dict[str, list[tuple[float, float, float]]]:
    """SR of several configurations over their training seeds, as a PNG at ``path``.

    When every group is named ``SERIES@X`` (:data:`SERIES_NAME`), one line per series over X (e.g. SR
    against dataset size or training iterations; ``x_scale`` one of :data:`X_SCALES`), else one bar per
    group. Each point or bar is the mean over the seeds with the standard deviation as its error bar, and
    every seed's own SR drawn as a dot. When every group holds one run (e.g. the checkpoints of one run), the
    error bar is that run's 95 % interval instead (trial-clustered, as ``navformer evaluate`` reports it).
    Returns the drawn values, ``{series (or group name): [(x, mean SR, std), ...]}`` (x is the bar position
    for bars; std 0 for groups of one run).
    """
    import re

    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    if not summaries:
        raise ValueError("no seed groups to plot")
    if x_scale not in X_SCALES:
        raise ValueError(f"x_scale={x_scale!r}: expected one of {', '.join(X_SCALES)}")
    single = all(len(group.runs) == 1 for group in summaries)
    matches = [re.match(SERIES_NAME, group.name) for group in summaries]
    drawn: dict[str, list[tuple[float, float, float]]] = {}
    fig, ax = plt.subplots(figsize=(6.5, 4.2), layout="constrained")
    colors = plt.get_cmap("tab10").colors
    if all(matches):
        series = list(dict.fromkeys(match["series"] for match in matches))
        for k, name in enumerate(series):
            points = sorted(
                (float(match["x"]), group)
                for match, group in zip(matches, summaries)
                if match["series"] == name
            )
            xs = [x for x, _ in points]
            means = [100 * group.mean["sr"] for _, group in points]
            stds = [100 * np.nan_to_num(group.std["sr"]) for _, group in points]
            bars = _interval_bars([group for _, group in points], means) if single else stds
            ax.errorbar(xs, means, yerr=bars, marker="o", capsize=4, color=colors[k % 10], label=name)
            for x, group in points if not single else ():
                seeds = [100 * run.metrics.sr for run in group.runs]
                ax.scatter([x] * len(seeds), seeds, s=14, color=colors[k % 10], alpha=0.45, zorder=3)
            drawn[name] = [(x, m, s) for x, m, s in zip(xs, means, stds)]
        xs = [x for points in drawn.values() for x, _, _ in points]
        if x_scale == "log" or (x_scale == "auto" and max(xs) >= 5 * min(xs)):
            ax.set_xscale("log")
            ax.minorticks_off()
        ticks = sorted({x for points in drawn.values() for x, _, _ in points})
        if ax.get_xscale() == "log" or not _labels_collide(ticks):
            ax.set_xticks(ticks, [f"{x:g}" for x in ticks])
        ax.set_xlabel(x_label)
        ax.legend()
    else:
        for k, group in enumerate(summaries):
            mean, std = 100 * group.mean["sr"], 100 * np.nan_to_num(group.std["sr"])
            bar = _interval_bars([group], [mean]) if single else std
            ax.bar(k, mean, yerr=bar, capsize=4, color=colors[k % 10], alpha=0.8)
            if not single:
                seeds = [100 * run.metrics.sr for run in group.runs]
                ax.scatter([k] * len(seeds), seeds, s=14, color="black", zorder=3)
            drawn[group.name] = [(float(k), mean, std)]
        ax.set_xticks(range(len(summaries)), [group.name for group in summaries])
    ax.set_ylabel(
        "SR (%) and its 95 % interval (one run each)"
        if single
        else "SR (%): mean ± std over seeds; dots: seeds"
    )
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
    return drawn


def _interval_bars(groups: Sequence[SeedGroupSummary], means: Sequence[float]) -> np.ndarray:
    """Asymmetric error bars ``[2, n]`` (percentage points below and above ``means``) of the groups' pooled SR
    intervals."""
    low = [mean - 100 * group.pooled.sr_ci[0] for group, mean in zip(groups, means)]
    high = [100 * group.pooled.sr_ci[1] - mean for group, mean in zip(groups, means)]
    return np.clip(np.array([low, high]), 0.0, None)
