"""Expert planner cost per robot-step against ``Simulator.step`` alone, measured in the same run.

    OMP_NUM_THREADS=1 python benchmarks/bench_experts.py --episodes 5

For each expert, every ``act`` call and every ``Simulator.step`` call of seeded episodes is timed; the table
gives the median and the mean (replans are spikes, the mean sets throughput) in ms per *robot*-step, and
the ratio to the simulator step. Component timings (median of repeats) follow. Prints markdown.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time

import numpy as np

from navformer_rl.constants import MAX_EPISODE_STEPS, SUCCESS_RADIUS
from navformer_rl.envs.robots import JACKAL
from navformer_rl.envs.sim import Simulator
from navformer_rl.envs.world import WorldConfig, generate_world
from navformer_rl.experts.astar import astar
from navformer_rl.experts.grid import distance_field
from navformer_rl.experts.lidar import StaticLidar
from navformer_rl.experts.mapping import LogOddsGrid
from navformer_rl.experts.policies import ExplorationExpert, FCAController, NHORCAExpert


def time_episodes(expert_cls, kind: str, size: float, robots: int, episodes: int, seed0: int) -> dict:
    plan, sim_t, plan_cpu, sim_cpu = [], [], [], []
    for k in range(episodes):
        world = generate_world(WorldConfig(size=size, kind=kind, n_robots=robots), seed0 + k)
        sim = Simulator(world, JACKAL, textured=False)
        expert = expert_cls()
        expert.reset(world, sim, np.random.default_rng(seed0 + k))
        targets = world.target_positions
        success = np.zeros(robots, dtype=bool)
        for _ in range(MAX_EPISODE_STEPS):
            active = ~success & ~expert.failed
            n = int(active.sum())
            if n == 0:
                break
            c0, t0 = time.process_time(), time.perf_counter()
            actions = expert.act(sim, active)
            c1, t1 = time.process_time(), time.perf_counter()
            sim.step(actions, active)
            c2, t2 = time.process_time(), time.perf_counter()
            plan.append((t1 - t0) / n)
            sim_t.append((t2 - t1) / n)
            plan_cpu.append((c1 - c0) / n)
            sim_cpu.append((c2 - c1) / n)
            success |= np.hypot(*(sim.poses[:, :2] - targets).T) <= SUCCESS_RADIUS
        sim.close()
    plan_ms, sim_ms = 1e3 * np.array(plan), 1e3 * np.array(sim_t)
    return {
        "robot_steps": len(plan),
        "plan_median": float(np.median(plan_ms)),
        "plan_mean": float(plan_ms.mean()),
        "sim_median": float(np.median(sim_ms)),
        "sim_mean": float(sim_ms.mean()),
        "plan_cpu_mean": 1e3 * float(np.mean(plan_cpu)),
        "sim_cpu_mean": 1e3 * float(np.mean(sim_cpu)),
    }


def median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def components(repeats: int) -> list[tuple[str, float]]:
    world = generate_world(WorldConfig(size=17.5, kind="maze", n_robots=1), 0)
    sim = Simulator(world, JACKAL, textured=False)
    pose = sim.poses[0].astype(np.float64)
    angles = np.linspace(-math.pi, math.pi, 180, endpoint=False)
    lidar = StaticLidar.for_world(world)
    grid = LogOddsGrid((world.size, world.size), 0.1)
    ranges = lidar.scan(pose, angles, 6.0)
    free = ~world.occupancy.inflate(0.35)[::2, ::2]  # the true 17.5 m maze at 0.1 m cells
    cells = np.argwhere(free)
    start, goal = tuple(cells[0]), tuple(cells[-1])
    out = [
        (
            "Simulator.ray_scan, 180 rays (pybullet)",
            median_ms(lambda: sim.ray_scan(0, 180, 2 * math.pi, 6.0), repeats),
        ),
        ("StaticLidar.scan, 180 rays (analytic)", median_ms(lambda: lidar.scan(pose, angles, 6.0), repeats)),
        (
            "LogOddsGrid.update, 180 rays, 17.5 m grid",
            median_ms(lambda: grid.update(pose, ranges, angles, 6.0), repeats),
        ),
        ("distance_field, 17.5 m maze at 0.1 m", median_ms(lambda: distance_field(free, [start]), repeats)),
        (
            "astar corner to corner, 17.5 m maze at 0.1 m",
            median_ms(lambda: astar(~free, start, goal), repeats),
        ),
        ("Simulator.step, 1 robot", median_ms(lambda: sim.step(np.zeros((1, 2))), repeats)),
    ]
    sim.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--seed", type=int, default=20_000)
    args = parser.parse_args()
    settings = [
        ("ExplorationExpert, maze 7.5 m, 1 robot", ExplorationExpert, "maze", 7.5, 1),
        ("ExplorationExpert, maze 12.5 m, 1 robot", ExplorationExpert, "maze", 12.5, 1),
        ("ExplorationExpert, maze 17.5 m, 1 robot", ExplorationExpert, "maze", 17.5, 1),
        ("NHORCAExpert, arena 12.5 m, 5 robots", NHORCAExpert, "arena", 12.5, 5),
        ("NHORCAExpert, arena 12.5 m, 9 robots", NHORCAExpert, "arena", 12.5, 9),
        ("FCAController, maze 12.5 m, 4 robots", FCAController, "maze", 12.5, 4),
    ]
    print(
        "| expert | robot-steps | planner wall ms/robot-step median | wall mean | CPU mean "
        "| Simulator.step wall ms/robot-step median | wall mean | CPU mean | planner / step (CPU means) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name, cls, kind, size, robots in settings:
        r = time_episodes(cls, kind, size, robots, args.episodes, args.seed)
        print(
            f"| {name} | {r['robot_steps']} | {r['plan_median']:.2f} | {r['plan_mean']:.2f} | "
            f"{r['plan_cpu_mean']:.2f} | {r['sim_median']:.3f} | {r['sim_mean']:.3f} | "
            f"{r['sim_cpu_mean']:.3f} | {r['plan_cpu_mean'] / max(r['sim_cpu_mean'], 1e-9):.1f} |",
            flush=True,
        )
    print()
    print("| component | ms (median) |")
    print("|---|---|")
    for name, ms in components(args.repeats):
        print(f"| {name} | {ms:.3f} |")
    print()
    print(
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs, load average "
        f"{os.getloadavg()[0]:.1f} at the end, Python {platform.python_version()}, numpy {np.__version__}."
    )


if __name__ == "__main__":
    main()
