"""Training checkpoints: an atomic folder per save, with a "run" part apart from a "resume" part.

Layout of a run directory::

    <run_dir>/checkpoints/
        latest                      text file: the name of the newest complete checkpoint folder
        iter_000500/
            config.json             {"format", "iteration", "model_config", "train_config", "run"}
            model.safetensors       NavFormerModel weights; metadata repeats format + model config
            resume.pt               torch.save of plain containers (optimiser, RNG, sampler, ...)

* The **run part** (``config.json`` + ``model.safetensors``) is all an evaluator needs:
  :func:`load_policy_model` rebuilds the ``NavFormerModel`` from it and never opens ``resume.pt``.
* ``run`` (absent from checkpoints of earlier versions) records how the run was made: ``world_size`` (the
  number of data-parallel processes, :func:`recorded_world_size`), ``backend`` and ``init_from`` (the
  checkpoint whose weights it started from: ``{"checkpoint", "folder", "iteration", "weights_sha256"}``,
  or None).
* The **resume part** (``resume.pt``) holds optimiser states, BYOL target parameters, RNG states (one per
  process under ``rng_ranks`` in a data-parallel run), the iteration and the samplers' states. It only
  contains tensors and plain Python containers, so it loads with ``torch.load(..., weights_only=True)``.

Atomicity: a checkpoint is written completely into a private temporary folder, flushed to disk, then
renamed into place with ``os.replace``; only then is ``latest`` rewritten (temp file + ``os.replace``). A
crash at any point leaves the previous checkpoint, and ``latest`` pointing at it, intact.

Permissions: ``mkdtemp`` / ``mkstemp`` (and safetensors) create owner-only folders and files; before the
rename they get the modes that ``mkdir`` / ``open`` give under the process umask (``0o777 & ~umask`` and
``0o666 & ~umask``: 0755 / 0644 with umask 022), so other users and containers can evaluate a checkpoint.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import torch

from navformer_rl.training.pretrained_registry import PRETRAINED_PREFIX, is_pretrained, resolve_pretrained
from navformer_rl.utils.durable import (
    atomic_write_text,
    publish_folder,
)

RUN_FORMAT = "navformer_rl.run/1"
"""Format tag written into every run part; a file without it is refused."""

CHECKPOINTS_DIRNAME = "checkpoints"
LATEST_FILENAME = "latest"
CONFIG_FILENAME = "config.json"
WEIGHTS_FILENAME = "model.safetensors"
RESUME_FILENAME = "resume.pt"


def checkpoint_name(iteration: int) -> str:
    """Folder name of the checkpoint taken after ``iteration`` completed iterations."""
    return f"iter_{iteration:06d}"


def save_checkpoint(
    run_dir: str | os.PathLike,
    iteration: int,
    *,
    model_state: Mapping[str, torch.Tensor],
    model_config: Mapping[str, Any],
    train_config: Mapping[str, Any],
    resume_state: Mapping[str, Any] | None,
    keep_last: int = 0,
    run_info: Mapping[str, Any] | None = None,
) -> Path:
    """Write one checkpoint folder atomically and point ``latest`` at it.

    Args:
        run_dir: the run directory; the checkpoint goes to ``run_dir/checkpoints/iter_XXXXXX``.
        iteration: number of completed training iterations.
        model_state: ``NavFormerModel.state_dict()`` (tensors; made contiguous and moved to CPU).
        model_config: JSON-serialisable ``NavFormerConfig`` fields.
        train_config: JSON-serialisable training configuration (stored for provenance).
        resume_state: plain containers of tensors/numbers for :func:`load_resume_state`, or ``None``
            to write a run part only.
        keep_last: keep only the newest ``keep_last`` checkpoints (0 keeps all).
        run_info: JSON-serialisable record of how the run was made (``world_size``, ``backend``,
            ``init_from``), written as the header's ``run``; None writes none.

    Returns:
        The path of the checkpoint folder.
    """
    root = Path(run_dir) / CHECKPOINTS_DIRNAME
    root.mkdir(parents=True, exist_ok=True)
    final = root / checkpoint_name(iteration)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=root))
    try:
        header = {
            "format": RUN_FORMAT,
            "iteration": int(iteration),
            "model_config": dict(model_config),
            "train_config": dict(train_config),
        }
        if run_info is not None:
            header["run"] = dict(run_info)
        write_run_part(tmp, header, model_state)
        if resume_state is not None:
            torch.save(dict(resume_state), tmp / RESUME_FILENAME)
        publish_folder(tmp, final)  # the same iteration saved twice replaces the older folder
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    atomic_write_text(root / LATEST_FILENAME, final.name + "\n")
    if keep_last > 0:
        _prune(root, keep_last, final)
    return final


def write_run_part(folder: Path, header: Mapping[str, Any], model_state: Mapping[str, torch.Tensor]) -> None:
    """Write ``folder/config.json`` (``header``) and ``folder/model.safetensors`` (``model_state`` on CPU,
    contiguous; its metadata repeats the format and ``header["model_config"]``). Not atomic by itself: callers
    write into a private folder and publish it."""
    from safetensors.torch import save_file

    (folder / CONFIG_FILENAME).write_text(json.dumps(dict(header), indent=2, sort_keys=True))
    tensors = {k: v.detach().to("cpu").contiguous() for k, v in model_state.items()}
    metadata = {
        "format": RUN_FORMAT,
        "model_config": json.dumps(dict(header["model_config"]), sort_keys=True),
    }
    save_file(tensors, str(folder / WEIGHTS_FILENAME), metadata=metadata)


def _prune(root: Path, keep_last: int, latest: Path) -> None:
    """Keep ``latest`` and the ``keep_last - 1`` checkpoints before it; delete the rest.

    Folders numbered beyond ``latest`` are left over from a crash between a folder's rename and the
    ``latest`` update (the resumed run has redone those iterations); they are deleted too, so a later
    ``keep_last`` count can never remove the folder ``latest`` names.
    """
    complete = sorted(p for p in root.glob("iter_*") if p.is_dir())
    kept = [p for p in complete if p.name <= latest.name][-keep_last:]
    for old in complete:
        if old not in kept:
            shutil.rmtree(old, ignore_errors=True)


def _latest_in(root: Path) -> Path | None:
    """The checkpoint folder that ``root/latest`` names (``None`` when ``root`` has no ``latest``)."""
    pointer = root / LATEST_FILENAME
    if not pointer.is_file():
        return None
    target = root / pointer.read_text().strip()
    if not (target / CONFIG_FILENAME).is_file():
        raise FileNotFoundError(
            f"{pointer} names {target.name!r}, which is not a complete checkpoint folder "
            f"(no {CONFIG_FILENAME}); the run directory was modified by hand"
        )
    return target


def run_folder_latest(run_dir: Path, resume: bool) -> Path | None:
    """The latest checkpoint of the run folder ``run_dir``, None for a new or checkpoint-less folder.

    Raises:
        ValueError: ``run_dir`` is a file.
        FileExistsError: ``run_dir`` holds checkpoints and ``resume`` is False (a fresh run never overwrites).
    """
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"output_dir={str(run_dir)!r} is a file; expected a folder (created if missing)")
    latest = latest_checkpoint(run_dir) if (run_dir / CHECKPOINTS_DIRNAME).is_dir() else None
    if latest is not None and not resume:
        raise FileExistsError(
            f"output_dir={str(run_dir)!r} already holds checkpoints (latest {latest.name}); "
            "set resume=true to continue that run or choose another output_dir"
        )
    return latest


def latest_checkpoint(run_dir: str | os.PathLike) -> Path | None:
    """The newest complete checkpoint folder of ``run_dir`` (``None`` when it has none)."""
    return _latest_in(Path(run_dir) / CHECKPOINTS_DIRNAME)


ACCEPTED_CHECKPOINT_PATHS = (
    f"a run directory (its {CHECKPOINTS_DIRNAME}/{LATEST_FILENAME}), its {CHECKPOINTS_DIRNAME}/ folder "
    f"or the {CHECKPOINTS_DIRNAME}/{LATEST_FILENAME} file (the latest checkpoint), a checkpoint folder "
    f"({CHECKPOINTS_DIRNAME}/iter_XXXXXX, holding {CONFIG_FILENAME} and {WEIGHTS_FILENAME}) "
    f"or a file in it such as {WEIGHTS_FILENAME}; or {PRETRAINED_PREFIX}NAME (shipped weights, e.g. "
    f"{PRETRAINED_PREFIX}navformer)"
)
"""The path forms :func:`resolve_checkpoint` accepts, in words (for error messages and ``--help``)."""


def resolve_checkpoint(path: str | os.PathLike) -> Path:
    """Turn any path that designates a checkpoint into its checkpoint folder.

    Accepted: a run directory (its latest checkpoint); its ``checkpoints/`` folder or the
    ``checkpoints/latest`` pointer file (the checkpoint ``latest`` names); a checkpoint folder
    ``checkpoints/iter_XXXXXX``; or one of that folder's files (``model.safetensors``, ``config.json``,
    ``resume.pt``); or ``pretrained:NAME``, the folder of shipped weights
    (:func:`~navformer_rl.training.pretrained_registry.resolve_pretrained`: its files checked against their
    sha256).

    Raises:
        FileNotFoundError: ``path`` is none of these (the message lists the accepted forms), or it has
            checkpoints but no completed one, or ``latest`` names a folder that is not a checkpoint, or
            the shipped weights it names are missing from this installation.
        ValueError: ``pretrained:NAME`` names no shipped weights (the message lists them) or a corrupt file.
    """
    if is_pretrained(path):
        return resolve_pretrained(path)
    path = Path(path)
    if path.is_file() and path.name in (WEIGHTS_FILENAME, CONFIG_FILENAME, RESUME_FILENAME):
        path = path.parent
    elif path.is_file() and path.name == LATEST_FILENAME:
        path = path.parent
    if (path / CONFIG_FILENAME).is_file() and (path / WEIGHTS_FILENAME).is_file():
        return path
    for root in (path, path / CHECKPOINTS_DIRNAME):  # a checkpoints/ folder, or a run directory
        latest = _latest_in(root)
        if latest is not None:
            return latest
    if (path / CHECKPOINTS_DIRNAME).is_dir() or (path.name == CHECKPOINTS_DIRNAME and path.is_dir()):
        raise FileNotFoundError(
            f"no complete checkpoint at {str(path)!r} yet: no {LATEST_FILENAME} pointer (the run has not "
            "finished writing its first checkpoint)"
        )
    raise FileNotFoundError(f"no checkpoint at {str(path)!r}: expected {ACCEPTED_CHECKPOINT_PATHS}")


def read_checkpoint_config(path: str | os.PathLike) -> dict[str, Any]:
    """The ``config.json`` header of a checkpoint (format-checked)."""
    folder = resolve_checkpoint(path)
    try:
        header = json.loads((folder / CONFIG_FILENAME).read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(
            f"{folder / CONFIG_FILENAME} is not valid JSON ({error}): a corrupt checkpoint"
        ) from None
    if not isinstance(header, dict):
        raise ValueError(f"{folder / CONFIG_FILENAME}: expected a JSON object, got {type(header).__name__}")
    if header.get("format") != RUN_FORMAT:
        raise ValueError(
            f"{folder / CONFIG_FILENAME} has format {header.get('format')!r}; expected {RUN_FORMAT!r} "
            "(not a navformer_rl training checkpoint, or one from an incompatible version)"
        )
    if not isinstance(header.get("model_config"), dict):
        raise ValueError(f"{folder / CONFIG_FILENAME} has no 'model_config' object: a corrupt checkpoint")
    return header


def training_context_steps(path: str | os.PathLike) -> int | None:
    """The trajectory window a checkpoint was trained on (its training ``data.context_steps``): None when it
    trained on windows up to the model's whole context (the paper's) or does not record its training
    configuration. The policy loaders attend to this many steps by default (``docs/model.md``)."""
    train_config = read_checkpoint_config(path).get("train_config")
    data = train_config.get("data") if isinstance(train_config, dict) else None
    value = data.get("context_steps") if isinstance(data, dict) else None
    if isinstance(value, int) and not isinstance(value, bool) and value >= 1:
        return value
    return None


def recorded_world_size(header: Mapping[str, Any]) -> int:
    """The number of data-parallel processes that wrote a checkpoint (its header's ``run.world_size``; 1 for a
    checkpoint that records none)."""
    return int((header.get("run") or {}).get("world_size", 1))


def load_model_state(path: str | os.PathLike) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
    """Read the run part: ``(model_config fields, state_dict)``, via safetensors (no pickle)."""
    from safetensors import SafetensorError, safe_open

    folder = resolve_checkpoint(path)
    header = read_checkpoint_config(folder)
    weights = folder / WEIGHTS_FILENAME
    try:
        with safe_open(str(weights), framework="pt") as handle:
            metadata = handle.metadata() or {}
            state = {key: handle.get_tensor(key) for key in handle.keys()}
    except (OSError, SafetensorError) as error:
        raise ValueError(
            f"{weights} cannot be read as safetensors ({error}): a corrupt or truncated checkpoint"
        ) from None
    if metadata.get("format") != RUN_FORMAT:
        raise ValueError(f"{weights} has format {metadata.get('format')!r}; expected {RUN_FORMAT!r}")
    if json.loads(metadata.get("model_config", "null")) != header["model_config"]:
        raise ValueError(
            f"{weights} and {folder / CONFIG_FILENAME} describe different model configurations "
            "(the folder mixes files from two checkpoints)"
        )
    return header["model_config"], state


def _config_from_dict(config_cls: type, values: Mapping[str, Any], path: str | os.PathLike) -> Any:
    """``config_cls`` from a checkpoint's ``model_config``; a PPO baseline's checkpoint (its config names a
    ``method``) is refused with the method to use instead."""
    known = {f.name for f in fields(config_cls)}
    method = values.get("method")
    if isinstance(method, str) and "method" not in known:
        raise ValueError(
            f"checkpoint {path} holds the {method} baseline (trained with PPO, `navformer train-ppo`), not a "
            f"NavFormer / DT model (`navformer evaluate --method {method}` evaluates it)"
        )
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(
            f"checkpoint model config has fields {unknown} that {config_cls.__name__} does not know; "
            "it was written by another model version"
        )
    kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
    return config_cls(**kwargs)


def read_model_config(path: str | os.PathLike) -> Any:
    """The ``NavFormerConfig`` a checkpoint's run part describes (from ``config.json``; weights not read).

    Raises:
        FileNotFoundError / ValueError: as :func:`read_checkpoint_config`, or fields ``NavFormerConfig`` does
            not know (written by another model version) or values it refuses.
    """
    from navformer_rl.modules import NavFormerConfig

    return _config_from_dict(NavFormerConfig, read_checkpoint_config(path)["model_config"], path)


def load_policy_model(path: str | os.PathLike, expected_config: Any | None = None) -> tuple[Any, Any]:
    """Rebuild the trained ``NavFormerModel`` from a checkpoint's run part, in eval mode on CPU.

    Args:
        path: a run directory, its ``checkpoints/`` folder or ``checkpoints/latest`` (the latest checkpoint),
            a checkpoint folder or its ``model.safetensors`` (see :func:`resolve_checkpoint`).
        expected_config: optional ``NavFormerConfig``; a checkpoint with another configuration is refused.

    Returns:
        ``(NavFormerConfig, NavFormerModel)``.

    Raises:
        FileNotFoundError: no checkpoint at ``path``.
        ValueError: the checkpoint is not ours, is of another configuration than ``expected_config``, or its
            weights do not fit the model its configuration describes.
    """
    from navformer_rl.modules import NavFormerConfig, NavFormerModel

    config_fields, state = load_model_state(path)
    config = _config_from_dict(NavFormerConfig, config_fields, path)
    if expected_config is not None and expected_config != config:
        diff = {
            f.name: (getattr(config, f.name), getattr(expected_config, f.name))
            for f in fields(NavFormerConfig)
            if getattr(config, f.name) != getattr(expected_config, f.name)
        }
        raise ValueError(
            f"checkpoint {path} was trained with another model config; (checkpoint, expected): {diff}"
        )
    model = NavFormerModel(config)
    load_model_weights(model, state, path)
    model.eval()
    return config, model


RENAMED_PREFIXES = {
    "static_encoder.": "dve.static_encoder.",
    "general_encoder.": "dve.general_encoder.",
    "return_embed.": "transformer.tokens.return_embed.",
    "action_embed.": "transformer.tokens.action_embed.",
    "timestep_embed.": "transformer.tokens.timestep_embed.",
    "modality_embed.": "transformer.tokens.modality_embed.",
    "embed_ln.": "transformer.tokens.embed_ln.",
    "transformer.blocks.": "transformer.gpt.blocks.",
    "transformer.ln_final.": "transformer.gpt.ln_final.",
}
"""State-dict names of the single-module model (checkpoints of ``navformer_rl.run/1`` written before the
model was split into its parts) -> the names of the parts. The parameter order is the same, so the
optimiser states of a resumed run still match."""


def upgrade_state_dict(state: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``state`` with the single-module model's names (``RENAMED_PREFIXES``) mapped to the current ones;
    current names are kept as they are."""
    upgraded = {}
    for name, tensor in state.items():
        for old, new in RENAMED_PREFIXES.items():
            if name.startswith(old):
                name = new + name[len(old) :]
                break
        upgraded[name] = tensor
    return upgraded


