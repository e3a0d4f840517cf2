"""Reading an experiment log for identification (``haa-sym identify --log``): a CSV with a header,
a ``time`` column (s) and one column per signal, named as the model names it.

Signals (SI units): inputs ``voltage`` (V, the motor voltage, held from t_k to t_k+1),
``current`` (A, the motor current a drive's own current loop imposes), ``T_dist`` (Nm at the
port), ``torque_ref`` (Nm, the reference of the file's torque loop); outputs ``torque`` (Nm, the
file's torque sensor), ``theta`` (rad, the file's encoder), ``current`` (A), ``velocity`` (rad/s,
the port body). Outputs are sampled at t_k.

Sampling: a log is used as measured. Its stamps give the mean and median period and the jitter
max |dt - mean| / mean, stated in the summary; nothing is resampled: the fit simulates the model
exactly on each interval (:func:`haa_sym.fit.model.simulate_stamps`). An interval longer than the
gap threshold (default :data:`GAP_PERIODS` median periods) splits the log into segments
(:attr:`Log.starts`): nothing is interpolated across a gap, and each later segment restarts from
an estimated state. ``window`` keeps the samples with START <= t < STOP (s of the log's time
column). A ``theta`` column spanning more than ``max_angle`` (default :data:`MAX_ANGLE`) is
refused: the model is linear about an operating point. Every unusable log is one
:class:`ParameterError` naming the log, the field, the value and what is allowed.
"""
from __future__ import annotations

import collections
import csv
import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from haa_sym.errors import ParameterError
from haa_sym.io.budget import LOG_BYTES_PER_FILE_BYTE, check_memory
from haa_sym.io.inputs import read_bytes

__all__ = ["INPUTS", "OUTPUTS", "OUTPUT_UNITS", "UNIFORM_JITTER", "GAP_PERIODS", "MAX_ANGLE", "Log", "read_log", "parse_window"]

INPUTS = ("voltage", "current", "T_dist", "torque_ref")
OUTPUTS = ("torque", "theta", "current", "velocity")
OUTPUT_UNITS = {"torque": "Nm", "theta": "rad", "current": "A", "velocity": "rad/s"}     # SI, as logged
UNIFORM_JITTER = 1e-6     # relative: below this the time stamps are rounding of a uniform clock
# the mean sampling periods a log may have, s: 10 MHz to 0.1 Hz, far beyond any drive's logger
PERIOD_RANGE = (1e-7, 10.0)
# an interval longer than this many median periods is a gap (the logger stalled: the ITregear
# logs' 30-300 ms pauses of a 2 ms loop); the fit restarts there from an estimated state
GAP_PERIODS = 10.0
# largest span of a theta column, rad: the model is linear about an operating point. A coarse
# guard, not a linearity test: a quarter turn (gravity's sin(theta) is already 36 % below theta
# at pi/2) catches a swing-up to +-pi (the DFKI pendulum log) and passes the synthetic logs of the
# tests (up to 0.57 rad of a linear model)
MAX_ANGLE = 0.5 * np.pi


@dataclass(frozen=True)
class Log:
    """One experiment as measured: stamps ``t`` (s), ``signals[name]`` (n,) at them, the mean
    period ``Ts`` (s), the first sample of each segment ``starts`` (split at gaps), whether the
    stamps are ``uniform``, whether the window starts at the log's first sample (``from_start``),
    the sampling as stated (``sampling``) and the file's ``sha256``."""

    name: str
    Ts: float
    signals: dict
    sampling: dict
    sha256: str
    path: str = field(default="", repr=False)
    t: np.ndarray = field(default=None, repr=False)
    starts: tuple = (0,)
    uniform: bool = True
    from_start: bool = True

    def __post_init__(self):
        if self.t is None:                 # a log built in code: uniform stamps from 0
            object.__setattr__(self, "t", self.Ts * np.arange(self.samples))

    @property
    def samples(self) -> int:
        return len(next(iter(self.signals.values())))

    @property
    def duration(self) -> float:
        return self.samples * self.Ts


def parse_window(text: str, flag: str = "--window") -> tuple[float, float]:
    """``START:STOP`` in seconds of a log's time column (either may be empty: the log's start or end)."""
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        lo = float(parts[0]) if parts[0].strip() else -np.inf
        hi = float(parts[1]) if parts[1].strip() else np.inf
    except ValueError:
        raise ParameterError(f"{flag} {text!r}; allowed: START:STOP in seconds of the log (START or STOP may be "
                             "empty)") from None
    if not lo < hi or np.isnan(lo) or np.isnan(hi):
        raise ParameterError(f"{flag} {text!r}: START must be below STOP; allowed: START:STOP in seconds")
    return lo, hi


