"""``report.md`` of the end-to-end demo: datasets, training curves, evaluation tables, maps and videos.

The evaluation part (tables in the paper's Table I layout with confidence intervals, the paper's numbers
beside ours, bar plots) comes from :func:`navformer_rl.evaluation.report.write_report`; this module adds
what the pipeline knows around it: dataset statistics and sample sheets, loss curves, stage timings and
what each video shows.
"""

from __future__ import annotations

import csv
import json
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from navformer_rl.utils.durable import atomic_write_text

if TYPE_CHECKING:
    from navformer_rl.demo.config import DemoConfig


def _dataset_section(data: dict[str, Path], report_dir: Path) -> list[str]:
    from navformer_rl.data.card import sample_sheet, save_png
    from navformer_rl.data.dataset import open_dataset

    lines = [
        "## Datasets (collected by the experts)\n",
        "| dataset | rows | trajectories | folder |",
        "|---|---|---|---|",
    ]
    sheets = []
    for name, path in data.items():
        dataset = open_dataset(path)
        trajectories = dataset.num_trajectories if dataset.episodes is not None else "-"
        lines.append(f"| {name} | {len(dataset)} | {trajectories} | `{os.path.relpath(path, report_dir)}` |")
        if name.startswith("held_out_"):
            continue  # they look like the training data; the table shows their size
        sheet = save_png(sample_sheet(dataset, n=2, frames=6), report_dir / "figures" / f"samples_{name}.png")
        sheets.append((name, sheet))
    lines.append("")
    if any(name.startswith("held_out_") for name in data):
        lines.append(
            "`held_out_e` / `held_out_ca` come from other mazes (another collection seed). The models never "
            "train on them; they measure how well the action loss carries over to new mazes (see Training).\n"
        )
    for name, sheet in sheets:
        caption = (
            "pairs (o^s, o^d): the same pose without and with the other robots"
            if name == "ssl"
            else "target image, then frames from the start to the end of a trajectory"
        )
        lines.append(f"**{name}** - {caption}:\n\n![{name} samples]({os.path.relpath(sheet, report_dir)})\n")
    return lines


def _read_scalar(csv_path: Path) -> tuple[list[float], list[float]]:
    steps, values = [], []
    with csv_path.open() as handle:
        for row in csv.reader(handle):
            if len(row) >= 2:
                steps.append(float(row[0]))
                values.append(float(row[1]))
    return steps, values


def _training_section(train_dirs: dict[str, Path], report_dir: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines = ["## Training\n"]
    if not train_dirs:
        return lines + ["No model was trained in this run.\n"]
    fig, axes = plt.subplots(1, len(train_dirs), figsize=(5 * len(train_dirs), 4.2), squeeze=False)
    for ax, (method, run_dir) in zip(axes[0], train_dirs.items()):
        scalars = sorted((run_dir / "logs").glob("*/scalars"))
        plotted = False
        for folder in scalars:
            names = list(CURVE_COLOURS)
            if not (folder / "loss_byol.csv").is_file():
                # without BYOL the total loss is loss_dt: one curve would hide under the other
                names.remove("loss")
            for name in names:
                path = folder / f"{name}.csv"
                if path.is_file():
                    steps, values = _read_scalar(path)
                    if steps:
                        style = {"marker": "o", "linestyle": "--"} if name.startswith("validation/") else {}
                        label = VALIDATION_CURVES.get(name, name)
                        ax.plot(steps, values, label=label, color=CURVE_COLOURS[name], **style)
                        plotted = True
        ax.set_title(method)
        ax.set_xlabel("iteration")
        ax.set_yscale("log")
        if plotted:  # below the axes: the curves fill the plot
            ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2)
        lines.append(f"- **{method}**: run folder `{os.path.relpath(run_dir, report_dir)}`")
    fig.tight_layout()
    figure = report_dir / "figures" / "training_losses.png"
    figure.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(figure, dpi=110)
    plt.close(fig)
    lines += ["", f"![training losses]({os.path.relpath(figure, report_dir)})\n"]
    return lines + _validation_table(train_dirs)


VALIDATION_CURVES = {
    "validation/loss_dt_exploration": "loss_dt, held-out D_e (eval mode)",
    "validation/loss_dt_collision_avoidance": "loss_dt, held-out D_ca (eval mode)",
}
"""The held-out curves drawn beside the training losses, and their legend labels."""
CURVE_COLOURS = {
    "loss_dt": "tab:blue",
    "loss_byol": "tab:orange",
    "loss": "tab:green",
    "validation/loss_dt_exploration": "tab:red",
    "validation/loss_dt_collision_avoidance": "tab:purple",
}
"""Each curve of the training figure in the same colour in every model's panel."""
VALIDATION_COLUMNS = {
    "train_loss_dt_exploration": "D_e, training data",
    "loss_dt_exploration": "D_e, held-out mazes",
    "train_loss_dt_collision_avoidance": "D_ca, training data",
    "loss_dt_collision_avoidance": "D_ca, held-out mazes",
}
"""The ``validation/`` metrics of the report's table and their column titles."""