def load_model_weights(model: Any, state: Mapping[str, torch.Tensor], path: str | os.PathLike) -> None:
    """``model.load_state_dict(state)`` after checking that the keys and shapes match exactly.

    Names of the single-module model (checkpoints written before it was split into its DVE, causal
    transformer and head) are mapped to the parts' names first (``upgrade_state_dict``).

    Raises:
        ValueError: naming the first missing, unexpected and wrongly shaped entries - e.g. for weights written
            by another version of the model code (a ResNet18 checkpoint from before its BatchNorm became
            GroupNorm carries running statistics the model no longer has).
    """
    state = upgrade_state_dict(state)
    mismatch = state_dict_mismatch(model.state_dict(), state)
    if mismatch:
        raise ValueError(
            f"checkpoint {path} does not match NavFormerModel({model.config}): {mismatch} (written by "
            "another version of the model code?)"
        )
    model.load_state_dict(state)


def state_dict_mismatch(expected: dict[str, torch.Tensor], state: dict[str, torch.Tensor]) -> str | None:
    """``"missing [...], unexpected [...], wrong shapes [...]"`` (the first five names of each) when ``state``
    cannot load into a module whose ``state_dict()`` is ``expected``; None when it can."""
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    wrong_shape = sorted(k for k in set(state) & set(expected) if state[k].shape != expected[k].shape)
    if not (missing or unexpected or wrong_shape):
        return None
    return f"missing {missing[:5]}, unexpected {unexpected[:5]}, wrong shapes {wrong_shape[:5]}"


