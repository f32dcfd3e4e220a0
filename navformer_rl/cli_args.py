"""Argument types shared by the ``navformer`` subcommands (argparse reports their errors in one line)."""

from __future__ import annotations

import argparse
from pathlib import Path


def seed(text: str) -> int:
    """A seed: an integer >= 0 (numpy's generators refuse negative ones)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer seed, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer seed, got {value}")
    return value


def output_folder(text: str) -> Path:
    """An output folder: missing (it is created) or an existing folder, not a file."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a file; expected a folder (created if missing)")
    return path
