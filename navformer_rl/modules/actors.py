"""TensorDict wrappers of ``NavFormerModel`` for training (teacher-forced trajectories)."""

from __future__ import annotations

from collections.abc import Sequence

from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey

from navformer_rl.modules.models.navformer import NavFormerModel

NAVFORMER_IN_KEYS: tuple[str, ...] = ("target_pixels", "pixels", "return_to_go", "action", "step", "mask")
"""Default in_keys, in the order of ``NavFormerModel.forward``'s arguments."""
NAVFORMER_OUT_KEYS: tuple[str, ...] = ("action_pred",)


def make_navformer_actor(
    model: NavFormerModel,
    in_keys: Sequence[NestedKey] = NAVFORMER_IN_KEYS,
    out_keys: Sequence[NestedKey] = NAVFORMER_OUT_KEYS,
) -> TensorDictModule:
    """Wrap ``model`` as a ``TensorDictModule`` reading a trajectory batch and writing predicted actions.

    Keys (defaults; pass ``in_keys`` in the same order to rename):

    ============== ========================================= ==========================================
    key            dtype / shape                             meaning
    ============== ========================================= ==========================================
    target_pixels  uint8 ``[N, 84, 84, 3]`` (or ``[N, T, ...]``) target image g (one per trajectory)
    pixels         uint8 ``[N, T, 84, 84, 3]``               observations o_t
    return_to_go   float32 ``[N, T, 1]``                     R-hat_t (eq. 3)
    action         float32 ``[N, T, 2]``                     actions a_t (teacher forcing)
    step           int64 ``[N, T]``                          absolute timestep, < ``max_timestep``
    mask           bool ``[N, T]``                           valid steps (padding on the right)
    action_pred    float32 ``[N, T, 2]`` (written)           a-hat_t in [-1, 1]; 0 on padded steps
    ============== ========================================= ==========================================

    The tensordict may have batch size ``[N]`` (per-step keys ``[N, T, ...]``, as the data package's
    ``TrajectoryBatcher`` yields) or ``[N, T]`` with ``target_pixels`` expanded over T. The module
    composes with ``TensorDictSequential`` and ``NavFormerLoss``.
    """
    if len(in_keys) != len(NAVFORMER_IN_KEYS):
        raise ValueError(
            f"in_keys={list(in_keys)!r}: expected {len(NAVFORMER_IN_KEYS)} keys in the order {list(NAVFORMER_IN_KEYS)}"
        )
    if len(out_keys) != 1:
        raise ValueError(f"out_keys={list(out_keys)!r}: expected exactly one key (the predicted actions)")
    return TensorDictModule(model, in_keys=list(in_keys), out_keys=list(out_keys))
