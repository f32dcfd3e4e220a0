"""Simulator: unicycle kinematics with known answers, blocked motion, collision kinds, cameras and rays."""

import dataclasses
import math

import numpy as np
import pytest

from navformer_rl.envs.robots import JACKAL, TURTLEBOT3
from navformer_rl.envs.sim import (
    COLLISION_NONE,
    COLLISION_ROBOT,
    COLLISION_WALL,
    CONTACT_EPS,
    Simulator,
)

FAR_TARGET = [(4.4, 4.4, "sphere", "red")]


def sim_at(make_open_world, poses, specs=None):
    n = len(poses)
    targets = [
        (4.4, 4.4 - 0.8 * k, "sphere" if k % 2 else "box", c)
        for k, c in zip(range(n), ["red", "blue", "green"])
    ]
    world = make_open_world(poses, targets)
    return Simulator(world, specs or [JACKAL] * n, textured=False)


def test_straight_line_known_answer(make_open_world):
    sim = sim_at(make_open_world, [(1.0, 2.5, 0.0)])
    contacts = sim.step(np.array([[1.0, 0.0]]))
    assert not contacts.collided[0] and contacts.kind[0] == COLLISION_NONE
    assert np.allclose(sim.poses[0], [1.2, 2.5, 0.0], atol=1e-6)  # v_max 1 m/s for 0.2 s
    assert np.allclose(sim.velocities[0], [1.0, 0.0])


def test_turning_known_answers(make_open_world):
    sim = sim_at(make_open_world, [(2.0, 2.0, 0.0)])
    for _ in range(5):
        sim.step(np.array([[0.0, 1.0]]))  # w_max 1.5 rad/s: 0.3 rad per step, no translation
    assert np.allclose(sim.poses[0], [2.0, 2.0, 1.5], atol=1e-6)
    sim.set_poses([[2.0, 2.0, 0.0]])
    sim.step(np.array([[0.5, 1.0]]))  # arc: v = 0.5, w = 1.5 for 0.2 s
    r = 0.5 / 1.5
    assert np.allclose(sim.poses[0], [2.0 + r * math.sin(0.3), 2.0 + r * (1 - math.cos(0.3)), 0.3], atol=1e-6)
    # a quarter circle of radius 2/pi: v = 1 m/s, w = pi/2 rad/s for 5 steps of 0.2 s
    quarter = Simulator(sim.world, [dataclasses.replace(JACKAL, w_max=math.pi / 2)], textured=False)
    quarter.set_poses([[1.0, 1.0, 0.0]])
    for _ in range(5):
        assert not quarter.step(np.array([[1.0, 1.0]])).collided[0]
    assert np.allclose(quarter.poses[0], [1.0 + 2 / math.pi, 1.0 + 2 / math.pi, math.pi / 2], atol=1e-5)


def test_actions_are_clipped_and_validated(make_open_world):
    a = sim_at(make_open_world, [(1.0, 2.5, 0.3)])
    b = sim_at(make_open_world, [(1.0, 2.5, 0.3)])
    a.step(np.array([[3.0, -7.0]]))
    b.step(np.array([[1.0, -1.0]]))
    assert np.array_equal(a.poses, b.poses)
    with pytest.raises(ValueError, match="finite"):
        a.step(np.array([[np.nan, 0.0]]))
    with pytest.raises(ValueError, match=r"shape \(1, 2\)"):
        a.step(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="actions must be numbers.*got 'forward'"):
        a.step("forward")
    with pytest.raises(ValueError, match="actions must be numbers"):
        a.step([{"v": 1.0}, 0.0])


