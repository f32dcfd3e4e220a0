"""On-disk schema of the NavFormer datasets (D_e, D_ca, D_ssl): keys, dtypes, shapes, version.

Trajectory datasets (D_e, D_ca) hold one flat row per robot-step (TorchRL TED-style keys):

=================================  ===============  ====================================================
key                                dtype            shape per row / meaning
=================================  ===============  ====================================================
``pixels``                         uint8            ``[84, 84, 3]`` HWC camera frame o_t
``target_id``                      int64            ``[]`` row of the dataset's targets table
``action``                         float32          ``[2]`` (linear, angular) normalised to [-1, 1]
``return_to_go``                   float32          ``[1]`` paper eq. (3): sum of rewards from t to the end
``episode``                        int64            ``[]`` unique trajectory id (0..n_trajectories-1)
``step``                           int64            ``[]`` timestep from 0
``task``                           int64            ``[]`` 0 = exploration (D_e), 1 = collision avoidance
``("next", "reward")``             float32          ``[1]`` 1 on the step the robot reaches its target
``("next", "done")``               bool             ``[1]``
``("next", "terminated")``         bool             ``[1]`` reached the target on this step
``("next", "truncated")``          bool             ``[1]``
``("next", "collision")``          bool             ``[1]`` in contact (wall or robot) after this step
``("privileged", "pose")``         float32          ``[3]`` (x, y, yaw) when o_t was taken
``("privileged", "target_position")`` float32       ``[2]``
=================================  ===============  ====================================================

The targets table is a uint8 ``[n_trajectories, 84, 84, 3]`` tensor: the target image ``g`` of each
trajectory, stored once (rows point to it with ``target_id``).

D_ssl holds one row per image pair: ``pixels_static`` / ``pixels_dynamic`` uint8 ``[84, 84, 3]`` (o^s without
the other robots, o^d with them, same camera pose), ``world`` int64 ``[]``, ``pose`` float32 ``[3]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
import torch
from tensordict import TensorDict

from navformer_rl.constants import IMAGE_SIZE
from navformer_rl.tasks import DATASETS

SCHEMA_VERSION = 1
"""Bump whenever a key, dtype or shape changes; loaders refuse versions they do not know."""

IMAGE_SHAPE = (IMAGE_SIZE, IMAGE_SIZE, 3)


class DatasetKind(str, Enum):
    """The three datasets of paper §V."""

    EXPLORATION = "e"
    COLLISION_AVOIDANCE = "ca"
    SSL = "ssl"

    @classmethod
    def parse(cls, value: str | DatasetKind) -> DatasetKind:
        """``"e"``, ``"ca"`` or ``"ssl"`` (or a member) -> member; anything else raises ``ValueError``."""
        try:
            return cls(value)
        except ValueError:
            raise ValueError(
                f"unknown dataset kind {value!r}; expected one of {[k.value for k in cls]}"
            ) from None

    @property
    def is_trajectory(self) -> bool:
        return self is not DatasetKind.SSL


TASK_ID = {DatasetKind(kind): d.task_id for kind, d in DATASETS.items() if d.task_id is not None}
"""Value of the ``task`` key for each trajectory dataset."""


@dataclass(frozen=True)
class FieldSpec:
    """dtype and per-row shape of one stored key."""

    dtype: torch.dtype
    shape: tuple[int, ...]

    def nbytes(self, rows: int) -> int:
        return rows * math.prod(self.shape) * torch.empty((), dtype=self.dtype).element_size()


TRAJECTORY_FIELDS: dict[tuple[str, ...], FieldSpec] = {
    ("pixels",): FieldSpec(torch.uint8, IMAGE_SHAPE),
    ("target_id",): FieldSpec(torch.int64, ()),
    ("action",): FieldSpec(torch.float32, (2,)),
    ("return_to_go",): FieldSpec(torch.float32, (1,)),
    ("episode",): FieldSpec(torch.int64, ()),
    ("step",): FieldSpec(torch.int64, ()),
    ("task",): FieldSpec(torch.int64, ()),
    ("next", "reward"): FieldSpec(torch.float32, (1,)),
    ("next", "done"): FieldSpec(torch.bool, (1,)),
    ("next", "terminated"): FieldSpec(torch.bool, (1,)),
    ("next", "truncated"): FieldSpec(torch.bool, (1,)),
    ("next", "collision"): FieldSpec(torch.bool, (1,)),
    ("privileged", "pose"): FieldSpec(torch.float32, (3,)),
    ("privileged", "target_position"): FieldSpec(torch.float32, (2,)),
}

SSL_FIELDS: dict[tuple[str, ...], FieldSpec] = {
    ("pixels_static",): FieldSpec(torch.uint8, IMAGE_SHAPE),
    ("pixels_dynamic",): FieldSpec(torch.uint8, IMAGE_SHAPE),
    ("world",): FieldSpec(torch.int64, ()),
    ("pose",): FieldSpec(torch.float32, (3,)),
}

TARGET_FIELDS: dict[tuple[str, ...], FieldSpec] = {("target_pixels",): FieldSpec(torch.uint8, IMAGE_SHAPE)}
"""The per-trajectory targets table (one row per trajectory)."""


def fields_for(kind: DatasetKind | str) -> dict[tuple[str, ...], FieldSpec]:
    """Row fields of a dataset kind."""
    kind = DatasetKind.parse(kind)
    return TRAJECTORY_FIELDS if kind.is_trajectory else SSL_FIELDS


def key_name(key: tuple[str, ...]) -> str:
    """``("next", "reward")`` -> ``"next.reward"`` (for messages and JSON)."""
    return ".".join(key)


def return_to_go(reward: np.ndarray) -> np.ndarray:
    """Paper eq. (3): ``R_t = sum_{t' >= t} r_t'`` (the reward of step t included, undiscounted).

    ``reward``: float ``[T]`` -> float32 ``[T]``.
    """
    reward = np.asarray(reward, dtype=np.float64)
    if reward.ndim != 1:
        raise ValueError(f"reward must be 1-D [T], got shape {reward.shape}")
    return np.cumsum(reward[::-1])[::-1].astype(np.float32)


def _as(name: str, value, dtype: np.dtype, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.asarray(value)
    if arr.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
    if dtype == np.uint8 and arr.dtype != np.uint8:
        raise ValueError(f"{name}: expected uint8 images, got {arr.dtype}")
    arr = arr.astype(dtype, copy=False)
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise ValueError(f"{name}: contains NaN or inf")
    return arr


def trajectory_rows(
    *,
    pixels: np.ndarray,
    action: np.ndarray,
    reward: np.ndarray,
    collision: np.ndarray,
    pose: np.ndarray,
    target_position: np.ndarray,
    succeeded: bool,
    task: int,
    episode: int,
    target_id: int,
) -> TensorDict:
    """Rows of one trajectory of length T in the trajectory schema.

    ``pixels`` uint8 ``[T, 84, 84, 3]`` (o_t, observed before ``action[t]``), ``action`` ``[T, 2]``
    in [-1, 1], ``reward`` ``[T]`` (reward after step t), ``collision`` bool ``[T]``, ``pose`` ``[T, 3]``,
    ``target_position`` ``[2]``. The last step is ``terminated`` when ``succeeded`` and ``truncated``
    otherwise; ``return_to_go`` follows eq. (3). Returns a ``TensorDict`` with batch size ``[T]``.
    """
    pixels = np.asarray(pixels)
    if pixels.ndim != 4 or pixels.shape[0] == 0:
        raise ValueError(f"pixels: expected [T, 84, 84, 3] with T >= 1, got {pixels.shape}")
    T = pixels.shape[0]
    pixels = _as("pixels", pixels, np.uint8, (T, *IMAGE_SHAPE))
    action = _as("action", action, np.float32, (T, 2))
    if np.abs(action).max() > 1.0 + 1e-6:
        raise ValueError(f"action: expected values in [-1, 1], got max |a| = {np.abs(action).max():.4f}")
    reward = _as("reward", reward, np.float32, (T,))
    collision = _as("collision", collision, bool, (T,))
    pose = _as("pose", pose, np.float32, (T, 3))
    target_position = _as("target_position", target_position, np.float32, (2,))
    last = np.zeros(T, dtype=bool)
    last[-1] = True
    terminated = last & bool(succeeded)
    truncated = last & (not succeeded)

    def col(x: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(x)).unsqueeze(-1)

    def full(v: int) -> torch.Tensor:
        return torch.full((T,), int(v), dtype=torch.int64)

    return TensorDict(
        {
            "pixels": torch.from_numpy(np.ascontiguousarray(pixels)),
            "target_id": full(target_id),
            "action": torch.from_numpy(np.ascontiguousarray(action)),
            "return_to_go": col(return_to_go(reward)),
            "episode": full(episode),
            "step": torch.arange(T, dtype=torch.int64),
            "task": full(task),
            "next": {
                "reward": col(reward),
                "done": col(last),
                "terminated": col(terminated),
                "truncated": col(truncated),
                "collision": col(collision),
            },
            "privileged": {
                "pose": torch.from_numpy(np.ascontiguousarray(pose)),
                "target_position": torch.from_numpy(target_position).expand(T, 2).clone(),
            },
        },
        batch_size=[T],
    )


def ssl_rows(
    *, pixels_static: np.ndarray, pixels_dynamic: np.ndarray, world: int, pose: np.ndarray
) -> TensorDict:
    """Rows of P image pairs from one world: ``pixels_static``/``pixels_dynamic`` uint8 ``[P, 84, 84, 3]``,
    ``pose`` ``[P, 3]``. Returns a ``TensorDict`` with batch size ``[P]``."""
    P = np.asarray(pixels_static).shape[0]
    s = _as("pixels_static", pixels_static, np.uint8, (P, *IMAGE_SHAPE))
    d = _as("pixels_dynamic", pixels_dynamic, np.uint8, (P, *IMAGE_SHAPE))
    pose = _as("pose", pose, np.float32, (P, 3))
    return TensorDict(
        {
            "pixels_static": torch.from_numpy(np.ascontiguousarray(s)),
            "pixels_dynamic": torch.from_numpy(np.ascontiguousarray(d)),
            "world": torch.full((P,), int(world), dtype=torch.int64),
            "pose": torch.from_numpy(np.ascontiguousarray(pose)),
        },
        batch_size=[P],
    )


def check_rows(td: TensorDict, fields: dict[tuple[str, ...], FieldSpec], where: str) -> None:
    """Raise ``ValueError`` naming ``where`` if ``td`` lacks a key of ``fields`` or has a wrong
    dtype/shape."""
    if td.batch_dims != 1:
        raise ValueError(f"{where}: expected a flat TensorDict [rows], got batch size {tuple(td.batch_size)}")
    for key, spec in fields.items():
        value = td.get(key, None)
        if value is None:
            raise ValueError(f"{where}: missing key {key_name(key)!r}")
        if value.dtype != spec.dtype or tuple(value.shape[1:]) != spec.shape:
            raise ValueError(
                f"{where}: key {key_name(key)!r} is {value.dtype} {tuple(value.shape[1:])} per row, "
                f"expected {spec.dtype} {spec.shape}"
            )
