"""Target images (one per shape x colour, deterministic) and the top-down map renderer."""

import itertools

import numpy as np
import pytest

from navformer_rl.constants import TARGET_COLORS, TARGET_SHAPES
from navformer_rl.envs.target_image import render_target_image
from navformer_rl.envs.target_nav import compose_frame
from navformer_rl.envs.topdown import ROBOT_COLORS, draw_topdown


def test_target_images_differ_per_shape_and_colour():
    images = {(s, c): render_target_image(s, c) for s, c in itertools.product(TARGET_SHAPES, TARGET_COLORS)}
    for image in images.values():
        assert image.dtype == np.uint8 and image.shape == (84, 84, 3)
    for a, b in itertools.combinations(images, 2):
        assert np.abs(images[a].astype(int) - images[b].astype(int)).sum() > 1000, (a, b)
    centre = images[("box", "red")][42, 42].astype(int)  # the object fills the image centre
    assert centre[0] > 120 and centre[0] > 2 * centre[1] and centre[0] > 2 * centre[2]
    centre = images[("sphere", "blue")][42, 42].astype(int)
    assert centre[2] > 120 and centre[2] > 2 * centre[0]


def test_target_image_is_deterministic_and_a_copy():
    first = render_target_image("sphere", "green")
    first[:] = 0
    second = render_target_image("sphere", "green")
    assert second.any()
    assert np.array_equal(second, render_target_image("sphere", "green"))


def test_target_image_rejects_unknown_names():
    with pytest.raises(ValueError, match="cone"):
        render_target_image("cone", "red")
    with pytest.raises(ValueError, match="pink"):
        render_target_image("box", "pink")


def test_topdown_draws_walls_targets_robots_and_paths(make_open_world):
    world = make_open_world([(1.0, 1.0, 0.0)], [(4.0, 4.0, "box", "red")])
    px, margin = 40.0, 10
    path = np.array([[1.0, 1.0], [1.0, 2.0], [2.0, 2.5]])
    img = draw_topdown(
        world, [path], np.array([[2.0, 2.5, 0.0]]), px_per_m=px, margin_px=margin, labels=False
    )
    assert img.dtype == np.uint8 and img.shape == (5 * 40 + 20, 5 * 40 + 20, 3)

    def at(x, y):
        return img[int(round(margin + (5.0 - y) * px)), int(round(margin + x * px))]

    assert np.array_equal(at(0.0, 2.5), [60, 60, 66])  # the left outer wall
    assert np.array_equal(at(4.0, 4.0), [int(255 * 0.90), int(255 * 0.08), int(255 * 0.08)])  # red cube
    assert np.array_equal(at(2.0, 2.35), ROBOT_COLORS[0])  # robot 0's disc (below its heading tick)
    assert np.array_equal(at(2.2, 2.5), [0, 0, 0])  # the heading tick points along +x
    assert np.array_equal(at(1.0, 1.5), ROBOT_COLORS[0])  # its trajectory
    assert np.array_equal(at(3.0, 1.0), [228, 225, 218])  # a 1 m grid line
    assert np.array_equal(at(3.5, 1.5), [245, 243, 238])  # empty floor


def test_topdown_and_frame_refuse_bad_arguments(make_open_world):
    world = make_open_world([(1.0, 1.0, 0.0)], [(4.0, 4.0, "sphere", "red")])
    for kwargs, message in (
        ({"px_per_m": float("inf")}, r"px_per_m must be a finite number > 0 \(pixels per metre\), got inf"),
        ({"margin_px": -100}, "margin_px must be an integer >= 0, got -100"),
        ({"margin_px": 2.5}, r"margin_px must be an integer >= 0, got 2\.5"),
        ({"poses": np.zeros((2, 2))}, r"poses must be float rows \[N, 3\] \(x, y, yaw\), got shape \(2, 2\)"),
        ({"trajectories": [np.zeros((4, 3))]}, r"trajectories\[0\] must be float rows \[N, 2\]"),
        ({"poses": np.zeros((2, 3)), "robot_specs": []}, "robot_specs has 0 entries for 2 poses"),
    ):
        with pytest.raises(ValueError, match=message):
            draw_topdown(world, **kwargs)
    # flat rows still work: read as the rows they hold (a 2-point path, one pose)
    path, pose = np.array([1.0, 1.0, 3.0, 2.0]), np.array([2.0, 3.0, 0.5])
    flat = draw_topdown(world, trajectories=[path], poses=pose)
    rows = draw_topdown(world, trajectories=[path.reshape(2, 2)], poses=pose.reshape(1, 3))
    assert flat.shape[2] == 3 and np.array_equal(flat, rows)
    assert not np.array_equal(flat, draw_topdown(world))  # the path and the robot were drawn
    topdown = draw_topdown(world, px_per_m=20)
    view = np.zeros((84, 84, 3), dtype=np.uint8)
    with pytest.raises(ValueError, match="view_px must be an integer >= 1, got -5"):
        compose_frame(topdown, [view], view_px=-5)
    with pytest.raises(
        ValueError, match=r"views\[0\] must be an RGB image \[h, w, 3\], got shape \(84, 84\)"
    ):
        compose_frame(topdown, [view[:, :, 0]])
    with pytest.raises(ValueError, match=r"topdown must be an RGB image \[H, W, 3\]"):
        compose_frame(topdown[:, :, 0], [view])
    assert compose_frame(topdown, [view], view_px=84).shape == (topdown.shape[0], topdown.shape[1] + 84, 3)
