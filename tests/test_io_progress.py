"""haa_sym.io.progress: progress on stderr only, --quiet silences it, --progress forces it, a bar
on a terminal."""
import io
import os
import sys

import pytest

from haa_sym.io import progress
from haa_sym.cli import main


# --- progress: stderr only, --quiet silences, --progress forces ----------------------------------
REGIONS = ["regions", "--P-gain", "log:1:20000:30", "--D-gain", "lin:1:50:20"]


@pytest.fixture
def reset_progress():
    yield
    progress.set_progress(None)


def test_progress_goes_to_stderr_and_quiet_silences_it(capsys, reset_progress):
    assert main(["--progress", *REGIONS]) == 0
    forced = capsys.readouterr()
    assert "region map" in forced.err and "600/600" in forced.err
    assert main(["--quiet", *REGIONS]) == 0
    quiet = capsys.readouterr()
    assert quiet.err == ""
    assert main([*REGIONS, "--quiet"]) == 0          # also after the command
    assert capsys.readouterr().err == ""
    # not a terminal, no flag: nothing either
    assert main(REGIONS) == 0
    plain = capsys.readouterr()
    assert plain.err == ""
    assert forced.out == quiet.out == plain.out and plain.out.startswith("600 points (curves):")


class _Terminal(io.StringIO):
    def isatty(self):
        return True

    def fileno(self):
        return 2


def test_progress_bar_appears_on_a_terminal(monkeypatch, capsys, reset_progress):
    """Default mode: a bar when stderr is a terminal and the work outlasts the delay (0 here
    instead of 2 s, to keep the test fast), also on a terminal reporting a 0 x 0 size (there
    tqdm alone draws nothing); --quiet wins over the terminal."""
    monkeypatch.setattr(progress, "DELAY_S", 0.0)
    monkeypatch.setattr(progress.os, "get_terminal_size", lambda fd: os.terminal_size((0, 0)))
    tty = _Terminal()
    monkeypatch.setattr(sys, "stderr", tty)
    with progress.progress(1, "sized") as bar:
        assert (bar.ncols, bar.nrows) == (80, 24)
    tty.seek(0)
    tty.truncate()
    assert main(REGIONS) == 0
    assert "region map" in tty.getvalue()
    out = capsys.readouterr().out
    tty.seek(0)
    tty.truncate()
    assert main(["-q", *REGIONS]) == 0
    assert tty.getvalue() == "" and capsys.readouterr().out == out


# --- a non-terminal (a log, CI, nohup): periodic plain lines ----------------------------------------
def test_non_terminal_gets_periodic_plain_lines(monkeypatch, reset_progress):
    """Default mode, stderr not a terminal: long work writes 'desc: done/total unit, elapsed s'
    lines every PERIOD_S (0.05 s here instead of 10 s) and a last line; work shorter than the
    period writes nothing; --quiet (set_progress(False)) writes nothing either."""
    import time
    log = io.StringIO()
    monkeypatch.setattr(sys, "stderr", log)
    monkeypatch.setattr(progress, "PERIOD_S", 0.05)
    with progress.progress(4, "schedule: cells (pass 2)", "task") as bar:
        for _ in range(4):
            time.sleep(0.06)
            bar.update(1)
    lines = log.getvalue().splitlines()
    assert len(lines) >= 3, lines
    assert all(ln.startswith("schedule: cells (pass 2): ") and ln.endswith(" s") and "\r" not in ln
               for ln in lines)
    assert "/4 task, elapsed " in lines[0]
    assert lines[-1].startswith("schedule: cells (pass 2): 4/4 task, elapsed ")
    done = [int(ln.split(": ")[-1].split("/")[0]) for ln in lines]
    assert done == sorted(done)
    log.seek(0)
    log.truncate()
    monkeypatch.setattr(progress, "PERIOD_S", 5.0)
    with progress.progress(2, "quick", "task") as bar:
        bar.update(2)
    assert log.getvalue() == ""
    monkeypatch.setattr(progress, "PERIOD_S", 0.01)
    progress.set_progress(False)
    with progress.progress(2, "quiet", "task") as bar:
        time.sleep(0.05)
        bar.update(2)
    assert log.getvalue() == ""


def test_a_bar_leaves_no_thread_behind(reset_progress):
    """No tqdm monitor thread: --scheduler local:N forks the command after its first bars
    (haa_sym.io.pool), and a fork while another thread may hold a lock is unsafe."""
    import threading

    import tqdm
    before = set(threading.enumerate())
    with progress.progress(50, "work", "task", True) as bar:
        for _ in range(50):
            bar.update(1)
    assert set(threading.enumerate()) - before == set()
    assert tqdm.tqdm.monitor_interval == 10          # a library caller's tqdm keeps its own setting
