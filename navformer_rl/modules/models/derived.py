"""Inference caches of tensors derived from parameters: when to rebuild them."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Generic, TypeVar

from torch import Tensor

Derived = TypeVar("Derived")


def parameter_key(tensors: Iterable[Tensor]) -> tuple:
    """Changes whenever one of ``tensors`` is updated in place (``_version``) or replaced (``data_ptr``).

    Not seen: writes that bypass the version counter (``p.data.copy_(...)``, fused optimizers such as
    ``AdamW(fused=True)``) and inference tensors (they have no version counter: only replacement is seen).
    """
    return tuple((tensor.data_ptr(), -1 if tensor.is_inference() else tensor._version) for tensor in tensors)


class DerivedCache(Generic[Derived]):
    """``build()``'s result, rebuilt on ``get()`` whenever one of ``sources`` changed since the last build.

    sources: the tensors (usually ``Parameter`` objects) the result is computed from, gathered once by the
    caller (``nn.Module`` attribute access costs ~2 us, more than the check itself). ``build`` runs under
    whatever grad mode the caller is in; call ``get`` under ``torch.no_grad()`` for inference tables.
    """

    def __init__(self, sources: Iterable[Tensor], build: Callable[[], Derived]) -> None:
        self.sources = tuple(sources)
        self.build = build
        self._key: tuple | None = None
        self._value: Derived | None = None

    def get(self) -> Derived:
        key = parameter_key(self.sources)
        if key != self._key:
            self._value, self._key = self.build(), key
        return self._value
