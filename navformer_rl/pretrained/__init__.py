"""Shipped weights: ``pretrained:NAME`` wherever a checkpoint is accepted, and loading them by name.

``--checkpoint pretrained:navformer`` (``navformer evaluate``, ``navformer validate``, the evaluation recipe)
resolves through :func:`~navformer_rl.training.checkpoint.resolve_checkpoint` to the shipped folder, whose
files are checked against the registry's sha256 first. :func:`load_pretrained` and
:func:`load_pretrained_policy` load them in Python; :func:`~navformer_rl.pretrained.export.write_pretrained`
(``navformer pretrained export``) ships a trained run. Layout and registry:
:mod:`navformer_rl.training.pretrained_registry` (resolving a name is part of resolving a checkpoint).
"""

from __future__ import annotations

import os
from typing import Any

from navformer_rl.training.pretrained_registry import (
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
    "load_pretrained_policy",
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
    from navformer_rl.training.checkpoint import load_policy_model

    config, model = load_policy_model(resolve_pretrained(name, root))
    return model, config


def load_pretrained_policy(name: str, root: str | os.PathLike | None = None, **policy_options: Any) -> Any:
    """The :class:`~navformer_rl.modules.NavFormerPolicy` (KV-cached, every robot in one batch) of the shipped
    weights ``name``; ``policy_options`` go to its constructor (e.g. ``native=False``). Without a
    ``context_steps`` option it attends to the window the weights were trained on (``data.context_steps``,
    e.g. 16) or, for weights trained on whole trajectories, to its whole context. Errors as
    :func:`load_pretrained`."""
    from navformer_rl.modules import NavFormerPolicy
    from navformer_rl.training.checkpoint import training_context_steps

    model, _ = load_pretrained(name, root)
    policy_options.setdefault("context_steps", training_context_steps(resolve_pretrained(name, root)))
    return NavFormerPolicy(model, **policy_options)
