"""A bounded in-process memo for the costly per-plant work (exact bases, ZOH discretisation,
loop coefficients): maps, Table 2 and the option scoring rebuild the same few plants thousands
of times. First in, first out beyond ``size`` entries, so that a long sweep over Ts or the
leg's inertia cannot grow it without limit. Keys must capture every input of ``build``.
"""
from __future__ import annotations

import threading
from typing import Callable, Hashable, TypeVar

import numpy as np

T = TypeVar("T")

__all__ = ["BoundedCache", "array_key"]


def array_key(*arrays) -> tuple:
    """Hashable, exact key of numpy arrays (bytes, shape and dtype)."""
    return tuple((a.shape, a.dtype.str, a.tobytes()) for a in map(np.asarray, arrays))


class BoundedCache:
    """``cache.get(key, build)``: ``build()``'s result, computed once per key (twice at most when
    two threads miss the same key at once: ``build`` runs outside the lock, as it may take long).

    Thread-safe: the schedule's dask threads and the explorer's sessions share it; eviction under a
    lock (two threads evicting the same oldest entry raised KeyError, and iterating while another
    thread inserted raised "dictionary changed size during iteration")."""

    def __init__(self, size: int = 256):
        self.size = size
        self._items: dict = {}
        self._lock = threading.Lock()

    def get(self, key: Hashable, build: Callable[[], T]) -> T:
        with self._lock:
            if key in self._items:
                return self._items[key]
        value = build()
        with self._lock:
            if key in self._items:          # another thread built it meanwhile: one value per key
                return self._items[key]
            while len(self._items) >= self.size:
                self._items.pop(next(iter(self._items)))
            self._items[key] = value
        return value

    def clear(self) -> None:
        with self._lock:
            self._items.clear()

    def __len__(self) -> int:
        return len(self._items)
