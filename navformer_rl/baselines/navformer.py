"""NavFormer (and its Table IV model ablations) as an evaluation policy, from a training checkpoint."""

from __future__ import annotations

import os

from navformer_rl.baselines.dt import is_dt_config


def load_navformer_policy(checkpoint: str | os.PathLike):
    """``(NavFormerPolicy, NavFormerConfig)`` from a NavFormer checkpoint (any path
    ``navformer_rl.training.checkpoint.resolve_checkpoint`` accepts: run dir, checkpoint folder, weights
    file, ...). The policy conditions on R-hat_1 = 1 and uses the KV cache; it attends to the window the
    checkpoint was trained on when that was shorter than the model's context (``data.context_steps``), else to
    the whole context.

    Raises:
        FileNotFoundError: nothing at ``checkpoint``.
        ValueError: not a navformer_rl checkpoint (foreign or corrupt), or a DT-baseline model.
    """
    from navformer_rl.modules import NavFormerPolicy
    from navformer_rl.training.checkpoint import load_policy_model, training_context_steps

    config, model = load_policy_model(checkpoint)
    if is_dt_config(config):
        raise ValueError(f"checkpoint {checkpoint} holds the DT baseline model; evaluate it with --method dt")
    return NavFormerPolicy(model, context_steps=training_context_steps(checkpoint)), config
