"""The action side of a diagnosis: the experts' command distribution, and the model's teacher-forced turns.

An MSE action head trained on demonstrations that turn left *or* right at a junction predicts their mean:
a smaller, centred turn. Two signatures are measured here:

- :func:`expert_command_statistics`: the distribution of the actions in D_e / D_ca (``action`` of every
  row, normalised), to set beside the policy's closed-loop commands
  (:func:`~navformer_rl.evaluation.diagnose.measures.command_statistics`): a narrower ``|angular|``
  distribution than the experts' is what averaging modes would give.
- :func:`teacher_forced_turns`: on held-out expert trajectories (the windows ``navformer validate`` scores,
  :class:`~navformer_rl.training.validation.FixedTrajectoryBatches`), the model's predicted angular action at
  the steps where the expert turns hard (``|a_angular| >``
  :data:`~navformer_rl.evaluation.diagnose.measures.LARGE_TURN`): ``magnitude_ratio`` = mean ``|predicted|`` /
  mean ``|expert|`` (1 = as hard as the expert, near 0 = the turn averaged away) and ``sign_agreement`` (the
  fraction turning the expert's way); and, with :func:`edge_of_view_turns`, the same steps' turns towards the
  target where it lies in the camera's cone near its edge (whether the model has learned to steer at a target
  at the side of its image, where the closed-loop diagnosis finds it does not); and, with
  :func:`turn_changes`, the steps where the expert changes its turn: a model that copies the previous action
  in its context (the "copycat" shortcut of behaviour cloning with action history) keeps the old turn there,
  while one that reads the image follows the expert.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import numpy as np

from navformer_rl.envs.robots import JACKAL
from navformer_rl.evaluation.diagnose.measures import (
    LARGE_TURN,
    OFF_CENTRE,
    SIGHTING_RANGES,
    TURN_CHANGE,
    bearing_to,
    command_statistics,
)

HALF_FIELD_OF_VIEW = np.radians(JACKAL.camera_fov_deg / 2)
"""Half the camera field of view of the dataset robots (the Jackal's 90°)."""

DATASET_KINDS = ("e", "ca")


def _open(datasets: Mapping[str, str | os.PathLike]) -> dict[str, Any]:
    """``{kind: NavDataset}``; ValueError for an unknown kind, FileNotFoundError for a missing folder."""
    from navformer_rl.data import open_dataset

    unknown = sorted(set(datasets) - set(DATASET_KINDS))
    if unknown or not datasets:
        raise ValueError(
            f"dataset kinds {unknown or '(none)'}: expected one or more of {list(DATASET_KINDS)}"
        )
    opened = {}
    for kind, path in datasets.items():
        if not os.path.exists(path):
            raise FileNotFoundError(f"{kind} dataset {str(path)!r} does not exist")
        opened[kind] = open_dataset(path, kind=kind)
    return opened


def expert_command_statistics(datasets: Mapping[str, str | os.PathLike]) -> dict[str, Any]:
    """``{kind: command_statistics(every row's action)}`` of the datasets ``{kind: folder}`` (kinds ``e``,
    ``ca``)."""
    out = {}
    for kind, dataset in _open(datasets).items():
        episode = dataset.rows["episode"].numpy()
        starts = np.r_[True, episode[1:] != episode[:-1]]
        out[kind] = command_statistics(dataset.rows["action"].numpy(), starts=starts)
    return out


def turn_agreement(
    predicted: np.ndarray, expert: np.ndarray, threshold: float = LARGE_TURN
) -> dict[str, Any]:
    """Predicted vs expert angular actions (float ``[N]`` each, normalised) at the ``N`` valid steps:
    ``steps``, ``large_turns`` (``|expert| > threshold``), and at those ``mean_abs_expert``,
    ``mean_abs_predicted``, ``magnitude_ratio`` (their quotient) and ``sign_agreement``; ``mse`` over all
    steps."""
    predicted = np.asarray(predicted, dtype=np.float64).reshape(-1)
    expert = np.asarray(expert, dtype=np.float64).reshape(-1)
    if predicted.shape != expert.shape:
        raise ValueError(
            f"predicted {predicted.shape} and expert {expert.shape} angular actions differ in shape"
        )
    large = np.abs(expert) > threshold
    out: dict[str, Any] = {
        "steps": int(expert.size),
        "large_turns": int(large.sum()),
        "mse": float(np.mean((predicted - expert) ** 2)) if expert.size else None,
        "mean_abs_expert": None,
        "mean_abs_predicted": None,
        "magnitude_ratio": None,
        "sign_agreement": None,
    }
    if large.any():
        abs_expert = float(np.abs(expert[large]).mean())
        abs_predicted = float(np.abs(predicted[large]).mean())
        out.update(
            mean_abs_expert=abs_expert,
            mean_abs_predicted=abs_predicted,
            magnitude_ratio=abs_predicted / abs_expert,
            sign_agreement=float(np.mean(np.sign(predicted[large]) == np.sign(expert[large]))),
        )
    return out


def edge_of_view_turns(
    predicted: np.ndarray,
    expert: np.ndarray,
    pose: np.ndarray,
    target: np.ndarray,
    max_range: float = SIGHTING_RANGES[-1],
) -> dict[str, Any]:
    """Turns towards the target at the steps whose target lies in the camera's cone between
    :data:`~navformer_rl.evaluation.diagnose.measures.OFF_CENTRE` and :data:`HALF_FIELD_OF_VIEW` off the
    heading, within ``max_range`` metres (walls are not checked: some of these targets are hidden).

    Args:
        predicted, expert: angular actions float ``[N]``; pose: ``(x, y, yaw)`` float ``[N, 3]``; target:
            the target's centre float ``[N, 2]``.

    Returns:
        ``steps``, and at those steps ``expert_toward`` / ``predicted_toward`` (the share of angular actions
        with the bearing's sign) and ``sign_agreement`` (predicted and expert turn the same way); None
        without such steps.
    """
    predicted, expert = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (predicted, expert))
    pose, target = np.asarray(pose, dtype=np.float64), np.asarray(target, dtype=np.float64)
    bearing = bearing_to(pose, target)
    distance = np.hypot(*(target[:, :2] - pose[:, :2]).T)
    edge = (np.abs(bearing) > OFF_CENTRE) & (np.abs(bearing) <= HALF_FIELD_OF_VIEW) & (distance <= max_range)
    if not edge.any():
        return {"steps": 0, "expert_toward": None, "predicted_toward": None, "sign_agreement": None}
    return {
        "steps": int(edge.sum()),
        "expert_toward": float(np.mean(expert[edge] * bearing[edge] > 0)),
        "predicted_toward": float(np.mean(predicted[edge] * bearing[edge] > 0)),
        "sign_agreement": float(np.mean(np.sign(predicted[edge]) == np.sign(expert[edge]))),
    }


