"""Is there a sustained oscillation in a trace? (docs/describing.md, "Detecting a limit cycle")

:func:`limit_cycle` looks at the tail of a uniformly sampled trace (after the transient), asks
whether it leaves a band about its mean on both sides often enough (hysteresis: noise and
quantisation steps are no oscillation), takes the period from the tail's autocorrelation and the
amplitudes over its whole periods, and decides whether the oscillation decays, grows or is
sustained. :func:`classify` turns that, the saturation and the linear loop's decision into the
verdict of a run (the one classifier of ``simulate`` and ``regions --nonlinear``). Every
threshold is a named argument or constant with a stated default.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from haa_sym.errors import ParameterError

__all__ = ["Oscillation", "limit_cycle", "tail_start", "theil_sen_slope", "classify", "OSCILLATION_KINDS", "VERDICTS",
           "SATURATING_FRACTION", "THEIL_SEN_MAX_POINTS", "ACF_PEAK_FRACTION", "ACF_MIN", "IRREGULAR_CHUNKS",
           "IRREGULAR_GROWTH_TOL"]

OSCILLATION_KINDS = ("none", "decaying", "sustained", "growing", "irregular")


@dataclass(frozen=True)
class Oscillation:
    """What :func:`limit_cycle` found in a trace.

    Attributes
    ----------
    kind : str
        "none" (fewer than ``min_cycles`` cycles above the hysteresis in the tail: converged,
        constant or drifting), "decaying", "sustained" or "growing"; "irregular": the tail
        leaves the band often enough and its swing neither grows nor decays, but no period
        repeats (autocorrelation below :data:`ACF_MIN`: a quantised loop's chatter); its
        ``amplitude`` is the half peak-to-peak of the last of :data:`IRREGULAR_CHUNKS` equal
        parts, its frequency NaN. Also a periodic-looking tail with a quiet period (bursts).
    amplitude : float
        Half the peak-to-peak of the tail's whole periods (median over the last ``min_cycles``),
        in the trace's unit; NaN for "none".
    fundamental : float
        Amplitude of the least-squares sinusoid at the detected frequency over the whole cycles
        of the tail (what a describing function predicts); NaN for "none".
    frequency_hz, omega, period : float
        Hz, rad/s and s, from the first dominant peak of the tail's autocorrelation, refined at
        its multiples; NaN for "none".
    growth_per_cycle : float
        Relative change of the cycle amplitude per cycle (Theil-Sen slope of log amplitude).
    n_cycles : int
        Whole periods in the tail.
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


#: Theil-Sen over at most this many points: a trace of 1 M samples cut into cycles of a few
#: samples has ~10^5 cycles, whose 5 10^9 pairwise slopes took 6.9 GB (issue 26); beyond it the
#: points are an evenly strided subsample (first and last kept), 32,640 slopes, 0.26 MB
THEIL_SEN_MAX_POINTS = 256
#: The period is the first autocorrelation peak at least this fraction of the highest peak
#: within the longest period allowed: later multiples of the period are as high (a periodic
#: trace) or lower (the biased estimate's taper), a spike inside a cycle is far lower (the
#: harmonic drive's spiky cycle: 0.03 at the spikes' spacing, 0.92 at its period)
ACF_PEAK_FRACTION = 0.8
#: ... and at least this (normalised autocorrelation, 1 at lag 0): below it the tail repeats
#: nothing (an aperiodic chatter, a drift with a few crossings): kind "irregular" or "none"
ACF_MIN = 0.3
#: Without a period, the tail's swing is judged on this many equal parts (half peak-to-peak
#: each, Theil-Sen slope of their logs): "irregular" when it changes by less than
#: IRREGULAR_GROWTH_TOL a part (a factor 2 over the 8 parts: a chatter's swing fluctuates by tens of
#: per cent from part to part), else growing or decaying
IRREGULAR_CHUNKS = 8
IRREGULAR_GROWTH_TOL = 0.1


def theil_sen_slope(y, max_points: int = THEIL_SEN_MAX_POINTS) -> float:
    """Theil-Sen slope of ``y`` against its index 0, 1, ..., n-1: the median of the slopes
    (y[j] - y[i]) / (j - i) over every pair i < j (Sen 1968), robust to a few outlying cycles.

    The same number as ``scipy.stats.theilslopes(y, np.arange(n))[0]`` for n <= ``max_points``;
    written here because importing scipy.stats would cost every ``haa-sym`` command about 0.5 s
    (docs/startup.md). Longer ``y``: the same estimator on ``max_points`` evenly strided points
    (their own indices as abscissae), so memory stays below ``max_points^2 / 2`` slopes.

    Parameters
    ----------
    y : array_like, shape (n,), n >= 2
        Values at equally spaced abscissae (unit spacing).
    max_points : int
        Points the pairs are formed from (default :data:`THEIL_SEN_MAX_POINTS`).

    Returns
    -------
    float
        The slope per index step (unit of ``y``).

    Examples
    --------
    >>> theil_sen_slope([0.0, 1.0, 2.0, 3.0, 40.0])          # one outlier does not move it
    1.0
    """
    y = np.asarray(y, float).ravel()
    x = np.arange(y.size, dtype=float)
    if y.size > max_points:
        pick = np.unique(np.round(np.linspace(0, y.size - 1, max_points)).astype(np.int64))
        x, y = x[pick], y[pick]
    # the pairs at lag k are (y[k:] - y[:-k]) / (x[k:] - x[:-k]): n (n - 1) / 2 slopes
    return float(np.median(np.concatenate([(y[k:] - y[:-k]) / (x[k:] - x[:-k]) for k in range(1, y.size)])))


def _autocorrelation(x: np.ndarray) -> np.ndarray:
    """sum_i x_i x_(i+k) of ``x`` (zero mean) at lags k = 0 .. n-1, by FFT (zero-padded to a power
    of two >= 2n: no wrap-around; O(n log n), a few buffers of 2n to 4n)."""
    n = x.size
    nfft = 1 << (2 * n - 1).bit_length()
    f = np.fft.rfft(x, nfft)
    return np.fft.irfft(f.real ** 2 + f.imag ** 2, nfft)[:n]


def _parabola(r: np.ndarray, k: int) -> float:
    """The vertex of the parabola through r[k-1], r[k], r[k+1] (a sub-sample peak)."""
    a, b, c = r[k - 1], r[k], r[k + 1]
    den = a - 2 * b + c
    return float(k + (0.5 * (a - c) / den if den < 0 else 0.0))


def _period(x: np.ndarray, max_lag: int) -> float | None:
    """The period of ``x`` in samples from its autocorrelation (docs/describing.md, "Detecting a
    limit cycle"), or None when no peak within ``max_lag`` qualifies."""
    n = x.size
    raw = _autocorrelation(x)
    if not raw[0] > 0:
        return None
    r = raw / raw[0]
    # a zero-mean periodic trace's autocorrelation sums to about zero over a period, so it falls
    # to <= 0 within the first; the peaks before that are noise on the decline from lag 0
    below = np.flatnonzero(r[1:max_lag + 1] <= 0)
    if not below.size:
        return None
    z = int(below[0]) + 1
    seg = r[z:max_lag + 2]
    peaks = np.flatnonzero((seg[1:-1] > seg[:-2]) & (seg[1:-1] >= seg[2:])) + z + 1
    peaks = peaks[peaks <= max_lag]
    if not peaks.size or r[peaks].max() < ACF_MIN:
        return None
    k = int(peaks[np.flatnonzero(r[peaks] >= ACF_PEAK_FRACTION * r[peaks].max())[0]])
    # refined on the correlation coefficient of x[:n-k] and x[k:] (each part's own energy, from
    # cumulative sums): 1 for a copy scaled by any factor, so an exponential envelope (a growing
    # or decaying cycle) does not shift the peak, as it does the plain estimate's by sigma/omega^2;
    # at the largest multiple m P within half the tail, where a sub-sample error is divided by m;
    # m doubles so that each search window (+-5 % of the period, at least 2 samples) holds the
    # peak found from the last estimate
    cs = np.concatenate([[0.0], np.cumsum(x * x)])
    lags = np.arange(n)
    ru = raw / np.sqrt(np.maximum(cs[n - lags] * (cs[n] - cs[lags]), 1e-300))
    P = _parabola(ru, k)
    m = 1
    while 2 * m * P + 3 <= n // 2:
        m *= 2
        c = int(round(m * P))
        w = max(2, int(math.ceil(0.05 * P)))
        lo, hi = max(c - w, 1), min(c + w, n - 2)
        j = lo + int(np.argmax(ru[lo:hi + 1]))
        if j in (lo, hi):             # no interior maximum: keep the estimate so far
            break
        P = _parabola(ru, j) / m
    return P


def tail_start(t, settle: float = 0.5) -> int:
    """Index of the first sample of the tail :func:`limit_cycle` analyses: the first t_i >= t_0 +
    ``settle`` (t_(n-1) - t_0), ``t`` increasing. A caller that keeps only a trace's tail (a run
    continued in segments, :mod:`haa_sym.analysis.nonlinear_map`) keeps it from here."""
    t = np.asarray(t, float).ravel()
    return int(np.argmax(t >= t[0] + settle * (t[-1] - t[0])))


def limit_cycle(t, y, *, settle: float = 0.5, min_cycles: int = 3, growth_tol: float = 0.01,
                hysteresis: float | None = None, noise_factor: float = 4.0,
                resolution: float = 0.0, peak: float | None = None) -> Oscillation:
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
        Band (trace unit) around the tail's mean that the trace has to leave on both sides
        ``min_cycles + 1`` times for an oscillation; default ``max(noise_factor * noise,
        resolution, 1e-9 * max|y|)`` where ``noise`` is the rms estimated from the sixth
        differences (white noise assumed).
    noise_factor : float
        Multiple of the noise rms used for the default hysteresis; default 4.
    resolution : float
        The trace's quantisation step (trace unit), if known; default 0. The default hysteresis
        is at least one step, so a signal toggling between two levels is an oscillation only if
        it spans more than one step.
    peak : float, optional
        The largest |y| of the whole trace when ``t``, ``y`` are only its tail (with ``settle =
        0``: a run continued in segments keeps its tail and this number, :func:`tail_start`);
        default max |y| of ``y``. It enters only the default hysteresis's floor.

    Returns
    -------
    Oscillation
        The period from the tail's autocorrelation, the amplitudes over its whole periods.
        Memory O(n): a few buffers of the tail's length (the FFT's of 2n to 4n), the Theil-Sen
        slope on at most :data:`THEIL_SEN_MAX_POINTS` cycles.
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
    i0 = tail_start(t, settle)
    tt, yy = t[i0:], y[i0:]
    offset = float(yy.mean())
    noise = _noise_rms(yy)
    h = hysteresis if hysteresis is not None else \
        max(noise_factor * noise, resolution, 1e-9 * (float(np.abs(y).max()) if peak is None else peak))
    none = Oscillation("none", np.nan, np.nan, np.nan, np.nan, np.nan, 0.0, 0, offset, float(h), noise)
    x = yy - offset
    # is there an oscillation beyond the band at all? A Schmitt trigger: the state is the side
    # of the band last left; min_cycles + 1 upward passages needed (noise and one quantum are not)
    side = np.where(x > h, 1, np.where(x < -h, -1, 0)).astype(np.int8)
    nz = np.flatnonzero(side)
    if nz.size < 2 or np.count_nonzero(np.diff(side[nz]) > 0) < min_cycles + 1:
        return none
    # its period: from the whole tail's autocorrelation (a cycle with several spikes crosses
    # the mean several times a period: counting crossings took each spike for a cycle)
    def irregular():
        # beyond the band often enough, but no period holds over the tail: a persistent irregular
        # or intermittent swing (a quantised loop's chatter: HyQ at beta 3 with a 4096-count
        # encoder and a 0.01 Nm quantum, P 100, D 25.5: 0.4-0.8 Nm in every eighth of the tail,
        # autocorrelation below ACF_MIN), unless its swing grows or decays from part to part (a
        # quiet part counts as the hysteresis band's half width)
        e = np.linspace(0, x.size, IRREGULAR_CHUNKS + 1).astype(np.int64)
        swing = 0.5 * (np.maximum.reduceat(yy, e[:-1]) - np.minimum.reduceat(yy, e[:-1]))
        g = float(np.expm1(theil_sen_slope(np.log(np.maximum(swing, max(h, 1e-300))))))
        kind = "irregular" if abs(g) < IRREGULAR_GROWTH_TOL else "growing" if g > 0 else "decaying"
        return Oscillation(kind, float(swing[-1]), np.nan, np.nan, np.nan, np.nan, g, 0, offset, float(h), noise)

    # scaled to |x| <= 1: the period does not depend on the scale, and the energies' products of
    # its refinement overflowed for a trace grown past 1e77 (300 s of a growing HyQ loop)
    Ps = _period(x / float(np.abs(x).max()), x.size // min_cycles)
    if Ps is None:
        return irregular()
    # whole periods counted back from the end; each one's half peak-to-peak
    n_win = int(x.size // Ps)
    edges = np.round(x.size - Ps * np.arange(n_win, -1, -1)).astype(np.int64)
    edges[0] = max(edges[0], 0)
    # the swings of yy itself, not of x = yy - offset: the same numbers, except that a growing
    # trace's mean (1e39 at 150 s of HyQ at P 2000, D 10) absorbed its early cycles (1e21) when
    # subtracted, so their swing came out 0 and the trace "irregular" with a growth of 1700 %
    amps = 0.5 * (np.maximum.reduceat(yy, edges[:-1]) - np.minimum.reduceat(yy, edges[:-1]))
    if n_win < min_cycles:
        return none
    if np.any(amps <= 0):            # a quiet period between bursts: no cycle of constant shape
        return irregular()
    if n_win >= 3:
        slope = theil_sen_slope(np.log(amps))
    else:
        slope = np.log(amps[-1] / amps[0]) / (n_win - 1)
    growth = float(np.expm1(slope))
    kind = "sustained" if abs(growth) < growth_tol else "growing" if growth > 0 else "decaying"
    period = float(Ps * dt.mean())
    w = 2 * np.pi / period
    ts, xs = tt[edges[0]:], yy[edges[0]:]
    M = np.stack([np.cos(w * ts), np.sin(w * ts), np.ones(ts.size)], axis=1)
    c = np.linalg.lstsq(M, xs, rcond=None)[0]
    return Oscillation(kind, float(np.median(amps[-min_cycles:])), float(np.hypot(c[0], c[1])), 1 / period,
                       w, period, growth, n_win, float(c[2]), float(h), noise)


# --- the verdict of a run --------------------------------------------------------------------------

#: The verdicts of a simulated run, in the order of their codes (``regions --nonlinear``'s
#: ``nonlinear_class``); rules in :func:`classify` and docs/simulate.md, "The verdict of a run".
VERDICTS = ("converging", "limit cycle", "saturating", "growing", "undecided", "diverged", "forced response")
#: Fraction of the last half's samples in saturation from which a run is "saturating".
SATURATING_FRACTION = 0.9


def classify(kind, tail_saturation, linear_stable, always_acting: bool,
             saturating_fraction: float = SATURATING_FRACTION, forced: bool = False) -> np.ndarray:
    """Verdict codes (into :data:`VERDICTS`) of simulated runs, elementwise; the first rule that
    applies decides (docs/simulate.md, "The verdict of a run"):

    1. ``diverged``: a state overflowed (``kind`` "non-finite").
    2. the linear regime (no sample of the last half saturated, no limit acting on every step):
       ``converging`` if the linear loop is stable, ``growing`` if not. A forced run
       (``forced``, the chirp) in this regime: ``forced response`` if stable.
    3. a forced run: ``forced response`` (its oscillation is the input's, never a limit cycle).
    4. ``limit cycle``: a sustained oscillation, periodic or irregular (``kind`` "irregular":
       persistent, beyond the band, no period).
    5. ``saturating``: at least ``saturating_fraction`` of the last half in saturation.
    6. ``growing``: an oscillation growing by more than ``growth_tol`` a cycle.
    7. ``converging``: the linear loop is stable.
    8. ``undecided``.

    Parameters
    ----------
    kind : array_like of str
        :func:`limit_cycle`'s kind of each run's torque signal (:data:`OSCILLATION_KINDS`), or
        "non-finite".
    tail_saturation : array_like
        Fraction of the last half's samples in saturation.
    linear_stable : array_like
        The linear loop's certified decision: True, False, or NaN/None where unknown (rules 2
        and 7 then do not apply).
    always_acting : bool
        A limit acts on every step (friction, a quantiser, noise, jitter).
    saturating_fraction : float
        Rule 5's threshold, default :data:`SATURATING_FRACTION`.
    forced : bool
        The experiment drives the loop for the whole run (the chirp).

    Returns
    -------
    ndarray of int8
    """
    kind = np.asarray(kind, str)
    ts = np.asarray(tail_saturation, float)
    ls = np.asarray(np.where(np.equal(linear_stable, None), np.nan, linear_stable), float)
    st, un = ls == 1, ls == 0
    linear_regime = (ts == 0) & (not always_acting)
    c = VERDICTS.index
    out = np.full(kind.shape, c("undecided"), np.int8)
    rules = [(kind == "non-finite", c("diverged")),
             (linear_regime & st, c("forced response") if forced else c("converging")),
             (linear_regime & un, c("growing")),
             (np.full(kind.shape, bool(forced)), c("forced response")),
             ((kind == "sustained") | (kind == "irregular"), c("limit cycle")),
             (ts >= saturating_fraction, c("saturating")),
             (kind == "growing", c("growing")),
             (st, c("converging"))]
    decided = np.zeros(kind.shape, bool)
    for cond, code in rules:
        new = cond & ~decided
        out[new] = code
        decided |= new
    return out