def _validation_table(train_dirs: dict[str, Path]) -> list[str]:
    """Eval-mode eq. 10 at each model's last validation: training data beside held-out mazes."""
    rows = []
    for method, run_dir in train_dirs.items():
        last: dict[str, tuple[float, float]] = {}
        for folder in sorted((run_dir / "logs").glob("*/scalars/validation")):
            for name in VALIDATION_COLUMNS:
                path = folder / f"{name}.csv"
                if path.is_file():
                    steps, values = _read_scalar(path)
                    if steps:
                        last[name] = (steps[-1], values[-1])
        if last:
            iteration = int(max(step for step, _ in last.values()))
            cells = [f"{last[name][1]:.3f}" if name in last else "-" for name in VALIDATION_COLUMNS]
            rows.append(f"| {method} | {iteration} | " + " | ".join(cells) + " |")
    if not rows:
        return []
    return [
        "Action loss (eq. 10, eval mode) at the last validation, on windows of the training data and on the "
        "held-out trajectories from other mazes (`validation/*` in each run's logs; docs/training.md):\n",
        "| model | iteration | " + " | ".join(VALIDATION_COLUMNS.values()) + " |",
        "|---|---|" + "---|" * len(VALIDATION_COLUMNS),
        *rows,
        "",
        "A held-out loss well above the training one means the model fits the mazes it was trained on better "
        "than new ones: at this demo's scale (a few dozen trajectories) expect a wide gap. These sets hold a "
        "few dozen trajectories, so their means are good to a few tens of percent. At this scale a model's "
        "held-out loss can also stay at its first validation's level for all of the demo's iterations and "
        "leave it later, at an iteration the training seed decides (docs/studies.md, 'The encoders' "
        "optimiser at the demo's scale'): one demo run says little about NavFormer against DT.\n",
    ]


def timings_markdown(timings: dict[str, tuple[float | None, float]]) -> list[str]:
    """The stage-time table of the report: per stage the seconds that computed its result and the seconds
    of this invocation (which only checked and reused a result it found finished)."""
    lines = [
        "| stage | seconds computing the result | seconds in this invocation |",
        "|---|---|---|",
    ]
    for stage, (computed, now) in timings.items():
        lines.append(f"| {stage} | {'-' if computed is None else f'{computed:.0f}'} | {now:.0f} |")
    return lines + [
        "",
        "The first column is the wall-clock time that produced each stage's result, over every invocation "
        "that worked on it (an interrupted run and the rerun that finished it add up); a rerun that reuses a "
        "finished result leaves it unchanged and only shows its own time in the second column. Evaluation: "
        "the sum of the methods' times in the Methods table below. `-`: not recorded (a result computed "
        "before `stage_times.json` existed).\n",
    ]


def robot_outcome(row: dict) -> str:
    """What one robot does in an episode, from its per-robot-trial row (``episodes.jsonl``), e.g. "robot 0
    reaches its target at step 123 (in contact on 2 of its steps)"."""
    contact = f"in contact on {row['collisions']} of its {row['steps']} steps"
    if not row.get("measured", True):
        return f"robot {row['robot']} is a scripted moving obstacle ({contact})"
    if row["success"]:
        touched = f" (in contact on {row['collisions']} of its steps)" if row["collisions"] else ""
        return f"robot {row['robot']} reaches its target at step {row['success_step']}{touched}"
    return (
        f"robot {row['robot']} does not reach its target in {row['steps']} steps: it ends "
        f"{row['final_distance']:.1f} m from it, {contact}"
    )


def video_captions(eval_dirs: Sequence[Path], report_dir: Path) -> list[str]:
    """The "What the videos show" section: per recorded episode, the method (the run's label), the maze and
    what every robot does, read from each evaluation folder's ``run.json`` (its videos) and
    ``episodes.jsonl`` (the records)."""
    from navformer_rl.evaluation.runner import _file_stem

    lines = []
    for folder in eval_dirs:
        run = json.loads((folder / "run.json").read_text())
        rows: dict[str, list[dict]] = {}
        with (folder / "episodes.jsonl").open() as handle:
            for line in handle:
                if line.strip():
                    row = json.loads(line)
                    rows.setdefault(_file_stem(row["episode_id"]), []).append(row)
        for video in run["files"].get("videos", []):
            robots = sorted(rows.get(Path(video).stem, []), key=lambda row: row["robot"])
            if not robots:
                continue
            first, link = robots[0], os.path.relpath(folder / video, report_dir)
            lines.append(
                f"- [{run['label']}, episode {first['episode_id']}]({link}) ({first['size']:g} m maze, "
                f"{first['n_robots']} robots): " + "; ".join(robot_outcome(row) for row in robots) + "."
            )
    if not lines:
        return []
    return [
        "### What the videos show\n",
        "Each video shows every robot's camera beside the top-down map of one episode; below, what happens "
        "in it, from the episode's records (`episodes.jsonl`: reaching the 1.5 m target disc, steps in "
        "contact with a wall or a robot).\n",
        *lines,
        "",
    ]


