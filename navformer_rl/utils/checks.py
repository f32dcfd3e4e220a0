"""Checks of argument and setting values, shared by the whole package (pure Python + numpy).

The ``is_*`` predicates answer whether a value has the expected type and range; the ``check_*`` functions
return the value converted to a plain Python ``int`` / ``float`` or raise ``ValueError`` naming the
argument, the bad value and what was expected, so that a wrong setting never surfaces as a traceback from
deep inside numpy, torch or pybullet. ``bool`` is never accepted as a number (``True`` is no count or seed);
numpy integer and float scalars are.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def is_integer(value: Any) -> bool:
    """True for Python and numpy integers (``bool`` excluded)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def is_count(value: Any) -> bool:
    """True for an integer >= 0 (``bool`` excluded), e.g. a count or a seed."""
    return is_integer(value) and value >= 0


def is_real(value: Any) -> bool:
    """True for Python and numpy integers and floats (``bool`` excluded)."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def check_seed(seed: Any, name: str = "seed") -> int:
    """``seed`` as an ``int``; ValueError unless it is an integer >= 0 (numpy's ``SeedSequence`` and
    gymnasium refuse negative and non-integer seeds)."""
    if not is_count(seed):
        raise ValueError(f"{name} must be a non-negative integer, got {seed!r}")
    return int(seed)


def check_int(value: Any, name: str, minimum: int = 1) -> int:
    """``value`` as an ``int``; ValueError unless it is an integer >= ``minimum``."""
    if not is_integer(value) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_number(
    value: Any,
    name: str,
    *,
    greater_than: float | None = None,
    at_least: float | None = None,
    at_most: float | None = None,
    unit: str = "",
) -> float:
    """``value`` as a ``float``; ValueError unless it is a finite real number within the given bounds
    (``greater_than`` exclusive, ``at_least`` and ``at_most`` inclusive). The message quotes ``unit``."""
    ok = is_real(value) and math.isfinite(value)
    if ok and greater_than is not None and not value > greater_than:
        ok = False
    if ok and at_least is not None and not value >= at_least:
        ok = False
    if ok and at_most is not None and not value <= at_most:
        ok = False
    if not ok:
        bounds = []
        if greater_than is not None:
            bounds.append(f"> {greater_than:g}")
        if at_least is not None:
            bounds.append(f">= {at_least:g}")
        if at_most is not None:
            bounds.append(f"<= {at_most:g}")
        expected = "a finite number" + (" " + " and ".join(bounds) if bounds else "")
        raise ValueError(f"{name} must be {expected}{f' ({unit})' if unit else ''}, got {value!r}")
    return float(value)
