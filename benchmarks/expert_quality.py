"""Expert quality on seeded episodes (a measurement script, not a test).

Exploration expert (frontier + A* + DWA, one robot) in random mazes of 7.5 / 12.5 / 17.5 m, and NH-ORCA teams
of 3-9 robots in the 12.5 m collision-avoidance arena; optionally FCA teams in mazes. No rendering.
Success = the robot came within ``SUCCESS_RADIUS`` (1.5 m) of its target centre within 500 steps.

    OMP_NUM_THREADS=1 python benchmarks/expert_quality.py --episodes 100 --out benchmarks/experts.md

Prints a markdown section ("## Expert quality") with the table, the machine and the command; with
``--out FILE`` it also writes it into FILE (atomically), replacing only that section when FILE already has one
and appending it otherwise, so the other sections of ``benchmarks/experts.md`` stay.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from navformer_rl.constants import MAX_EPISODE_STEPS, SUCCESS_RADIUS
from navformer_rl.envs.robots import JACKAL
from navformer_rl.envs.sim import COLLISION_ROBOT, COLLISION_WALL, Simulator
from navformer_rl.envs.world import WorldConfig, generate_world
from navformer_rl.experts.policies import ExplorationExpert, FCAController, NHORCAExpert


def run_episode(expert, world, seed: int) -> dict:
    """Roll one episode; returns per-episode statistics."""
    sim = Simulator(world, JACKAL, textured=False)
    try:
        expert.reset(world, sim, np.random.default_rng(seed))
        n = sim.n_robots
        targets = world.target_positions.astype(np.float64)
        success = np.zeros(n, dtype=bool)
        robot_hits = np.zeros(n, dtype=np.int64)
        wall_hits = np.zeros(n, dtype=np.int64)
        plan_time, robot_steps, steps = 0.0, 0, 0
        for t in range(MAX_EPISODE_STEPS):
            active = ~success & ~expert.failed
            if not active.any():
                break
            t0 = time.perf_counter()
            actions = expert.act(sim, active)
            plan_time += time.perf_counter() - t0
            robot_steps += int(active.sum())
            contacts = sim.step(actions, active)
            robot_hits += contacts.kind == COLLISION_ROBOT
            wall_hits += contacts.kind == COLLISION_WALL
            success |= np.hypot(*(sim.poses[:, :2] - targets).T) <= SUCCESS_RADIUS
            steps = t + 1
        return {
            "seed": seed,
            "robots": n,
            "success": success.tolist(),
            "steps": steps,
            "robot_collision_steps": robot_hits.tolist(),
            "wall_collision_steps": wall_hits.tolist(),
            "stuck_events": getattr(expert, "stuck_events", np.zeros(n, dtype=np.int64)).tolist(),
            "ms_per_robot_step": 1000.0 * plan_time / max(robot_steps, 1),
        }
    finally:
        sim.close()


def exploration(size: float, episodes: int, seed0: int) -> list[dict]:
    out = []
    for k in range(episodes):
        seed = seed0 + k
        world = generate_world(WorldConfig(size=size, kind="maze", n_robots=1), seed)
        out.append(run_episode(ExplorationExpert(), world, seed))
    return out


def collision_avoidance(
    episodes: int, seed0: int, expert_cls=NHORCAExpert, kind="arena", size=12.5
) -> list[dict]:
    out = []
    for k in range(episodes):
        seed = seed0 + k
        n = 3 + k % 7  # 3..9 robots, evenly
        world = generate_world(WorldConfig(size=size, kind=kind, n_robots=n), seed)
        out.append(run_episode(expert_cls(), world, seed))
    return out


def summarise(rows: list[dict]) -> dict:
    eps = len(rows)
    all_success = np.array([all(r["success"]) for r in rows])
    robot_success = np.concatenate([r["success"] for r in rows])
    any_robot_coll = np.array([sum(r["robot_collision_steps"]) > 0 for r in rows])
    any_wall_coll = np.array([sum(r["wall_collision_steps"]) > 0 for r in rows])
    steps = np.array([r["steps"] for r in rows])
    return {
        "episodes": eps,
        "episode_success": float(all_success.mean()),
        "robot_success": float(robot_success.mean()),
        "robot_collision_episodes": float(any_robot_coll.mean()),
        "wall_contact_episodes": float(any_wall_coll.mean()),
        "median_steps_success": float(np.median(steps[all_success])) if all_success.any() else float("nan"),
        "ms_per_robot_step_median": float(np.median([r["ms_per_robot_step"] for r in rows])),
        "failed_seeds": [r["seed"] for r, ok in zip(rows, all_success) if not ok],
    }


def atomic_write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


SECTION_HEADING = "## Expert quality"


def replace_section(document: str, section: str) -> str:
    """``document`` with its :data:`SECTION_HEADING` section (up to the next ``## `` heading) replaced by
    ``section``, or with ``section`` appended when it has none."""
    lines = document.splitlines()
    if SECTION_HEADING not in lines:
        return (document.rstrip("\n") + "\n\n" if document.strip() else "") + section.rstrip("\n") + "\n"
    start = lines.index(SECTION_HEADING)
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
    kept_after = "\n".join(lines[end:])
    before = "\n".join(lines[:start])
    parts = [part for part in (before, section.rstrip("\n"), kept_after) if part]
    return "\n\n".join(part.strip("\n") for part in parts) + "\n"


def pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=10_000, help="first world seed")
    parser.add_argument("--sizes", type=float, nargs="*", default=[7.5, 12.5, 17.5])
    parser.add_argument("--skip-ca", action="store_true")
    parser.add_argument("--fca", action="store_true", help="also run FCA teams (3-9 robots) in 12.5 m mazes")
    parser.add_argument(
        "--out", type=Path, default=None, help="markdown file whose '## Expert quality' section to replace"
    )
    parser.add_argument("--json", type=Path, default=None, help="also write raw per-episode rows here")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")

    results: dict[str, dict] = {}
    raw: dict[str, list[dict]] = {}
    t_start = time.time()
    for size in args.sizes:
        key = f"exploration maze {size:g} m (1 robot)"
        raw[key] = exploration(size, args.episodes, args.seed)
        results[key] = summarise(raw[key])
        print(key, json.dumps(results[key]), flush=True)
    if not args.skip_ca:
        key = "NH-ORCA arena 12.5 m (3-9 robots)"
        raw[key] = collision_avoidance(args.episodes, args.seed)
        results[key] = summarise(raw[key])
        print(key, json.dumps(results[key]), flush=True)
    if args.fca:
        key = "FCA maze 12.5 m (3-9 robots)"
        raw[key] = collision_avoidance(args.episodes, args.seed, FCAController, "maze")
        results[key] = summarise(raw[key])
        print(key, json.dumps(results[key]), flush=True)
    elapsed = time.time() - t_start

    lines = [
        SECTION_HEADING,
        "",
        f"Seeded episodes (world seeds {args.seed}..{args.seed + args.episodes - 1}), no rendering, success "
        f"= within {SUCCESS_RADIUS} m of the target within {MAX_EPISODE_STEPS} steps. Team "
        "episodes use 3 + k mod 7 robots.",
        "",
        "| setting | episodes | all robots succeed | robots succeed | episodes with robot-robot collision "
        "| episodes with wall contact | median steps (successes) | planner ms / robot-step (median) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for key, r in results.items():
        lines.append(
            f"| {key} | {r['episodes']} | {pct(r['episode_success'])} | {pct(r['robot_success'])} | "
            f"{pct(r['robot_collision_episodes'])} | {pct(r['wall_contact_episodes'])} | "
            f"{r['median_steps_success']:.0f} | {r['ms_per_robot_step_median']:.2f} |"
        )
    lines += [""]
    for key, r in results.items():
        if r["failed_seeds"]:
            lines.append(f"- {key}: failed seeds {r['failed_seeds']}")
    lines += [
        "",
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs (shared with "
        f"other jobs), Python {platform.python_version()}, "
        f"numpy {np.__version__}. Wall time {elapsed / 60:.1f} min.",
        "",
        "Command: `OMP_NUM_THREADS=1 python "
        + " ".join(["benchmarks/expert_quality.py", *sys.argv[1:]])
        + "`",
        "",
    ]
    section = "\n".join(lines)
    print(section)
    if args.out is not None:
        previous = args.out.read_text() if args.out.exists() else ""
        atomic_write(args.out, replace_section(previous, section))
    if args.json is not None:
        atomic_write(args.json, json.dumps({"summary": results, "episodes": raw}, indent=1))


if __name__ == "__main__":
    main()
