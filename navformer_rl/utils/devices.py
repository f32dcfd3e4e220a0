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
    """``name`` if it is ``auto``, ``cpu``, ``cuda`` or ``cuda:N`` and usable here; otherwise ValueError
    naming ``option``, the value and what was expected (a CUDA device on a machine where torch sees none, or a
    GPU number beyond those present)."""
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


def cpu_has_native_bfloat16() -> bool:
    """Whether this CPU computes bfloat16 in hardware (AVX512-BF16 or AMX), as torch's CPU kernels see it.

    Without it (AVX2-only x86 CPUs, for example) oneDNN emulates bf16 by converting to fp32 and back, and
    bf16 autocast trains several times slower than fp32 (:func:`bfloat16_autocast_warning`)."""
    import torch

    cpu = torch.cpu
    checks = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    return any(getattr(cpu, name, lambda: False)() for name in checks)


def fast_autocast_dtype(device: torch.device) -> str | None:
    """The ``model.autocast_dtype`` that trains fastest on ``device`` as measured (docs/training.md):
    ``"bfloat16"`` on a GPU or a CPU with native bf16, None (fp32) on a CPU that would emulate it."""
    if device.type == "cpu" and not cpu_has_native_bfloat16():
        return None
    return "bfloat16"


def bfloat16_autocast_warning(device: torch.device, autocast_dtype: str | None) -> str | None:
    """A one-line warning when ``autocast_dtype`` is bfloat16 on a CPU without native bf16, else None."""
    if device.type != "cpu" or autocast_dtype != "bfloat16" or cpu_has_native_bfloat16():
        return None
    import torch

    capability = torch.backends.cpu.get_cpu_capability()
    return (
        f"model.autocast_dtype=bfloat16 on a CPU without native bf16 (torch sees {capability}, no "
        "AVX512-BF16 or AMX): bf16 is emulated there and trains several times slower than fp32 (about 7x in "
        "docs/training.md); leave model.autocast_dtype unset (fp32) on this machine"
    )
