"""All-or-nothing output files: a command's outputs appear together, or none changes.

A :class:`Transaction` stages every output to a temporary file in the target's own directory
(created with mode 0666 minus the umask, like any new file), and :meth:`Transaction.commit`
moves them into place with ``os.replace`` only when every one has been written. On any failure,
including ``KeyboardInterrupt``, the temporaries are removed and the existing files are left
untouched. A whole directory (``haa-sym reproduce --out DIR``) is staged as a temporary sibling
directory and swapped in at the end, so DIR is either the old one or the complete new one.

Paths are checked before any work starts (:func:`check_file`, :func:`check_directory`): a file
target must not be a directory, and the existing part of its path must be directories, the
deepest of them writable. Missing parent directories are one rule for every output (``--out``,
``--plot``, ``--c-out``, ``reproduce --out``): the transaction creates them when it stages the
first output below them (mode 0777 minus the umask, like ``mkdir -p``) and, if it rolls back,
removes again those it created that are still empty. So a failed or interrupted command leaves
no new directory behind; the one exception is a directory another process put a file into
meanwhile, which is not ours to delete. Messages name the user's path, never a temporary one.

No output replaces one of the command's own inputs: every file read through
:mod:`haa_sym.io.inputs` inside a command is recorded (by device and inode, so through any
symbolic or hard link), and :func:`check_file` (before the work and again at commit) refuses
such a target, as :func:`check_directory` refuses a directory holding one.

Replacing an existing target keeps what the user set on it:

* its permission bits: the new file (or directory) gets the old one's mode (a 0600 file stays
  0600, a 0700 directory 0700), not the umask's default;
* a symbolic link is followed: the file (or directory) it points to is written and the link
  stays a link (a dangling link creates its target, whose directory must exist);
* a read-only target (no write permission bit for anyone, e.g. 0444, or not writable by the
  user) is refused before any work, with the path and what is allowed: the user made it
  read-only, so it is not replaced behind their back (``chmod u+w`` it, or write elsewhere).

Example
-------
>>> with Transaction() as tx:                                   # doctest: +SKIP
...     tx.write_text("table.csv", "a,b\\n1,2\\n")
...     save_figure(fig, "plot.png", tx)       # both appear at the end of the block, or neither
"""
from __future__ import annotations

import contextlib
import csv
import io
import os
import re
import secrets
import shutil
import stat
from pathlib import Path
from typing import Callable, Iterator

from haa_sym.errors import OutputError
from haa_sym.io.inputs import check_no_input_below, check_not_input

__all__ = ["OutputError", "Transaction", "transaction", "check_file", "check_directory", "write_text",
           "csv_text"]


def _label(path: Path, field: str | None) -> str:
    return f"{field} {str(path)!r}" if field else repr(str(path))


def _missing_parents(path: Path) -> list[Path]:
    """The ancestors of ``path`` that do not exist, outermost first (what ``mkdir -p`` creates)."""
    missing = []
    parent = path.parent
    # a dangling symbolic link "does not exist" but cannot be created over: it counts as existing
    while not parent.exists() and not parent.is_symlink() and parent != parent.parent:
        missing.append(parent)
        parent = parent.parent
    return missing[::-1]


def _check_parent(path: Path, field: str | None) -> None:
    """The parent of ``path`` exists as a writable directory, or can be created: its deepest
    existing ancestor is a writable directory."""
    missing = _missing_parents(path)
    base = missing[0].parent if missing else path.parent
    if not base.is_dir():
        raise OutputError(f"{_label(path, field)}: {str(base)!r} is not a directory; allowed: a path "
                          "whose existing part is directories (missing ones are created)")
    if not os.access(base, os.W_OK | os.X_OK):
        what = f"cannot create directory {str(missing[0])!r}: " if missing else ""
        raise OutputError(f"{_label(path, field)}: {what}directory {str(base)!r} is not writable")


def _follow(path: Path) -> Path:
    """``path`` with its symbolic links resolved: the file the user's link points to is the one
    written (the link stays a link)."""
    return path.resolve() if path.is_symlink() else path


def _check_writable(path: Path, shown: Path, field: str | None, what: str) -> None:
    """Refuse an existing read-only target (see the module docstring)."""
    try:
        mode = path.stat().st_mode
    except (FileNotFoundError, NotADirectoryError):
        return                                   # a new file; _check_parent judges the directory
    if not (mode & 0o222) or not os.access(path, os.W_OK):
        raise OutputError(f"{_label(shown, field)}: the existing {what} is read-only (mode "
                          f"{stat.S_IMODE(mode):04o}); allowed: a writable {what} (chmod u+w it) or a new path")


