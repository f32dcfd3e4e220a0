"""Numbers and names fixed by the paper's protocol (§III, §VII.A), shared by every component."""

CONTROL_DT = 0.2
"""Seconds per env step (paper §VII.A: 'Each timestep is 0.2 s')."""

MAX_EPISODE_STEPS = 500
"""A trial ends after 500 steps (paper §VII.A)."""

SUCCESS_RADIUS = 1.5
"""A robot has found its target within 1.5 m of it (paper §VII.A)."""

IMAGE_SIZE = 84
"""Camera frames and target images are 84 x 84 x 3 uint8, stored HWC (paper §IV.B)."""

EVAL_SIZES = (7.5, 12.5, 17.5)
EVAL_ROBOT_COUNTS = (2, 4, 6)
MIN_WORLD_SIZE = 5.0
MAX_WORLD_SIZE = 17.5

TARGET_SHAPES = ("sphere", "box")
TARGET_COLORS = ("green", "red", "white", "yellow", "blue")
