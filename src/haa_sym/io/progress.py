"""Progress bars and progress messages, on stderr only (stdout carries results).

One process-wide setting, :func:`set_progress`, chosen by the command line (``haa-sym --quiet``,
``haa-sym --progress``):

``None`` (default)  a bar on a terminal, for work that lasts more than ``DELAY_S`` (tqdm's own
                    ``delay``: nothing is drawn for shorter work, so quick calls stay silent);
                    when stderr is not a terminal (a log, a CI job, ``nohup``), one plain line
                    every ``PERIOD_S`` seconds (``desc: done/total unit, elapsed s``) for work
                    that lasts longer than that, and a last line when it ends: a bar's carriage
                    returns are unreadable in a log, and silence cannot be told from a hang;
``True``            a bar from the start, also when stderr is not a terminal (logs, tests);
``False``           nothing: no bars and no progress messages.

Example
-------
>>> from haa_sym.io.progress import progress
>>> with progress(3, "demo", enabled=False) as bar:
...     bar.update(3)
"""
from __future__ import annotations

import os
import sys
import threading
import time

__all__ = ["set_progress", "progress", "message", "DELAY_S", "PERIOD_S", "PeriodicLines"]

DELAY_S = 2.0
#: Seconds between the plain progress lines written when stderr is not a terminal.
PERIOD_S = 10.0
# redraw at most twice a second: the bar must not cost time on a loaded 2-core machine
MININTERVAL_S = 0.5

_mode: bool | None = None


def set_progress(mode: bool | None) -> None:
    """Process-wide progress setting: None (terminal only), True (always) or False (never)."""
    global _mode
    _mode = mode


def _shape(file) -> tuple[int | None, int | None]:
    """(columns, rows) for tqdm. A terminal that reports a size of 0 x 0 (a pty nobody sized:
    ``script``, some IDE and CI consoles) makes tqdm compute -1 x -1 and draw nothing at all;
    use 80 x 24 then. (None, None): not a terminal, tqdm's own defaults."""
    try:
        size = os.get_terminal_size(file.fileno())
    except (AttributeError, OSError, ValueError):
        return None, None
    return (size.columns if size.columns > 0 else 80), (size.lines if size.lines > 0 else 24)


def _is_terminal(file) -> bool:
    try:
        return bool(file.isatty())
    except (AttributeError, OSError, ValueError):
        return False


class PeriodicLines:
    """Progress for a non-terminal: a line ``desc: done/total unit, elapsed s`` every
    ``period`` seconds while the work runs (from a daemon thread, so a single long task still
    shows the clock running), and a last line at the end if any line was written. Work shorter
    than ``period`` writes nothing. The subset of tqdm's interface the package uses
    (``update``, ``refresh``, ``n``, ``total``, a context manager)."""

    def __init__(self, total: int, desc: str, unit: str, file, period: float):
        self.total, self.desc, self.unit, self.file, self.period = total, desc, unit, file, period
        self.n, self.lines = 0, 0
        self._start = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="haa_sym-progress", daemon=True)
        self._thread.start()

    def _line(self) -> None:
        with self._lock:
            done = self.n
        self.file.write(f"{self.desc}: {done}/{self.total} {self.unit}, elapsed "
                        f"{time.monotonic() - self._start:.0f} s\n")
        self.file.flush()
        self.lines += 1

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            self._line()

    def update(self, n: int = 1) -> None:
        with self._lock:
            self.n += n

    def refresh(self) -> None:
        """tqdm's redraw after ``total`` changed: the next periodic line shows the new total."""

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join()
        if self.lines:
            self._line()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def progress(total: int, desc: str, unit: str = "it", enabled: bool | None = None):
    """A tqdm bar on stderr for ``total`` units of work.

    Parameters
    ----------
    total : int
        Units of work (``bar.update(n)`` as they complete).
    desc : str
        Label in front of the bar.
    unit : str
        Name of one unit ("pt" for gain points, "section", ...).
    enabled : bool or None
        Overrides the process-wide setting for this bar; None follows :func:`set_progress`.

    Returns
    -------
    tqdm.tqdm or PeriodicLines
        Use as a context manager. PeriodicLines (plain lines every :data:`PERIOD_S` s) in the
        default mode when stderr is not a terminal.
    """
    mode = _mode if enabled is None else enabled
    file = sys.stderr
    if mode is None and not _is_terminal(file):
        return PeriodicLines(total, desc, unit, file, PERIOD_S)
    ncols, nrows = _shape(file)
    # on a terminal the bar erases itself when done; forced (a log), its last state stays
    return _bar_class()(total=total, desc=desc, unit=unit, file=file, leave=bool(mode),
                # disable=None: tqdm shows the bar only when ``file`` is a terminal
                disable=None if mode is None else not mode,
                delay=0.0 if mode else DELAY_S, mininterval=MININTERVAL_S, ncols=ncols, nrows=nrows)


_BAR: list = []


def _bar_class():
    """tqdm without its monitor thread (a class of its own: a library caller's tqdm keeps its
    setting). The thread outlives every bar, and ``--scheduler local:N`` forks the worker
    processes later in the same process (haa_sym.io.pool): a fork while another thread may hold
    a lock (stderr's, tqdm's) can leave the child waiting on it for ever, and Python 3.12 warns
    on it. The monitor only refreshes a bar whose updates stalled; these bars refresh on
    ``mininterval`` and on every update."""
    if not _BAR:
        from tqdm import tqdm

        class Bar(tqdm):
            monitor_interval = 0
        _BAR.append(Bar)
    return _BAR[0]


def message(text: str) -> None:
    """A progress message on stderr (what is being computed); silent with ``set_progress(False)``.
    Written through tqdm so that it does not break a bar being drawn."""
    if _mode is False:
        return
    from tqdm import tqdm
    tqdm.write(text, file=sys.stderr)
    sys.stderr.flush()