def check_file(path: str | Path, field: str | None = None) -> Path:
    """Check that ``path`` can be written as a file: not a directory, not a read-only file; its
    parent a writable directory, or missing below a writable directory (the transaction creates
    it). Returns the path to write: a symbolic link resolved to its target.

    ``field`` (e.g. ``--out``) is how messages name the path.
    """
    shown = Path(path)
    path = _follow(shown)
    if path.is_dir():
        raise OutputError(f"{_label(shown, field)} is a directory; allowed: a file path")
    try:
        mode = path.stat().st_mode
    except OSError:
        mode = None                                # a new file
    if mode is not None and not stat.S_ISREG(mode):
        # os.replace would put a regular file where a device or a FIFO was (/dev/full, as root)
        raise OutputError(f"{_label(shown, field)} is not a regular file (a device, FIFO or socket); allowed: a "
                          "new path or an existing regular file")
    check_not_input(path, field, shown)
    _check_writable(path, shown, field, "file")
    _check_parent(path, field)
    return path


def check_directory(path: str | Path, field: str | None = None,
                    replaceable: Callable[[Path], str | None] | None = None) -> Path:
    """Check that ``path`` can be (re)placed as a whole directory.

    Missing parents are allowed as for :func:`check_file`. An existing ``path`` must be a
    directory that ``replaceable`` accepts: it returns None, or why the directory must not be
    replaced (e.g. it holds files the command does not write). Returns the path with a final
    symbolic link resolved (the directory it points to is the one replaced).
    """
    path = _follow(Path(path))
    check_no_input_below(path, field)
    if path.exists():
        if not path.is_dir():
            raise OutputError(f"{_label(path, field)} is not a directory; allowed: a new or existing "
                              "directory")
        _check_writable(path, path, field, "directory")
        why = replaceable(path) if replaceable else None
        if why:
            raise OutputError(f"{_label(path, field)}: {why}")
    _check_parent(path, field)
    return path


def _same_file(a: Path, b: Path) -> bool:
    """Whether the targets ``a`` and ``b`` (links resolved) name one file: the same path, or
    an existing file under two names (a hard link)."""
    if os.path.abspath(a) == os.path.abspath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _sibling(target: Path, tag: str) -> Path:
    # hidden, in the target's directory (same file system, so os.replace is a rename)
    return target.parent / f".{target.name}.{secrets.token_hex(4)}.{tag}"


def _create_sibling(target: Path, field: str | None, make, verb: str, what: str):
    """``(tmp, make(tmp))`` for a fresh temporary sibling of ``target``; a name taken by a
    concurrent writer is retried, any other failure is one error naming the user's path."""
    for _ in range(100):
        tmp = _sibling(target, "tmp")
        try:
            return tmp, make(tmp)
        except FileExistsError:
            continue
        except OSError as exc:
            raise OutputError(f"{_label(target, field)}: cannot {verb} ({exc.strerror})") from None
    raise OutputError(f"{_label(target, field)}: cannot create {what} next to it")


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _keep_mode(target: Path, *, fd: int | None = None, path: Path | None = None) -> None:
    """Give the staged temporary (an open ``fd`` or a ``path``) the existing target's permission
    bits, so that replacing a file never widens (or narrows) who may read it."""
    try:
        mode = stat.S_IMODE(target.stat().st_mode)
    except (FileNotFoundError, NotADirectoryError):
        return                                   # a new target: the umask's default
    if fd is not None:
        os.fchmod(fd, mode)
    else:
        os.chmod(path, mode)


