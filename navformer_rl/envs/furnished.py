"""Table II's furnished worlds (paper §VII.B): a bookstore, a two-room café and a multi-room house.

Out-of-distribution evaluation worlds, never used for training: rooms, doorways and furniture built from
axis-aligned boxes, painted in wall, floor and furniture colours that no training world uses
(:data:`PALETTES`, disjoint from the maze palette and the target colours: tested), with the training target
objects. ``generate_world(WorldConfig(kind="bookstore", size=15.6, n_robots=3), seed)`` makes one (the walls
come from :func:`furnished_walls`, targets and starts are placed as in a maze); the same seed gives the same
world, another seed moves the furniture, partitions and doorways.

Geometry. A world stays the square ``[0, size]^2`` of every ``WorldSpec``, ``size`` being the footprint's
longer side (:func:`furnished_size`): the building fills ``[0, fx] x [0, fy]`` (``FURNISHED_FOOTPRINTS``) and
the strip beyond its shorter side is solid (part of that side's outer wall box), so the free space is the
building alone. Every box, furniture included, is in ``WorldSpec.walls``: it blocks motion, rays, sight lines
and the occupancy map. :class:`SceneStyle` tells the simulator each box's colour and height and the floor's
texture.

Passages. Doorways are at least :data:`MIN_DOOR` wide, free-standing furniture keeps :data:`MIN_GAP` from
everything and the bookstore's aisles are at least 1.5 m; a layout is redrawn until the free space is one
connected component both for the robot's disc and for a disc :data:`PLANNER_MARGIN` larger (the experts' A*
and NH-ORCA plan with about 0.1-0.15 m more than the robot radius), so every room is reachable by the robots
and by the experts' planners.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from navformer_rl.constants import FURNISHED_FOOTPRINTS
from navformer_rl.envs.occupancy import OccupancyMap

FURNISHED_KINDS: tuple[str, ...] = tuple(FURNISHED_FOOTPRINTS)
"""``("bookstore", "cafe", "house")``."""

OUTER_WALL = 0.10
INNER_WALL = 0.12
WALL_HEIGHT = 2.4
"""Outer and partition wall thickness and the walls' height in metres (the mazes' walls are 1.0 m high)."""
MIN_DOOR = 1.2
"""Narrowest doorway in metres: a Jackal (0.6 m) with 0.3 m to spare on each side."""
MIN_GAP = 1.3
"""Metres free-standing furniture keeps from every other box
(wall-standing furniture from other furniture)."""
PLANNER_MARGIN = 0.15
"""The free space must stay connected for a disc of ``robot_radius + PLANNER_MARGIN`` as well."""
MAX_TRIES = 100
"""Layouts drawn before :func:`furnished_walls` gives up."""

Rect = tuple[float, float, float, float]
"""An axis-aligned rectangle ``(x0, y0, x1, y1)`` in metres."""
RGB = tuple[float, float, float]


@dataclass(frozen=True)
class Palette:
    """A furnished kind's look: ``walls`` RGB in [0, 1], per furniture role its RGB and height in metres,
    and the floor texture's ``floor`` colours ``(light, dark, seam)``, ``floor_pattern`` and
    ``floor_metres`` (the side of one texture repeat)."""

    walls: RGB
    furniture: dict[str, tuple[RGB, float]]
    floor: tuple[RGB, RGB, RGB]
    floor_pattern: str
    floor_metres: float

    def colours(self) -> list[RGB]:
        """Every colour of this palette (walls, furniture, floor)."""
        return [self.walls, *(rgb for rgb, _ in self.furniture.values()), *self.floor]


_WOOD_DARK, _CHARCOAL = (0.26, 0.15, 0.09), (0.15, 0.15, 0.17)
PALETTES: dict[str, Palette] = {
    "bookstore": Palette(
        walls=(0.13, 0.35, 0.37),  # deep teal
        furniture={
            "shelf": (_WOOD_DARK, 1.9),
            "wall_shelf": ((0.40, 0.12, 0.10), 2.1),  # oxblood
            "counter": (_CHARCOAL, 1.0),
            "display_table": ((0.62, 0.45, 0.26), 0.8),  # light oak
            "sofa": ((0.70, 0.52, 0.10), 0.8),  # mustard
        },
        floor=((0.52, 0.33, 0.18), (0.44, 0.27, 0.14), (0.30, 0.18, 0.10)),  # dark wooden planks
        floor_pattern="planks",
        floor_metres=2.0,
    ),
    "cafe": Palette(
        walls=(0.66, 0.30, 0.20),  # terracotta
        furniture={
            "table": ((0.10, 0.09, 0.09), 0.75),
            "chair": ((0.10, 0.30, 0.22), 0.5),  # bottle green
            "counter": ((0.42, 0.16, 0.34), 1.05),  # plum
            "display_case": ((0.60, 0.78, 0.80), 1.2),  # glass
            "plant": ((0.28, 0.34, 0.12), 1.3),  # olive
        },
        floor=((0.86, 0.80, 0.66), (0.18, 0.22, 0.28), (0.10, 0.12, 0.16)),  # cream and slate tiles
        floor_pattern="checker",
        floor_metres=1.0,
    ),
    "house": Palette(
        walls=(0.72, 0.82, 0.90),  # pale sky
        furniture={
            "wood": ((0.36, 0.24, 0.16), 0.75),  # tables, desks, stands
            "tall_wood": ((0.36, 0.24, 0.16), 2.0),  # wardrobes, bookshelves
            "sofa": ((0.50, 0.14, 0.22), 0.8),  # wine
            "bed": ((0.60, 0.55, 0.75), 0.55),  # lilac grey
            "chair": (_CHARCOAL, 0.5),
            "counter": (_CHARCOAL, 0.9),
            "appliance": ((0.78, 0.80, 0.80), 1.8),  # fridge
            "low_appliance": ((0.78, 0.80, 0.80), 0.55),  # bathtub
        },
        floor=((0.78, 0.58, 0.32), (0.70, 0.50, 0.26), (0.50, 0.34, 0.18)),  # honey parquet
        floor_pattern="basket",
        floor_metres=1.0,
    ),
}
"""The look of each furnished kind (colours far from the training palette and the targets: tested)."""


@dataclass(frozen=True, eq=False)  # holds arrays: identity equality, hashable
class SceneStyle:
    """How the simulator and the top-down map paint a furnished world (``WorldSpec.style``; ``None`` for the
    training worlds, which keep their own look).

    Attributes:
        roles: per wall box its role, ``"wall"`` or a furniture role of the kind's :class:`Palette`.
        box_rgba: float32 ``[W, 4]`` colour of each wall box.
        box_height: float32 ``[W]`` height of each wall box in metres.
        floor_texture: uint8 ``[H, W, 3]`` RGB, one repeat of the floor pattern.
        floor_metres: side of one repeat in metres.
        floor_rgba: the plain floor colour (``textured=False``).
    """

    roles: tuple[str, ...]
    box_rgba: np.ndarray
    box_height: np.ndarray
    floor_texture: np.ndarray
    floor_metres: float
    floor_rgba: tuple[float, float, float, float]

    @property
    def wall_height(self) -> float:
        """Height of the walls (``WorldSpec.wall_height`` of a furnished world) in metres."""
        return WALL_HEIGHT


def furnished_size(kind: str) -> float:
    """Side of the square world of a furnished ``kind``: its footprint's longer side in metres."""
    return float(max(FURNISHED_FOOTPRINTS[kind]))