def test_bad_simulator_arguments_raise_value_error(make_open_world):
    world = make_open_world([(1.0, 2.5, 0.0)], FAR_TARGET)
    with pytest.raises(ValueError, match="robot_specs must be a RobotSpec.*get_robot_spec.*got 'jackal'"):
        Simulator(world, "jackal")
    with pytest.raises(ValueError, match="robot_specs must be a RobotSpec.*got \\['jackal'\\]"):
        Simulator(world, ["jackal"])
    for dt in (0.0, -0.2, math.nan):
        with pytest.raises(
            ValueError, match=f"dt must be a finite number > 0 \\(seconds per step\\), got {dt}"
        ):
            Simulator(world, JACKAL, dt=dt)
    with pytest.raises(ValueError, match="world must be a WorldSpec"):
        Simulator(world.config, JACKAL)


def test_robot_driven_into_a_wall_stops_and_counts(make_open_world):
    sim = sim_at(make_open_world, [(4.5, 2.5, 0.0)])  # the wall face is at x = 4.95
    contacts = sim.step(np.array([[1.0, 0.0]]))
    assert contacts.collided[0] and contacts.kind[0] == COLLISION_WALL
    assert sim.poses[0, 0] == pytest.approx(4.95 - JACKAL.radius, abs=1e-3)
    assert sim.poses[0, 0] <= 4.95 - JACKAL.radius
    assert sim.velocities[0, 0] == pytest.approx(0.75, abs=0.01)
    again = sim.step(np.array([[1.0, 0.0]]))  # still pushing: blocked again, no motion
    assert again.collided[0] and sim.poses[0, 0] == pytest.approx(4.65, abs=1e-3)
    turned = sim.step(np.array([[0.0, 1.0]]))  # turning in place while touching: still in contact
    assert turned.collided[0] and turned.kind[0] == COLLISION_WALL
    sim.set_poses([[sim.poses[0, 0], 2.5, math.pi / 2]])
    along = sim.step(np.array([[1.0, 0.0]]))  # driving along the wall while touching it: in contact
    assert along.collided[0] and sim.poses[0, 1] == pytest.approx(2.7, abs=1e-6)
    sim.set_poses([[sim.poses[0, 0], 2.5, 0.0]])
    away = sim.step(np.array([[-1.0, 0.0]]))  # driving away from the contact
    assert not away.collided[0] and away.kind[0] == COLLISION_NONE


def test_contact_tolerance_is_contact_eps(make_open_world):
    """A disc within CONTACT_EPS of the wall is in contact; 2 CONTACT_EPS away it is not (standing still)."""
    face = 4.95 - JACKAL.radius
    sim = sim_at(make_open_world, [(face - 0.5 * CONTACT_EPS, 2.5, 0.0)])
    assert sim.step(np.zeros((1, 2))).kind[0] == COLLISION_WALL
    sim.set_poses([[face - 2 * CONTACT_EPS, 2.5, 0.0]])
    assert not sim.step(np.zeros((1, 2))).collided[0]


@pytest.mark.parametrize("order", ["mover_first", "mover_last"])
def test_robot_driven_into_is_flagged_too(make_open_world, order):
    """A drives into a standing B: both are in contact on that step (kind robot), in either index order,
    and a turning B pushed against stays in contact while A keeps pushing."""
    a_pose, b_pose = (1.5, 2.5, 0.0), (2.2, 2.5, math.pi / 2)  # 0.7 m apart: gap 0.1 m
    poses = [a_pose, b_pose] if order == "mover_first" else [b_pose, a_pose]
    a, b = (0, 1) if order == "mover_first" else (1, 0)
    sim = sim_at(make_open_world, poses)
    drive = np.zeros((2, 2))
    drive[a] = (1.0, 0.0)
    contacts = sim.step(drive)
    assert contacts.collided.all() and (contacts.kind == COLLISION_ROBOT).all()
    assert np.hypot(*(sim.poses[a, :2] - sim.poses[b, :2])) == pytest.approx(2 * JACKAL.radius, abs=1e-3)
    drive[b] = (0.0, 1.0)  # B turns in place, A keeps pushing
    assert sim.step(drive).collided.all()
    drive[a] = (-1.0, 0.0)  # A backs off: nobody is in contact any more
    assert not sim.step(drive).collided.any()