class Transaction:
    """Outputs staged to temporaries and committed together (see the module docstring).

    Use as a context manager: a normal exit commits, an exception (any, including
    ``KeyboardInterrupt``) rolls back and propagates.
    """

    def __init__(self) -> None:
        self._staged: list[tuple[Path, Path, bool]] = []   # (temporary, target, is_directory)
        self._dir_checks: dict[Path, tuple] = {}             # target -> (field, replaceable)
        self._created: list[Path] = []                       # parent directories this one made

    def _make_parents(self, target: Path, field: str | None) -> None:
        """Create the missing parents of ``target``, remembering them for :meth:`rollback`."""
        for d in _missing_parents(target):
            try:
                os.mkdir(d, 0o777)
            except FileExistsError:
                continue                         # made meanwhile by someone else: not ours
            except OSError as exc:
                raise OutputError(f"{_label(target, field)}: cannot create directory {str(d)!r} "
                                  f"({exc.strerror})") from None
            self._created.append(d)

    def __enter__(self) -> "Transaction":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.commit()
        else:
            self.rollback()
        return False

    @contextlib.contextmanager
    def open(self, path: str | Path, mode: str = "wb", field: str | None = None) -> Iterator:
        """A file object writing the staged content of ``path`` (``mode`` "w" or "wb")."""
        target = check_file(path, field)
        same = next((t for _, t, _ in self._staged if _same_file(t, target)), None)
        if same is not None:
            # two outputs of one command in one file: the second would replace the first silently
            raise OutputError(f"{_label(Path(path), field)}: the same file as another output of this command "
                              f"({str(same)!r}); allowed: a path of its own for each output")
        self._make_parents(target, field)
        # 0o666 & ~umask, as open() gives a new file (mkstemp would force 0600)
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
        tmp, fd = _create_sibling(target, field, lambda t: os.open(t, flags, 0o666), "write",
                                  "a temporary file")
        try:
            _keep_mode(target, fd=fd)
            with os.fdopen(fd, mode) as fh:
                yield fh
        except BaseException as exc:
            _remove(tmp)                         # a failed write is never committed
            if isinstance(exc, OSError):
                raise OutputError(f"{_label(target, field)}: cannot write ({exc.strerror or exc})") from None
            raise
        self._staged.append((tmp, target, False))

    def write_text(self, path: str | Path, text: str, field: str | None = None) -> Path:
        with self.open(path, "w", field) as fh:
            fh.write(text)
        return Path(path)

    def directory(self, path: str | Path, field: str | None = None,
                  replaceable: Callable[[Path], str | None] | None = None) -> Path:
        """Stage the whole directory ``path``: returns an empty temporary sibling to fill.

        At commit the old directory (if any, and if ``replaceable`` still accepts it, see
        :func:`check_directory`) is replaced by the staged one.
        """
        target = check_directory(path, field, replaceable)
        self._make_parents(target, field)
        # 0o777 & ~umask, like mkdir (mkdtemp forces 0700)
        tmp, _ = _create_sibling(target, field, lambda t: os.mkdir(t, 0o777), "create",
                                 "a temporary directory")
        try:
            _keep_mode(target, path=tmp)
        except OSError as exc:
            _remove(tmp)
            raise OutputError(f"{_label(target, field)}: cannot write ({exc.strerror or exc})") from None
        self._staged.append((tmp, target, True))
        self._dir_checks[target] = (field, replaceable)
        return tmp

    def commit(self) -> None:
        """Move every staged output into place; on failure put back what was there."""
        done: list[tuple[Path, Path | None, bool]] = []   # (target, backup of the old one, existed)
        target = None
        try:
            # everything that can be checked is checked before the first target changes
            for _, target, is_dir in self._staged:
                if is_dir:
                    check_directory(target, *self._dir_checks[target])
                else:
                    check_file(target)
            for tmp, target, is_dir in self._staged:
                existed = target.exists()
                backup = _sibling(target, "old") if existed else None
                if existed and is_dir:
                    os.rename(target, backup)            # DIR is absent until the next rename
                elif existed:
                    try:
                        os.link(target, backup)          # keeps the old file while it is replaced
                    except OSError:
                        backup = None                    # no hard links here: no way back
                try:
                    os.replace(tmp, target)
                except BaseException:
                    if backup is not None:
                        (os.rename(backup, target) if is_dir else backup.unlink())
                    raise
                done.append((target, backup, existed))
        except BaseException as exc:
            for old_target, backup, existed in reversed(done):
                with contextlib.suppress(OSError):
                    if backup is not None:
                        if backup.is_dir():
                            _remove(old_target)
                            os.rename(backup, old_target)
                        else:
                            os.replace(backup, old_target)
                    elif not existed:
                        _remove(old_target)
            self.rollback()
            if isinstance(exc, OSError) and target is not None:
                raise OutputError(f"{_label(target, None)}: cannot write ({exc.strerror or exc})") from None
            raise
        self._staged = []
        self._created = []                       # they hold the outputs now: kept
        for _, backup, _ in done:
            if backup is not None:
                _remove(backup)

    def rollback(self) -> None:
        """Remove every staged temporary and the parent directories this transaction created
        (innermost first, each only if empty); the targets are untouched."""
        for tmp, _, _ in self._staged:
            _remove(tmp)
        self._staged = []
        for d in reversed(self._created):
            with contextlib.suppress(OSError):   # not empty: another writer's file is in it
                os.rmdir(d)
        self._created = []


@contextlib.contextmanager
def transaction(tx: Transaction | None = None) -> Iterator[Transaction]:
    """``tx`` itself (committed by its owner), or a new transaction committed at the end."""
    if tx is not None:
        yield tx
    else:
        with Transaction() as own:
            yield own


def write_text(path: str | Path, text: str, tx: Transaction | None = None, field: str | None = None) -> Path:
    """Write ``text`` to ``path`` through ``tx`` (or on its own, atomically)."""
    with transaction(tx) as t:
        return t.write_text(path, text, field)


_CSV_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def csv_text(rows: list[dict]) -> str:
    """CSV text that ``numpy.genfromtxt(..., delimiter=",", names=True)`` reads back unchanged:
    headers are plain identifiers (genfromtxt rewrites others, e.g. drops dots) and no value
    holds a comma, quote or newline (genfromtxt does not parse CSV quoting)."""
    for name in rows[0]:
        if not _CSV_NAME.fullmatch(name):
            raise ValueError(f"CSV header {name!r} is not a plain identifier")
    for row in rows:
        for v in row.values():
            if any(ch in str(v) for ch in ',"\n'):
                raise ValueError(f"CSV value {v!r} holds a comma, quote or newline")
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()
