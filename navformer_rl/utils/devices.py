"""Device names accepted by training and evaluation, checked before any work starts.

``auto`` picks CUDA when torch sees a GPU, else the CPU; ``cpu``, ``cuda`` and ``cuda:N`` name one. torch is
imported only to check a CUDA name or resolve a device, so parsing command lines stays light.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

DEVICES = ("auto", "cpu", "cuda")
"""The device names a configuration may give (``cuda:N`` also works: GPU number N)."""
_CUDA_INDEX = re.compile(r"^cuda:(\d+)$")


def check_device(name: object, option: str = "device") -> str:
    """``name`` if it is ``auto``, ``cpu``, ``cuda`` or ``cuda:N`` and usable here; otherwise ValueError naming
    ``option``, the value and what was expected (a CUDA device on a machine where torch sees none, or a GPU
    number beyond those present)."""
    if not isinstance(name, str) or not (name in DEVICES or _CUDA_INDEX.match(name)):
        raise ValueError(f"{option}={name!r}: expected one of {list(DEVICES)} or 'cuda:N' (GPU number N)")
    if name.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise ValueError(
                f"{option}={name} but torch sees no CUDA device (torch {torch.__version__}); use "
                f"{option}=auto or {option}=cpu"
            )
        match = _CUDA_INDEX.match(name)
        if match and int(match.group(1)) >= torch.cuda.device_count():
            raise ValueError(
                f"{option}={name}: torch sees {torch.cuda.device_count()} CUDA device(s), numbered from 0"
            )
    return name


def resolve_device(name: str) -> torch.device:
    """The torch device of a checked name: ``auto`` -> CUDA when available, else CPU."""
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)
