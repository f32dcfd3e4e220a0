"""Compiled inference kernel (optional): the transformer step on a few new tokens as one C call.

``native_status()`` builds it with the system C compiler on first use (see ``build``) and says whether it is
available; ``IncrementalNavFormer`` uses it when it is (``native=None``) and the torch path otherwise.
"""

from navformer_rl.modules.decoding.native.build import NativeBuildError, NativeStatus, native_status
from navformer_rl.modules.decoding.native.step import BlockedKVCache, NativeTransformerStep, native_support

__all__ = [
    "BlockedKVCache",
    "NativeBuildError",
    "NativeStatus",
    "NativeTransformerStep",
    "native_status",
    "native_support",
]