def turn_changes(
    predicted: np.ndarray, expert: np.ndarray, previous: np.ndarray, threshold: float = TURN_CHANGE
) -> dict[str, Any]:
    """Predicted turns where the expert changes its turn: steps whose expert angular action differs from the
    step before's by more than ``threshold`` (float ``[N]`` each; ``previous`` is NaN where the step has no
    valid predecessor in its window).

    A model that copies the previous action in its context predicts the old turn there (``captured`` near 0,
    ``moves_expert_way`` near half); one that reads the change from the image follows the expert (both near
    1).

    Returns:
        ``steps``; ``captured``: the median of ``(predicted - previous) / (expert - previous)``, the part of
        the expert's change the prediction makes; ``moves_expert_way``: the share of predictions that move
        from the previous action in the expert's direction; None without such steps.
    """
    predicted, expert, previous = (
        np.asarray(a, dtype=np.float64).reshape(-1) for a in (predicted, expert, previous)
    )
    change = expert - previous
    changed = np.abs(change) > threshold  # False where previous is NaN
    if not changed.any():
        return {"steps": 0, "captured": None, "moves_expert_way": None}
    moved = predicted[changed] - previous[changed]
    return {
        "steps": int(changed.sum()),
        "captured": float(np.median(moved / change[changed])),
        "moves_expert_way": float(np.mean(moved * change[changed] > 0)),
    }