def nested_report(markdown: str) -> str:
    """A ``write_report`` report as a section body: its marker line and ``# title`` dropped, every heading
    one level deeper (to sit under the demo report's ``## Evaluation``)."""
    from navformer_rl.evaluation.report import REPORT_MARKER

    body = markdown.removeprefix(REPORT_MARKER + "\n")
    if not body.startswith("# "):
        raise ValueError(f"expected a report starting with its '# title', got {body[:60]!r}")
    return re.sub(r"^(#+) ", r"#\1 ", body.split("\n", 1)[1], flags=re.MULTILINE)


def _shipped_note(eval_dirs: Sequence[Path]) -> list[str]:
    names = [
        folder.name.removeprefix("pretrained_")
        for folder in eval_dirs
        if folder.name.startswith("pretrained_")
    ]
    if not names:
        return []
    from navformer_rl.training.checkpoint import read_checkpoint_config

    described = []
    for name in names:
        header = read_checkpoint_config(f"pretrained:{name}")
        described.append(f"`pretrained:{name}` ({header['iteration']:,} training iterations)")
    return [
        f"{', '.join(described)}: the shipped weights (their data, training and results with intervals are "
        "on their model cards, `navformer_rl/pretrained/weights/<name>/MODEL_CARD.md`, docs/pretrained.md), "
        "evaluated on the same episodes: a longer-trained policy beside what the demo's small training "
        "reaches.\n"
    ]


def write_demo_report(
    cfg: DemoConfig,
    data: dict[str, Path],
    train_dirs: dict[str, Path],
    eval_dirs: Sequence[Path],
    timings: dict[str, tuple[float | None, float]],
) -> Path:
    """Write ``<out>/report.md`` (and ``figures/``) and return its path.

    ``timings`` maps a stage to ``(seconds that computed its result, None when unknown; seconds it took in
    this invocation)`` (see :mod:`navformer_rl.demo.pipeline`).
    """
    from navformer_rl.demo.config import environment_summary, write_json
    from navformer_rl.evaluation.report import write_report

    report_dir = cfg.out_dir
    evaluation_md = write_report(eval_dirs, report_dir / "evaluation.md", title="Evaluation", seed=cfg.seed)
    evaluation = nested_report(evaluation_md.read_text())

    lines = [
        "# NavFormer end-to-end demo\n",
        "Small-scale run of the whole pipeline on the embedded pybullet mazes: expert data collection, "
        "training of NavFormer and the DT baseline, evaluation with VRW and the privileged FCA upper bound. "
        f"It is far below paper scale ({cfg.iterations} training iterations instead of 10,000, "
        f"{cfg.exploration_trajectories} + {cfg.collision_trajectories} trajectories instead of "
        f"3,496 + 7,467, batches of {cfg.exploration_batch} / {cfg.collision_batch} trajectories and "
        f"{cfg.ssl_batch} pairs instead of 25 / 150 / 512, and {cfg.trials_per_setup} evaluation trials on "
        f"the `{cfg.setups}` protocol instead of 60 on each of Table I's 9 setups), so NavFormer's numbers "
        "show the pipeline working, not the paper's result. `docs/reproduce.md` has the paper-scale "
        "commands.\n",
        *_shipped_note(eval_dirs),
        *timings_markdown(timings),
    ]
    lines += _dataset_section(data, report_dir)
    lines += _training_section(train_dirs, report_dir)
    lines += ["## Evaluation\n", evaluation, *video_captions(eval_dirs, report_dir)]
    settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in cfg.__dict__.items()}
    write_json(report_dir / "demo_config.json", {"config": settings, "machine": environment_summary()})
    lines += [
        "## Settings\n",
        "`demo_config.json` holds the demo's settings and the machine; each training run's resolved "
        "configuration is its `train/<method>/train_config.json`, each evaluation's method, checkpoint hash "
        "and seeds its `eval/<method>/run.json`.\n",
    ]
    report = report_dir / "report.md"
    atomic_write_text(report, "\n".join(lines) + "\n")
    return report
