"""pybullet body builders shared by the simulator and the target-image renderer (primitives only).

Every function takes the ``pybullet`` module ``p`` and a client id ``c`` and returns the new body id.
Bodies are static (mass 0); the simulator moves robots with ``resetBasePositionAndOrientation``.
"""

from __future__ import annotations

import os
import tempfile

import cv2
import numpy as np

from navformer_rl.envs.robots import RobotSpec

WALL_PALETTE = np.array(
    [
        (0.62, 0.60, 0.56),
        (0.48, 0.55, 0.62),
        (0.70, 0.63, 0.50),
        (0.55, 0.50, 0.58),
        (0.66, 0.66, 0.66),
        (0.50, 0.58, 0.52),
        (0.72, 0.56, 0.50),
        (0.42, 0.46, 0.52),
    ]
)
"""Muted wall colours (far from the saturated target colours); the simulator gives each wall box one."""

PLAIN_FLOOR_RGBA = (0.55, 0.53, 0.50, 1.0)
_VERTEX_JITTER = 0.01234
_TILE_LIGHT, _TILE_DARK, _SEAM = (150, 142, 128), (120, 114, 106), (92, 88, 82)


def _floor_texture(p, c, img: np.ndarray | None = None) -> int:
    """``img`` (uint8 ``[H, W, 3]`` RGB; default a repeating 2 x 2 pattern of one-metre two-tone tiles with
    thin seams) loaded as a pybullet texture (written to a temporary PNG, removed right after loading)."""
    if img is None:
        px = 32
        tile = np.arange(2 * px) // px
        checker = (tile[:, None] + tile[None, :]) % 2 == 0
        img = np.where(checker[..., None], _TILE_LIGHT, _TILE_DARK).astype(np.uint8)
        img[::px] = _SEAM
        img[:, ::px] = _SEAM
    fd, path = tempfile.mkstemp(suffix=".png", prefix="navformer_floor_")
    os.close(fd)
    try:
        cv2.imwrite(path, img[:, :, ::-1])  # cv2 writes BGR
        return p.loadTexture(path, physicsClientId=c)
    finally:
        os.remove(path)


def add_floor(
    p,
    c,
    size: float,
    textured: bool = True,
    margin: float = 0.5,
    texture: np.ndarray | None = None,
    texture_metres: float = 2.0,
    plain_rgba=PLAIN_FLOOR_RGBA,
) -> int:
    """A visual-only floor mesh over ``[-margin, size + margin]^2`` at z = 0, tiled in 1 m squares when
    ``textured`` (the tiles give the cameras cues of distance and motion), else plain (``plain_rgba``).
    ``texture`` (uint8 ``[H, W, 3]`` RGB covering ``texture_metres`` square, repeated) replaces the tiles,
    e.g. a furnished world's floor.

    The mesh is split into quads of about 1 m, which keeps the tiny renderer's texture mapping tidy.
    """
    n = int(np.ceil(size + 2 * margin))
    # vertex lines sit off round coordinates: the tiny renderer drops triangles whose vertex lies exactly
    # in the camera's plane (e.g. a camera at x = 1.0 over a vertex at x = 1.0)
    ticks = -margin - _VERTEX_JITTER + np.arange(n + 1, dtype=np.float64) * (size + 2 * margin) / n
    gx, gy = np.meshgrid(ticks, ticks, indexing="xy")
    vertices = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    k = np.arange(n)
    corner = (k[:, None] * (n + 1) + k[None, :]).ravel()  # lower-left vertex of each quad (row-major)
    quads = np.stack([corner, corner + 1, corner + n + 2, corner, corner + n + 2, corner + n + 1], axis=1)
    vis = p.createVisualShape(
        p.GEOM_MESH,
        vertices=vertices.tolist(),
        indices=quads.ravel().tolist(),
        uvs=(vertices[:, :2] / texture_metres).tolist(),  # the default texture: 2 x 2 one-metre tiles
        normals=[[0.0, 0.0, 1.0]] * len(vertices),
        rgbaColor=[1, 1, 1, 1] if textured else list(plain_rgba),
        physicsClientId=c,
    )
    floor = p.createMultiBody(0, -1, vis, [0.0, 0.0, 0.0], physicsClientId=c)
    if textured:
        p.changeVisualShape(floor, -1, textureUniqueId=_floor_texture(p, c, texture), physicsClientId=c)
    return floor


