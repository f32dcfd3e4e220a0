"""The Decision Transformer baseline (paper §VII.A): one visual encoder, the action read from the
observation token's hidden state (no THSC). It is ``NavFormerConfig.dt_baseline()`` trained by the
same recipe, so it runs through the same ``NavFormerPolicy`` (KV cache, R-hat_1 = 1)."""

from __future__ import annotations

import os


def is_dt_config(config) -> bool:
    """True for the DT baseline's ``NavFormerConfig``: general encoder only, no THSC."""
    return (not config.use_static_encoder) and config.use_general_encoder and not config.thsc


def load_dt_policy(checkpoint: str | os.PathLike):
    """``(NavFormerPolicy, NavFormerConfig)`` from a DT checkpoint (any path
    ``navformer_rl.training.checkpoint.resolve_checkpoint`` accepts: run dir, checkpoint folder, weights
    file, ...). The policy attends to the window the checkpoint was trained on (``data.context_steps``) when
    set, else to the whole context.

    Raises:
        FileNotFoundError: nothing at ``checkpoint``.
        ValueError: not a navformer_rl checkpoint, or a NavFormer (not DT) model.
    """
    from navformer_rl.modules import NavFormerPolicy
    from navformer_rl.training.checkpoint import load_policy_model, training_context_steps

    config, model = load_policy_model(checkpoint)
    if not is_dt_config(config):
        raise ValueError(
            f"checkpoint {checkpoint} holds a NavFormer model "
            f"(use_static_encoder={config.use_static_encoder}, thsc={config.thsc}), not the DT baseline "
            "(NavFormerConfig.dt_baseline()); evaluate it with --method navformer"
        )
    return NavFormerPolicy(model, context_steps=training_context_steps(checkpoint)), config