# ---------------------------------------------------------------------------------------------- layout
def _overlaps(a: Rect, b: Rect, eps: float = 1e-6) -> bool:
    """True when two rectangles overlap with positive area (touching is fine)."""
    return a[0] < b[2] - eps and b[0] < a[2] - eps and a[1] < b[3] - eps and b[1] < a[3] - eps


def _grow(r: Rect, d: float) -> Rect:
    return (r[0] - d, r[1] - d, r[2] + d, r[3] + d)


def _bbox(rects: Sequence[Rect]) -> Rect:
    return (
        min(r[0] for r in rects),
        min(r[1] for r in rects),
        max(r[2] for r in rects),
        max(r[3] for r in rects),
    )


Group = list[tuple[Rect, str]]
"""Furniture placed together (e.g. a table and its chairs): ``(rect, role)`` pairs in a local frame."""


class _Layout:
    """Boxes of one furnished world under construction: walls, furniture and keep-out zones (doorways,
    walkways) that furniture must leave free."""

    def __init__(self, kind: str, rng: np.random.Generator) -> None:
        self.kind, self.rng = kind, rng
        self.fx, self.fy = FURNISHED_FOOTPRINTS[kind]
        self.size = furnished_size(kind)
        self.rects: list[Rect] = []
        self.roles: list[str] = []
        self.keepouts: list[Rect] = []
        h, s = OUTER_WALL / 2, self.size
        top = s + h if self.fy < s else self.fy + h  # the solid strip beyond a shorter side joins its wall
        right = s + h if self.fx < s else self.fx + h
        self.add((-h, -h, self.fx + h, h), "wall")
        self.add((-h, self.fy - h, max(self.fx + h, right), top), "wall")
        self.add((-h, -h, h, self.fy + h), "wall")
        self.add((self.fx - h, -h, right, max(self.fy + h, top)), "wall")

    @property
    def inner(self) -> Rect:
        """The building's floor inside its outer walls."""
        h = OUTER_WALL / 2
        return (h, h, self.fx - h, self.fy - h)

    def add(self, rect: Rect, role: str) -> None:
        self.rects.append(tuple(float(v) for v in rect))
        self.roles.append(role)

    def partition(
        self, axis: str, at: float, lo: float, hi: float, doors: Sequence[tuple[float, float]] = ()
    ):
        """A partition wall on ``x = at`` (``axis="x"``) or ``y = at`` from ``lo`` to ``hi``, broken by
        ``doors`` ``(start, end)`` along it; each doorway gets a keep-out zone reaching ``MIN_GAP`` into
        both rooms."""
        h = INNER_WALL / 2
        cuts = [lo, *[v for door in sorted(doors) for v in door], hi]
        for a, b in zip(cuts[0::2], cuts[1::2]):
            if b - a > 1e-6:
                self.add((at - h, a, at + h, b) if axis == "x" else (a, at - h, b, at + h), "wall")
        for a, b in doors:
            zone = (at - MIN_GAP, a - 0.2, at + MIN_GAP, b + 0.2)
            self.keepouts.append(zone if axis == "x" else (zone[1], zone[0], zone[3], zone[2]))

    def fits(self, parts: Sequence[Rect], gap: float, wall_gap: float) -> bool:
        """True when ``parts`` lie inside the building, their bounding box grown by ``gap`` meets no
        furniture, they meet no keep-out zone, and grown by ``wall_gap`` (0: touching is fine) they meet no
        wall."""
        box = _bbox(parts)
        x0, y0, x1, y1 = self.inner
        if box[0] < x0 - 1e-6 or box[1] < y0 - 1e-6 or box[2] > x1 + 1e-6 or box[3] > y1 + 1e-6:
            return False
        grown = _grow(box, gap)
        for rect, role in zip(self.rects, self.roles):
            if role == "wall":
                if any(_overlaps(_grow(p, wall_gap), rect) for p in parts):
                    return False
            elif _overlaps(grown, rect):
                return False
        return not any(_overlaps(box, zone) for zone in self.keepouts)

    def place(self, parts: Group) -> None:
        for rect, role in parts:
            self.add(rect, role)

    def free_standing(self, group: Group, area: Rect, tries: int = 60, gap: float = MIN_GAP) -> bool:
        """Put ``group`` (local frame) at a random centre in ``area``, turned by a random multiple of 90
        degrees, ``gap`` from everything; False when ``tries`` draws found no room."""
        for _ in range(tries):
            parts = _turn(group, int(self.rng.integers(4)))
            bx = _bbox([r for r, _ in parts])
            w, d = bx[2] - bx[0], bx[3] - bx[1]
            if area[2] - area[0] < w or area[3] - area[1] < d:
                continue
            x = self.rng.uniform(area[0], area[2] - w) - bx[0]
            y = self.rng.uniform(area[1], area[3] - d) - bx[1]
            placed = [((r[0] + x, r[1] + y, r[2] + x, r[3] + y), role) for r, role in parts]
            if self.fits([r for r, _ in placed], gap, gap):
                self.place(placed)
                return True
        return False

    def against_wall(
        self, group: Group, room: Rect, sides: str = "blrt", tries: int = 40, gap: float = MIN_GAP
    ) -> bool:
        """Put ``group`` with its back (local ``y = 0``) against one of the ``sides`` (``b``ottom, ``l``eft,
        ``r``ight, ``t``op) of ``room`` (inner faces), at a random place along it; an end closer than 0.9 m
        to the room's corner is pushed into the corner (no useless slots). ``gap`` from other furniture."""
        bx = _bbox([r for r, _ in group])
        length = bx[2] - bx[0]
        for _ in range(tries):
            side = sides[int(self.rng.integers(len(sides)))]
            span = (room[2] - room[0]) if side in "bt" else (room[3] - room[1])
            if span < length:
                continue
            a = self.rng.uniform(0.0, span - length)
            a = 0.0 if a < 0.9 else (span - length if span - length - a < 0.9 else a)
            placed = [(_on_wall(r, side, a - bx[0], room), role) for r, role in group]
            if self.fits([r for r, _ in placed], gap, 0.0):
                self.place(placed)
                return True
        return False

    def walls(self) -> np.ndarray:
        """float32 ``[W, 4]`` boxes ``(cx, cy, half_x, half_y)``."""
        r = np.array(self.rects, dtype=np.float64)
        return np.stack(
            [
                (r[:, 0] + r[:, 2]) / 2,
                (r[:, 1] + r[:, 3]) / 2,
                (r[:, 2] - r[:, 0]) / 2,
                (r[:, 3] - r[:, 1]) / 2,
            ],
            axis=1,
        ).astype(np.float32)


