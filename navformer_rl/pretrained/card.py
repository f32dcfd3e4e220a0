"""Model cards of shipped weights: facts measured from a training run and its evaluations, as markdown.

Every number on a card is read from a file: the checkpoint's ``config.json`` (iteration, seed, batch sizes,
data paths), the run's training log (``logs/<exp_name>/scalars/iteration_s.csv``: the training time), the
datasets' ``metadata.json`` (their sizes), and evaluation folders (``run.json`` and ``summary.csv`` of
``navformer evaluate``). The author adds prose only (:data:`PROSE_FIELDS`: summary, hardware, known failure
modes, notes).
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

PROSE_FIELDS: dict[str, type] = {"summary": str, "hardware": str, "failure_modes": list, "notes": list}
"""The fields a card file (``--card card.json``) may hold: text, or lists of text (one bullet each)."""

DATASETS = (("D_e", "exploration_path", "exploration_trajectories", "trajectories"),
            ("D_ca", "collision_path", "collision_trajectories", "trajectories"),
            ("D_ssl", "ssl_path", "ssl_pairs", "pairs"))  # fmt: skip
"""(name, ``data.`` path key, ``data.`` head-limit key, unit) of the training datasets."""
MODEL_FIELDS = ("encoder", "use_static_encoder", "use_general_encoder", "thsc", "d_embed", "n_blocks",
                "n_heads", "context_tokens")  # fmt: skip
"""The ``NavFormerConfig`` fields the card's model row shows."""


def check_prose(fields: Mapping[str, Any]) -> dict[str, Any]:
    """``fields`` (as a dict) if every key is a :data:`PROSE_FIELDS` entry of the right type; ValueError
    otherwise."""
    if not isinstance(fields, Mapping):
        raise ValueError(f"card fields: expected a JSON object, got {type(fields).__name__}")
    for key, value in fields.items():
        expected = PROSE_FIELDS.get(key)
        if expected is None:
            raise ValueError(f"card field {key!r} is not one of {', '.join(PROSE_FIELDS)}")
        if not isinstance(value, expected) or (
            expected is list and not all(isinstance(item, str) for item in value)
        ):
            kind = "a list of strings" if expected is list else "a string"
            raise ValueError(f"card field {key!r}: expected {kind}, got {value!r}")
    return dict(fields)


def training_facts(folder: Path, header: dict[str, Any]) -> dict[str, Any]:
    """What the checkpoint folder and its run directory record about the training.

    Returns ``{"checkpoint", "iteration", "model_config", "train_config", "data": [{"name", "path", "unit",
    "available", "used", "seed"}], "training_seconds", "timing_source", "init_from", "averaged_from"}``
    (``init_from``: the run's record of the weights it was fine-tuned from, ``{"checkpoint", "folder",
    "iteration", "weights_sha256"}``, or None; ``averaged_from``: for an averaged checkpoint
    (:mod:`navformer_rl.training.averaging`), its sources ``[{"checkpoint", "iteration", "weights_sha256"}]``,
    else None); ``available`` / ``used`` /
    ``seed`` (the collection's) / ``training_seconds`` are None where the files that would give them are not
    there.
    """
    from navformer_rl.training.checkpoint import CHECKPOINTS_DIRNAME

    train_config = header.get("train_config") if isinstance(header.get("train_config"), dict) else {}
    data = train_config.get("data") or {}
    datasets = []
    for name, path_key, limit_key, unit in DATASETS:
        path = data.get(path_key)
        if path is None:
            continue
        available, seed = _datasets_items([path] if isinstance(path, str) else list(path))
        limit = data.get(limit_key)
        used = None if available is None else (available if limit is None else min(available, limit))
        datasets.append(
            {"name": name, "path": path, "unit": unit, "available": available, "used": used, "seed": seed}
        )
    run_dir = folder.parent.parent if folder.parent.name == CHECKPOINTS_DIRNAME else None
    exp_name = (train_config.get("logger") or {}).get("exp_name")
    log = (
        None
        if run_dir is None or exp_name is None
        else run_dir / "logs" / exp_name / "scalars" / "iteration_s.csv"
    )
    seconds = None if log is None else _logged_seconds(log, int(header["iteration"]))
    return {
        "checkpoint": str(folder),
        "iteration": int(header["iteration"]),
        "model_config": header["model_config"],
        "train_config": train_config,
        "data": datasets,
        "training_seconds": seconds,
        "timing_source": None if seconds is None else str(log),
        "init_from": (header.get("run") or {}).get("init_from"),
        "averaged_from": (header.get("run") or {}).get("averaged_from"),
    }


