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

FURNISHED_FOOTPRINTS: dict[str, tuple[float, float]] = {
    "bookstore": (14.3, 15.6),
    "cafe": (9.3, 23.1),
    "house": (19.0, 11.0),
}
"""Table II's out-of-distribution worlds (paper §VII.B): kind -> footprint ``(x, y)`` in metres."""
TABLE2_ROBOTS = 3
TABLE2_TARGETS = 8
"""Fig. 4: three Jackals and eight target objects in each photorealistic world (five no robot seeks)."""
TABLE2_TRIALS_PER_KIND = 30
"""Table II: three Jackal robots, 30 trials in each world kind (paper §VII.B)."""
