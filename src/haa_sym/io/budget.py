"""Memory budget: work that would need more than it is refused before anything is allocated.

The budget is :data:`MEMORY_BUDGET_BYTES` (a quarter of the physical memory), overridden by the
environment variable ``HAA_SYM_MEMORY_BUDGET`` (bytes, or with a binary suffix K, M, G or T,
e.g. ``HAA_SYM_MEMORY_BUDGET=2G``). The estimates are peak bytes measured with ``tracemalloc``
(numpy reports its buffers there) and rounded up:

* the loop coefficients of :meth:`haa_sym.loop.closed_loop.ClosedLoop.loop_coefficients`: 1.6-1.7 kB per
  frequency (the 7 x 7 complex resolvent of every frequency dominates);
* a sweep over gain points (:mod:`haa_sym.analysis.sweep`): 30-32 B per point and frequency of the block
  evaluated at once (``regions.CHUNK`` points in a region map, every point in ``passivity``),
  plus 44 B per point for the result arrays of a region map;
* a simulation (:mod:`haa_sym.analysis.simulate`) with its limit-cycle check: 188-214 B per
  sample (the inputs, the state trace, the columns, and the check's autocorrelation, 58-81 B of
  that: FFT buffers of 2 to 4 times the trace's last half; measured 2026-11-26 at 1 M samples
  with the supply and quantisers, 50,000 with friction), and ``haa-sym simulate`` 1.04-1.14 kB
  per sample with its CSV text and figure (the rows are formatted strings). The check used to
  take the Theil-Sen slope over every pair of cycles (6.9 GB at 1 M samples, not counted); it
  now uses at most :data:`haa_sym.analysis.oscillation.THEIL_SEN_MAX_POINTS` cycles;
* reading a CSV log (:mod:`haa_sym.io.logs`): 5.1 B per byte of the file;
* an identification's fit (:func:`fit_bytes`): 1.1-2.3 kB per sample, by states, outputs and keys.

Example
-------
>>> check_memory(sweep_bytes(200 * 100, 1000, chunk=512), "a region map")   # passes: ~25 MB
>>> sweep_bytes(10**6 * 10**6, 1000, chunk=512) > 2**40
True
"""
from __future__ import annotations

import os
import re

from haa_sym.errors import ParameterError

__all__ = ["MEMORY_BUDGET_BYTES", "memory_budget", "check_memory", "sweep_bytes", "BYTES_PER_OMEGA",
           "BYTES_PER_POINT", "BYTES_PER_CELL", "BYTES_PER_SAMPLE", "CSV_BYTES_PER_SAMPLE", "fit_bytes",
           "LOG_BYTES_PER_FILE_BYTE"]

BYTES_PER_OMEGA = 2048      # loop coefficients, per frequency (measured 1.6-1.7 kB)
BYTES_PER_POINT = 64        # result arrays of a region map, per gain point (measured 44 B)
BYTES_PER_CELL = 40         # sweep products, per gain point x frequency (measured 30-32 B)
BYTES_PER_SAMPLE = 256      # a simulation with its limit-cycle check, per sample (measured 188-214 B)
CSV_BYTES_PER_SAMPLE = 1280  # haa-sym simulate with --out and --plot, per sample (measured 1.04-1.14 kB)
# reading a CSV log, per byte of the file: its text, the lines and numpy's parse (measured 5.1 B on
# a 33 MB, 1,000,000-row log)
LOG_BYTES_PER_FILE_BYTE = 6
# an output-error fit, per sample: FIT_BYTES_PER_SAMPLE + FIT_BYTES_PER_TERM x (states + outputs)
# x (1 + keys), the simulated states and outputs with their sensitivities to every key. Peak RSS
# measured (haa-sym identify, 300,000 samples): harmonic drive (5 states) 1 output 2 keys 1.09 kB,
# 2 outputs 4 keys 2.26 kB; HyQ (7 states) 1 output 2 keys 1.40 kB; the estimate is 1.3-1.5x above
FIT_BYTES_PER_SAMPLE = 200
FIT_BYTES_PER_TERM = 80


def _physical_memory() -> int:
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 8 * 2**30


# A quarter of the machine: the analyses share it with other work (and the two BLAS threads).
MEMORY_BUDGET_BYTES: int = _physical_memory() // 4
_ENV = "HAA_SYM_MEMORY_BUDGET"
_SUFFIX = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def memory_budget() -> int:
    """The budget in bytes: ``HAA_SYM_MEMORY_BUDGET`` if set, else :data:`MEMORY_BUDGET_BYTES`."""
    text = os.environ.get(_ENV, "").strip()
    if not text:
        return MEMORY_BUDGET_BYTES
    m = re.fullmatch(r"(\d+(?:\.\d*)?(?:[eE]\d+)?)\s*([KMGT]?)(?:i?B)?", text, re.IGNORECASE)
    if not m or float(m.group(1)) <= 0:
        raise ParameterError(f"{_ENV} = {text!r}; allowed: a number of bytes > 0, optionally with a "
                             "suffix K, M, G or T (powers of 1024), e.g. 2G")
    return int(float(m.group(1)) * _SUFFIX[m.group(2).upper()])


def _human(n: float) -> str:
    units = ("B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB")
    i = 0
    while n >= 1024 and i < len(units) - 1:
        n, i = n / 1024, i + 1
    return f"{n:.3g} {units[i]}"


def check_memory(nbytes: float, what: str) -> None:
    """Refuse work estimated at ``nbytes`` if it exceeds :func:`memory_budget`.

    Raises
    ------
    ParameterError
        Naming the work, the bytes it would need and the budget.
    """
    budget = memory_budget()
    if nbytes > budget:
        raise ParameterError(f"{what} would need about {_human(nbytes)} of memory; allowed: at most "
                             f"{_human(budget)} (the memory budget; set {_ENV} to change it)")


def fit_bytes(n_samples: int, n_states: int, n_outputs: int, n_keys: int) -> int:
    """Peak bytes of an output-error fit (:mod:`haa_sym.fit.identify`) of ``n_keys`` keys over
    ``n_samples`` samples of a model with ``n_states`` states and ``n_outputs`` outputs."""
    return n_samples * (FIT_BYTES_PER_SAMPLE + FIT_BYTES_PER_TERM * (n_states + n_outputs) * (1 + n_keys))


def sweep_bytes(n_points: int, n_omega: int, chunk: int | None = None) -> int:
    """Peak bytes of a frequency sweep over ``n_points`` gain points on ``n_omega`` frequencies,
    evaluated ``chunk`` points at a time (None: all at once)."""
    block = n_points if chunk is None else min(chunk, n_points)
    return n_omega * BYTES_PER_OMEGA + n_points * BYTES_PER_POINT + block * n_omega * BYTES_PER_CELL
