"""Robot bodies and their limits (paper §VII: Jackal robots; §VII.C: TurtleBot3 as unseen obstacles).

Every robot is a kinematic unicycle whose collision footprint is a disc of ``radius`` metres. Actions at
every API are normalised ``(linear, angular)`` in ``[-1, 1]``; a :class:`RobotSpec` scales them to
``v = a0 * v_max`` (m/s) and ``w = a1 * w_max`` (rad/s). The acceleration limits ``a_max`` / ``alpha_max``
are not enforced by the simulator (it applies the commanded velocity for the whole 0.2 s step); planners
such as DWA use them to shape their dynamic windows.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RobotSpec:
    """Geometry, limits and look of one robot style.

    Attributes:
        name: style name (``"jackal"`` or ``"turtlebot3"``).
        radius: collision disc radius in metres (the footprint used for contacts and clearances).
        v_max: linear speed limit in m/s (action ``a0 = 1`` drives forward at ``v_max``).
        w_max: angular speed limit in rad/s (action ``a1 = 1`` turns counter-clockwise at ``w_max``).
        a_max: linear acceleration limit in m/s^2 (for planners; not enforced by the simulator).
        alpha_max: angular acceleration limit in rad/s^2 (for planners; not enforced by the simulator).
        camera_height: camera height above the floor in metres.
        camera_forward: camera offset ahead of the body centre in metres (outside the body, so the body
            never occludes its own view).
        camera_fov_deg: vertical (= horizontal, square image) field of view in degrees.
        color: RGBA of the main body, each in ``[0, 1]``.
        accent_color: RGBA of the top plate / sensor.
        body_shape: ``"box"`` (length x width x height from ``body_size``) or ``"cylinder"``
            (radius ``radius``, height ``body_size[2]``).
        body_size: ``(length, width, height)`` of the visual body in metres.
    """

    name: str
    radius: float
    v_max: float
    w_max: float
    a_max: float
    alpha_max: float
    camera_height: float
    camera_forward: float
    camera_fov_deg: float
    color: tuple[float, float, float, float]
    accent_color: tuple[float, float, float, float]
    body_shape: str
    body_size: tuple[float, float, float]


JACKAL = RobotSpec(
    name="jackal",
    radius=0.30,
    v_max=1.0,
    w_max=1.5,
    a_max=2.0,
    alpha_max=4.0,
    camera_height=0.30,
    camera_forward=0.28,
    camera_fov_deg=90.0,
    color=(0.18, 0.18, 0.18, 1.0),
    accent_color=(0.95, 0.55, 0.05, 1.0),
    body_shape="box",
    body_size=(0.508, 0.430, 0.25),
)
"""Clearpath Jackal: 0.508 x 0.430 x 0.25 m box body (dark chassis, orange top plate), collision disc
r = 0.30 m (the body's half-diagonal is 0.333 m, so box corners may visually touch a wall by up to 3 cm)."""

TURTLEBOT3 = RobotSpec(
    name="turtlebot3",
    radius=0.20,
    v_max=0.26,
    w_max=1.82,
    a_max=1.0,
    alpha_max=3.0,
    camera_height=0.20,
    camera_forward=0.22,
    camera_fov_deg=90.0,
    color=(0.08, 0.08, 0.10, 1.0),
    accent_color=(0.35, 0.35, 0.40, 1.0),
    body_shape="cylinder",
    body_size=(0.40, 0.40, 0.19),
)
"""TurtleBot3 (Waffle-like limits 0.26 m/s, 1.82 rad/s): round, near-black body of radius 0.20 m with a grey
sensor puck - visibly different from the Jackal, for the unseen-obstacle experiment (paper Table III)."""

ROBOT_SPECS: dict[str, RobotSpec] = {JACKAL.name: JACKAL, TURTLEBOT3.name: TURTLEBOT3}


def get_robot_spec(name: str) -> RobotSpec:
    """Return the :class:`RobotSpec` called ``name`` (``"jackal"`` or ``"turtlebot3"``)."""
    try:
        return ROBOT_SPECS[name]
    except KeyError:
        raise ValueError(f"unknown robot style {name!r}; expected one of {sorted(ROBOT_SPECS)}") from None