def _datasets_items(paths: list[str]) -> tuple[int | None, int | None]:
    """``(items, collection seed)`` of one folder or a list of folders read as one (``data.*_path`` as a
    list): the summed items (None when any folder's are unknown) and the seed they share (None when they
    differ)."""
    found = [_dataset_items(Path(path)) for path in paths]
    items = None if any(n is None for n, _ in found) else sum(n for n, _ in found)
    seeds = {seed for _, seed in found}
    return items, seeds.pop() if len(seeds) == 1 else None


def _dataset_items(path: Path) -> tuple[int | None, int | None]:
    """``(items, collection seed)`` of a complete dataset folder (trajectories or pairs; ``settings.seed``
    of its ``metadata.json``, None when it records none); ``(None, None)`` when it is not there or not
    complete."""
    try:
        metadata = json.loads((path / "metadata.json").read_text())
        items = metadata["counts"]["items"] if metadata.get("status") == "complete" else None
        seed = (metadata.get("settings") or {}).get("seed")
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None, None
    if not isinstance(items, int):
        return None, None
    return items, seed if isinstance(seed, int) else None


def _logged_seconds(log: Path, iteration: int) -> float | None:
    """The summed iteration times of iterations 1..``iteration`` from the training log's ``iteration_s``
    rows (``step,mean over the iterations since the previous row``); None when the log does not reach
    ``iteration`` exactly or is missing."""
    if not log.is_file():
        return None
    total, previous = 0.0, 0
    for row in csv.reader(log.read_text().splitlines()):
        step, mean = int(row[0]), float(row[1])
        if step > iteration:
            break
        total += mean * (step - previous)
        previous = step
    return total if previous == iteration else None


def evaluation_facts(folder: Path, weights_sha256: str) -> dict[str, Any]:
    """``run.json`` and ``summary.csv`` of an evaluation of the weights whose sha256 is ``weights_sha256``.

    Raises:
        FileNotFoundError: ``folder`` is not a finished evaluation (no ``run.json`` or ``summary.csv``).
        ValueError: it evaluated other weights.
    """
    run_file, summary_file = folder / "run.json", folder / "summary.csv"
    for path in (run_file, summary_file):
        if not path.is_file():
            raise FileNotFoundError(f"{folder} is not a finished evaluation folder: no {path.name}")
    run = json.loads(run_file.read_text())
    if run.get("checkpoint_sha256") != weights_sha256:
        raise ValueError(
            f"{folder} evaluated other weights (sha256 {str(run.get('checkpoint_sha256'))[:16]}...), not the "
            f"exported ones ({weights_sha256[:16]}...); evaluate the exported checkpoint"
        )
    with summary_file.open() as handle:
        rows = list(csv.DictReader(handle))
    return {"folder": str(folder), "run": run, "rows": rows}


def _value(row: dict[str, str], key: str) -> tuple[float, tuple[float, float]]:
    def number(text: str) -> float:
        return float(text) if text else math.nan

    return number(row[key]), (number(row[f"{key}_low"]), number(row[f"{key}_high"]))


def _results_markdown(evaluation: dict[str, Any]) -> list[str]:
    from navformer_rl.evaluation.tables import format_ratio, format_sr

    run = evaluation["run"]
    episodes = run.get("episode_set", {})
    lines = [
        f"### {run.get('label')} on `{episodes.get('name')}`",
        "",
        f"{episodes.get('episodes')} episodes of at most {episodes.get('max_steps')} steps (episode set "
        f"sha256 {str(episodes.get('content_sha256'))[:16]}...), policy seed {run.get('seed')}, model on "
        f"{run.get('device')} ({run.get('transformer_step')} transformer step"
        + (f", attending to its last {run['context_steps']} steps" if run.get("context_steps") else "")
        + "), "
        f"{100 * float(run.get('confidence', math.nan)):g} % intervals resampling whole "
        f"{run.get('cluster')}s; {run.get('seconds')} s of evaluation with {run.get('workers')} worker(s). "
        f"Folder: `{evaluation['folder']}`.",
        "",
        "| setup | trials | robot-trials | SR | SPL | CR |",
        "|---|---|---|---|---|---|",
    ]
    for row in evaluation["rows"]:
        sr, spl, cr = (_value(row, key) for key in ("sr", "spl", "cr"))
        lines.append(
            f"| {row['setup']} | {row['n_trials']} | {row['n_robot_trials']} | {format_sr(*sr)} | "
            f"{format_ratio(*spl)} | {format_ratio(*cr)} |"
        )
    return [*lines, ""]