def test_inactive_robot_driven_into_is_flagged(make_open_world):
    sim = sim_at(make_open_world, [(1.5, 2.5, 0.0), (2.2, 2.5, 0.0)])
    contacts = sim.step(np.array([[1.0, 0.0], [1.0, 0.0]]), active=np.array([True, False]))
    assert contacts.collided.all() and np.allclose(sim.poses[1], [2.2, 2.5, 0.0])


def test_hidden_robots_are_never_in_contact(make_open_world):
    sim = sim_at(make_open_world, [(1.5, 2.5, 0.0), (2.2, 2.5, 0.0)])
    sim.set_robot_visible(1, False)
    contacts = sim.step(np.array([[1.0, 0.0], [0.0, 0.0]]))  # A drives through the hidden B
    assert not contacts.collided.any() and sim.poses[0, 0] == pytest.approx(1.7, abs=1e-6)


def test_head_on_robots_never_overlap(make_open_world):
    sim = sim_at(make_open_world, [(1.5, 2.5, 0.0), (3.5, 2.5, math.pi)])
    kinds = []
    for _ in range(10):
        kinds.append(sim.step(np.array([[1.0, 0.0], [1.0, 0.0]])).kind.copy())
        gap = np.hypot(*(sim.poses[0, :2] - sim.poses[1, :2]))
        assert gap >= 2 * JACKAL.radius - 1e-9
    assert gap == pytest.approx(2 * JACKAL.radius, abs=1e-3)
    assert (np.array(kinds[-1]) == COLLISION_ROBOT).all()
    assert (np.array(kinds[0]) == COLLISION_NONE).all()


def test_adversarial_random_actions_never_overlap(tiny_maze):
    sim = Simulator(tiny_maze, [JACKAL, TURTLEBOT3, JACKAL], textured=False)
    rng = np.random.default_rng(0)
    boxes, circles, radii = tiny_maze.obstacle_boxes, tiny_maze.obstacle_circles, sim.radii
    counts = np.zeros(3, dtype=int)
    for _ in range(400):
        contacts = sim.step(rng.uniform(-1.5, 1.5, size=(3, 2)))
        counts += np.bincount(contacts.kind, minlength=3)
        p = sim.poses[:, :2].astype(np.float64)
        dx = np.maximum(np.abs(p[:, None, 0] - boxes[None, :, 0]) - boxes[None, :, 2], 0)
        dy = np.maximum(np.abs(p[:, None, 1] - boxes[None, :, 1]) - boxes[None, :, 3], 0)
        assert (np.hypot(dx, dy).min(axis=1) >= radii - 1e-6).all()
        d_circle = np.hypot(p[:, None, 0] - circles[None, :, 0], p[:, None, 1] - circles[None, :, 1])
        assert (d_circle >= radii[:, None] + circles[None, :, 2] - 1e-6).all()
        d_pair = np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1)) - radii[:, None] - radii[None]
        assert d_pair[~np.eye(3, dtype=bool)].min() >= -1e-6
    assert counts[COLLISION_WALL] > 0  # the test did push robots into walls


def test_inactive_robots_do_not_move(make_open_world):
    sim = sim_at(make_open_world, [(1.0, 1.0, 0.0), (1.0, 3.0, 0.0)])
    sim.step(np.ones((2, 2)), active=np.array([True, False]))
    assert np.allclose(sim.poses[1], [1.0, 3.0, 0.0]) and np.allclose(sim.velocities[1], 0.0)
    assert not np.allclose(sim.poses[0], [1.0, 1.0, 0.0])


def test_set_poses_rejects_overlaps(make_open_world):
    sim = sim_at(make_open_world, [(1.0, 1.0, 0.0), (1.0, 3.0, 0.0)])
    with pytest.raises(ValueError, match="overlaps"):
        sim.set_poses([[0.1, 1.0, 0.0], [1.0, 3.0, 0.0]])
    with pytest.raises(ValueError, match="overlaps"):
        sim.set_poses([[1.0, 1.0, 0.0], [1.3, 1.0, 0.0]])


