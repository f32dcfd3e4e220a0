"""Env step cost against the bare 84x84 render of the same scene (issue 2's performance goal: <= 15 %).

For each world size and robot count, the script steps an env with uniform random actions and, right
after every step, times the bare camera render(s) of the very same scene. It reports medians over all
timed steps of the wall-clock time and of the thread's CPU time (robust on a shared machine), the time
spent in the renders inside the step, the env's own work (step minus those renders) and the overhead
``step / bare render - 1``:

- ``TargetNavEnv`` (gymnasium): robot 0 renders one camera; the other robots are driven by the default
  goal-seeking obstacle policy (their planning is part of the step).
- ``MultiRobotNavEnv`` (TorchRL): every robot renders its camera; ``env.step`` includes building the
  output TensorDict (the caller's ``step_mdp`` is not timed).

Run: ``OMP_NUM_THREADS=1 python benchmarks/bench_env.py [--steps 300] [--sizes 7.5 12.5 17.5] [--robots 1 4]``
(prints a markdown table).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np
import torch
from torchrl.envs.utils import step_mdp

from navformer_rl.envs.multi_robot import MultiRobotNavEnv
from navformer_rl.envs.target_nav import TargetNavEnv


class _Timer:
    """Collects wall-clock (``perf_counter``) and thread CPU (``thread_time``) durations per label."""

    def __init__(self) -> None:
        self.samples: dict[str, list[float]] = {}
        self._label, self._keep, self._start = "", False, (0.0, 0.0)

    def __call__(self, label: str, keep: bool) -> _Timer:
        self._label, self._keep = label, keep
        return self

    def __enter__(self) -> None:
        self._start = (time.perf_counter(), time.thread_time())

    def __exit__(self, *exc) -> None:
        if self._keep:
            wall, cpu = time.perf_counter() - self._start[0], time.thread_time() - self._start[1]
            self.samples.setdefault(f"{self._label}_wall", []).append(wall)
            self.samples.setdefault(f"{self._label}_cpu", []).append(cpu)

    def medians(self) -> dict[str, float]:
        return {key: statistics.median(values) for key, values in self.samples.items()}


class _RenderMeter:
    """Sums the wall and CPU time spent in ``Simulator.render_pose`` (every camera render goes through it)."""

    def __init__(self) -> None:
        self.wall = self.cpu = 0.0

    def attach(self, sim) -> None:
        original = sim.render_pose

        def timed(pose, spec):
            wall, cpu = time.perf_counter(), time.thread_time()
            try:
                return original(pose, spec)
            finally:
                self.wall += time.perf_counter() - wall
                self.cpu += time.thread_time() - cpu

        sim.render_pose = timed

    def take(self) -> tuple[float, float]:
        out = (self.wall, self.cpu)
        self.wall = self.cpu = 0.0
        return out


def _record(timer: _Timer, meter: _RenderMeter, keep: bool) -> None:
    wall, cpu = meter.take()
    if keep:
        timer.samples.setdefault("in_step_wall", []).append(wall)
        timer.samples.setdefault("in_step_cpu", []).append(cpu)


def bench_gym(size: float, n_robots: int, steps: int, seed: int) -> dict[str, float]:
    """Median wall and CPU seconds of ``env.step``, of the renders inside it, and of the bare ``render(0)``
    of the same scene right after."""
    env = TargetNavEnv(size=size, n_robots=n_robots)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    timer, meter = _Timer(), _RenderMeter()
    meter.attach(env.simulator)
    for k in range(steps + 10):
        action = rng.uniform(-1, 1, 2).astype(np.float32)
        meter.take()
        with timer("step", k >= 10):  # 10 warm-up steps
            _, _, terminated, truncated, _ = env.step(action)
        _record(timer, meter, k >= 10)
        with timer("render", k >= 10):
            env.simulator.render(0)
        if terminated or truncated:
            env.reset()
            meter.attach(env.simulator)  # a new world has a new simulator
    env.close()
    return timer.medians()


def bench_multi(size: float, n_robots: int, steps: int, seed: int) -> dict[str, float]:
    """Median wall and CPU seconds of ``env.step``, of the renders inside it, and of the bare ``render_all``
    of the same scene right after."""
    env = MultiRobotNavEnv(size=size, n_robots=n_robots, seed=seed)
    generator = torch.Generator().manual_seed(seed)
    td = env.reset()
    timer, meter = _Timer(), _RenderMeter()
    meter.attach(env.simulator)
    for k in range(steps + 10):
        td["agents", "action"] = torch.rand(n_robots, 2, generator=generator) * 2 - 1
        rendering = ~td["privileged", "success"].squeeze(-1).numpy()  # the robots the step renders
        meter.take()
        with timer("step", k >= 10):
            td = env.step(td)
        _record(timer, meter, k >= 10)
        td = step_mdp(td)  # the caller's loop, not the env: untimed
        with timer("render", k >= 10):
            env.simulator.render_all(rendering)
        if td["done"].item():
            td = env.reset()
            meter.attach(env.simulator)
    env.close()
    return timer.medians()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300, help="timed steps per configuration")
    parser.add_argument("--sizes", type=float, nargs="+", default=[7.5, 12.5, 17.5])
    parser.add_argument("--robots", type=int, nargs="+", default=[1, 4])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"python {platform.python_version()}"
    )
    print(f"steps per row: {args.steps} (after 10 warm-up steps), uniform random actions, seed {args.seed}\n")
    print(
        "| env | size (m) | robots | cameras | step CPU (ms) | renders in step CPU (ms) | env work CPU (ms) "
        "| bare render CPU (ms) | overhead CPU vs bare | step wall (ms) | "
        "bare render wall (ms) | overhead wall |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, bench in (("TargetNavEnv (gymnasium)", bench_gym), ("MultiRobotNavEnv (TorchRL)", bench_multi)):
        for size in args.sizes:
            for n in args.robots:
                m = bench(size, n, args.steps, args.seed)
                cameras = 1 if bench is bench_gym else n
                cells = [name, f"{size:g}", str(n), str(cameras)]
                cells += [f"{m['step_cpu'] * 1e3:.2f}", f"{m['in_step_cpu'] * 1e3:.2f}"]
                cells += [f"{(m['step_cpu'] - m['in_step_cpu']) * 1e3:.2f}", f"{m['render_cpu'] * 1e3:.2f}"]
                cells += [f"{100 * (m['step_cpu'] / m['render_cpu'] - 1):+.1f} %"]
                cells += [f"{m['step_wall'] * 1e3:.2f}", f"{m['render_wall'] * 1e3:.2f}"]
                cells += [f"{100 * (m['step_wall'] / m['render_wall'] - 1):+.1f} %"]
                print("| " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
