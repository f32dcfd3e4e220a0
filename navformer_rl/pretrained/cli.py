"""``navformer pretrained``: list the shipped weights, or ship a trained run (:mod:`navformer_rl.pretrained`).

Examples::

    navformer pretrained list
    navformer pretrained export --checkpoint runs/navformer --name navformer \\
        --evaluation runs/eval/navformer --card card.json
"""

from __future__ import annotations

import argparse

EPILOG = """\
examples:
  navformer pretrained list
  navformer pretrained export --checkpoint runs/navformer --name navformer --evaluation runs/eval/nf \\
      --card card.json
  navformer evaluate --method navformer --checkpoint pretrained:navformer --protocol table1 \\
      --out runs/eval/shipped

card.json holds the card's prose only: {"summary": "...", "hardware": "...", "failure_modes": ["..."],
"notes": ["..."]}; every number on the card is read from the run and evaluation folders. docs/pretrained.md
"""


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``pretrained`` subcommand (``list``, ``export``) to the ``navformer`` CLI."""
    parser = subparsers.add_parser(
        "pretrained",
        help="list the shipped weights (pretrained:NAME), or ship a trained run",
        description="Shipped weights are used as --checkpoint pretrained:NAME; `export` ships a trained run "
        "with its model card.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    listing = actions.add_parser(
        "list", help="the shipped names, their method and whether their files check out"
    )
    listing.set_defaults(run=_run_list)
    export = actions.add_parser(
        "export",
        help="copy a checkpoint's weights into the pretrained folder with a model card and registry entry",
    )
    export.add_argument("--checkpoint", required=True, help="a run dir or checkpoint folder to ship")
    export.add_argument("--name", required=True, help="the shipped name, e.g. navformer, dt")
    export.add_argument(
        "--evaluation",
        nargs="*",
        default=[],
        metavar="DIR",
        help="`navformer evaluate` folders of this checkpoint: their results go on the card",
    )
    export.add_argument("--card", metavar="FILE", help="JSON file with the card's prose (see below)")
    export.add_argument(
        "--out",
        metavar="DIR",
        help="pretrained folder to write into (default: the package's, or $NAVFORMER_PRETRAINED_DIR)",
    )
    export.add_argument("--force", action="store_true", help="replace weights already shipped under --name")
    export.set_defaults(run=_run_export)
    return parser


def _run_list(args: argparse.Namespace) -> int:
    from navformer_rl.pretrained import pretrained_root, read_registry, resolve_pretrained

    root = pretrained_root()
    models = read_registry(root)
    print(f"pretrained folder: {root}")
    if not models:
        print("no shipped weights")
        return 0
    print("| name | method | files |")
    print("|---|---|---|")
    for name, entry in sorted(models.items()):
        try:
            resolve_pretrained(name, root)
            state = "ok"
        except (ValueError, FileNotFoundError) as error:
            state = f"error: {error}"
        print(f"| pretrained:{name} | {entry.get('method')} | {state} |")
    return 0


def _run_export(args: argparse.Namespace) -> int:
    from navformer_rl.pretrained.export import write_pretrained

    folder = write_pretrained(
        args.checkpoint,
        args.name,
        evaluations=args.evaluation,
        card=args.card,
        out_dir=args.out,
        overwrite=args.force,
    )
    print(f"shipped pretrained:{args.name} in {folder} (model card: {folder / 'MODEL_CARD.md'})")
    return 0
