"""``navformer export minari``: write D_e or D_ca as a Minari dataset
(:func:`navformer_rl.export.minari.export_minari`).

Examples::

    navformer export minari data/e --id navformer/e-small-v0 --root ~/minari
    MINARI_DATASETS_PATH=~/minari \
        python -c "import minari; print(minari.load_dataset('navformer/e-small-v0'))"
"""

from __future__ import annotations

import argparse
import sys

from navformer_rl.export.minari import DATASETS_PATH_ENV, DEFAULT_CHUNK_STEPS, INSTALL_HINT
from navformer_rl.utils import cli_args

_EPILOG = f"""\
examples:
  navformer export minari data/e --id navformer/e-small-v0 --root ~/minari
  navformer export minari data/ca --id navformer/ca-small-v0 --root ~/minari --force

open the result with MINARI_DATASETS_PATH=~/minari set:
  minari.load_dataset("navformer/e-small-v0")
  navformer_rl.export.minari_replay_buffer("navformer/e-small-v0", 32)  # TorchRL's MinariExperienceReplay,
      # its rows filled (TorchRL 0.14.1's alone serves zeros)

needs the optional extra: {INSTALL_HINT}. docs/datasets.md#minari
"""


def register(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``export`` subcommand (format ``minari``) to the ``navformer`` CLI."""
    parser = subparsers.add_parser(
        "export",
        help="write a dataset in another tool's format (minari)",
        description="Write a collected dataset in another tool's format.",
    )
    formats = parser.add_subparsers(dest="format", metavar="FORMAT", required=True)
    minari = formats.add_parser(
        "minari",
        help="D_e or D_ca as a Minari dataset (one trajectory per episode)",
        description="Write a D_e or D_ca folder as a Minari dataset (HDF5, images stored raw), which "
        "minari.load_dataset and TorchRL's MinariExperienceReplay (through minari_replay_buffer) open.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    minari.add_argument("dataset", metavar="DATASET", help="a D_e or D_ca folder (navformer collect e|ca)")
    minari.add_argument(
        "--id", dest="dataset_id", required=True, metavar="NAMESPACE/NAME-vN", help="the Minari dataset id"
    )
    minari.add_argument(
        "--root",
        type=cli_args.output_folder,
        default=None,
        metavar="DIR",
        help=f"Minari datasets folder (default: ${DATASETS_PATH_ENV}, else ~/.minari/datasets)",
    )
    minari.add_argument("--force", action="store_true", help="replace a Minari dataset with the same id")
    minari.add_argument(
        "--chunk-steps",
        type=cli_args.int_at_least(1),
        default=DEFAULT_CHUNK_STEPS,
        metavar="N",
        help=f"steps held in memory per written chunk (default: {DEFAULT_CHUNK_STEPS})",
    )
    minari.add_argument("--author", default="navformer_rl", help="Minari 'author' (default: navformer_rl)")
    minari.add_argument(
        "--verify", action="store_true", help="check the dataset's files against their sha256 first"
    )
    minari.add_argument("--no-progress", action="store_true", help="no progress bar")
    minari.set_defaults(run=_run_minari)
    return parser


def _run_minari(args: argparse.Namespace) -> int:
    """Handler of ``export minari``; user errors end as one line on stderr (status 2)."""
    from navformer_rl.export.minari import MinariNotInstalledError, export_minari

    try:
        folder = export_minari(
            args.dataset,
            args.dataset_id,
            args.root,
            force=args.force,
            chunk_steps=args.chunk_steps,
            author=args.author,
            verify=args.verify,
            progress=not args.no_progress,
        )
    except MinariNotInstalledError as error:
        print(f"navformer {args.command}: error: {error}", file=sys.stderr)
        return 2
    print(f"{args.dataset_id}: {folder}")
    return 0
