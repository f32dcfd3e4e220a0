"""TorchRL env transforms a policy of this project needs: the reset markers, and uint8 HWC images.

- :func:`add_policy_transforms` appends to an env what a policy reads and the env lacks: TorchRL's
  ``InitTracker`` (``"is_init"``: the Collector looks for it, and warns without it) and ``StepCounter`` (for a
  policy reading a ``step_count`` key the env does not write). ``MultiRobotNavEnv`` writes
  ``("agents", "step_count")`` itself; the single-robot ``make_torchrl_target_nav_env`` writes neither.
- :class:`ToUint8Image`: the models take images as the envs and datasets store them, uint8 HWC
  ``[..., 84, 84, 3]`` (the encoders convert them on the fly, one ``permute`` away from channels-last
  float: no float copy of a frame is kept anywhere, which matters for replay buffers of millions of frames).
  TorchRL's ``ToTensorImage`` writes float CHW in [0, 1] instead; this transform turns such images back, for
  an env whose pixels come out of a transform chain built for other models.

The policy is read by its attributes (``is_init_key``, ``step_count_key``: ``NavFormerPolicy``'s), so any
policy naming its keys the same way is served.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from tensordict.utils import NestedKey
from torchrl.data import Bounded, Composite
from torchrl.envs import EnvBase, InitTracker, StepCounter, Transform


def policy_transforms(env: EnvBase, policy: Any = None) -> list[Transform]:
    """The transforms ``env`` lacks for ``policy``: ``InitTracker(init_key)`` unless the env's specs hold the
    policy's ``is_init_key`` (default ``"is_init"``), and ``StepCounter(step_count_key=...)`` when the policy
    reads a ``step_count_key`` the env does not write (a root key; nested ones come from the env itself)."""
    keys = set(env.full_observation_spec.keys(True, True)) | set(env.full_state_spec.keys(True, True))
    init_key = getattr(policy, "is_init_key", None) or "is_init"
    step_key = getattr(policy, "step_count_key", None)
    transforms: list[Transform] = []
    if step_key is not None and step_key not in keys:
        if not isinstance(step_key, str):
            raise ValueError(
                f"the policy reads {step_key!r}, which the env does not write; StepCounter writes a root "
                "key: set the policy's step_count key to one (policy.set_keys(step_count='step_count'))"
            )
        transforms.append(StepCounter(step_count_key=step_key))
    if init_key not in keys:
        transforms.append(InitTracker(init_key=init_key))
    return transforms


def add_policy_transforms(env: EnvBase, policy: Any = None) -> EnvBase:
    """``env`` with :func:`policy_transforms` appended (``env.append_transform``, TorchRL's way: a
    ``TransformedEnv`` is extended in place), or ``env`` itself when it lacks none.

    Examples:
        >>> from navformer_rl.envs.multi_robot import MultiRobotNavEnv
        >>> from navformer_rl.envs.policy_transforms import add_policy_transforms
        >>> env = add_policy_transforms(MultiRobotNavEnv(size=7.5, n_robots=2, seed=0))
        >>> type(env.transform).__name__  # only InitTracker: ("agents", "step_count") is the env's own
        'InitTracker'
    """
    for transform in policy_transforms(env, policy):
        env = env.append_transform(transform)
    return env


class ToUint8Image(Transform):
    """Float CHW images in [0, 1] ``[..., 3, H, W]`` (TorchRL's ``ToTensorImage`` output) -> uint8 HWC
    ``[..., H, W, 3]``, the layout NavFormer's encoders and ``NavFormerPolicy`` read (rounded; values outside
    [0, 1] clipped). On observations at ``reset`` and ``step``, and their specs.

    Args:
        in_keys: the image keys (default ``["pixels"]``; e.g. ``[("agents", "pixels"), ("agents",
            "target_pixels")]``).
        out_keys: where the uint8 images go (default: in place).

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from navformer_rl.envs.policy_transforms import ToUint8Image
        >>> frames = TensorDict({"pixels": torch.rand(2, 3, 84, 84)}, batch_size=[2])
        >>> images = ToUint8Image()(frames)["pixels"]  # in place: frames now holds uint8 HWC
        >>> images.dtype, images.shape
        (torch.uint8, torch.Size([2, 84, 84, 3]))
    """

    def __init__(
        self, in_keys: Sequence[NestedKey] | None = None, out_keys: Sequence[NestedKey] | None = None
    ) -> None:
        in_keys = ["pixels"] if in_keys is None else list(in_keys)
        super().__init__(in_keys=in_keys, out_keys=in_keys if out_keys is None else list(out_keys))

    def _apply_transform(self, images: torch.Tensor) -> torch.Tensor:
        if not images.is_floating_point() or images.dim() < 3 or images.shape[-3] != 3:
            raise ValueError(
                f"ToUint8Image: expected float CHW images [..., 3, H, W] in [0, 1], got {images.dtype} "
                f"{list(images.shape)}"
            )
        return (images.clamp(0.0, 1.0) * 255.0).round().to(torch.uint8).movedim(-3, -1)

    def _reset(self, tensordict, tensordict_reset):
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        for in_key, out_key in zip(self.in_keys, self.out_keys, strict=True):
            spec = observation_spec[in_key]
            *lead, channels, height, width = spec.shape
            observation_spec[out_key] = Bounded(
                0, 255, shape=(*lead, height, width, channels), dtype=torch.uint8, device=spec.device
            )
        return observation_spec
