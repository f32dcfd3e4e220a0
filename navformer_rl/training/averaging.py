"""Checkpoint averaging: the uniform mean of the weights of several checkpoints of one training run.

An opt-in beyond the paper (``docs/deviations.md``), after stochastic weight averaging (Izmailov et al., UAI
2018) and latest-weight averaging (Kaddour, 2022): a policy's closed-loop success can swing by several points
between checkpoints a few hundred iterations apart while the offline loss falls smoothly
(``docs/studies.md``), and the mean of a run's last checkpoints is one model instead of one draw. Measured on
the paper's 10,000-iteration run, the mean of the last 1,000 iterations' checkpoints follows the last one it
averages (the same SR within 2.5 points at 2,000-5,000; +5.0 [-5.6, +15.3] at 9,000-10,000, and -5.0
[-14.1, +4.2] for the DT baseline's run) rather than removing the swings.

The result is a checkpoint's run part (``config.json`` + ``model.safetensors``, no ``resume.pt``) that every
command accepting ``--checkpoint`` reads, and ``init_from=`` fine-tunes from. Its header is the newest
source's (``iteration``: the newest source's, ``train_config``: the newest source's) with
``run.averaged_from`` added: ``[{"checkpoint", "iteration", "weights_sha256"}, ...]`` in iteration order.

The model has no running statistics (its CNNs use GroupNorm), so the averaged parameters need no
recomputed normalisation statistics, unlike SWA with BatchNorm.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from navformer_rl.training.checkpoint import (
    CHECKPOINTS_DIRNAME,
    WEIGHTS_FILENAME,
    load_model_state,
    read_checkpoint_config,
    resolve_checkpoint,
    state_dict_mismatch,
    write_run_part,
)
from navformer_rl.training.pretrained_registry import file_sha256
from navformer_rl.utils.durable import publish_folder


def run_checkpoints(run_dir: str | os.PathLike, first: int, last: int) -> list[Path]:
    """The regular checkpoints of ``run_dir`` whose iteration lies in ``[first, last]``, oldest first.

    Regular: iterations that are multiples of the run's ``checkpoint.interval``, so the selected weights are
    evenly spaced (a checkpoint a stop wrote between two intervals, e.g. ``iter_005042``, is left out).

    Raises:
        FileNotFoundError: ``run_dir`` has no ``checkpoints/`` folder.
        ValueError: ``first > last``, or fewer than two regular checkpoints in the range.
    """
    if first > last:
        raise ValueError(f"first iteration {first} is after last iteration {last}; expected first <= last")
    root = Path(run_dir) / CHECKPOINTS_DIRNAME
    if not root.is_dir():
        raise FileNotFoundError(
            f"no run directory at {str(run_dir)!r}: expected a folder holding {CHECKPOINTS_DIRNAME}/"
        )
    selected = []
    for folder in sorted(p for p in root.glob("iter_*") if p.is_dir()):
        header = read_checkpoint_config(folder)
        iteration = int(header["iteration"])
        interval = int(((header.get("train_config") or {}).get("checkpoint") or {}).get("interval", 1) or 1)
        if first <= iteration <= last and iteration % interval == 0:
            selected.append(folder)
    if len(selected) < 2:
        raise ValueError(
            f"{str(run_dir)!r} has {len(selected)} regular checkpoint(s) between iterations {first} and "
            f"{last}; averaging needs at least 2"
        )
    return selected


def average_checkpoints(
    checkpoints: Sequence[str | os.PathLike], out: str | os.PathLike, *, overwrite: bool = False
) -> Path:
    """Write the uniform average of ``checkpoints``' weights as the checkpoint folder ``out``.

    Floating-point tensors are summed in float64 and divided by the number of checkpoints, then stored in
    their own dtype; other tensors must be equal in every checkpoint. The folder appears atomically.

    Args:
        checkpoints: two or more paths that :func:`~navformer_rl.training.checkpoint.resolve_checkpoint`
            accepts, all of one run (the same model configuration, training seed and ``init_from``).
        out: the folder to write (``out/config.json``, ``out/model.safetensors``).
        overwrite: replace an existing ``out`` (FileExistsError otherwise).

    Returns:
        ``out`` as a Path.

    Raises:
        ValueError: fewer than two distinct checkpoints, or checkpoints of different models or runs.
        FileExistsError: ``out`` exists and ``overwrite`` is False.
        FileNotFoundError: a path that designates no checkpoint.
    """
    folders = [resolve_checkpoint(path) for path in checkpoints]
    if len({folder.resolve() for folder in folders}) != len(folders) or len(folders) < 2:
        raise ValueError(
            f"averaging needs at least 2 distinct checkpoints, got {[str(folder) for folder in folders]}"
        )
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(
            f"--out {str(out)!r} is a file; expected a folder to write the averaged checkpoint into"
        )
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists; pass overwrite (--force) to replace it")
    headers = [read_checkpoint_config(folder) for folder in folders]
    order = sorted(range(len(folders)), key=lambda i: int(headers[i]["iteration"]))
    folders, headers = [folders[i] for i in order], [headers[i] for i in order]
    _check_one_run(folders, headers)
    states = [load_model_state(folder)[1] for folder in folders]
    averaged = _mean_state(states, folders)

    newest = headers[-1]
    run = dict(newest.get("run") or {})
    run["averaged_from"] = [
        {
            "checkpoint": str(folder),
            "iteration": int(header["iteration"]),
            "weights_sha256": file_sha256(folder / WEIGHTS_FILENAME),
        }
        for folder, header in zip(folders, headers)
    ]
    header = {**newest, "run": run}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        write_run_part(tmp, header, averaged)
        publish_folder(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _run_identity(header: Mapping[str, Any]) -> tuple[Any, Any]:
    """``(training seed, init_from weights sha256)``: what checkpoints of one run share."""
    init_from = (header.get("run") or {}).get("init_from") or {}
    return (header.get("train_config") or {}).get("seed"), init_from.get("weights_sha256")


def _check_one_run(folders: Sequence[Path], headers: Sequence[Mapping[str, Any]]) -> None:
    """Refuse checkpoints of different models or of different runs (their weights share no trajectory, so
    their mean is not a model of either)."""
    reference, reference_header = folders[0], headers[0]
    for folder, header in zip(folders[1:], headers[1:]):
        config, expected = header["model_config"], reference_header["model_config"]
        if config != expected:
            differing = sorted(k for k in set(config) | set(expected) if config.get(k) != expected.get(k))
            raise ValueError(
                f"checkpoints {reference} and {folder} have different model configurations (fields "
                f"{differing}); only checkpoints of one run can be averaged"
            )
        if _run_identity(header) != _run_identity(reference_header):
            raise ValueError(
                f"checkpoints {reference} and {folder} come from different runs (training seed, init_from: "
                f"{_run_identity(reference_header)} vs {_run_identity(header)}); only checkpoints of one run "
                "can be averaged"
            )


def _mean_state(
    states: Sequence[Mapping[str, torch.Tensor]], folders: Sequence[Path]
) -> dict[str, torch.Tensor]:
    """The entry-wise mean of ``states`` (float64 accumulation); non-float entries must agree."""
    reference = dict(states[0])
    for state, folder in zip(states[1:], folders[1:]):
        mismatch = state_dict_mismatch(reference, dict(state))
        if mismatch:
            raise ValueError(f"{folder} does not hold the same tensors as {folders[0]}: {mismatch}")
    averaged = {}
    for key, tensor in reference.items():
        if tensor.is_floating_point():
            total = torch.zeros(tensor.shape, dtype=torch.float64)
            for state in states:
                total += state[key].to(torch.float64)
            averaged[key] = (total / len(states)).to(tensor.dtype)
        else:
            for state, folder in zip(states[1:], folders[1:]):
                if not torch.equal(state[key], tensor):
                    raise ValueError(
                        f"{key} ({tensor.dtype}) differs between {folders[0]} and {folder}; non-float "
                        "entries cannot be averaged"
                    )
            averaged[key] = tensor.clone()
    return averaged
