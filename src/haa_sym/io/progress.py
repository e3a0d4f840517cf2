"""Progress bars and progress messages, on stderr only (stdout carries results).

One process-wide setting, :func:`set_progress`, chosen by the command line (``haa-sym --quiet``,
``haa-sym --progress``):

``None`` (default)  a bar on a terminal, for work that lasts more than ``DELAY_S`` (tqdm's own
                    ``delay``: nothing is drawn for shorter work, so quick calls stay silent);
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

__all__ = ["set_progress", "progress", "message", "DELAY_S"]

DELAY_S = 2.0
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
    tqdm.tqdm
        Use as a context manager.
    """
    from tqdm import tqdm
    mode = _mode if enabled is None else enabled
    file = sys.stderr
    ncols, nrows = _shape(file)
    # on a terminal the bar erases itself when done; forced (a log), its last state stays
    return tqdm(total=total, desc=desc, unit=unit, file=file, leave=bool(mode),
                # disable=None: tqdm shows the bar only when ``file`` is a terminal
                disable=None if mode is None else not mode,
                delay=0.0 if mode else DELAY_S, mininterval=MININTERVAL_S, ncols=ncols, nrows=nrows)


def message(text: str) -> None:
    """A progress message on stderr (what is being computed); silent with ``set_progress(False)``.
    Written through tqdm so that it does not break a bar being drawn."""
    if _mode is False:
        return
    from tqdm import tqdm
    tqdm.write(text, file=sys.stderr)
    sys.stderr.flush()
