"""Analytic lidar vs the simulator's pybullet rays; camera visibility with known answers."""

import math

import numpy as np
import pytest

from navformer_rl.experts.lidar import StaticLidar
from navformer_rl.experts.visibility import segment_hits_boxes, target_visible


def test_lidar_known_distances_box_and_disc():
    lidar = StaticLidar(np.array([[3.0, 0.0, 0.5, 2.0]]), np.array([[0.0, 4.0, 1.0]]))
    angles = np.array([0.0, math.pi / 2, math.pi, math.atan2(2.0, 2.5)])
    r = lidar.scan(np.array([0.0, 0.0, 0.0]), angles, 10.0)
    assert r[0] == pytest.approx(2.5)  # box face at x = 2.5
    assert r[1] == pytest.approx(3.0)  # disc of radius 1 centred 4 m up
    assert r[2] == pytest.approx(10.0)  # nothing behind: max range
    assert r[3] == pytest.approx(math.hypot(2.5, 2.0))  # box corner (2.5, 2.0)
    # Heading rotates the rays: at yaw = pi/2 the ray at angle 0 looks up.
    assert lidar.scan(np.array([0.0, 0.0, math.pi / 2]), np.zeros(1), 10.0)[0] == pytest.approx(3.0)


def test_lidar_matches_simulator_rays():
    from navformer_rl.envs.robots import JACKAL
    from navformer_rl.envs.sim import Simulator
    from navformer_rl.envs.world import WorldConfig, generate_world

    world = generate_world(WorldConfig(size=7.5, kind="maze", n_robots=2), 3)
    sim = Simulator(world, JACKAL, textured=False)
    try:
        sim.set_robot_visible(1, False)  # the analytic lidar sees the static scene only
        angles = np.linspace(-math.pi, math.pi, 180, endpoint=False)
        ref = sim.ray_scan(0, 180, 2 * math.pi, 6.0)
        ours = StaticLidar.for_world(world).scan(sim.poses[0].astype(np.float64), angles, 6.0)
    finally:
        sim.close()
    close = np.abs(ref - ours) < 2e-3
    assert close.mean() >= 0.98  # the rest are grazing rays along a wall face (float round-off)


def test_segment_box_intersection():
    box = np.array([[1.0, 0.0, 0.1, 1.0]])
    assert segment_hits_boxes(np.array([0.0, 0.0]), np.array([2.0, 0.0]), box)
    assert not segment_hits_boxes(np.array([0.0, 0.0]), np.array([0.8, 0.0]), box)
    assert not segment_hits_boxes(np.array([0.0, 1.5]), np.array([2.0, 1.5]), box)
    assert segment_hits_boxes(np.array([1.0, 3.0]), np.array([1.0, -3.0]), box)  # vertical, inside slab


def test_target_visibility_fov_range_and_occlusion():
    walls = np.array([[2.0, 2.0, 0.05, 0.5]])
    pose = np.array([0.0, 0.0, 0.0])
    fov = math.radians(90)
    assert target_visible(pose, np.array([3.0, 0.0]), walls, fov, 5.0)
    assert not target_visible(pose, np.array([-3.0, 0.0]), walls, fov, 5.0)  # behind
    assert not target_visible(pose, np.array([3.0, 3.5]), walls, fov, 5.0)  # 49 degrees off-axis
    assert target_visible(pose, np.array([3.0, 2.9]), np.zeros((0, 4)), fov, 5.0)  # 44 degrees
    assert not target_visible(pose, np.array([6.0, 0.0]), walls, fov, 5.0)  # beyond range
    assert not target_visible(pose, np.array([3.0, 3.0]), walls, fov, 5.0)  # wall at x=2, y in [1.5, 2.5]
