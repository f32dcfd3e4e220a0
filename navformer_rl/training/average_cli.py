"""``navformer average-checkpoints``: one checkpoint whose weights are the mean of several of one run's
(:func:`navformer_rl.training.averaging.average_checkpoints`)::

    navformer average-checkpoints --run runs/navformer --first 9000 --last 10000 --out runs/navformer_avg
"""

from __future__ import annotations

import argparse

from navformer_rl.utils import cli_args

EPILOG = """\
examples:
  navformer average-checkpoints --run runs/navformer --first 9000 --last 10000 --out runs/navformer_avg
  navformer average-checkpoints --checkpoint runs/nf/checkpoints/iter_00{90,95}00 runs/nf --out runs/nf_avg
  navformer evaluate --method navformer --checkpoint runs/navformer_avg --protocol table1 --out runs/eval/avg

An opt-in beyond the paper (stochastic / latest weight averaging): the uniform mean of the checkpoints'
weights, written as a checkpoint every --checkpoint option accepts. docs/training.md
"""


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``average-checkpoints`` subcommand to the ``navformer`` CLI."""
    parser = subparsers.add_parser(
        "average-checkpoints",
        help="average the weights of several checkpoints of one run into one checkpoint",
        description="Write the uniform mean of the weights of two or more checkpoints of one training run "
        "as a checkpoint folder (config.json + model.safetensors).",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sources = parser.add_mutually_exclusive_group(required=True)
    sources.add_argument(
        "--checkpoint",
        nargs="+",
        metavar="PATH",
        help="the checkpoints to average: checkpoint folders or run directories (their latest checkpoint)",
    )
    sources.add_argument(
        "--run",
        dest="run_dir",
        metavar="DIR",
        help="a run directory: average its regular checkpoints (multiples of its checkpoint.interval) from "
        "--first to --last",
    )
    parser.add_argument(
        "--first", type=cli_args.int_at_least(0), metavar="ITERATION", help="with --run: the first iteration"
    )
    parser.add_argument(
        "--last", type=cli_args.int_at_least(0), metavar="ITERATION", help="with --run: the last iteration"
    )
    parser.add_argument(
        "--out",
        required=True,
        type=cli_args.output_folder,
        metavar="DIR",
        help="the checkpoint folder to write",
    )
    parser.add_argument("--force", action="store_true", help="replace an existing --out")
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Select the checkpoints, average them, print what was written."""
    from navformer_rl.training.averaging import average_checkpoints, run_checkpoints
    from navformer_rl.training.checkpoint import read_checkpoint_config

    if args.run_dir is not None:
        if args.first is None or args.last is None:
            raise ValueError("--run needs --first and --last (the iterations to average between)")
        checkpoints = run_checkpoints(args.run_dir, args.first, args.last)
    else:
        if args.first is not None or args.last is not None:
            raise ValueError(
                "--first / --last select checkpoints of --run; with --checkpoint list them instead"
            )
        checkpoints = args.checkpoint
    out = average_checkpoints(checkpoints, args.out, overwrite=args.force)
    sources = read_checkpoint_config(out)["run"]["averaged_from"]
    iterations = ", ".join(str(source["iteration"]) for source in sources)
    print(f"averaged {len(sources)} checkpoints (iterations {iterations}) -> {out}")
    return 0
