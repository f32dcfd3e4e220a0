"""Target images (one per shape x colour, deterministic) and the top-down map renderer."""

import itertools

import numpy as np
import pytest

from navformer_rl.constants import TARGET_COLORS, TARGET_SHAPES
from navformer_rl.envs.target_image import render_target_image
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
