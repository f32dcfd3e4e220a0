"""Argument types shared by the ``navformer`` subcommands (argparse reports their errors in one line)."""

from __future__ import annotations

import argparse
from pathlib import Path

from navformer_rl.checks import check_seed


def seed(text: str) -> int:
    """A seed: an integer >= 0 (:func:`navformer_rl.checks.check_seed`; numpy's generators refuse negative
    ones)."""
    try:
        value: int | str = int(text)
    except ValueError:
        value = text  # not an integer: check_seed quotes the text
    try:
        return check_seed(value)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def output_folder(text: str) -> Path:
    """An output folder: missing (it is created) or an existing folder, not a file."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a file; expected a folder (created if missing)")
    return path
