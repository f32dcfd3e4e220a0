"""World demo: a seeded maze, robots driven by the goal-seeking policy, a map and an egocentric video.

``run_world_demo`` writes ``map.png`` (top-down map with every robot's trajectory) and ``egocentric.mp4``
(H.264; each frame: the top-down map beside all robots' 84x84 cameras, scaled up) and returns their paths.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np

from navformer_rl.constants import CONTROL_DT, SUCCESS_RADIUS
from navformer_rl.envs.obstacle_policy import GoalSeekingPolicy
from navformer_rl.envs.robots import JACKAL
from navformer_rl.envs.sim import Simulator
from navformer_rl.envs.topdown import ROBOT_COLORS, draw_topdown
from navformer_rl.envs.world import WorldConfig, generate_world
from navformer_rl.utils.checks import check_int
from navformer_rl.utils.durable import atomic_path
from navformer_rl.utils.mp4 import Mp4Writer

_MAP_PX = 600
_CAMERA_PX = 168


def run_world_demo(
    out_dir: str | os.PathLike,
    size: float = 12.5,
    n_robots: int = 4,
    steps: int = 200,
    seed: int = 0,
    progress: bool = True,
) -> dict[str, Path]:
    """Generate the maze for ``seed``, drive ``n_robots`` Jackals for ``steps`` steps of 0.2 s with the
    goal-seeking policy (a robot stops once it is within 1.5 m of its target), and write
    ``out_dir/map.png`` and ``out_dir/egocentric.mp4`` (5 frames/s = real time) atomically.

    Returns ``{"map": Path, "video": Path}``. ValueError for a bad size, robot count, step count or seed.
    """
    steps = check_int(steps, "steps")
    from tqdm.auto import tqdm

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    world = generate_world(WorldConfig(size=size, n_robots=n_robots), seed)
    sim = Simulator(world, JACKAL)
    policy = GoalSeekingPolicy()
    policy.reset(world, sim, np.random.default_rng(seed))
    targets = world.target_positions.astype(np.float64)
    found = np.zeros(n_robots, dtype=bool)
    paths = [[p[:2].astype(np.float64)] for p in sim.poses]
    px_per_m = (_MAP_PX - 24) / world.size
    video_path = out / "egocentric.mp4"
    try:
        with Mp4Writer(video_path, 1.0 / CONTROL_DT) as video:
            cameras = sim.render_all()
            video.write(_frame(world, paths, sim, cameras, found, 0, steps, px_per_m))
            for t in tqdm(range(1, steps + 1), desc="world demo", unit="step", disable=not progress):
                active = ~found
                actions = policy.act(sim, range(n_robots))
                sim.step(actions, active)
                poses = sim.poses
                for i in np.flatnonzero(active):
                    paths[i].append(poses[i, :2].astype(np.float64))
                found |= np.hypot(*(poses[:, :2] - targets).T) <= SUCCESS_RADIUS
                fresh = sim.render_all(active)
                cameras[active] = fresh[active]
                video.write(_frame(world, paths, sim, cameras, found, t, steps, px_per_m))
    finally:
        sim.close()
    map_path = out / "map.png"
    image = draw_topdown(world, [np.array(p) for p in paths], sim.poses, sim.robot_specs, px_per_m=px_per_m)
    _write_png_atomic(map_path, image)
    return {"map": map_path, "video": video_path}


def _frame(
    world, paths, sim: Simulator, cameras: np.ndarray, found: np.ndarray, t: int, steps: int, px_per_m: float
):
    """uint8 RGB frame: a title bar, the top-down map on the left,
    the cameras in a 2-column grid on the right."""
    topdown = draw_topdown(world, [np.array(p) for p in paths], sim.poses, sim.robot_specs, px_per_m=px_per_m)
    n = len(cameras)
    cols = 1 if n <= 3 else 2
    rows = math.ceil(n / cols)
    tile = min(_CAMERA_PX, (topdown.shape[0] - 4) // rows)
    grid = np.full((topdown.shape[0], cols * (tile + 6) + 6, 3), 255, dtype=np.uint8)
    for i, image in enumerate(cameras):
        r, c = divmod(i, cols)
        y, x = 6 + r * (tile + 6), 6 + c * (tile + 6)
        if y + tile > grid.shape[0]:
            break
        color = tuple(int(v) for v in ROBOT_COLORS[i % len(ROBOT_COLORS)])
        cv2.rectangle(grid, (x - 3, y - 3), (x + tile + 2, y + tile + 2), color, -1)
        grid[y : y + tile, x : x + tile] = cv2.resize(image, (tile, tile), interpolation=cv2.INTER_NEAREST)
        label = f"{i}: found" if found[i] else str(i)
        cv2.putText(
            grid, label, (x + 4, y + 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 2, cv2.LINE_AA
        )
        cv2.putText(grid, label, (x + 4, y + 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, color, 1, cv2.LINE_AA)
    body = np.concatenate([topdown, grid], axis=1)
    bar = np.full((28, body.shape[1], 3), 255, dtype=np.uint8)
    title = (
        f"seed {world.seed} | {world.size:g} m maze | step {t}/{steps} ({t * CONTROL_DT:.1f} s) | "
        f"found {int(found.sum())}/{len(found)}"
    )
    cv2.putText(bar, title, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (20, 20, 20), 1, cv2.LINE_AA)
    frame = np.concatenate([bar, body], axis=0)
    return frame[: frame.shape[0] // 2 * 2, : frame.shape[1] // 2 * 2]  # even sides for video codecs


def _write_png_atomic(path: Path, image_rgb: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), image_rgb[:, :, ::-1]):
            raise OSError(f"could not write {path}")
