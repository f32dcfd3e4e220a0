"""Goal-seeking obstacle policy (reaches its target; known seeded outcome) and the world demo outputs."""

import cv2
import numpy as np
import pytest

from navformer_rl.constants import SUCCESS_RADIUS
from navformer_rl.envs.demo import run_world_demo
from navformer_rl.envs.obstacle_policy import GoalSeekingPolicy, ObstaclePolicy, coarsen, descent_successors
from navformer_rl.envs.occupancy import OccupancyMap
from navformer_rl.envs.robots import JACKAL
from navformer_rl.envs.sim import Simulator


def drive_until_found(world, n_steps):
    sim = Simulator(world, JACKAL, textured=False)
    policy = GoalSeekingPolicy()
    assert isinstance(policy, ObstaclePolicy)
    policy.reset(world, sim, np.random.default_rng(0))
    found_at = np.full(world.n_robots, -1)
    for t in range(n_steps):
        sim.step(policy.act(sim, range(world.n_robots)))
        near = np.hypot(*(sim.poses[:, :2] - world.target_positions).T) <= SUCCESS_RADIUS
        found_at[near & (found_at < 0)] = t + 1
    return found_at


def test_goal_seeking_crosses_an_open_room(make_open_world):
    world = make_open_world([(0.6, 0.6, 0.0)], [(4.3, 4.3, "box", "green")])
    found_at = drive_until_found(world, 60)
    # 5.2 m straight line minus the 1.5 m success radius at up to 0.8 m/s: at least 24 steps
    assert 24 <= found_at[0] <= 40


def test_goal_seeking_robots_find_their_targets_in_a_maze(tiny_maze):
    assert (drive_until_found(tiny_maze, 300) > 0).all()


def test_coarsen_samples_the_inflated_map_at_cell_centres():
    grid = np.zeros((8, 8), dtype=bool)
    grid[5, 2] = True  # next to the sample point (6, 2) of coarse cell (1, 0)
    occ = OccupancyMap(grid, 0.05)
    coarse = coarsen(occ, 4)
    assert coarse.resolution == 0.2 and coarse.shape == (2, 2)
    assert not coarse.grid.any()  # no sample point is a wall
    inflated = coarsen(occ, 4, clearance=0.05)  # the wall grows onto (6, 2)
    assert inflated.grid.tolist() == [[False, False], [True, False]]


def test_world_demo_writes_a_map_and_a_video(tmp_path):
    paths = run_world_demo(tmp_path / "demo", size=5.0, n_robots=2, steps=4, seed=1, progress=False)
    image = cv2.imread(str(paths["map"]))
    assert image is not None and image.shape[0] == image.shape[1] == 600
    video = cv2.VideoCapture(str(paths["video"]))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 5  # the start frame + one per step
    ok, frame = video.read()
    assert ok and frame.shape[1] > frame.shape[0]
    assert sorted(p.name for p in (tmp_path / "demo").iterdir()) == ["egocentric.mp4", "map.png"]


def test_descent_successors_point_downhill():
    field = np.array([[2.0, 1.0, 2.0], [1.0, 0.0, np.inf], [2.0, 1.0, 2.0]])
    successor = descent_successors(field).reshape(3, 3)
    # every cell, the unreachable one included, steps onto the goal (flat index 4), a fixed point
    assert (successor == 4).all()
    ramp = np.array([[0.0, 1.0, 2.0, 3.0]])
    assert descent_successors(ramp).tolist() == [0, 0, 1, 2]
    assert descent_successors(np.full((2, 2), np.inf)).tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"coarsening": 0}, "coarsening must be an integer >= 1, got 0"),
        ({"coarsening": 2.5}, r"coarsening must be an integer >= 1, got 2\.5"),
        ({"lookahead": 0.0}, r"lookahead must be a finite number > 0 \(metres\), got 0\.0"),
        ({"margin": -0.1}, r"margin must be a finite number >= 0 \(metres\), got -0\.1"),
        ({"speed": 1.5}, r"speed must be a finite number >= 0 and <= 1 \(fraction of v_max\), got 1\.5"),
        ({"patience": -1}, "patience must be an integer >= 0, got -1"),
        ({"backing_steps": None}, "backing_steps must be an integer >= 0, got None"),
    ],
)
def test_goal_seeking_policy_refuses_bad_settings(kwargs, message):
    with pytest.raises(ValueError, match=message):
        GoalSeekingPolicy(**kwargs)


def test_world_demo_refuses_bad_step_counts(tmp_path):
    for steps in (0, 2.5):
        with pytest.raises(ValueError, match=f"steps must be an integer >= 1, got {steps}"):
            run_world_demo(tmp_path / "demo", size=5.0, n_robots=1, steps=steps, progress=False)
