"""Reading a user's input files: only regular files, of bounded size, never blocking, and
remembered so that no command writes over one of its own inputs.

Every file a command reads on the user's behalf (an actuator file, a log, a measured-points or
schedule CSV, an identification report) goes through :func:`read_bytes` / :func:`read_text`:

* the file is opened with ``O_NONBLOCK`` and checked with ``fstat`` before a byte is read, so a
  FIFO, a device (``/dev/zero``, ``/dev/stdin``), a socket or a directory is refused at once
  (it used to block the explorer's server, or fill the memory until the process died);
* at most ``limit`` bytes are read (default :data:`MAX_INPUT_BYTES`; a larger file is refused
  with its size, never read whole);
* inside a :func:`command_scope` (the command line opens one per command, the explorer one per
  export), the file's identity (its resolved path and its device and inode, so a symbolic or a
  hard link to it is the same file) is recorded, and :mod:`haa_sym.io.outputs` refuses to write
  or replace any recorded input: ``identify --log data.toml --out data.toml`` is one line, not a
  lost log;
* inside :func:`restrict_reads` (the explorer's server), only the files and directories given
  may be read: a page's URL cannot name ``/etc/passwd``.

This module sits at the bottom layer (beside :mod:`haa_sym.errors`, see
``tests/test_architecture.py``): the parameter reader of :mod:`haa_sym.model.params` uses it.

Example
-------
>>> from haa_sym.io.inputs import command_scope, read_text
>>> with command_scope():                                         # doctest: +SKIP
...     text = read_text("run.csv", "--log")    # recorded: writing run.csv now is refused
"""
from __future__ import annotations

import contextlib
import os
import stat
import threading
from pathlib import Path
from typing import Iterable, Iterator

from haa_sym.errors import OutputError, ParameterError

__all__ = ["MAX_INPUT_BYTES", "read_bytes", "read_text", "command_scope", "protect", "check_not_input",
           "check_no_input_below", "restrict_reads", "recorded_inputs"]

# The largest input file read, bytes: 1 GiB holds a 30-million-row three-column log, far more
# than any analysis here needs, and bounds what a mistaken path (a disk image, a core dump) costs
# before the refusal. Readers of small files pass a smaller limit (an actuator file: 16 MiB).
MAX_INPUT_BYTES = 1 << 30

_lock = threading.Lock()
_scopes: list[dict] = []          # the open command scopes, innermost last: {(dev, ino): shown path}
_roots: list[tuple[Path, ...]] = []   # the read restrictions in force, innermost last


def _human(n: int) -> str:
    for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n} bytes"


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def _allowed(real: Path) -> bool:
    """Whether ``real`` (a resolved path) is readable under every restriction in force."""
    for roots in _roots:
        if not any(real == r or r in real.parents for r in roots):
            return False
    return True


