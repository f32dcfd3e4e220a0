"""The ``navformer`` command: ``demo``, ``world-demo``, ``collect``, ``train``, ``validate``,
``average-checkpoints``, ``evaluate``, ``pretrained``, ``export``.

Each subcommand is a thin layer over a library function; its parser lives next to that function
(``register(subparsers)`` in ``navformer_rl.data.cli``, ``navformer_rl.training.cli``,
``navformer_rl.training.validate_cli``, ``navformer_rl.training.average_cli``,
``navformer_rl.evaluation.cli``, ``navformer_rl.demo.cli``, ``navformer_rl.pretrained.cli``,
``navformer_rl.export.cli``). Heavy imports happen only when a subcommand runs.

Errors a user can fix (bad values, missing files) are printed as one line and exit with status 2;
set ``NAVFORMER_DEBUG=1`` to see the traceback. Ctrl-C and SIGTERM stop a command the same way (its
clean-up runs: process pools and collectors shut down, finished work stays; ``train`` first checkpoints the
iteration under way) with one line and status 130 or 143.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading
from collections.abc import Sequence

from navformer_rl.utils.durable import FolderLockedError
from navformer_rl.utils.interrupts import Terminated
from navformer_rl.utils.mp4 import VideoEncoderError

SUBCOMMAND_MODULES: tuple[str, ...] = (
    "navformer_rl.demo.cli",
    "navformer_rl.data.cli",
    "navformer_rl.training.cli",
    "navformer_rl.training.validate_cli",
    "navformer_rl.training.average_cli",
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


def _raise_terminated(signum: int, frame) -> None:
    raise Terminated()


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``navformer`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handle_sigterm = (
        threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
    )
    if handle_sigterm:
        signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        return _run(args)
    finally:
        if handle_sigterm:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _run(args: argparse.Namespace) -> int:
    """``args.run(args)``, with the user's errors and interrupts as one line and an exit status."""
    try:
        result = args.run(args)
    except USER_ERRORS as error:
        if os.environ.get("NAVFORMER_DEBUG"):
            raise
        message = error.args[0] if isinstance(error, KeyError) and error.args else error
        print(f"navformer {args.command}: error: {message}", file=sys.stderr)
        return 2
    except Exception as error:
        interrupt = _interrupted(error)
        if interrupt is None:
            raise
        return _report_interrupt(args.command, interrupt)
    except KeyboardInterrupt as interrupt:
        return _report_interrupt(args.command, interrupt)
    return int(result or 0)


def _interrupted(error: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C (or SIGTERM) ``error`` was raised while handling, if any (a context manager's exit may
    replace the ``KeyboardInterrupt`` with its own error, e.g. tensordict's ``to_module``)."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def _report_interrupt(command: str, interrupt: KeyboardInterrupt) -> int:
    """One line on stderr; 143 after SIGTERM, 130 after Ctrl-C."""
    what = "terminated" if isinstance(interrupt, Terminated) else "interrupted"
    print(f"navformer {command}: {what} (finished work is kept; rerun to resume)", file=sys.stderr)
    return 143 if isinstance(interrupt, Terminated) else 130
