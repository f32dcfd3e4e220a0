"""Shipped weights: ``pretrained:NAME`` wherever a checkpoint is accepted, and loading them by name.

``--checkpoint pretrained:navformer`` (``navformer evaluate``, ``navformer validate``, the evaluation recipe)
resolves through :func:`~navformer_rl.checkpoint.resolve_checkpoint` to the shipped folder, whose files are
checked against the registry's sha256 first. :func:`load_pretrained` and ``NavFormerPolicy.from_pretrained``
load them in Python; :func:`~navformer_rl.pretrained.export.write_pretrained` (``navformer pretrained
export``) ships a trained run. Layout and registry: :mod:`navformer_rl.pretrained.registry`.
"""

from __future__ import annotations

import os
from typing import Any

from navformer_rl.pretrained.registry import (
    CARD_FILENAME,
    PRETRAINED_DIR_ENV,
    PRETRAINED_PREFIX,
    is_pretrained,
    pretrained_root,
    read_registry,
    resolve_pretrained,
    shipped_names,
)

__all__ = [
    "CARD_FILENAME",
    "PRETRAINED_DIR_ENV",
    "PRETRAINED_PREFIX",
    "is_pretrained",
    "load_pretrained",
    "pretrained_root",
    "read_registry",
    "resolve_pretrained",
    "shipped_names",
]


def load_pretrained(name: str, root: str | os.PathLike | None = None) -> tuple[Any, Any]:
    """``(NavFormerModel, NavFormerConfig)`` of the shipped weights ``name`` (``navformer``, ``dt``, ... or
    ``pretrained:NAME``), in eval mode on the CPU.

    Args:
        name: a shipped name (:func:`shipped_names`).
        root: the pretrained root (default :func:`pretrained_root`).

    Raises:
        ValueError: an unknown name (the message lists the shipped ones) or a corrupt file.
        FileNotFoundError: a registered name whose files this installation lacks.
    """
    from navformer_rl.checkpoint import load_policy_model

    config, model = load_policy_model(resolve_pretrained(name, root))
    return model, config