def render_card(
    designation: str,
    method: str,
    files: dict[str, dict[str, Any]],
    parameters: int,
    dtypes: list[str],
    training: dict[str, Any],
    evaluations: list[dict[str, Any]],
    prose: dict[str, Any],
) -> str:
    """The model card (markdown) of the shipped weights ``designation`` (``pretrained:NAME``).

    Args:
        designation: ``pretrained:NAME``.
        method: ``navformer`` or ``dt``.
        files: ``{filename: {"bytes": int, "sha256": str}}`` of the shipped files.
        parameters / dtypes: tensor element count and dtypes of ``model.safetensors``.
        training: :func:`training_facts`.
        evaluations: :func:`evaluation_facts` of each evaluation folder.
        prose: :data:`PROSE_FIELDS` values.
    """
    config, model = training["train_config"], training["model_config"]
    data_config, optim = config.get("data") or {}, config.get("optim") or {}
    architecture = ", ".join(f"{key}={model[key]}" for key in MODEL_FIELDS if key in model)
    lines = [f"# `{designation}`: {'the DT baseline' if method == 'dt' else 'NavFormer'}", ""]
    if prose.get("summary"):
        lines += [prose["summary"], ""]
    lines += [
        f"Evaluate with `navformer evaluate --method {method} --checkpoint {designation} ...`; load with "
        f'`load_pretrained_policy("{designation.split(":", 1)[1]}")` (docs/pretrained.md).',
        "",
        "## Weights",
        "",
        "| file | bytes | sha256 |",
        "|---|---|---|",
        *(f"| {name} | {info['bytes']} | `{info['sha256']}` |" for name, info in sorted(files.items())),
        "",
        f"{parameters} tensor elements ({', '.join(dtypes)}), exported from `{training['checkpoint']}`.",
        "",
        "## Training",
        "",
        "| | |",
        "|---|---|",
        f"| model | {architecture} (every field: config.json) |",
        f"| ablation | {config.get('ablation', 'not recorded')} |",
        f"| iterations | {training['iteration']} "
        f"(of optim.iterations={optim.get('iterations', 'not recorded')}) |",
        f"| seed | {config.get('seed', 'not recorded')} |",
        f"| batches | {data_config.get('exploration_batch_trajs')} D_e trajectories, "
        f"{data_config.get('collision_batch_trajs')} D_ca trajectories"
        + (
            ""
            if data_config.get("ssl_path") is None
            else f", {data_config.get('ssl_batch_pairs')} D_ssl pairs"
        )
        + " |",
    ]
    if data_config.get("context_steps") is not None:  # an opt-in, not the paper's: trained on shorter windows
        lines.append(
            f"| trajectory windows | {data_config['context_steps']} steps (data.context_steps); the policy "
            "attends to as many at evaluation |"
        )
    for dataset in training["data"]:
        size = (
            "size not recorded (folder not found at export)"
            if dataset["available"] is None
            else f"{dataset['used']} of its {dataset['available']} {dataset['unit']} used"
            + ("" if dataset["seed"] is None else f" (collection seed {dataset['seed']})")
        )
        path = dataset["path"] if isinstance(dataset["path"], str) else " + ".join(dataset["path"])
        lines.append(f"| {dataset['name']} | `{path}`: {size} |")
    seconds = training["training_seconds"]
    timing = (
        "not recorded (no training log reaching this iteration)"
        if seconds is None
        else f"{seconds:.0f} s ({seconds / 3600:.2f} h): the summed iteration times of "
        f"`{training['timing_source']}` (validation and checkpoint writes excluded)"
    )
    source = training.get("init_from")
    if source:
        lines.append(
            f"| initialised from | `{source.get('checkpoint')}`: iteration {source.get('iteration')} of "
            f"`{source.get('folder')}` (weights sha256 `{str(source.get('weights_sha256'))[:16]}...`); "
            "fine-tuned with fresh optimisers, so the iterations and training time here are this run's own |"
        )
    averaged = training.get("averaged_from")
    if averaged:
        iterations = ", ".join(str(source.get("iteration")) for source in averaged)
        lines.append(
            f"| weights | the uniform mean of {len(averaged)} checkpoints of the run (iterations "
            f"{iterations}; `navformer average-checkpoints`) |"
        )
    lines += [
        f"| device setting | {config.get('device', 'not recorded')} |",
        f"| hardware | {prose.get('hardware', 'not recorded')} |",
        f"| training time | {timing} |",
        "",
        "## Results",
        "",
    ]
    if evaluations:
        for evaluation in evaluations:
            lines += _results_markdown(evaluation)
    else:
        lines += ["No evaluation was exported with these weights.", ""]
    lines += ["## Known failure modes", ""]
    lines += [f"- {item}" for item in prose.get("failure_modes", [])] or ["None recorded."]
    if prose.get("notes"):
        lines += ["", "## Notes", "", *(f"- {item}" for item in prose["notes"])]
    return "\n".join(lines) + "\n"
