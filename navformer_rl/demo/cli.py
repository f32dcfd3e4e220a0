"""``navformer demo`` and ``navformer world-demo``: argument parsing over
:func:`~navformer_rl.demo.pipeline.run_demo` and :func:`~navformer_rl.envs.demo.run_world_demo`."""

from __future__ import annotations

import argparse
from pathlib import Path

from navformer_rl.demo.config import BASELINES, TRAINED_METHODS, DemoConfig
from navformer_rl.demo.pipeline import run_demo
from navformer_rl.utils import cli_args


def _demo_config_from_args(args: argparse.Namespace) -> DemoConfig:
    overrides = {
        name: getattr(args, name)
        for name in ("seed", "workers", "iterations")
        if getattr(args, name, None) is not None
    }
    if args.methods:
        overrides["methods"] = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    if args.no_shipped:
        overrides["shipped"] = ()
    return DemoConfig.preset(args.preset, out_dir=Path(args.out), **overrides)


def _run_demo_command(args: argparse.Namespace) -> int:
    cfg = _demo_config_from_args(args)
    run_demo(cfg, progress=not args.no_progress)
    return 0


def _run_world_demo_command(args: argparse.Namespace) -> int:
    from navformer_rl.envs.demo import run_world_demo

    paths = run_world_demo(
        args.out,
        size=args.size,
        n_robots=args.robots,
        steps=args.steps,
        seed=args.seed,
        progress=not args.no_progress,
    )
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``demo`` and ``world-demo`` to the ``navformer`` CLI."""
    demo = subparsers.add_parser(
        "demo",
        help="end to end: collect -> train -> evaluate -> report (8-15 min on 2 CPU cores)",
        description="Collect small D_e / D_ca / D_ssl with the experts, train NavFormer and the DT baseline, "
        "evaluate them with VRW and FCA on fixed episodes, and write report.md in --out. Rerun the same "
        "command to resume after an interruption.",
    )
    demo.add_argument(
        "--out", type=cli_args.output_folder, default="runs/demo", help="run folder (default runs/demo)"
    )
    demo.add_argument(
        "--preset",
        default="default",
        choices=("default", "quick"),
        help="default: 8-15 min on 2 cores; quick: a few minutes, a smoke check",
    )
    demo.add_argument("--seed", type=cli_args.seed, help="base seed (default 0)")
    demo.add_argument(
        "--workers", type=cli_args.int_at_least(1), help="processes for collection and evaluation (default 2)"
    )
    demo.add_argument("--iterations", type=cli_args.int_at_least(1), help="training iterations per model")
    demo.add_argument("--methods", help=f"comma-separated subset of {','.join(TRAINED_METHODS + BASELINES)}")
    demo.add_argument(
        "--no-shipped",
        action="store_true",
        help="do not evaluate the shipped NavFormer (pretrained:navformer) beside the models trained here",
    )
    demo.add_argument("--no-progress", action="store_true", help="no progress bars")
    demo.set_defaults(run=_run_demo_command)

    world = subparsers.add_parser(
        "world-demo",
        help="a seeded maze with moving robots: top-down map + egocentric video",
        description="Generate a seeded maze with several robots, drive them with the goal-seeking obstacle "
        "policy, and write map.png (trajectories) and egocentric.mp4 into --out.",
    )
    world.add_argument(
        "--out",
        type=cli_args.output_folder,
        default="runs/world-demo",
        help="output folder (default runs/world-demo)",
    )
    world.add_argument("--size", type=float, default=12.5, help="maze side in metres, 5-17.5 (default 12.5)")
    world.add_argument(
        "--robots", type=cli_args.int_at_least(1), default=4, help="number of robots (default 4)"
    )
    world.add_argument(
        "--steps", type=cli_args.int_at_least(1), default=200, help="steps of 0.2 s (default 200)"
    )
    world.add_argument("--seed", type=cli_args.seed, default=0, help="world seed (default 0)")
    world.add_argument("--no-progress", action="store_true", help="no progress bar")
    world.set_defaults(run=_run_world_demo_command)
