"""Inference caches of tensors derived from parameters: when to rebuild them."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Generic, TypeVar

from torch import Tensor

Derived = TypeVar("Derived")


def parameter_key(versioned: Iterable[Tensor], unversioned: Iterable[Tensor] = ()) -> tuple:
    """Changes whenever one of ``versioned`` is updated in place (``_version``) or replaced (``data_ptr``),
    or one of ``unversioned`` (inference tensors, which have no version counter) is replaced.

    Not seen: writes that bypass the version counter (``p.data.copy_(...)``, fused optimizers such as
    ``AdamW(fused=True)``) and in-place writes to inference tensors.
    """
    return (
        tuple((tensor.data_ptr(), tensor._version) for tensor in versioned),
        tuple(tensor.data_ptr() for tensor in unversioned),
    )


class DerivedCache(Generic[Derived]):
    """``build()``'s result, rebuilt on ``get(build)`` whenever one of ``sources`` changed since the last
    build.

    sources: the tensors (usually ``Parameter`` objects) the result is computed from, gathered once by the
    caller (``nn.Module`` attribute access costs ~2 us, more than the check itself); those made under
    inference mode are followed by ``data_ptr`` only (see ``parameter_key``). ``build`` runs under
    whatever grad mode the caller is in; call ``get`` under ``torch.no_grad()`` for inference tables.
    ``build`` is passed to ``get`` rather than kept, so that an owner's bound method (``self._build``) makes
    no reference cycle: the owner, and the tables it holds, are freed as soon as it is dropped.
    """

    def __init__(self, sources: Iterable[Tensor]) -> None:
        self.sources = tuple(sources)
        self._versioned = tuple(t for t in self.sources if not t.is_inference())
        self._unversioned = tuple(t for t in self.sources if t.is_inference())
        self._key: tuple | None = None
        self._value: Derived | None = None

    def get(self, build: Callable[[], Derived]) -> Derived:
        key = parameter_key(self._versioned, self._unversioned)
        if key != self._key:
            self._value, self._key = build(), key
        return self._value
