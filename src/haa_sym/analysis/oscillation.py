"""Is there a sustained oscillation in a trace? (docs/describing.md, "Detecting a limit cycle")

:func:`limit_cycle` looks at the tail of a uniformly sampled trace (after the transient), finds
its cycles from crossings of the tail's mean with hysteresis (so noise and quantisation steps do
not count as crossings), and from the cycles' amplitudes decides whether the oscillation decays,
grows or is sustained. Every threshold is a named argument with a stated default.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from haa_sym.errors import ParameterError

__all__ = ["Oscillation", "limit_cycle", "theil_sen_slope", "OSCILLATION_KINDS"]

OSCILLATION_KINDS = ("none", "decaying", "sustained", "growing")


@dataclass(frozen=True)
class Oscillation:
    """What :func:`limit_cycle` found in a trace.

    Attributes
    ----------
    kind : str
        "none" (fewer than ``min_cycles`` cycles above the hysteresis in the tail: converged,
        constant or drifting), "decaying", "sustained" or "growing".
    amplitude : float
        Half the peak-to-peak of the tail's cycles (median over the last ``min_cycles`` cycles),
        in the trace's unit; NaN for "none".
    fundamental : float
        Amplitude of the least-squares sinusoid at the detected frequency over the whole cycles
        of the tail (what a describing function predicts); NaN for "none".
    frequency_hz, omega, period : float
        Hz, rad/s and s, from the mean time between upward crossings (first to last over the
        number of cycles); NaN for "none".
    growth_per_cycle : float
        Relative change of the cycle amplitude per cycle (Theil-Sen slope of log amplitude).
    n_cycles : int
        Whole cycles found in the tail.
    offset : float
        The level of the oscillation (the constant of the least-squares fit over whole cycles);
        the mean of the tail for "none" (the crossings are counted at that mean).
    hysteresis : float
        The band around ``offset`` a crossing has to pass (trace unit).
    noise : float
        The estimated rms of the noise on the tail (trace unit).
    """

    kind: str
    amplitude: float
    fundamental: float
    frequency_hz: float
    omega: float
    period: float
    growth_per_cycle: float
    n_cycles: int
    offset: float
    hysteresis: float
    noise: float


# order of the differences the noise is estimated from: white noise's k-th difference has
# variance C(2k, k) sigma^2 (924 sigma^2 for k = 6), a sinusoid's is (2 sin(omega Ts / 2))^k times
# its amplitude, which for k = 6 keeps oscillations up to about a sixth of the sampling rate
# from passing for noise (docs/describing.md)
NOISE_DIFFERENCE_ORDER = 6


def _noise_rms(y: np.ndarray) -> float:
    """rms of white noise on a smooth signal, from the median absolute deviation of its
    differences of order NOISE_DIFFERENCE_ORDER."""
    k = NOISE_DIFFERENCE_ORDER
    d = np.diff(y, k)
    if d.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(math.comb(2 * k, k)))


def theil_sen_slope(y: np.ndarray) -> float:
    """The Theil-Sen slope of ``y`` over its index: the median of the slopes of all pairs
    (what ``scipy.stats.theilslopes(y)[0]`` returns, without its per-call overhead, which is
    most of a classification's cost in a map of thousands of runs)."""
    y = np.asarray(y, float)
    i, j = np.triu_indices(y.size, 1)
    return float(np.median((y[j] - y[i]) / (j - i)))


def limit_cycle(t, y, *, settle: float = 0.5, min_cycles: int = 3, growth_tol: float = 0.01,
                hysteresis: float | None = None, noise_factor: float = 4.0,
                resolution: float = 0.0) -> Oscillation:
    """Detect a sustained oscillation in the trace ``y(t)`` after its transient.

    Parameters
    ----------
    t, y : array_like
        Sample times (s, increasing, uniform to 1e-6 relative) and values (any unit).
    settle : float
        Fraction of the trace's duration discarded as the transient (0 <= settle < 1); default
        0.5: the second half is analysed.
    min_cycles : int
        Whole cycles the tail must hold for an oscillation to be reported; default 3.
    growth_tol : float
        ``|growth_per_cycle|`` below this is "sustained"; default 0.01 (1 % per cycle).
    hysteresis : float, optional
        Band (trace unit) around the tail's mean that a crossing has to pass; default
        ``max(noise_factor * noise, resolution, 1e-9 * max|y|)`` where ``noise`` is the rms
        estimated from the sixth differences (white noise assumed).
    noise_factor : float
        Multiple of the noise rms used for the default hysteresis; default 4.
    resolution : float
        The trace's quantisation step (trace unit), if known; default 0. The default hysteresis
        is at least one step, so a signal toggling between two levels is an oscillation only if
        it spans more than one step.

    Returns
    -------
    Oscillation
    """
    t, y = np.asarray(t, float).ravel(), np.asarray(y, float).ravel()
    if t.shape != y.shape or t.size < 8:
        raise ParameterError(f"trace of {t.size} times and {y.size} values; allowed: equal lengths >= 8")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise ParameterError("trace with non-finite values; allowed: finite times and values")
    dt = np.diff(t)
    if not (np.all(dt > 0) and np.ptp(dt) <= 1e-6 * dt.mean()):
        raise ParameterError("trace times; allowed: increasing and uniformly spaced (1e-6 relative)")
    if not 0 <= settle < 1:
        raise ParameterError(f"settle = {settle!r}; allowed: 0 <= settle < 1 (a fraction of the duration)")
    if not (isinstance(min_cycles, int) and min_cycles >= 2):
        raise ParameterError(f"min_cycles = {min_cycles!r}; allowed: an integer >= 2")
    tail = t >= t[0] + settle * (t[-1] - t[0])
    tt, yy = t[tail], y[tail]
    offset = float(yy.mean())
    noise = _noise_rms(yy)
    h = hysteresis if hysteresis is not None else \
        max(noise_factor * noise, resolution, 1e-9 * float(np.abs(y).max()))
    none = Oscillation("none", np.nan, np.nan, np.nan, np.nan, np.nan, 0.0, 0, offset, float(h), noise)
    x = yy - offset
    # Schmitt trigger: the state is the side of the band last left (forward fill of the signs)
    side = np.where(x > h, 1, np.where(x < -h, -1, 0))
    last = np.maximum.accumulate(np.where(side != 0, np.arange(x.size), 0))
    state = np.where(side[last] != 0, side[last], 0)
    ups = np.flatnonzero((state[1:] == 1) & (state[:-1] == -1)) + 1
    if ups.size < min_cycles + 1:
        return none
    # the crossing time: the last zero crossing of x before the trigger, linearly interpolated
    times = []
    for i in ups:
        j = i
        while j > 0 and x[j - 1] > 0:
            j -= 1
        j = max(j, 1)
        x0, x1 = x[j - 1], x[j]
        times.append(tt[j - 1] + (tt[j] - tt[j - 1]) * (-x0 / (x1 - x0) if x1 != x0 else 0.0))
    times = np.array(times)
    # the mean period over every whole cycle: a cycle of a few samples has crossings that jitter
    # by a sample, whose median would be biased
    period = float((times[-1] - times[0]) / (times.size - 1))
    amps = np.array([0.5 * np.ptp(yy[a:b]) for a, b in zip(ups[:-1], ups[1:])])
    if np.any(amps <= 0):
        return none
    n = amps.size
    if n >= 3:
        slope = theil_sen_slope(np.log(amps))
    else:
        slope = np.log(amps[-1] / amps[0]) / (n - 1)
    growth = float(np.expm1(slope))
    kind = "sustained" if abs(growth) < growth_tol else "growing" if growth > 0 else "decaying"
    w = 2 * np.pi / period
    seg = (tt >= times[0]) & (tt < times[-1])
    M = np.stack([np.cos(w * tt[seg]), np.sin(w * tt[seg]), np.ones(seg.sum())], axis=1)
    c = np.linalg.lstsq(M, yy[seg], rcond=None)[0]
    return Oscillation(kind, float(np.median(amps[-min_cycles:])), float(np.hypot(c[0], c[1])), 1 / period,
                       w, period, growth, int(n), float(c[2]), float(h), noise)
