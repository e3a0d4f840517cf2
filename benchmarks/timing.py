"""What every benchmark times with: the best of a few runs of one call."""
from __future__ import annotations

import time

REPEATS = 3


def best(fn, repeats: int = REPEATS):
    """``(seconds, result)``: the fastest of ``repeats`` calls of ``fn()`` (perf_counter)."""
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out