def add_furnished_scene(p, c, size: float, walls: np.ndarray, style, textured: bool = True) -> None:
    """A furnished world's floor and boxes: ``walls`` float ``[W, 4]`` ``(cx, cy, half_x, half_y)``, each in
    its ``style`` (:class:`~navformer_rl.envs.furnished.SceneStyle`) colour and height; the floor in the
    style's texture, or plain in its ``floor_rgba`` when not ``textured``."""
    add_floor(p, c, size, textured, texture=style.floor_texture, texture_metres=style.floor_metres,
              plain_rgba=style.floor_rgba)  # fmt: skip
    for (cx, cy, hx, hy), rgba, height in zip(
        np.asarray(walls, dtype=np.float64), style.box_rgba.astype(np.float64), style.box_height
    ):
        add_box(p, c, (cx, cy, float(height) / 2), (hx, hy, float(height) / 2), tuple(rgba))


def add_box(p, c, centre, half_extents, rgba) -> int:
    """A static box (visual + collision) centred at ``centre`` (x, y, z)."""
    vis = p.createVisualShape(
        p.GEOM_BOX, halfExtents=list(half_extents), rgbaColor=list(rgba), physicsClientId=c
    )
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(half_extents), physicsClientId=c)
    return p.createMultiBody(0, col, vis, [float(v) for v in centre], physicsClientId=c)


def add_target(p, c, shape: str, rgba, half: float, position) -> int:
    """A target object resting on the floor at ``position`` (x, y): sphere of radius ``half`` or cube of
    half side ``half``."""
    centre = [float(position[0]), float(position[1]), half]
    if shape == "box":
        return add_box(p, c, centre, (half, half, half), rgba)
    vis = p.createVisualShape(p.GEOM_SPHERE, radius=half, rgbaColor=list(rgba), physicsClientId=c)
    col = p.createCollisionShape(p.GEOM_SPHERE, radius=half, physicsClientId=c)
    return p.createMultiBody(0, col, vis, centre, physicsClientId=c)


def add_robot(p, c, spec: RobotSpec, position) -> int:
    """A robot body from two primitives (chassis + top plate or sensor puck) with a cylinder collision
    shape of the spec's radius (so ray scans see it). ``createVisualShapeArray`` gets every optional
    list: pybullet 3.2.7 segfaults without them."""
    length, width, height = spec.body_size
    identity = [0.0, 0.0, 0.0, 1.0]
    if spec.body_shape == "box":
        shapes = [p.GEOM_BOX, p.GEOM_BOX]
        half_extents = [[length / 2, width / 2, height / 2], [length / 2 * 0.8, width / 2 * 0.8, 0.02]]
        radii, lengths = [0.0, 0.0], [0.0, 0.0]
        positions = [[0, 0, height / 2], [-0.03, 0, height + 0.02]]
    else:
        shapes = [p.GEOM_CYLINDER, p.GEOM_CYLINDER]
        half_extents = [[0, 0, 0], [0, 0, 0]]
        radii, lengths = [spec.radius, spec.radius * 0.35], [height, 0.05]
        positions = [[0, 0, height / 2], [-0.03, 0, height + 0.025]]
    vis = p.createVisualShapeArray(
        shapeTypes=shapes,
        halfExtents=half_extents,
        radii=radii,
        lengths=lengths,
        rgbaColors=[list(spec.color), list(spec.accent_color)],
        fileNames=["", ""],
        meshScales=[[1, 1, 1], [1, 1, 1]],
        visualFramePositions=positions,
        visualFrameOrientations=[identity, identity],
        physicsClientId=c,
    )
    col = p.createCollisionShape(
        p.GEOM_CYLINDER,
        radius=spec.radius,
        height=height,
        collisionFramePosition=[0, 0, height / 2],
        physicsClientId=c,
    )
    return p.createMultiBody(0, col, vis, [float(v) for v in position], physicsClientId=c)
