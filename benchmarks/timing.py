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


# --- where the results go, and what they were measured on ----------------------------------------

import datetime as _dt
import json as _json
import os as _os
import platform as _platform
from pathlib import Path as _Path

ROOT = _Path(__file__).resolve().parent.parent


def results_dir() -> _Path:
    """``$HAA_SYM_BENCH_DIR``, else ``bench-results/`` at the top of the checkout (git-ignored):
    never inside the tracked tree."""
    return _Path(_os.environ.get("HAA_SYM_BENCH_DIR") or ROOT / "bench-results")


def _cpu_model() -> str:
    try:
        for line in _Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return _platform.processor() or _platform.machine()


def _load() -> list[float] | None:
    try:
        return [round(x, 2) for x in _os.getloadavg()]
    except OSError:
        return None


def _blas() -> list[dict]:
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return []
    keys = ("user_api", "internal_api", "version", "num_threads", "threading_layer", "architecture")
    return [{k: d.get(k) for k in keys} for d in threadpool_info()]


class Run:
    """The machine and the date of one benchmark script's run: create it at the start (load
    average then), ``write(name, data)`` at the end (load average again, the JSON written)."""

    def __init__(self, script: str):
        import numpy as np
        self.info = {
            "script": script,
            "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "platform": _platform.platform(),
            "cpu_model": _cpu_model(),
            "cpu_count": _os.cpu_count(),
            "python": _platform.python_version(),
            "numpy": np.__version__,
            "blas": _blas(),
            "load_average_start": _load(),
        }

    def write(self, name: str, data: dict) -> _Path:
        self.info["load_average_end"] = _load()
        self.info["date_end"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        out = results_dir() / name
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(_json.dumps({"run": self.info, **data}, indent=1) + "\n")
        return out