def read_bytes(path: str | os.PathLike, field: str, *, limit: int | None = None, where: str | None = None) -> bytes:
    """The content of the regular file ``path`` (see the module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        The file, as the user gave it (messages quote it so).
    field : str
        How messages name the input (``--log``, ``--params``, ``schedule``).
    limit : int, optional
        The largest size accepted, bytes (default :data:`MAX_INPUT_BYTES`).
    where : str, optional
        How messages name the input instead of ``field`` and the path (the caller's own label).

    Raises
    ------
    ParameterError
        One line naming ``field``, the path and what is allowed: a missing or unreadable file,
        not a regular file, larger than ``limit``, or outside the :func:`restrict_reads` roots.
    """
    limit = MAX_INPUT_BYTES if limit is None else int(limit)
    shown = os.fspath(path)
    label = where or f"{field} {shown!r}"
    try:
        real = Path(shown).expanduser().resolve()
    except (OSError, RuntimeError) as exc:       # a symbolic-link loop
        raise ParameterError(f"{label}: cannot resolve the path ({exc}); allowed: a readable file") from None
    with _lock:
        allowed = _allowed(real)
        roots = [str(r) for rs in _roots for r in rs]
    if not allowed:
        raise ParameterError(f"{label}: outside the files this server may read; allowed: files in or below "
                             f"{roots}")
    try:
        # O_NONBLOCK: opening a FIFO with no writer would otherwise wait forever
        fd = os.open(real, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise ParameterError(f"{label}: no such file; allowed: an existing file") from None
    except OSError as exc:
        raise ParameterError(f"{label}: cannot open ({exc.strerror or exc}); allowed: a readable file") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ParameterError(f"{label}: {_kind(st.st_mode)}; allowed: a regular file")
        if st.st_size > limit:
            raise ParameterError(f"{label}: {_human(st.st_size)}; allowed: a file of at most {_human(limit)}")
        os.set_blocking(fd, True)
        chunks, total = [], 0
        while True:
            # one byte past the limit tells a file that grew while it was read
            chunk = os.read(fd, min(1 << 24, limit + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > limit:
                raise ParameterError(f"{label}: more than {_human(limit)} (it grew while being read); allowed: "
                                     f"a file of at most {_human(limit)}")
    except OSError as exc:
        raise ParameterError(f"{label}: cannot read ({exc.strerror or exc}); allowed: a readable file") from None
    finally:
        os.close(fd)
    _record(st, shown)
    return b"".join(chunks)


def read_text(path: str | os.PathLike, field: str, *, limit: int | None = None, encoding: str = "utf-8",
              where: str | None = None) -> str:
    """:func:`read_bytes` decoded (``encoding``; "utf-8-sig" drops a byte-order mark). A file
    that is not text in that encoding is one line naming the first bad byte and its offset."""
    raw = read_bytes(path, field, limit=limit, where=where)
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as exc:
        raise ParameterError(f"{where or f'{field} {os.fspath(path)!r}'}: not a text file (byte 0x{exc.object[exc.start]:02x} "
                             f"at offset {exc.start} is not {encoding.upper().removesuffix('-SIG')}); allowed: a "
                             f"{encoding.upper().removesuffix('-SIG')} text file") from None


# ----------------------------------------------------------------------------- command scope

def _record(st: os.stat_result, shown: str) -> None:
    real = Path(shown).expanduser().resolve()
    with _lock:
        for scope in _scopes:
            scope.setdefault((st.st_dev, st.st_ino), (shown, real))


@contextlib.contextmanager
def command_scope() -> Iterator[None]:
    """Record every input read inside the block (see the module docstring); scopes nest."""
    scope: dict = {}
    with _lock:
        _scopes.append(scope)
    try:
        yield
    finally:
        with _lock:
            _scopes.remove(scope)


def protect(path: str | os.PathLike) -> None:
    """Record ``path`` as an input of every open scope without reading it (e.g. the explorer's
    actuator file, which its export must never replace). A missing path records nothing."""
    try:
        st = os.stat(path)
    except OSError:
        return
    _record(st, os.fspath(path))


def recorded_inputs() -> list[str]:
    """The inputs recorded by the innermost open scope, as the user named them."""
    with _lock:
        return [shown for shown, _ in _scopes[-1].values()] if _scopes else []


def check_not_input(target: str | os.PathLike, field: str | None = None, shown: str | os.PathLike | None = None
                    ) -> None:
    """Refuse (:class:`OutputError`) to write ``target`` when it is one of the inputs recorded
    in an open scope: the same file by device and inode, so through any symbolic or hard link."""
    try:
        st = os.stat(target)
    except OSError:
        return                                   # a new file cannot be an input
    with _lock:
        hit = next((s[(st.st_dev, st.st_ino)][0] for s in _scopes if (st.st_dev, st.st_ino) in s), None)
    if hit is not None:
        name = os.fspath(shown if shown is not None else target)
        label = f"{field} {name!r}" if field else repr(name)
        same = "" if os.fspath(hit) == name else f" (the same file as {hit!r})"
        raise OutputError(f"{label}: is one of this command's inputs{same}; allowed: an output path that is not "
                          "an input (write elsewhere, then move it)")


def check_no_input_below(directory: str | os.PathLike, field: str | None = None) -> None:
    """Refuse (:class:`OutputError`) to replace the whole ``directory`` when a recorded input
    lies in or below it (``reproduce --out DIR`` would delete it)."""
    d = Path(directory).expanduser().resolve()
    with _lock:
        hit = next((shown for s in _scopes for shown, real in s.values() if d == real or d in real.parents), None)
    if hit is not None:
        label = f"{field} {os.fspath(directory)!r}" if field else repr(os.fspath(directory))
        raise OutputError(f"{label}: holds {hit!r}, one of this command's inputs, and would be replaced; allowed: "
                          "an output directory that holds no input")


@contextlib.contextmanager
def restrict_reads(roots: Iterable[str | os.PathLike]) -> Iterator[tuple[Path, ...]]:
    """Allow reads only of the files in ``roots`` and of files in or below its directories
    (resolved: a link out of them is refused) while the block runs; restrictions nest (a read
    must satisfy every one in force). Yields the resolved roots. Nothing is allowed implicitly:
    the explorer passes the bundled model directory among its roots (this module sits below
    :mod:`haa_sym.model.resources`, which knows where that is)."""
    resolved = tuple(Path(r).expanduser().resolve() for r in roots)
    with _lock:
        _roots.append(resolved)
    try:
        yield resolved
    finally:
        with _lock:
            _roots.remove(resolved)