def teacher_forced_turns(
    checkpoint: str | os.PathLike,
    datasets: Mapping[str, str | os.PathLike],
    threshold: float = LARGE_TURN,
    batch_trajs: int = 16,
    max_trajectories: int | None = None,
    seed: int = 0,
    device: str = "cpu",
) -> dict[str, Any]:
    """``{kind: turn_agreement(...) + loss_dt}`` of a checkpoint's teacher-forced predictions on held-out
    trajectories; ``loss_dt`` is eq. 10 over every valid step (``navformer validate``'s number).

    The windows are those of :func:`navformer_rl.training.validation.score_checkpoints` with the same ``seed``
    / ``max_trajectories`` (one per trajectory, at most the model's context); the model runs in eval mode
    and reads the expert's past actions (teacher forcing), writing ``action_pred`` ``[N, T, 2]``.

    Args:
        checkpoint: any form :func:`~navformer_rl.training.checkpoint.resolve_checkpoint` takes
            (``pretrained:NAME`` too).
        datasets: ``{kind: folder}`` of held-out D_e (``e``) / D_ca (``ca``).
    """

    import torch

    from navformer_rl.data.fit import check_model_reads
    from navformer_rl.modules import make_navformer_actor
    from navformer_rl.training import checkpoint as ckpt
    from navformer_rl.training.validation import FixedTrajectoryBatches, evaluation_mode
    from navformer_rl.utils.devices import check_device, resolve_device

    torch_device = resolve_device(check_device(device))
    opened = _open(datasets)
    config, model = ckpt.load_policy_model(ckpt.resolve_checkpoint(checkpoint))
    check_model_reads(
        config, opened, {k: f"{k} dataset {str(p)!r}" for k, p in datasets.items()}, tunable=False
    )
    model.to(torch_device)
    actor = make_navformer_actor(model)
    out = {}
    with evaluation_mode(model):
        for kind, dataset in opened.items():
            batches = FixedTrajectoryBatches(
                dataset, batch_trajs, config.window_steps, seed, max_trajectories=max_trajectories
            )
            predicted, expert, previous, pose, target = [], [], [], [], []
            for batch in batches:
                batch = batch.to(torch_device)
                mask = batch["mask"]
                prediction = actor(batch.copy())["action_pred"]
                predicted.append(prediction[mask].float().cpu().numpy())
                expert.append(batch["action"][mask].float().cpu().numpy())
                before = torch.full_like(batch["action"][..., 1], float("nan"))
                before[:, 1:] = torch.where(mask[:, :-1], batch["action"][:, :-1, 1], float("nan"))
                previous.append(before[mask].float().cpu().numpy())
                pose.append(batch["privileged", "pose"][mask].cpu().numpy())
                target.append(batch["privileged", "target_position"][mask].cpu().numpy())
            predicted, expert = np.concatenate(predicted), np.concatenate(expert)
            out[kind] = {
                **turn_agreement(predicted[:, 1], expert[:, 1], threshold),
                "loss_dt": float(np.mean(np.sum((predicted - expert) ** 2, axis=1))),
                "edge_of_view": edge_of_view_turns(
                    predicted[:, 1], expert[:, 1], np.concatenate(pose), np.concatenate(target)
                ),
                "turn_changes": turn_changes(predicted[:, 1], expert[:, 1], np.concatenate(previous)),
            }
    return out
