"""A bounded in-process memo for the costly per-plant work (exact bases, ZOH discretisation,
loop coefficients): maps, Table 2 and the option scoring rebuild the same few plants thousands
of times. First in, first out beyond ``size`` entries, so that a long sweep over Ts or the
leg's inertia cannot grow it without limit. Keys must capture every input of ``build``.
"""
from __future__ import annotations

from typing import Callable, Hashable, TypeVar

import numpy as np

T = TypeVar("T")

__all__ = ["BoundedCache", "array_key"]


def array_key(*arrays) -> tuple:
    """Hashable, exact key of numpy arrays (bytes, shape and dtype)."""
    return tuple((a.shape, a.dtype.str, a.tobytes()) for a in map(np.asarray, arrays))


class BoundedCache:
    """``cache.get(key, build)``: ``build()``'s result, computed once per key."""

    def __init__(self, size: int = 256):
        self.size = size
        self._items: dict = {}

    def get(self, key: Hashable, build: Callable[[], T]) -> T:
        try:
            return self._items[key]
        except KeyError:
            pass
        value = build()
        if len(self._items) >= self.size:
            self._items.pop(next(iter(self._items)))
        self._items[key] = value
        return value

    def clear(self) -> None:
        self._items.clear()

    def __len__(self) -> int:
        return len(self._items)