def _read_rows(path: Path, label: str) -> tuple[list[str], np.ndarray, bytes]:
    try:
        size = os.stat(path).st_size
    except OSError:
        size = 0                        # read_bytes says what is wrong with the path
    check_memory(size * LOG_BYTES_PER_FILE_BYTE, f"{label}: reading its {size} bytes")
    raw = read_bytes(path, "--log", where=label)
    # utf-8-sig: a spreadsheet's export starts with a byte-order mark, which is no part of "time"
    text = raw.decode("utf-8-sig", errors="replace").splitlines()
    lines = [line for line in text if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise ParameterError(f"{label}: empty file; allowed: a CSV with a header line (time and signals)")
    try:
        header = [h.strip() for h in next(csv.reader(lines[:1]))]
    except csv.Error as exc:        # a header field over csv's 128 KiB limit
        raise ParameterError(f"{label}: the header is not CSV ({exc}); allowed: comma-separated column "
                             "names") from None
    if len(header) == 1 and any(sep in header[0] for sep in ";\t"):
        # a spreadsheet's ';' or a tab export would otherwise be named as a number that fails to parse
        raise ParameterError(f"{label}: header {header[0]!r} is one column; allowed: comma-separated columns")
    data = _fast_body(lines[1:], len(header))
    if data is not None:
        return header, data, raw
    reader = csv.reader(lines)
    try:
        rows = list(reader)
    except csv.Error as exc:        # e.g. a field over csv's 128 KiB limit: no number is that long
        raise ParameterError(f"{label}: line {reader.line_num} is not CSV ({exc}); allowed: comma-separated "
                             "numbers") from None
    body = rows[1:]
    for i, r in enumerate(body):
        if len(r) != len(header):
            raise ParameterError(f"{label}: data row {i + 1} has {len(r)} fields, the header {len(header)}; "
                                 "allowed: one value per column")
    data = np.empty((len(body), len(header)))
    for i, r in enumerate(body):
        for j, x in enumerate(r):
            try:
                data[i, j] = float(x) if x.strip() else np.nan
            except ValueError:
                raise ParameterError(f"{label}: data row {i + 1}, column {header[j]!r}: {_short(x)!r} is not a "
                                     "number; allowed: numbers (empty or nan fields are refused as NaN rows)") from None
    return header, data, raw


def _short(text: str, n: int = 40) -> str:
    """``text`` cut to ``n`` characters for a message (a 1 MB field is not quoted whole)."""
    return text if len(text) <= n else text[:n] + f"... ({len(text)} characters)"


def _names(items, n: int = 10) -> str:
    """The first ``n`` of ``items`` for a message, and how many more: a 100,000-column header is
    not one 1 MB line."""
    items = list(items)
    shown = ", ".join(repr(_short(str(x))) for x in items[:n])
    return f"[{shown}{f', ... ({len(items) - n} more)' if len(items) > n else ''}]"


def _fast_body(lines: list[str], width: int) -> np.ndarray | None:
    """The numbers of a well-formed body by numpy's C parser (a 30,000-row log in milliseconds);
    None when anything is unusual (empty fields, ragged rows, text), which the careful reader
    then names row by row."""
    if not lines:
        return np.empty((0, width))
    try:
        data = np.loadtxt(lines, delimiter=",", dtype=float, ndmin=2)
    except ValueError:
        return None
    return data if data.shape[1] == width else None


def read_log(path: str | Path, inputs: tuple[str, ...], outputs: tuple[str, ...], *,
             window: tuple[float, float] | None = None, gap: float | None = None,
             max_angle: float = MAX_ANGLE, label: str | None = None) -> Log:
    """Read ``path`` and return the columns ``inputs`` and ``outputs`` as measured.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    inputs, outputs : tuple of str
        Signal names the fit uses (:data:`INPUTS`, :data:`OUTPUTS`); each must be a column.
    window : (float, float), optional
        Keep START <= t < STOP (s of the log's time column); it must overlap the log.
    gap : float, optional
        An interval longer than this (s) splits the log into segments; default
        :data:`GAP_PERIODS` median periods. Must be > 0.
    max_angle : float
        Largest span of a ``theta`` column (rad), if the log has one.
    label : str, optional
        How messages name the log (default ``--log PATH``).

    Raises
    ------
    ParameterError
        A column missing or unknown, NaN rows, fewer than 3 samples, time not increasing, a window
        outside the log, a gap threshold <= 0, an angle beyond ``max_angle``, or a constant first
        input (the drive's; ``T_dist`` may be constant).
    """
    path = Path(path)
    label = label or f"--log {str(path)!r}"
    if gap is not None and not gap > 0:
        raise ParameterError(f"--gap {gap!r}; allowed: a threshold > 0 (s) above which an interval splits the log")
    needed = tuple(dict.fromkeys(tuple(inputs) + tuple(outputs)))
    header, data, raw = _read_rows(path, label)
    allowed = ("time",) + INPUTS + tuple(o for o in OUTPUTS if o not in INPUTS)
    unknown = [h for h in header if h not in allowed]
    if unknown:
        raise ParameterError(f"{label}: unknown column(s) {_names(unknown)}; allowed: {list(allowed)}")
    # counted once (header.count per column is quadratic: minutes for a 100,000-column header)
    dup = sorted(h for h, n in collections.Counter(header).items() if n > 1)
    if dup:
        raise ParameterError(f"{label}: column(s) {dup} given twice; allowed: each column once")
    missing = [c for c in ("time",) + needed if c not in header]
    if missing:
        raise ParameterError(f"{label}: missing column(s) {missing} (it has {_names(header)}); allowed: a header "
                             f"with time and {list(needed)}")
    used = ("time",) + needed + (("theta",) if "theta" in header and "theta" not in needed else ())
    cols = {h: data[:, i] for i, h in enumerate(header) if h in used}
    bad = np.flatnonzero(~np.all(np.isfinite(np.column_stack(list(cols.values()))), axis=1))
    if bad.size:
        rows = ", ".join(str(i + 1) for i in bad[:5]) + (" ..." if bad.size > 5 else "")
        raise ParameterError(f"{label}: {bad.size} row(s) with NaN, infinite (beyond 1.8e308) or missing values "
                             f"(data rows {rows}); "
                             "allowed: finite numbers in every used column (cut or repair the log)")
    t = cols.pop("time")
    if t.size < 3:
        raise ParameterError(f"{label}: {t.size} samples; allowed: at least 3 (and several periods of the "
                             "slowest mode)")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0])
        raise ParameterError(f"{label}: time is not increasing at data row {i + 2} (t = {float(t[i + 1])!r} after "
                             f"{float(t[i])!r}); allowed: strictly increasing time stamps (s)")
    from_start = True
    if window is not None:
        lo, hi = window
        inside = (t >= lo) & (t < hi)
        if np.count_nonzero(inside) < 3:
            raise ParameterError(f"{label}: --window {lo:g}:{hi:g} s holds {np.count_nonzero(inside)} samples of "
                                 f"a log from {float(t[0]):g} to {float(t[-1]):g} s; allowed: a window inside the log")
        from_start = bool(inside[0])
        t = t[inside]
        cols = {k: v[inside] for k, v in cols.items()}
        dt = np.diff(t)
    mean = float((t[-1] - t[0]) / (t.size - 1))
    if not PERIOD_RANGE[0] <= mean <= PERIOD_RANGE[1]:
        # a time column in another unit (ms, us, ticks) or stamps near the ends of the float range:
        # the sampled model would overflow or lose every digit
        raise ParameterError(f"{label}: mean sampling period {mean:.6g} s; allowed: {PERIOD_RANGE[0]:g} to "
                             f"{PERIOD_RANGE[1]:g} s (the time column in seconds)")
    median = float(np.median(dt))
    threshold = GAP_PERIODS * median if gap is None else float(gap)
    starts = (0,) + tuple(int(i) + 1 for i in np.flatnonzero(dt > threshold))
    jitter = float(np.max(np.abs(dt - mean)) / mean)
    uniform = jitter <= UNIFORM_JITTER and len(starts) == 1
    sampling = {"mean_period": mean, "median_period": median, "jitter": jitter,
                "jitter_rms": float(np.std(dt) / mean), "samples_in_file": int(data.shape[0]),
                "gap_threshold": threshold, "segments": len(starts), "longest_interval": float(dt.max()),
                "window": None if window is None else [float(t[0]), float(t[-1])], "uniform": uniform}
    if "theta" in cols:
        span = float(np.ptp(cols["theta"]))
        if span > max_angle:
            raise ParameterError(f"{label}: theta spans {span:.3g} rad ({float(cols['theta'].min()):.3g} .. "
                                 f"{float(cols['theta'].max()):.3g}); allowed: at most {max_angle:g} rad: the model "
                                 "is linear about an operating point (--max-angle lifts the limit; --window a "
                                 "small-motion part)")
        if "theta" not in needed:
            cols.pop("theta")
    for k in inputs[:1]:           # the drive's input must excite it; a port torque may stay 0
        v = cols[k]
        if np.ptp(v) <= 1e-12 * max(1.0, float(np.max(np.abs(v)))):
            raise ParameterError(f"{label}: input {k} is constant ({float(v[0])!r}); allowed: an input that "
                                 "excites the drive (a band-limited random signal or a chirp)")
    return Log(path.name, mean, {k: np.ascontiguousarray(cols[k]) for k in needed}, sampling,
               hashlib.sha256(raw).hexdigest(), str(path), np.ascontiguousarray(t), starts, uniform, from_start)