def test_set_poses_refuses_poses_outside_the_world(make_open_world):
    inner_wall_only = np.array(
        [(2.5, 2.5, 0.05, 0.5)], dtype=np.float32
    )  # no outer walls: nothing else stops it
    world = make_open_world(
        [(1.0, 1.0, 0.0), (1.0, 4.0, 0.0)], FAR_TARGET + [(4.0, 1.0, "box", "blue")], inner_wall_only
    )
    sim = Simulator(world, [JACKAL, TURTLEBOT3], textured=False)
    with pytest.raises(
        ValueError, match=r"robot 0 is outside the world: its disc \(radius 0\.3 m\) must lie within"
    ):
        sim.set_poses([[-50.0, -50.0, 0.0], [30.0, 30.0, 0.0]])
    with pytest.raises(ValueError, match=r"robot 1 is outside the world.*0\.2 <= x, y <= 4\.8"):
        sim.set_poses([[4.9, 2.5, 0.0]], indices=[1])  # the disc pokes out of [0, 5]^2
    assert np.allclose(sim.poses[:, :2], [[1.0, 1.0], [1.0, 4.0]])  # nothing moved
    sim.set_poses([[0.3, 0.3, 0.0], [4.8, 2.5, 0.0]])  # touching the border is fine
    assert np.allclose(sim.poses[:, :2], [[0.3, 0.3], [4.8, 2.5]])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((2.5, math.pi, 6.0), r"n_rays must be an integer >= 1, got 2\.5"),
        ((0, math.pi, 6.0), r"n_rays must be an integer >= 1, got 0"),
        ((4, 0.0, 6.0), r"fov must be a finite number > 0 \(radians\), got 0\.0"),
        ((4, math.pi, float("nan")), r"max_range must be a finite number > 0 \(metres\), got nan"),
    ],
)
def test_ray_scan_refuses_bad_settings(make_open_world, args, message):
    sim = sim_at(make_open_world, [(2.5, 2.5, 0.0)])
    with pytest.raises(ValueError, match=message):
        sim.ray_scan(0, *args)


def test_ray_scan_known_distances_and_hidden_robots(make_open_world):
    sim = sim_at(make_open_world, [(2.5, 2.5, 0.0), (4.0, 2.5, 0.0)])
    # 4 rays over a full circle: -pi, -pi/2, 0, +pi/2
    scan = sim.ray_scan(0, 4, 2 * math.pi, 6.0)
    assert scan.dtype == np.float32 and scan.shape == (4,)
    assert scan[0] == pytest.approx(2.45, abs=1e-3) and scan[1] == pytest.approx(2.45, abs=1e-3)
    assert scan[2] == pytest.approx(4.0 - JACKAL.radius - 2.5, abs=1e-3)  # robot 1's cylinder
    assert sim.ray_scan(0, 4, 2 * math.pi, 1.0)[0] == pytest.approx(1.0)  # nothing within range
    sim.set_robot_visible(1, False)
    assert sim.ray_scan(0, 4, 2 * math.pi, 6.0)[2] == pytest.approx(2.45, abs=1e-3)


def test_camera_images_see_other_robots(make_open_world):
    sim = sim_at(make_open_world, [(2.0, 2.5, 0.0), (3.2, 2.5, 0.0)])
    with_robot = sim.render(0)
    assert with_robot.dtype == np.uint8 and with_robot.shape == (84, 84, 3)
    sim.set_robot_visible(1, False)
    without = sim.render(0)
    assert np.abs(with_robot.astype(int) - without.astype(int)).sum(axis=-1).astype(bool).sum() > 200
    sim.set_robot_visible(1, True)
    assert np.array_equal(sim.render(0), with_robot)  # deterministic
    frames = sim.render_all(np.array([False, True]))
    assert frames.shape == (2, 84, 84, 3) and not frames[0].any() and frames[1].any()
    sim.close()
    sim.close()
