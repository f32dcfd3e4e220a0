"""constraints.txt pins the dependency versions the suite and the shipped runs were made with: the environment
running the tests is that one (tests/test_gpu_run.py then holds the GPU machine's wheels to it)."""

from __future__ import annotations

import importlib.metadata
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def pins(text: str) -> dict[str, str]:
    """``{normalised name: version}`` of the ``name==version`` lines of a requirements-style text."""
    found = re.findall(r"^\s*([A-Za-z0-9_.\-]+)==([^\s#]+)", text, flags=re.MULTILINE)
    return {re.sub(r"[-_.]+", "-", name).lower(): version for name, version in found}


def test_the_environment_is_the_pinned_one():
    pinned = pins((ROOT / "constraints.txt").read_text())
    assert {"torchrl", "tensordict", "kornia", "pybullet", "numpy", "gymnasium"} <= set(pinned)
    for name, version in pinned.items():
        assert importlib.metadata.version(name) == version, f"{name}: constraints.txt pins {version}"
