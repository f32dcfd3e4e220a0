"""Collection throughput per core for D_e, D_ca and D_ssl, against the simulator step alone.

All in one process (one core), on the same seeded worlds the collection uses. Rates are per **CPU
second of this process** (``time.process_time``: robust to other jobs sharing the cores); the wall-clock
seconds of the run are printed beside them.

* ``collect``: the library's work units (expert + cameras + shard rows), robot-steps/s and stored rows/s;
* ``planner only``: the same episodes with the cameras off (``run_episode(record=False)``);
* ``env step alone``: per robot-step one 84x84 render plus ``Simulator.step`` with random actions, in the
  same worlds and with the same number of robots (for D_ssl: the two bare renders of a pair).

The projection divides the paper's sizes (342,954 D_e steps, 469,378 D_ca steps, 98,000 D_ssl pairs) by the
measured stored-rows rate times the number of cores (failed episodes included in the cost).

Usage: ``OMP_NUM_THREADS=1 python benchmarks/bench_collect.py [--episodes 12] [--ca-episodes 4]
[--ssl-worlds 3] [--cores 2]``. Prints a markdown table.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from navformer_rl.data import expert_episodes as C
from navformer_rl.data.collect_settings import settings_for
from navformer_rl.data.schema import DatasetKind

PAPER = {"e": 342_954, "ca": 469_378, "ssl": 98_000}


def _env_step_rate(world, n_robots: int, steps: int, seed: int) -> float:
    """Robot-steps/s of render + step with random actions (``steps`` robot-steps, all robots active)."""
    from navformer_rl.envs.robots import JACKAL
    from navformer_rl.envs.sim import Simulator

    sim = Simulator(world, JACKAL)
    rng = np.random.default_rng(seed)
    try:
        t0 = time.process_time()
        done = 0
        while done < steps:
            sim.render_all()
            sim.step(rng.uniform(-1, 1, size=(n_robots, 2)))
            done += n_robots
        return done / (time.process_time() - t0)
    finally:
        sim.close()


def _planner_only(world, rng, expert_cls, max_steps: int) -> tuple[float, int]:
    from navformer_rl.envs.robots import JACKAL
    from navformer_rl.envs.sim import Simulator

    sim = Simulator(world, JACKAL)
    try:
        expert = expert_cls()
        expert.reset(world, sim, rng)
        t0 = time.process_time()
        trajs = C.run_episode(world, sim, expert, max_steps, record=False)
        return time.process_time() - t0, sum(len(t.actions) for t in trajs)
    finally:
        sim.close()


def bench_exploration(n: int) -> dict[str, float]:
    from navformer_rl.experts.policies import ExplorationExpert

    s = settings_for("e", "paper", seed=123, episodes_per_unit=1)
    t0, w0 = time.process_time(), time.perf_counter()
    steps = rows = 0
    for u in range(n):
        r, _, counters = C.exploration_unit(s, u)
        steps += counters["robot_steps"]
        rows += sum(x.shape[0] for x in r)
    collect_time, wall = time.process_time() - t0, time.perf_counter() - w0
    plan_time = plan_steps = 0
    env_rates = []
    for u in range(n):
        world, rng = C.exploration_world(s, u, 0)
        dt, k = _planner_only(world, rng, ExplorationExpert, s.max_steps)
        plan_time += dt
        plan_steps += k
        env_rates.append(_env_step_rate(world, 1, 60, u))
    return _summary("e", steps, rows, collect_time, wall, plan_steps / plan_time, float(np.median(env_rates)))


def bench_collision_avoidance(n: int) -> dict[str, float]:
    from navformer_rl.experts.policies import NHORCAExpert

    s = settings_for("ca", "paper", seed=123)
    t0, w0 = time.process_time(), time.perf_counter()
    steps = rows = 0
    for u in range(n):
        r, _, counters = C.collision_avoidance_unit(s, u)
        steps += counters["robot_steps"]
        rows += sum(x.shape[0] for x in r)
    collect_time, wall = time.process_time() - t0, time.perf_counter() - w0
    plan_time = plan_steps = 0
    env_rates = []
    for u in range(n):
        world, rng = C.collision_avoidance_world(s, u)
        dt, k = _planner_only(world, rng, NHORCAExpert, s.max_steps)
        plan_time += dt
        plan_steps += k
        env_rates.append(_env_step_rate(world, world.n_robots, 200, u))
    return _summary(
        "ca", steps, rows, collect_time, wall, plan_steps / plan_time, float(np.median(env_rates))
    )


def bench_ssl(n: int) -> dict[str, float]:
    from navformer_rl.envs.robots import JACKAL
    from navformer_rl.envs.sim import Simulator
    from navformer_rl.envs.world import WorldConfig, generate_world

    s = settings_for("ssl", "paper", seed=123)
    t0, w0 = time.process_time(), time.perf_counter()
    pairs = 0
    for u in range(n):
        rows, _ = C.ssl_unit(s, u)
        pairs += rows.shape[0]
    collect_time, wall = time.process_time() - t0, time.perf_counter() - w0
    # reference: two bare renders per pair in a 12.5 m maze with 14 robots (the mean of 4-25)
    world = generate_world(WorldConfig(size=12.5, n_robots=1), 7)
    from navformer_rl.envs.world import sample_start_poses

    poses = sample_start_poses(world, 14, np.random.default_rng(0), min_target_distance=0.0)
    sim = Simulator(world, [JACKAL] * 14, poses=poses)
    try:
        t1 = time.process_time()
        for _ in range(10):
            for i in range(14):
                sim.render(i)
                sim.render_pose(poses[i], JACKAL)
        ref = 140 / (time.process_time() - t1)
    finally:
        sim.close()
    return _summary("ssl", pairs, pairs, collect_time, wall, float("nan"), ref)


def _summary(kind, steps, rows, seconds, wall, planner_rate, env_rate) -> dict[str, float]:
    return {
        "kind": kind,
        "robot_steps": steps,
        "rows": rows,
        "seconds": seconds,
        "wall": wall,
        "steps_per_s": steps / seconds,
        "rows_per_s": rows / seconds,
        "planner_rate": planner_rate,
        "env_rate": env_rate,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=12, help="D_e episodes")
    parser.add_argument("--ca-episodes", type=int, default=4, help="D_ca arena episodes")
    parser.add_argument("--ssl-worlds", type=int, default=3)
    parser.add_argument("--cores", type=int, default=2, help="cores for the projection")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    results = [
        bench_exploration(args.episodes),
        bench_collision_avoidance(args.ca_episodes),
        bench_ssl(args.ssl_worlds),
    ]
    print(
        "| dataset | measured | collect: robot-steps/s/core | stored rows/s/core | planner only (no cameras) "
        "| env step alone (render + step) | collect / env step | paper-scale projection "
        f"({args.cores} cores) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    total = 0.0
    for r in results:
        unit = "pairs" if r["kind"] == "ssl" else "robot-steps"
        hours = PAPER[r["kind"]] / (r["rows_per_s"] * args.cores) / 3600
        total += hours
        planner = "-" if np.isnan(r["planner_rate"]) else f"{r['planner_rate']:,.0f}"
        print(
            f"| {DatasetKind(r['kind']).name} | {r['robot_steps']:,} {unit}, {r['seconds']:.1f} CPU s "
            f"({r['wall']:.1f} s wall) | "
            f"{r['steps_per_s']:,.1f} | {r['rows_per_s']:,.1f} | {planner} | {r['env_rate']:,.1f} | "
            f"{r['steps_per_s'] / r['env_rate']:.2f} | {hours * 60:.0f} min |"
        )
    print(f"\nall three datasets: {total * 60:.0f} min on {args.cores} cores")


if __name__ == "__main__":
    main()
