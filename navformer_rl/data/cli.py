"""``navformer collect``: the dataset collection subcommand.

``register(subparsers)`` adds ``collect`` to the package CLI (``navformer_rl/cli/main.py``); this module also
runs alone: ``python -m navformer_rl.data.cli collect e --out data/e``.
"""

from __future__ import annotations

import argparse
import sys

from navformer_rl.utils import cli_args
from navformer_rl.utils.backends import add_backend_options, backend_problem, session

KINDS = ("e", "ca", "ssl", "all")

_EPILOG = """\
kinds:
  e    D_e, single-robot exploration trajectories in 5-17.5 m mazes (paper: 3,496)
  ca   D_ca, NH-ORCA trajectories in the 12.5 m arena, ego + 2-8 robots (paper: 7,467)
  ssl  D_ssl, (o^s, o^d) image pairs over worlds with 4-25 robots (paper: 98,000 over 1,000 worlds)
  all  the three, under OUT/e, OUT/ca, OUT/ssl

Interrupted? Run the same command again: finished work units are kept and the result is identical.
--worlds bookstore|cafe|house|furnished collects in Table II's furnished worlds instead of the training
worlds ('furnished' draws the kind per world), e.g. small data for fine-tuning in a new world style (paper
§VIII): --worlds furnished --robots 2 for two-robot D_ca (docs/datasets.md, "Other worlds").
DAgger (e / ca): --dagger-policy runs/navformer mixes the trained policy into the expert's driving
(the stored actions stay the expert's); then fine-tune on the aggregate, docs/datasets.md ("DAgger").
--backend ray runs each work unit as a Ray task (pip install "navformer_rl[distributed]"): a local Ray
instance with --workers CPUs, or the cluster of --ray-address / $RAY_ADDRESS (docs/datasets.md, "Ray").
"""


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``collect`` subcommand to ``subparsers``; it sets ``run`` to the handler."""
    parser = subparsers.add_parser(
        "collect",
        help="collect the offline datasets (D_e, D_ca, D_ssl)",
        description="Collect NavFormer's offline datasets with the expert planners (resumable, parallel).",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("kind", choices=KINDS, help="which dataset")
    parser.add_argument(
        "--out", type=cli_args.output_folder, required=True, help="dataset folder (for 'all': parent folder)"
    )
    parser.add_argument(
        "--scale", choices=("small", "paper"), default="small", help="dataset sizes (default: small)"
    )
    parser.add_argument("--seed", type=cli_args.seed, default=0, help="base seed (default: 0)")
    parser.add_argument(
        "--workers",
        type=cli_args.int_at_least(1),
        default=None,
        help="worker processes, or Ray tasks at once with --backend ray (default: every core this process "
        "may use)",
    )
    parser.add_argument(
        "--n",
        type=cli_args.int_at_least(1),
        default=None,
        help="override the size: trajectories for e/ca, worlds for ssl (not with 'all')",
    )
    parser.add_argument(
        "--action-noise",
        type=cli_args.number_between(0.0, 1.0),
        default=None,
        help="e / ca: std of Gaussian noise on the executed normalised actions, labels stay the expert's "
        "(DART; not in the paper; default 0)",
    )
    parser.add_argument(
        "--dagger-policy",
        metavar="CHECKPOINT",
        default=None,
        help="e / ca: DAgger (not in the paper): a NavFormer / DT checkpoint (run dir, checkpoint folder or "
        "file, pretrained:NAME) that drives the robots at the steps the expert does not; every trajectory "
        "is kept, labels stay the expert's",
    )
    parser.add_argument(
        "--dagger-beta",
        type=cli_args.number_between(0.0, 1.0),
        default=None,
        help="with --dagger-policy: probability that a robot executes the expert's action at a step "
        "(default 0.5)",
    )
    parser.add_argument(
        "--worlds",
        choices=("bookstore", "cafe", "house", "furnished"),
        default=None,
        help="collect in Table II's furnished worlds of this kind ('furnished': a kind drawn per world) "
        "instead of the paper's training worlds (default: mazes for e / ssl, the arena for ca)",
    )
    parser.add_argument(
        "--distractors",
        type=cli_args.int_at_least(0),
        default=None,
        metavar="K",
        help="e: K more targets in each maze that the robot does not seek, beside its own (not in the paper; "
        "default 0; fewer where a small maze cannot hold them)",
    )
    parser.add_argument(
        "--robots",
        type=robot_range,
        default=None,
        metavar="N|LO-HI",
        help="ca / ssl: robots per world, the ego robot included (default: the paper's, ca 3-9, ssl 4-25)",
    )
    add_backend_options(parser, "work units")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(run=run_collect)
    return parser


def run_collect(args: argparse.Namespace) -> int:
    """Handler of ``collect``; returns the exit status (errors end with a one-line message, status 2)."""
    if args.kind == "all" and args.n is not None:
        return _error("--n applies to one dataset kind, not to 'all'")
    if args.kind == "ssl" and args.action_noise is not None:
        return _error("--action-noise applies to e and ca (D_ssl has no actions)")
    if args.kind == "ssl" and args.dagger_policy is not None:
        return _error("--dagger-policy applies to e and ca (D_ssl has no actions)")
    if args.kind == "e" and args.robots is not None:
        return _error("--robots applies to ca and ssl (D_e has one robot per world)")
    if args.kind != "e" and args.distractors is not None:
        return _error(
            f"--distractors applies to e, not to {args.kind!r} (D_ca's worlds hold every robot's target)"
        )
    if args.dagger_beta is not None and args.dagger_policy is None:
        return _error("--dagger-beta needs --dagger-policy CHECKPOINT")
    if args.dagger_policy is not None and args.action_noise:
        return _error(
            "--dagger-policy and --action-noise together: choose one (the policy in the loop already takes "
            "the robots off the expert's path)"
        )
    problem = backend_problem(args)
    if problem is not None:
        return _error(problem)

    from navformer_rl.data.collect import collect, default_workers, settings_for
    from navformer_rl.data.schema import DatasetKind

    workers = default_workers() if args.workers is None else args.workers
    options = {} if args.action_noise is None else {"action_noise": args.action_noise}
    world_options = {} if args.worlds is None else {"worlds": args.worlds}
    if args.distractors is not None:
        options["distractors"] = args.distractors
    if args.dagger_policy is not None:
        from navformer_rl.data.dagger import dagger_settings

        beta = 0.5 if args.dagger_beta is None else args.dagger_beta
        try:
            options["dagger"] = dagger_settings(args.dagger_policy, beta)
        except (ValueError, FileNotFoundError) as err:
            return _error(f"--dagger-policy: {err}")
    if args.kind == "all":
        jobs = [
            (kind, args.out / kind.value, _overrides(kind, options, world_options, args.robots))
            for kind in DatasetKind
        ]
    else:
        kind = DatasetKind.parse(args.kind)
        field = "n_worlds" if kind is DatasetKind.SSL else "n_trajectories"
        size = {} if args.n is None else {field: args.n}
        jobs = [(kind, args.out, {**_overrides(kind, options, world_options, args.robots), **size})]
    try:
        with session(args.backend, workers, args.ray_address):  # one Ray session for every kind of 'all'
            for kind, out, overrides in jobs:
                settings = settings_for(kind, args.scale, args.seed, **overrides)
                path = collect(
                    kind,
                    out,
                    settings,
                    workers=workers,
                    progress=not args.no_progress,
                    backend=args.backend,
                    ray_address=args.ray_address,
                )
                print(f"{kind.value}: {path}")
    except (ValueError, FileNotFoundError, RuntimeError) as err:
        return _error(str(err))
    return 0


def robot_range(text: str) -> tuple[int, int]:
    """``--robots``: ``N`` or ``LO-HI`` robots per world (ego included), 1 <= LO <= HI."""
    lo, sep, hi = text.partition("-")
    try:
        bounds = (int(lo), int(hi) if sep else int(lo))
    except ValueError:
        bounds = (0, -1)
    if not 1 <= bounds[0] <= bounds[1]:
        raise argparse.ArgumentTypeError(f"{text!r}: expected N or LO-HI robots with 1 <= LO <= HI")
    return bounds


def _overrides(kind, options: dict, world_options: dict, robots: tuple[int, int] | None) -> dict:
    """The settings overrides of one dataset ``kind``: the action options (e / ca), the worlds, and the
    robot count (ca: ``other_robots`` excludes the ego robot; ssl: ``robots``)."""
    from navformer_rl.data.schema import DatasetKind

    overrides = {**world_options} if kind is DatasetKind.SSL else {**options, **world_options}
    if robots is not None and kind is DatasetKind.COLLISION_AVOIDANCE:
        overrides["other_robots"] = (robots[0] - 1, robots[1] - 1)
    elif robots is not None and kind is DatasetKind.SSL:
        overrides["robots"] = robots
    return overrides


def _error(message: str) -> int:
    print(f"navformer collect: error: {message}", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="navformer")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    raise SystemExit(main())
