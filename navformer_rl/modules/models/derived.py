"""Inference caches of tensors derived from parameters: when to rebuild them."""

from __future__ import annotations

from collections.abc import Iterable

from torch import Tensor


def parameter_key(tensors: Iterable[Tensor]) -> tuple:
    """Changes whenever one of ``tensors`` is updated in place (``_version``) or replaced (``data_ptr``)."""
    return tuple((tensor.data_ptr(), tensor._version) for tensor in tensors)
