"""Target visibility for the experts: camera field of view, range and line of sight through the walls."""

from __future__ import annotations

import math

import numpy as np


def segment_hits_boxes(a: np.ndarray, b: np.ndarray, boxes: np.ndarray) -> bool:
    """True when the segment ``a -> b`` (``[2]`` each) crosses any axis-aligned box ``[W, 4] = (cx, cy, hx,
    hy)`` (slab test, vectorised over boxes)."""
    if len(boxes) == 0:
        return False
    d = b - a
    lo = boxes[:, :2] - boxes[:, 2:]
    hi = boxes[:, :2] + boxes[:, 2:]
    t0 = np.zeros(len(boxes))
    t1 = np.ones(len(boxes))
    for k in range(2):
        if abs(d[k]) < 1e-12:
            outside = (a[k] < lo[:, k]) | (a[k] > hi[:, k])
            t0 = np.where(outside, 2.0, t0)
            continue
        ta = (lo[:, k] - a[k]) / d[k]
        tb = (hi[:, k] - a[k]) / d[k]
        t0 = np.maximum(t0, np.minimum(ta, tb))
        t1 = np.minimum(t1, np.maximum(ta, tb))
    return bool(np.any(t0 <= t1))


def target_visible(
    pose: np.ndarray,
    target: np.ndarray,
    walls: np.ndarray,
    fov: float,
    max_range: float,
    camera_forward: float = 0.0,
) -> bool:
    """Whether the target centre is seen by the robot's forward camera at ``pose = (x, y, yaw)``.

    Visible when the camera (``camera_forward`` ahead of the centre) is within ``max_range`` of the target
    centre, the bearing is within ``+-fov/2`` of the heading, and no wall box cuts the line of sight.
    """
    x, y, yaw = (float(v) for v in pose)
    cam = np.array([x + camera_forward * math.cos(yaw), y + camera_forward * math.sin(yaw)])
    tgt = np.asarray(target, dtype=np.float64)
    delta = tgt - cam
    dist = math.hypot(delta[0], delta[1])
    if dist > max_range:
        return False
    bearing = math.atan2(delta[1], delta[0]) - yaw
    bearing = math.pi - (math.pi - bearing) % (2 * math.pi)
    if abs(bearing) > fov / 2:
        return False
    return not segment_hits_boxes(cam, tgt, walls)
