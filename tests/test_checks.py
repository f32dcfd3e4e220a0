"""navformer_rl.utils.checks: the shared value checks (bools refused, numpy scalars accepted and converted,
messages naming the argument, the value and what was expected) and the CLI's seed type built on them."""

from __future__ import annotations

import argparse
import math
import re

import numpy as np
import pytest

from navformer_rl.utils import cli_args
from navformer_rl.utils.checks import check_int, check_number, check_seed, is_count, is_integer, is_real


@pytest.mark.parametrize("value", [0, 3, np.int64(3), np.uint8(0), 2**40])
def test_is_count_accepts_integers_from_0(value):
    assert is_count(value) and is_integer(value) and is_real(value)


@pytest.mark.parametrize("value", [True, False, -1, np.int32(-2), 1.0, "1", None, [1]])
def test_is_count_refuses_bools_negatives_and_non_integers(value):
    assert not is_count(value)


def test_is_real_takes_numpy_floats_but_not_bools():
    assert is_real(np.float32(0.5)) and is_real(1.5) and not is_real(True) and not is_real("1.5")


@pytest.mark.parametrize("value", [0, 7, np.int64(7), np.uint32(7)])
def test_check_seed_returns_a_plain_int(value):
    seed = check_seed(value)
    assert seed == value and type(seed) is int


@pytest.mark.parametrize("value", [-1, True, 1.0, "3", None, np.int8(-1)])
def test_check_seed_names_the_bad_value(value):
    with pytest.raises(
        ValueError, match=f"^world_seed must be a non-negative integer, got {re.escape(repr(value))}$"
    ):
        check_seed(value, "world_seed")


def test_check_int_converts_numpy_integers_and_refuses_bools_and_floats():
    assert type(check_int(np.int16(4), "n")) is int and check_int(0, "n", minimum=0) == 0
    for bad in (0, True, 2.0, np.float64(2.0), None):
        with pytest.raises(ValueError, match=f"^n must be an integer >= 1, got {re.escape(repr(bad))}$"):
            check_int(bad, "n")


def test_check_number_bounds_and_message():
    value = check_number(np.float32(0.25), "speed", at_least=0, at_most=1)
    assert value == 0.25 and type(value) is float
    assert check_number(3, "dt", greater_than=0) == 3.0
    for bad in (0.0, -1, math.nan, math.inf, True, "1"):
        with pytest.raises(
            ValueError, match=rf"^dt must be a finite number > 0 \(seconds\), got {re.escape(repr(bad))}$"
        ):
            check_number(bad, "dt", greater_than=0, unit="seconds")
    with pytest.raises(ValueError, match=r"^x must be a finite number >= 0.5 and <= 1, got 1.5$"):
        check_number(1.5, "x", at_least=0.5, at_most=1)
    with pytest.raises(ValueError, match=r"^x must be a finite number, got inf$"):
        check_number(math.inf, "x")


@pytest.mark.parametrize("text, seed", [("0", 0), ("42", 42), (" 7 ", 7)])
def test_cli_seed_parses_non_negative_integers(text, seed):
    assert cli_args.seed(text) == seed


@pytest.mark.parametrize("text, shown", [("-1", "-1"), ("abc", "'abc'"), ("1.5", "'1.5'"), ("", "''")])
def test_cli_seed_refuses_other_text_in_one_line(text, shown):
    with pytest.raises(
        argparse.ArgumentTypeError, match=f"^seed must be a non-negative integer, got {shown}$"
    ):
        cli_args.seed(text)
