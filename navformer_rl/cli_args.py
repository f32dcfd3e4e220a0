"""Argument types shared by the ``navformer`` subcommands (argparse reports their errors in one line)."""

from __future__ import annotations

import argparse


def seed(text: str) -> int:
    """A seed: an integer >= 0 (numpy's generators refuse negative ones)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer seed, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer seed, got {value}")
    return value
