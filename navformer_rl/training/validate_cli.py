"""``navformer validate``: the teacher-forced action loss of trained checkpoints on held-out trajectories.

The offline form of training's ``validation.*`` (:func:`navformer_rl.training.validation.score_checkpoints`)::

    navformer validate --checkpoint runs/nf/checkpoints/iter_* \\
        --exploration data/val_e --collision data/val_ca
"""

from __future__ import annotations

import argparse

from navformer_rl.utils import cli_args

EPILOG = """\
examples:
  navformer validate --checkpoint runs/navformer --exploration data/val_e --collision data/val_ca
  navformer validate --checkpoint runs/navformer/checkpoints/iter_* runs/dt --collision data/val_ca \\
      --json val.json

Eq. 10 (squared action error summed over the action dims, averaged over every valid step) with the model in
eval mode, one window per trajectory (seeded, as training's validation.seed). docs/training.md
"""


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``validate`` subcommand to the ``navformer`` CLI."""
    parser = subparsers.add_parser(
        "validate",
        help="teacher-forced action loss (eq. 10) of checkpoints on held-out D_e / D_ca",
        description="Score trained checkpoints on expert trajectories they did not train on: the action "
        "loss of eq. 10 in eval mode, on the same fixed windows for every checkpoint.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--checkpoint",
        nargs="+",
        required=True,
        metavar="PATH",
        help=(
            "run directories (their latest checkpoint), checkpoint folders "
            "(e.g. runs/nf/checkpoints/iter_*) or shipped weights (pretrained:navformer, pretrained:dt)"
        ),
    )
    parser.add_argument("--exploration", metavar="DIR", help="a D_e dataset folder (held out)")
    parser.add_argument("--collision", metavar="DIR", help="a D_ca dataset folder (held out)")
    parser.add_argument(
        "--batch-trajs", type=cli_args.int_at_least(1), default=16, help="trajectories per forward pass (16)"
    )
    parser.add_argument(
        "--max-trajectories",
        type=cli_args.int_at_least(1),
        default=None,
        help="a seeded subset of this many per dataset (all)",
    )
    parser.add_argument("--seed", type=cli_args.seed, default=0, help="subsets and window offsets (0)")
    parser.add_argument(
        "--context-steps",
        type=cli_args.int_at_least(1),
        default=None,
        help="windows of at most this many steps for every checkpoint (default: the model's whole window, "
        "256 steps; give the W of checkpoints trained with data.context_steps=W)",
    )
    parser.add_argument("--device", default="cpu", help="cpu (default), cuda, cuda:N or auto")
    parser.add_argument("--json", metavar="FILE", help="also write the rows as JSON to FILE")
    parser.set_defaults(run=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Score every checkpoint; print a markdown table (and write ``--json``)."""
    import json

    from navformer_rl.training.validation import score_checkpoints
    from navformer_rl.utils.durable import atomic_write_text

    datasets = {kind: path for kind, path in (("e", args.exploration), ("ca", args.collision)) if path}
    if not datasets:
        raise ValueError(
            "give --exploration DIR and / or --collision DIR: the held-out trajectories to score"
        )
    rows = score_checkpoints(
        args.checkpoint,
        datasets,
        batch_trajs=args.batch_trajs,
        max_trajectories=args.max_trajectories,
        seed=args.seed,
        device=args.device,
        context_steps=args.context_steps,
    )
    losses = [key for key in rows[0] if key.startswith("loss_dt_")]
    print("| checkpoint | iteration | " + " | ".join(losses) + " |")
    print("|---|---|" + "---|" * len(losses))
    for row in rows:
        print(
            f"| {row['checkpoint']} | {row['iteration']} | "
            + " | ".join(f"{row[k]:.4f}" for k in losses)
            + " |"
        )
    if args.json:
        atomic_write_text(args.json, json.dumps(rows, indent=2) + "\n")
        print(f"rows written to {args.json}")
    return 0