def _on_wall(r: Rect, side: str, a: float, room: Rect) -> Rect:
    """Local rectangle (``u`` along the wall, ``v`` away from it) to world, offset ``a`` along the side."""
    u0, v0, u1, v1 = r
    x0, y0, x1, y1 = room
    if side == "b":
        return (x0 + a + u0, y0 + v0, x0 + a + u1, y0 + v1)
    if side == "t":
        return (x0 + a + u0, y1 - v1, x0 + a + u1, y1 - v0)
    if side == "l":
        return (x0 + v0, y0 + a + u0, x0 + v1, y0 + a + u1)
    return (x1 - v1, y0 + a + u0, x1 - v0, y0 + a + u1)


def _turn(group: Group, quarter_turns: int) -> Group:
    """``group`` turned by ``quarter_turns`` x 90 degrees about its local origin."""
    out = group
    for _ in range(quarter_turns % 4):
        out = [((-r[3], r[0], -r[1], r[2]), role) for r, role in out]
    return out


def _item(length: float, depth: float, role: str) -> Group:
    """One box, ``length`` along a wall and ``depth`` away from it."""
    return [((0.0, 0.0, length, depth), role)]


def _table_with_chairs(
    width: float, depth: float, sides: str, table: str = "table", chair: str = "chair"
) -> Group:
    """A table ``width x depth`` centred at the origin with 0.45 m chairs 0.05 m off the ``sides`` it names
    (``b``, ``t``: one chair per 0.6 m of width; ``l``, ``r``: one per 0.6 m of depth)."""
    parts: Group = [((-width / 2, -depth / 2, width / 2, depth / 2), table)]
    c, off = 0.45, 0.05
    for side in sides:
        along = width if side in "bt" else depth
        n = max(1, int(along // 0.6))
        for k in range(n):
            u = (k + 0.5) * along / n - along / 2
            if side in "bt":
                v = -depth / 2 - off - c / 2 if side == "b" else depth / 2 + off + c / 2
                parts.append(((u - c / 2, v - c / 2, u + c / 2, v + c / 2), chair))
            else:
                v = -width / 2 - off - c / 2 if side == "l" else width / 2 + off + c / 2
                parts.append(((v - c / 2, u - c / 2, v + c / 2, u + c / 2), chair))
    return parts


def _at_wall(group: Group) -> Group:
    """``group`` shifted so that its back (lowest local ``y``) is at ``y = 0`` and its left end at
    ``x = 0``."""
    bx = _bbox([r for r, _ in group])
    return [((r[0] - bx[0], r[1] - bx[1], r[2] - bx[0], r[3] - bx[1]), role) for r, role in group]


# ---------------------------------------------------------------------------------------------- the kinds
def _bookstore(lay: _Layout) -> None:
    """A hall of shelf stacks: double-sided shelves 0.6-0.8 m deep in rows along x or y, in one block or two
    either side of a main aisle, shelving along the side and back walls, walkways around the stacks, and a
    lobby with a checkout counter, display tables and a sofa."""
    rng = lay.rng
    x0, y0, x1, y1 = lay.inner
    lobby = y0 + rng.uniform(3.6, 4.4)  # the stacks start here
    back = y1 - rng.uniform(2.6, 3.2)  # ... and end here
    depth = 0.45  # wall shelving
    lay.add((x0, lobby - rng.uniform(0.0, 1.0), x0 + depth, y1), "wall_shelf")
    lay.add((x0 + depth, y1 - depth, x0 + (x1 - x0) * rng.uniform(0.55, 0.8), y1), "wall_shelf")
    lay.add((x1 - depth, lobby + rng.uniform(0.0, 1.5), x1, back + rng.uniform(-1.0, 0.5)), "wall_shelf")
    left, right = x0 + depth + rng.uniform(1.6, 1.9), x1 - depth - rng.uniform(1.6, 1.9)
    shelf = rng.uniform(0.6, 0.8)
    if rng.random() < 0.6:  # two blocks either side of a main aisle
        centre = (x0 + x1) / 2 + rng.uniform(-0.5, 0.5)
        half_aisle = rng.uniform(2.0, 2.4) / 2
        blocks = [(left, lobby, centre - half_aisle, back), (centre + half_aisle, lobby, right, back)]
    else:
        blocks = [(left, lobby, right, back)]
    for block in blocks:
        _shelf_rows(lay, block, bool(rng.random() < 0.5), shelf)
    counter = rng.uniform(2.2, 2.8)
    cx1 = x1 - rng.uniform(1.3, 1.6)
    cy0 = y0 + rng.uniform(1.2, 1.4)  # staff space behind the counter, open at both ends
    lay.add((cx1 - counter, cy0, cx1, cy0 + 0.7), "counter")
    foyer = (x0, y0, x1, lobby)
    for _ in range(int(rng.integers(1, 3))):
        lay.free_standing(_item(1.2, 0.8, "display_table"), foyer)
    lay.against_wall(_item(1.8, 0.8, "sofa"), (x0, y0, x1, lobby), sides="bl")


def _shelf_rows(lay: _Layout, block: Rect, along_x: bool, shelf: float, aisle: float = 1.5) -> None:
    """Fill ``block`` with rows of double-sided shelves (``shelf`` deep) at least ``aisle`` apart, the outer
    rows on the block's edges; a row longer than 2.5 m plus the passage is broken by a 1.3-1.6 m passage half
    the time."""
    rng = lay.rng
    bx0, by0, bx1, by1 = block
    across = (by1 - by0) if along_x else (bx1 - bx0)
    n = max(1, int((across + aisle) // (shelf + aisle)))
    pitch = (across - shelf) / (n - 1) if n > 1 else 0.0
    start = (by0 if along_x else bx0) + (0.0 if n > 1 else (across - shelf) / 2)
    lo, hi = (bx0, bx1) if along_x else (by0, by1)
    for k in range(n):
        a = start + k * pitch
        pieces = [(lo, hi)]
        gap = rng.uniform(1.3, 1.6)
        if hi - lo > 2.5 + gap and rng.random() < 0.5:
            cut = rng.uniform(lo + 1.0, hi - 1.0 - gap)
            pieces = [(lo, cut), (cut + gap, hi)]
        for p0, p1 in pieces:
            lay.add((p0, a, p1, a + shelf) if along_x else (a, p0, a + shelf, p1), "shelf")


def _cafe(lay: _Layout) -> None:
    """Two dining rooms joined by one doorway in a cross partition, a walkway through both (kept free from
    the doorway to either end), a counter and a display case in the front room, tables with chairs along the
    long walls and free-standing, and plants by the walls."""
    rng = lay.rng
    x0, y0, x1, y1 = lay.inner
    wall_y = (y0 + y1) / 2 + rng.uniform(-1.5, 1.5)
    door = rng.uniform(1.6, 2.0)
    dx0 = rng.uniform(x0 + 1.5, x1 - 1.5 - door)
    lay.partition("y", wall_y, x0, x1, [(dx0, dx0 + door)])
    lay.keepouts.append((dx0 - 0.1, y0, dx0 + door + 0.1, y1))  # the walkway
    h = INNER_WALL / 2
    front, rear = (x0, y0, x1, wall_y - h), (x0, wall_y + h, x1, y1)
    lay.against_wall(_item(1.4, 0.6, "display_case"), front, sides="b")
    counter = rng.uniform(3.0, 4.0)  # parallel to a long wall, staff space behind it open at both ends
    lay.free_standing(_item(counter, 0.7, "counter"), front, gap=1.2)
    for room in (front, rear):
        for corner in rng.permutation(4)[:2]:
            lay.against_wall(_item(0.5, 0.5, "plant"), room, sides="blrt"[corner], tries=4, gap=0.9)
        for _ in range(5):  # by a long wall: chairs on the three other sides
            width = 0.8 if rng.random() < 0.5 else 1.2
            lay.against_wall(_at_wall(_table_with_chairs(width, 0.7, "lrt")), room, sides="lr", tries=15)
        for _ in range(5):
            width, depth = (0.8, 0.8) if rng.random() < 0.5 else (1.2, 0.8)
            sides = "".join(s for s in "bltr" if rng.random() < 0.75) or "bt"
            lay.free_standing(_table_with_chairs(width, depth, sides), room, tries=25)


def _house(lay: _Layout) -> None:
    """A living room over the full depth at one end, a corridor from it along the house with two or three
    rooms either side (a doorway each onto the corridor, sometimes one between neighbours), furnished by
    room type (bedroom, kitchen, bathroom, study)."""
    rng = lay.rng
    x0, y0, x1, y1 = lay.inner
    h = INNER_WALL / 2
    width = rng.uniform(1.7, 2.0)
    mid = (y0 + y1) / 2 + rng.uniform(-0.7, 0.7)
    c0, c1 = mid - width / 2, mid + width / 2  # corridor walls
    living = x0 + rng.uniform(5.5, 6.8)
    rooms: list[Rect] = []
    living_doors: dict[str, list[tuple[float, float]]] = {"low": [], "high": []}
    for band, (b0, b1), wall_at in (("low", (y0, c0), c0), ("high", (c1, y1), c1)):
        length = x1 - living
        n = int(rng.integers(2, 4))
        cuts = [living] + [living + length * (k / n + rng.uniform(-0.06, 0.06)) for k in range(1, n)] + [x1]
        corridor_doors = []
        for k in range(n):
            r0, r1 = cuts[k] + h, cuts[k + 1] - (h if k < n - 1 else 0.0)
            w = rng.uniform(MIN_DOOR, 1.4)
            a = rng.uniform(r0 + 0.3, r1 - 0.3 - w)
            corridor_doors.append((a, a + w))
            inner_y = (b0, wall_at - h) if band == "low" else (wall_at + h, b1)
            rooms.append((r0, inner_y[0], r1, inner_y[1]))
        lay.partition("y", wall_at, living - h, x1, corridor_doors)
        for k in range(1, n):  # partitions between neighbouring rooms, a third of them with a doorway
            doors = []
            if rng.random() < 0.35:
                w = rng.uniform(MIN_DOOR, 1.4)
                a = rng.uniform(b0 + 0.4, b1 - 0.4 - w)
                doors.append((a, a + w))
            lay.partition(
                "x", cuts[k], b0 if band == "low" else c1 + h, c0 - h if band == "low" else b1, doors
            )
        if rng.random() < 0.5:  # a doorway from the living room into this band's first room
            w = rng.uniform(MIN_DOOR, 1.4)
            lo, hi = (b0, c0) if band == "low" else (c1, b1)
            a = rng.uniform(lo + 0.4, hi - 0.4 - w)
            living_doors[band].append((a, a + w))
    lay.partition("x", living, y0, c0 - h, living_doors["low"])
    lay.partition("x", living, c1 + h, y1, living_doors["high"])
    lay.keepouts.append((living - MIN_GAP - 0.6, c0, x1, c1))  # the corridor and its mouth stay free
    _living_room(lay, (x0, y0, living - h, y1))
    kinds = ["kitchen", "bathroom", *rng.permutation(["bedroom", "bedroom", "study", "bedroom"]).tolist()]
    for room, kind in zip(rooms, [kinds[int(i)] for i in rng.permutation(len(rooms))]):
        _ROOMS[kind](lay, room)


def _living_room(lay: _Layout, room: Rect) -> None:
    lay.against_wall(_item(2.2, 0.9, "sofa"), room)
    lay.against_wall(_item(1.6, 0.45, "wood"), room)  # TV stand
    lay.against_wall(_item(1.2, 0.4, "tall_wood"), room)  # bookshelf
    lay.free_standing(_item(1.1, 0.6, "wood"), room)  # coffee table
    lay.free_standing(_table_with_chairs(1.6, 0.9, "bltr", "wood"), room)
    lay.free_standing(_item(0.85, 0.85, "sofa"), room)  # armchair


def _bedroom(lay: _Layout, room: Rect) -> None:
    bed = [
        ((0.0, 0.0, 0.45, 0.45), "wood"),
        ((0.45, 0.0, 1.95, 2.0), "bed"),
        ((1.95, 0.0, 2.4, 0.45), "wood"),
    ]
    lay.against_wall(bed, room)
    lay.against_wall(_item(1.2, 0.6, "tall_wood"), room)  # wardrobe


def _kitchen(lay: _Layout, room: Rect) -> None:
    span = min(room[2] - room[0], room[3] - room[1])
    lay.against_wall(_item(min(3.0, span - 0.2), 0.6, "counter"), room)
    lay.against_wall(_item(0.7, 0.7, "appliance"), room)  # fridge
    lay.free_standing(_table_with_chairs(1.2, 0.8, "bt", "wood"), room)


def _bathroom(lay: _Layout, room: Rect) -> None:
    lay.against_wall(_item(1.7, 0.75, "low_appliance"), room)  # bathtub
    lay.against_wall(_item(0.8, 0.5, "wood"), room, gap=0.9)  # washbasin cabinet


def _study(lay: _Layout, room: Rect) -> None:
    desk = [((0.0, 0.0, 1.4, 0.7), "wood"), ((0.475, 0.85, 0.925, 1.3), "chair")]
    lay.against_wall(desk, room)
    lay.against_wall(_item(1.2, 0.35, "tall_wood"), room)
    lay.against_wall(_item(1.2, 0.35, "tall_wood"), room)


_ROOMS: dict[str, Callable[[_Layout, Rect], None]] = {
    "bedroom": _bedroom,
    "kitchen": _kitchen,
    "bathroom": _bathroom,
    "study": _study,
}
_KINDS: dict[str, Callable[[_Layout], None]] = {"bookstore": _bookstore, "cafe": _cafe, "house": _house}


# ---------------------------------------------------------------------------------------------- look
def floor_texture(palette: Palette, px_per_m: int = 32) -> np.ndarray:
    """uint8 ``[n, n, 3]`` RGB, one repeat (``palette.floor_metres``) of the floor: ``"planks"`` (0.2 m
    boards with staggered joints), ``"checker"`` (0.5 m tiles) or ``"basket"`` (0.5 m squares of three
    strips, alternating direction); thin seams in the seam colour."""
    light, dark, seam = (np.array(c) * 255 for c in palette.floor)
    n = int(round(palette.floor_metres * px_per_m))
    u = np.arange(n) / px_per_m  # metres
    x, y = np.meshgrid(u, u, indexing="xy")
    if palette.floor_pattern == "planks":
        row = np.floor(y / 0.2).astype(int)
        shifted = x + (row % 4) * 0.5
        board = np.floor(shifted / 1.0).astype(int)
        pick = (row * 7 + board * 3) % 2 == 0
        edge = (np.mod(y, 0.2) < 1.0 / px_per_m) | (np.mod(shifted, 1.0) < 1.0 / px_per_m)
    elif palette.floor_pattern == "checker":
        pick = (np.floor(x / 0.5) + np.floor(y / 0.5)) % 2 == 0
        edge = (np.mod(x, 0.5) < 1.0 / px_per_m) | (np.mod(y, 0.5) < 1.0 / px_per_m)
    elif palette.floor_pattern == "basket":
        square = (np.floor(x / 0.5) + np.floor(y / 0.5)) % 2 == 0
        strip = np.where(square, np.floor(np.mod(y, 0.5) / (0.5 / 3)), np.floor(np.mod(x, 0.5) / (0.5 / 3)))
        pick = strip % 2 == 0
        across = np.where(square, np.mod(y, 0.5 / 3), np.mod(x, 0.5 / 3))
        edge = (
            (across < 1.0 / px_per_m) | (np.mod(x, 0.5) < 1.0 / px_per_m) | (np.mod(y, 0.5) < 1.0 / px_per_m)
        )
    else:
        raise ValueError(
            f"unknown floor pattern {palette.floor_pattern!r}; expected planks, checker or basket"
        )
    img = np.where(pick[..., None], light, dark)
    img[edge] = seam
    return np.round(img).astype(np.uint8)


def scene_style(kind: str, roles: Sequence[str]) -> SceneStyle:
    """The :class:`SceneStyle` of a ``kind`` world whose wall boxes have ``roles``."""
    palette = PALETTES[kind]
    looks = {"wall": (palette.walls, WALL_HEIGHT), **palette.furniture}
    rgba = np.array([(*looks[role][0], 1.0) for role in roles], dtype=np.float32).reshape(-1, 4)
    height = np.array([looks[role][1] for role in roles], dtype=np.float32)
    light, dark, _ = palette.floor
    plain = tuple(float((a + b) / 2) for a, b in zip(light, dark))
    return SceneStyle(
        roles=tuple(roles),
        box_rgba=rgba,
        box_height=height,
        floor_texture=floor_texture(palette),
        floor_metres=float(palette.floor_metres),
        floor_rgba=(*plain, 1.0),
    )


# ---------------------------------------------------------------------------------------------- entry
def furnished_walls(
    kind: str, robot_radius: float, rng: np.random.Generator, resolution: float
) -> tuple[np.ndarray, OccupancyMap, SceneStyle]:
    """Draw a ``kind`` layout with ``rng``: ``(walls float32 [W, 4], wall_map, style)``, ``wall_map`` the
    walls' :class:`OccupancyMap` at ``resolution`` m. Layouts are redrawn (up to :data:`MAX_TRIES`) until the
    free space is one component for discs of ``robot_radius`` and ``robot_radius + PLANNER_MARGIN``;
    ValueError for an unknown kind or when none is."""
    if kind not in _KINDS:
        raise ValueError(f"unknown furnished world kind {kind!r}; expected one of {FURNISHED_KINDS}")
    for _ in range(MAX_TRIES):
        lay = _Layout(kind, rng)
        _KINDS[kind](lay)
        walls = lay.walls()
        wall_map = OccupancyMap.from_shapes(lay.size, resolution, walls)
        if all(wall_map.free_components(r)[1] == 1 for r in (robot_radius, robot_radius + PLANNER_MARGIN)):
            return walls, wall_map, scene_style(kind, lay.roles)
    raise ValueError(
        f"could not draw a {kind} whose free space is connected for robot_radius={robot_radius!r} m "
        f"(+ {PLANNER_MARGIN} m for the planners) in {MAX_TRIES} tries; use a smaller robot_radius"
    )
