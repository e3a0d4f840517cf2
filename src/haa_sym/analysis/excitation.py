"""Excitation signals for identification experiments (``haa-sym simulate --excitation``,
docs/simulate.md, "Logs for identify"): a torque reference of unit peak that the run scales by
its amplitude. Pure numpy; every bad specification is one :class:`ParameterError` naming the
field, the value and what is allowed.

``chirp:F0:F1``
    A linear sweep sin(2 pi (F0 t + (F1 - F0) t^2 / (2 T))) from F0 to F1 Hz over the run T.
``prbs:F_CLOCK``
    A pseudo-random binary sequence +-1 (seeded, from numpy's generator; not a maximal-length
    shift register), each level held for round(1 / (F_CLOCK Ts)) samples: its power is flat to
    within 3 dB up to about 0.44 F_CLOCK and has nulls at multiples of F_CLOCK.
``multisine:F0:F1[:N]``
    N (default :data:`MULTISINE_N`) sines log-spaced from F0 to F1 Hz, each on the run's
    frequency grid (a whole number of periods over the run, so none leaks into the others; at
    least one grid step apart, so a short run packs the low ones at 1 / T spacing), with
    Schroeder's phases (a low crest factor), scaled to unit peak.

Example
-------
>>> u = excitation_signal("multisine:1:20:5", 1000, 1e-3, seed=0)
>>> u.shape, float(abs(u).max())
((1000,), 1.0)
"""
from __future__ import annotations

import math

import numpy as np

from haa_sym.errors import ParameterError
from haa_sym.io.budget import check_memory

__all__ = ["EXCITATIONS", "MULTISINE_N", "parse_excitation", "excitation_signal"]

EXCITATIONS = {"chirp": "chirp:F0:F1 (Hz, a linear sweep over the run)",
               "prbs": "prbs:F_CLOCK (Hz, a random binary +-1 held 1 / F_CLOCK)",
               "multisine": "multisine:F0:F1[:N] (Hz, N log-spaced sines, Schroeder phases)"}
MULTISINE_N = 20


def _allowed(spec: str, field: str, why: str) -> ParameterError:
    return ParameterError(f"{field} {spec!r}: {why}; allowed: " + ", ".join(EXCITATIONS.values()))


def parse_excitation(spec: str, Ts: float, field: str = "--excitation") -> tuple[str, tuple]:
    """``(kind, numbers)`` of a specification, checked against the sampling period ``Ts`` (s):
    frequencies finite, > 0, F0 < F1, at most Nyquist (0.5 / Ts); N an integer >= 1."""
    kind, *parts = str(spec).split(":")
    if kind not in EXCITATIONS:
        raise _allowed(spec, field, f"unknown kind {kind!r}")
    counts = {"chirp": (2,), "prbs": (1,), "multisine": (2, 3)}[kind]
    if len(parts) not in counts:
        raise _allowed(spec, field, f"{kind} takes {' or '.join(map(str, counts))} numbers")
    try:
        nums = [float(p) for p in parts]
    except ValueError:
        raise _allowed(spec, field, "not a number") from None
    freqs = nums[:2] if kind != "prbs" else nums[:1]
    nyquist = 0.5 / Ts
    if not all(math.isfinite(f) and 0 < f <= nyquist for f in freqs):
        raise _allowed(spec, field, f"frequencies must be > 0 and at most Nyquist {nyquist:g} Hz (Ts = {Ts:g} s)")
    if kind != "prbs" and not freqs[0] < freqs[1]:
        raise _allowed(spec, field, "F0 must be below F1")
    if kind == "multisine":
        n = nums[2] if len(nums) == 3 else MULTISINE_N
        if not (n == int(n) and n >= 1):
            raise _allowed(spec, field, f"N = {n:g} sines")
        return kind, (freqs[0], freqs[1], int(n))
    return kind, tuple(freqs)


def excitation_signal(spec: str, n: int, Ts: float, seed: int = 0, field: str = "--excitation") -> np.ndarray:
    """The ``n`` samples (at t = k Ts) of the excitation ``spec`` (:func:`parse_excitation`),
    peak 1. ``seed`` draws the PRBS levels."""
    kind, p = parse_excitation(spec, Ts, field)
    t = np.arange(n) * Ts
    T = max(t[-1], Ts)
    if kind == "chirp":
        f0, f1 = p
        return np.sin(2 * np.pi * (f0 * t + (f1 - f0) * t ** 2 / (2 * T)))
    if kind == "prbs":
        hold = max(1, int(round(1.0 / (p[0] * Ts))))
        levels = np.random.default_rng(seed).integers(0, 2, -(-n // hold)) * 2.0 - 1.0
        return np.repeat(levels, hold)[:n]
    f0, f1, count = p
    period = n * Ts
    too_many = ParameterError(f"{field} {spec!r}: {count} sines between {f0:g} and {f1:g} Hz need a run of more "
                              f"than {period:g} s (its frequency grid is 1 / {period:g} Hz); allowed: fewer sines, a "
                              "wider band or a longer --duration")
    if count > f1 * period + 1:          # more sines than grid lines below F1: refused before any work
        raise too_many
    check_memory(16.0 * n * count, f"{field} {spec!r}: {count} sines over {n} samples")
    # on the run's grid (k / period): log-spaced, each at least one grid step above the one
    # before (the grid is coarser than the log spacing at the low end of a short run):
    # k_i = max(k_i, k_(i-1) + 1) for every i is a running maximum of k_i - i
    k = np.maximum(np.round(np.geomspace(f0, f1, count) * period), 1.0)
    i = np.arange(k.size, dtype=float)
    k = np.maximum.accumulate(k - i) + i
    if k[-1] > math.floor(f1 * period + 0.5) or k[-1] / period > 0.5 / Ts:
        raise too_many
    m = np.arange(1, k.size + 1)
    phases = -np.pi * m * (m - 1) / k.size                   # Schroeder (1970)
    u = np.sin(2 * np.pi * np.outer(t, k / period) + phases).sum(axis=1)
    return u / np.abs(u).max()
