"""Argument types shared by the ``navformer`` subcommands (argparse reports their errors in one line)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

from navformer_rl.utils.checks import check_seed


def seed(text: str) -> int:
    """A seed: an integer >= 0 (:func:`navformer_rl.utils.checks.check_seed`; numpy's generators refuse
    negative ones)."""
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


def int_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type: an integer >= ``minimum`` (argparse prefixes the error with the flag's name)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {value}")
        return value

    return parse


def number_between(low: float, high: float) -> Callable[[str], float]:
    """An argparse type: a finite number in ``[low, high]`` (argparse prefixes the error with the flag)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number in [{low}, {high}], got {text!r}") from None
        if not (math.isfinite(value) and low <= value <= high):
            raise argparse.ArgumentTypeError(f"expected a number in [{low}, {high}], got {text}")
        return value

    return parse
