"""The registry of shipped weights: where they live, which names exist, and ``pretrained:NAME`` -> folder.

Layout of the pretrained root (the package's ``navformer_rl/pretrained/weights/``, or the folder that the
environment variable ``NAVFORMER_PRETRAINED_DIR`` names)::

    registry.json               {"format": REGISTRY_FORMAT,
                                 "models": {NAME: {"method", "files": {file: sha256}}}}
    <NAME>/
        config.json             the run part of a training checkpoint (navformer_rl.training.checkpoint),
                                byte for byte
        model.safetensors
        MODEL_CARD.md           data, iterations, seeds, hardware, time, results, known failure modes

:func:`resolve_pretrained` checks every file the registry lists against its sha256 before handing out the
folder, which any checkpoint consumer then reads like a checkpoint folder. This module imports no torch.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any

from navformer_rl.utils.durable import atomic_write_json

PRETRAINED_PREFIX = "pretrained:"
"""``--checkpoint pretrained:NAME`` designates the shipped weights NAME."""
PRETRAINED_DIR_ENV = "NAVFORMER_PRETRAINED_DIR"
"""Environment variable naming another pretrained root (a folder laid out as the module docstring says)."""
REGISTRY_FILENAME = "registry.json"
REGISTRY_FORMAT = "navformer_rl.pretrained/1"
CARD_FILENAME = "MODEL_CARD.md"
NAME_PATTERN = re.compile(r"^[a-z0-9][a-z0-9_.-]*$")
"""Shipped names: lower-case letters, digits, ``_ . -``; starting with a letter or digit."""

PACKAGED_ROOT = Path(__file__).resolve().parents[1] / "pretrained" / "weights"


def pretrained_root() -> Path:
    """The pretrained root: ``$NAVFORMER_PRETRAINED_DIR`` when set (non-empty), else the packaged folder."""
    override = os.environ.get(PRETRAINED_DIR_ENV)
    return Path(override) if override else PACKAGED_ROOT


def is_pretrained(checkpoint: str | os.PathLike) -> bool:
    """Whether ``checkpoint`` is a ``pretrained:NAME`` designation rather than a path."""
    return os.fspath(checkpoint).startswith(PRETRAINED_PREFIX)


def check_name(name: str) -> str:
    """``name`` if it is a valid shipped name (:data:`NAME_PATTERN`); ValueError otherwise."""
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        raise ValueError(
            f"pretrained name {name!r}: expected lower-case letters, digits, '_', '.' or '-', starting with "
            "a letter or digit (e.g. navformer, dt)"
        )
    return name


def read_registry(root: str | os.PathLike | None = None) -> dict[str, dict[str, Any]]:
    """The registry's models, ``{name: {"method": str, "files": {filename: sha256}}}`` (empty when the root
    has no ``registry.json``).

    Raises:
        NotADirectoryError: the root (e.g. ``$NAVFORMER_PRETRAINED_DIR``) is not a folder.
        ValueError: ``registry.json`` is not a registry of this format.
    """
    root = pretrained_root() if root is None else Path(root)
    if not root.is_dir():
        raise NotADirectoryError(
            f"pretrained root {str(root)!r} is not a folder (is {PRETRAINED_DIR_ENV} set to a wrong path?)"
        )
    path = root / REGISTRY_FILENAME
    if not path.is_file():
        return {}
    try:
        registry = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(
            f"{path} is not valid JSON ({error}); restore it or reinstall navformer_rl"
        ) from None
    if not isinstance(registry, dict):
        registry = {}
    models = registry.get("models")
    if registry.get("format") != REGISTRY_FORMAT or not isinstance(models, dict):
        raise ValueError(
            f"{path} is not a pretrained registry of format {REGISTRY_FORMAT!r} with a 'models' object; "
            "restore it or reinstall navformer_rl"
        )
    for name, entry in models.items():
        files = entry.get("files") if isinstance(entry, dict) else None
        if not isinstance(files, dict) or not files or not all(isinstance(v, str) for v in files.values()):
            raise ValueError(f"{path}: entry {name!r} has no 'files' object of sha256 strings")
    return models


def write_registry_entry(root: str | os.PathLike, name: str, entry: dict[str, Any]) -> None:
    """Add (or replace) ``name``'s entry in ``root/registry.json`` (created when missing), atomically."""
    root = Path(root)
    models = read_registry(root)
    models[check_name(name)] = entry
    atomic_write_json(root / REGISTRY_FILENAME, {"format": REGISTRY_FORMAT, "models": models})


def shipped_names(root: str | os.PathLike | None = None) -> tuple[str, ...]:
    """The names the registry lists (sorted), shipped or not."""
    return tuple(sorted(read_registry(root)))


def file_sha256(path: str | os.PathLike) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def pretrained_name(checkpoint: str | os.PathLike) -> str:
    """``NAME`` of ``pretrained:NAME`` (a bare ``NAME`` is returned as it is)."""
    text = os.fspath(checkpoint)
    return text[len(PRETRAINED_PREFIX) :] if text.startswith(PRETRAINED_PREFIX) else text


def resolve_pretrained(checkpoint: str | os.PathLike, root: str | os.PathLike | None = None) -> Path:
    """The folder of the shipped weights ``pretrained:NAME`` (or ``NAME``), after checking every file the
    registry lists against its sha256.

    Raises:
        ValueError: NAME is not in the registry (the message lists the shipped names), or a file's sha256
            differs from the registry's (a corrupt or modified file; the message names it).
        FileNotFoundError: NAME is registered but a file of it is missing from this installation.
    """
    root = pretrained_root() if root is None else Path(root)
    name = pretrained_name(checkpoint)
    designation = PRETRAINED_PREFIX + name
    models = read_registry(root)
    entry = models.get(name)
    registry = root / REGISTRY_FILENAME
    if entry is None:
        shipped = (
            f"the shipped names are {', '.join(sorted(models))} (registry {registry}); pass one of them or "
            if models
            else f"none are (registry {registry}); pass "
        )
        raise ValueError(
            f"{designation!r} is not shipped in this installation: {shipped}a training run directory"
        )
    folder = root / name
    for filename, expected in sorted(entry["files"].items()):
        path = folder / filename
        if not path.is_file():
            raise FileNotFoundError(
                f"{designation} is not shipped in this installation: {path} is missing; install navformer_rl "
                "from a source that includes its weights, "
                f"or set {PRETRAINED_DIR_ENV} to a folder holding them"
            )
        found = file_sha256(path)
        if found != expected:
            raise ValueError(
                f"{path} is corrupt: its sha256 is {found[:16]}..., {registry} records {expected[:16]}... "
                f"for {designation}; restore the file (e.g. git checkout -- {path.name} in its folder) or "
                "reinstall navformer_rl"
            )
    return folder
