"""Checks of what the TensorDict modules, the actor, the losses and the policy read, at their boundary.

A missing key or a batch in the wrong layout is refused there with one line naming the key and what to set,
rather than failing deep inside a part (an ``AttributeError`` on ``None``, a shape error on an internal
embedding). ``mask`` is the only optional input of a trajectory batch; a padded batch without one is
refused where the timesteps show the padding (:func:`check_unmasked_padding`).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey


class MissingKeyError(KeyError, ValueError):
    """A required TensorDict key is absent. A ``KeyError`` (what a TensorDict lookup raises) and a
    ``ValueError`` (what the project raises on bad input), printed as its one-line message."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def require_keys(
    tensordict: TensorDictBase, required: Mapping[NestedKey, str], who: str, how_to_rename: str
) -> None:
    """Raise :class:`MissingKeyError` naming the first key of ``required`` (key -> what it holds) that
    ``tensordict`` lacks, the keys it has, and ``how_to_rename`` (how to point ``who`` at other keys)."""
    for key, meaning in required.items():
        if tensordict.get(key, None) is None:
            present = sorted(map(str, tensordict.keys(include_nested=True, leaves_only=True)))
            raise MissingKeyError(
                f"{who} reads {key!r} ({meaning}), missing from the tensordict with keys {present}; set it, "
                f"or {how_to_rename}"
            )


FLAT_BATCH_HINT = (
    "a flat [N * T] replay-buffer sample (SliceSampler, trajectory_buffer) must be reshaped to trajectories "
    "first: sample.reshape(N, -1), or draw it through navformer_rl.data.CrossTaskReplayBuffer"
)


def check_trajectory_steps(
    value: torch.Tensor, key: NestedKey, trailing: int, who: str, expected: str
) -> None:
    """Refuse ``value`` (the tensordict's ``key``) unless it has two leading dims ``[N, T]`` before its
    ``trailing`` dims, naming the flat-sample mistake when it has one."""
    if value.dim() != 2 + trailing:
        flat = value.dim() == 1 + trailing
        raise ValueError(
            f"{who}: {key!r} must be {expected}, got shape {list(value.shape)}"
            + (f"; {FLAT_BATCH_HINT}" if flat else "")
        )


def check_unmasked_padding(
    step: torch.Tensor | None, mask_key: NestedKey, step_key: NestedKey, who: str
) -> None:
    """Refuse a batch without a mask whose timesteps ``step`` (int ``[N, T]``) do not increase by one along
    T: its trajectories are padded (the data package's padding repeats the last step; zero padding restarts
    at 0), and without ``mask`` the padded steps would count as valid."""
    if step is None or step.dim() < 2 or step.shape[-1] < 2:
        return
    if bool((step[..., 1:] == step[..., :-1] + 1).all()):
        return
    raise ValueError(
        f"{who}: the batch has no {mask_key!r} but its {step_key!r} does not increase by one along T, so it "
        f"looks padded and the padded steps would count as valid; set {mask_key!r} (bool [N, T], False on "
        "padding; a SliceSampler(pad_output=True) sample holds it as ('collector', 'mask'))"
    )
