"""How much of a checkpoint's action rests on each visual encoder: its frame embeddings replaced by a mean.

A teacher-forced reading beside the probes of :mod:`~navformer_rl.evaluation.diagnose.probe`: the same
held-out windows, with one encoder's frame embeddings (NavFormer's e^s = f_s(o) or e^ca = f_g(o), DT's single
e), or all of a model's at once, replaced at every step by their mean over the batch's valid frames (a mean
ablation). The navigation network then reads the same target image, returns-to-go and expert actions, and
nothing of the frames through that encoder. How far the action moves, and how much the held-out action loss
(eq. 10: the squared error summed over the action's dimensions, averaged over frames) rises, say how much of
the policy rests on that encoder. A probe says what an embedding holds; this says what the trained policy
takes from it. The same with the past actions (:data:`PAST_ACTIONS`: every action token given the mean
action) says how much the policy continues what was done before, which teacher forcing feeds it from the
expert and closed loop from itself.

The mean is the batch's (16 held-out trajectories by default, thousands of frames), so the replaced embedding
is a typical frame's, not zeros the network never saw in training.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from torch import Tensor

PAST_ACTIONS = "past_actions"
"""The knockout of the action tokens: every step's action (the expert's, teacher-forced) replaced by the mean
action, so the navigation network reads the frames and the target and not what was done before."""

KNOCKOUT_PREFIX = "action_without_"
"""The probe's frames hold ``action_without_<encoder>``: float ``[N, A]``, the action with that encoder's
frame embeddings replaced by their mean."""


def knockout_key(encoder: str) -> str:
    """The frames' key of the actions without ``encoder`` (``"static"`` -> ``"action_without_static"``)."""
    return KNOCKOUT_PREFIX + encoder


def knockout_sets(encoders: tuple[str, ...] | list[str]) -> dict[str, tuple[str, ...]]:
    """The encoder knockouts of a model with these encoders: each alone, and ``"all"`` of them at once when
    there are several (DT's one encoder is already all of its view of the frames)."""
    sets = {name: (name,) for name in encoders}
    if len(encoders) > 1:
        sets["all"] = tuple(encoders)
    return sets


def mean_embedding(embedding: Tensor, mask: Tensor) -> Tensor:
    """``embedding`` ``[B, T, d]`` (frame embeddings, or actions) with every step replaced by the mean over
    the valid steps (bool ``mask`` ``[B, T]``), computed in float32 and returned in the input's dtype."""
    valid = mask.unsqueeze(-1).float()  # [B, T, 1]
    mean = (embedding.float() * valid).sum(dim=(0, 1)) / valid.sum().clamp_min(1.0)  # [d]
    return mean.to(embedding.dtype).expand_as(embedding)


def knockout_summary(
    frames: Mapping[str, np.ndarray], resamples: int = 1000, seed: int = 0
) -> dict[str, Any]:
    """Each encoder's knockout against the model's own teacher-forced action.

    Args:
        frames: :func:`~navformer_rl.evaluation.diagnose.probe.frame_embeddings` output with ``action``
            (the expert's) ``[N, A]``, ``action_own`` ``[N, A]``, ``trajectory`` ``[N]`` and one
            ``action_without_<encoder>`` ``[N, A]`` per knockout of :func:`knockout_sets`.
        resamples: bootstrap resamples of whole trajectories for the interval of the loss's rise.

    Returns:
        ``{}`` without knockout actions; otherwise ``{"loss": the held-out action loss with every encoder,
        "encoders": {encoder, "all" or "past_actions", in the frames' order: {"change": [A] mean |action
        without it - own action|, "loss": the loss without it, "increase": loss without - loss with, "low",
        "high": its 95 % interval}}}``.
    """
    encoders = [k[len(KNOCKOUT_PREFIX) :] for k in frames if k.startswith(KNOCKOUT_PREFIX)]
    if not encoders:
        return {}
    expert, own = frames["action"], frames["action_own"]
    own_error = np.sum((own - expert) ** 2, axis=1)  # [N]
    _, trajectory = np.unique(frames["trajectory"], return_inverse=True)
    groups = int(trajectory.max()) + 1
    counts = np.bincount(trajectory, minlength=groups)
    draws = np.random.default_rng(seed).integers(0, groups, size=(resamples, groups))  # [R, G]
    summary: dict[str, Any] = {"loss": float(own_error.mean()), "encoders": {}}
    for encoder in encoders:
        without = frames[knockout_key(encoder)]
        error = np.sum((without - expert) ** 2, axis=1)
        rise = np.bincount(trajectory, weights=error - own_error, minlength=groups)  # per trajectory
        spread = rise[draws].sum(axis=1) / counts[draws].sum(axis=1)
        low, high = np.quantile(spread, [0.025, 0.975])
        summary["encoders"][encoder] = {
            "change": [float(v) for v in np.abs(without - own).mean(axis=0)],
            "loss": float(error.mean()),
            "increase": float((error - own_error).mean()),
            "low": float(low),
            "high": float(high),
        }
    return summary


def _signed(value: float, digits: int) -> float:
    """``value`` rounded to ``digits``, without a negative zero (a "+0.0000", not "-0.0000", in the table)."""
    return round(value, digits) + 0.0


def knockout_markdown(summaries: Mapping[str, Mapping[str, Any]]) -> str:
    """One row per model and encoder of :func:`knockout_summary` results ``{model label: summary}``."""
    lines = [
        "Each encoder's frame embeddings (all: every encoder's; past actions: the action tokens) replaced by "
        "their mean over the batch's frames (teacher-forced, the same windows): mean |change| of the action "
        "(linear, angular) and the held-out action loss (eq. 10), with its rise (95 % interval, trajectories "
        "resampled):\n",
        "| model | without | action change | loss: with -> without | rise | rise, share of the loss |",
        "|---|---|---|---|---|---|",
    ]
    for label, summary in summaries.items():
        for encoder, row in summary["encoders"].items():
            change = ", ".join(f"{v:.3f}" for v in row["change"])
            without = encoder.replace("_", " ")
            rise, low, high = (_signed(row[k], 4) for k in ("increase", "low", "high"))
            share = _signed(row["increase"] / summary["loss"], 2) if summary["loss"] else float("nan")
            lines.append(
                f"| {label} | {without} | {change} | {summary['loss']:.4f} -> {row['loss']:.4f} | "
                f"{rise:+.4f} [{low:+.4f}, {high:+.4f}] | {share:+.0%} |"
            )
    return "\n".join(lines) + "\n"