def load_resume_state(path: str | os.PathLike) -> dict[str, Any]:
    """Load a checkpoint's resume part with ``torch.load(weights_only=True)``."""
    folder = resolve_checkpoint(path)
    resume = folder / RESUME_FILENAME
    if not resume.is_file():
        raise FileNotFoundError(
            f"checkpoint {folder} has no resume part ({RESUME_FILENAME}); it cannot be resumed"
        )
    return torch.load(resume, map_location="cpu", weights_only=True)


def capture_rng_state() -> dict[str, Any]:
    """Global RNG states (torch CPU + CUDA, numpy legacy, python ``random``) as plain containers."""
    np_state = np.random.get_state()
    state: dict[str, Any] = {
        "torch": torch.get_rng_state(),
        "numpy": {
            "name": np_state[0],
            "keys": torch.from_numpy(np_state[1].astype(np.int64)),
            "pos": int(np_state[2]),
            "has_gauss": int(np_state[3]),
            "cached_gaussian": float(np_state[4]),
        },
        "python": random.getstate(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def restore_rng_state(state: Mapping[str, Any]) -> None:
    """Inverse of :func:`capture_rng_state`."""
    torch.set_rng_state(state["torch"])
    np_state = state["numpy"]
    np.random.set_state(
        (
            np_state["name"],
            np_state["keys"].numpy().astype(np.uint32),
            np_state["pos"],
            np_state["has_gauss"],
            np_state["cached_gaussian"],
        )
    )
    random.setstate(state["python"])
    if "cuda" in state and torch.cuda.is_available():
        # one state per GPU visible when it was saved; a resume may see fewer (or more) GPUs
        for index, device_state in enumerate(state["cuda"][: torch.cuda.device_count()]):
            torch.cuda.set_rng_state(device_state, index)
