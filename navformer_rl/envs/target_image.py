"""The target image g (paper §III, §V): an 84x84 view of the target object alone.

One generator for datasets and evaluation: the object stands on the same tiled floor as in the worlds,
0.9 m in front of a Jackal camera (0.30 m high, 90 deg field of view), looking straight at it. Images
are deterministic and cached per ``(shape, color)``.
"""

from __future__ import annotations

import functools

import numpy as np

from navformer_rl.constants import IMAGE_SIZE
from navformer_rl.envs.robots import JACKAL
from navformer_rl.envs.scene import add_floor, add_target
from navformer_rl.envs.sim import import_pybullet
from navformer_rl.envs.world import TARGET_HALF_EXTENT, TARGET_RGBA

VIEW_DISTANCE = 0.9
"""Metres from the camera to the object's centre."""


def render_target_image(shape: str, color: str) -> np.ndarray:
    """uint8 ``[84, 84, 3]`` (HWC, RGB) image of the target ``(shape, color)``; a fresh copy each call.

    ValueError for an unknown shape (``TARGET_HALF_EXTENT``) or colour (``TARGET_RGBA``).
    """
    if shape not in TARGET_HALF_EXTENT:
        raise ValueError(f"unknown target shape {shape!r}; expected one of {sorted(TARGET_HALF_EXTENT)}")
    if color not in TARGET_RGBA:
        raise ValueError(f"unknown target colour {color!r}; expected one of {sorted(TARGET_RGBA)}")
    return _cached_target_image(shape, color).copy()


@functools.cache
def _cached_target_image(shape: str, color: str) -> np.ndarray:
    p = import_pybullet()  # lazy: importing this module starts nothing

    c = p.connect(p.DIRECT)
    try:
        add_floor(p, c, size=4.0, textured=True, margin=2.0)
        half = TARGET_HALF_EXTENT[shape]
        add_target(p, c, shape, TARGET_RGBA[color], half, (1.0 + VIEW_DISTANCE, 2.0))
        eye = (1.0, 2.0, JACKAL.camera_height)
        view = p.computeViewMatrix(eye, (2.0, 2.0, eye[2]), (0.0, 0.0, 1.0))
        proj = p.computeProjectionMatrixFOV(JACKAL.camera_fov_deg, 1.0, 0.05, 20.0)
        out = p.getCameraImage(
            IMAGE_SIZE,
            IMAGE_SIZE,
            view,
            proj,
            renderer=p.ER_TINY_RENDERER,
            shadow=0,
            flags=p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=c,
        )
    finally:
        p.disconnect(physicsClientId=c)
    image = np.asarray(out[2], dtype=np.uint8).reshape(IMAGE_SIZE, IMAGE_SIZE, 4)[:, :, :3].copy()
    image.flags.writeable = False
    return image
