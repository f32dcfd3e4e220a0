"""The ``navformer`` command: ``demo``, ``world-demo``, ``collect``, ``train``, ``validate``, ``evaluate``,
``pretrained``, ``export``.

Each subcommand is a thin layer over a library function; its parser lives next to that function
(``register(subparsers)`` in ``navformer_rl.data.cli``, ``navformer_rl.training.cli``,
``navformer_rl.training.validate_cli``, ``navformer_rl.evaluation.cli``, ``navformer_rl.demo.cli``,
``navformer_rl.pretrained.cli``, ``navformer_rl.export.cli``). Heavy imports
happen only when a subcommand runs.

Errors a user can fix (bad values, missing files) are printed as one line and exit with status 2;
set ``NAVFORMER_DEBUG=1`` to see the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from navformer_rl.utils.durable import FolderLockedError
from navformer_rl.utils.mp4 import VideoEncoderError

SUBCOMMAND_MODULES: tuple[str, ...] = (
    "navformer_rl.demo.cli",
    "navformer_rl.data.cli",
    "navformer_rl.training.cli",
    "navformer_rl.training.validate_cli",
    "navformer_rl.online.cli",
    "navformer_rl.evaluation.cli",
    "navformer_rl.pretrained.cli",
    "navformer_rl.export.cli",
)

USER_ERRORS = (
    ValueError,
    FileNotFoundError,
    FileExistsError,
    NotADirectoryError,
    PermissionError,
    KeyError,
    FolderLockedError,
    VideoEncoderError,
)


def build_parser() -> argparse.ArgumentParser:
    """Return the ``navformer`` parser with every subcommand registered."""
    from navformer_rl import __version__

    parser = argparse.ArgumentParser(
        prog="navformer",
        description="NavFormer target-driven navigation: worlds, expert datasets, training, evaluation.",
    )
    parser.add_argument("--version", action="version", version=f"navformer_rl {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module_name in SUBCOMMAND_MODULES:
        importlib.import_module(module_name).register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``navformer`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        result = args.run(args)
    except USER_ERRORS as error:
        if os.environ.get("NAVFORMER_DEBUG"):
            raise
        message = error.args[0] if isinstance(error, KeyError) and error.args else error
        print(f"navformer {args.command}: error: {message}", file=sys.stderr)
        return 2
    except Exception as error:
        if not _interrupted(error):
            raise
        return _report_interrupt(args.command)
    except KeyboardInterrupt:
        return _report_interrupt(args.command)
    return int(result or 0)


def _interrupted(error: BaseException) -> bool:
    """Whether ``error`` was raised while handling a Ctrl-C (a context manager's exit may replace the
    ``KeyboardInterrupt`` with its own error, e.g. tensordict's ``to_module``)."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


def _report_interrupt(command: str) -> int:
    print(f"navformer {command}: interrupted (finished work is kept; rerun to resume)", file=sys.stderr)
    return 130
