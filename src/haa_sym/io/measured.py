"""Reading measured stability points (``regions --measured points.csv``, issue 17): a CSV with
a header naming the columns ``P_gain`` (Nm/rad), ``D_gain`` (Nms/rad) and ``outcome``
(``stable``, ``unstable`` or ``limit_cycle``), one experiment per row. Other columns (a note, a
date) are allowed and ignored; blank lines are skipped. Every mistake is one line naming the
file, the line and the value."""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass

import numpy as np

from haa_sym.errors import ParameterError
from haa_sym.io.inputs import read_text

__all__ = ["OUTCOMES", "COLUMNS", "MeasuredPoints", "read_measured"]

OUTCOMES = ("stable", "unstable", "limit_cycle")
COLUMNS = ("P_gain", "D_gain", "outcome")
# the largest measured-points file read, bytes (a few hundred bytes a point: a million points)
MAX_BYTES = 64 << 20


@dataclass(frozen=True)
class MeasuredPoints:
    """Experiments: ``P_gain`` (Nm/rad), ``D_gain`` (Nms/rad), ``outcome`` (one of
    :data:`OUTCOMES`), flat arrays of one length; ``source``: the file."""

    P_gain: np.ndarray
    D_gain: np.ndarray
    outcome: np.ndarray
    source: str


def read_measured(path, field: str = "--measured") -> MeasuredPoints:
    """The points of ``path``, checked (module docstring); ParameterError of one line otherwise."""
    where = f"{field} {str(path)!r}"
    allowed = f"allowed: a CSV with the header columns {list(COLUMNS)}, outcome one of {list(OUTCOMES)}"
    text = read_text(path, field, encoding="utf-8-sig", limit=MAX_BYTES, where=where)
    rows = csv.reader(io.StringIO(text))
    header, P, D, out = None, [], [], []
    for row in _rows(rows, where, allowed):
        line = rows.line_num
        if not any(c.strip() for c in row):
            continue
        if header is None:
            header = [c.strip() for c in row]
            missing = [c for c in COLUMNS if c not in header]
            if missing:
                raise ParameterError(f"{where} line {line}: header {_short(header)} lacks {missing}; {allowed}")
            twice = [c for c in COLUMNS if header.count(c) > 1]
            if twice:                       # which of the two is the experiment's is not ours to guess
                raise ParameterError(f"{where} line {line}: header {_short(header)} names {twice[0]} "
                                     f"{header.count(twice[0])} times; {allowed}, each once")
            idx = [header.index(c) for c in COLUMNS]
            continue
        if len(row) != len(header):
            raise ParameterError(f"{where} line {line}: {len(row)} fields, the header has {len(header)}; {allowed}")
        vals = [row[i].strip() for i in idx]
        for name, v, lst in (("P_gain", vals[0], P), ("D_gain", vals[1], D)):
            try:
                x = float(v)
            except ValueError:
                x = math.nan
            if not (math.isfinite(x) and x >= 0):
                unit = "Nm/rad" if name == "P_gain" else "Nms/rad"
                raise ParameterError(f"{where} line {line}: {name} = {_short(v)!r}; allowed: a finite number >= 0 ({unit})")
            lst.append(x)
        if vals[2] not in OUTCOMES:
            raise ParameterError(f"{where} line {line}: outcome = {_short(vals[2])!r}; allowed: one of {list(OUTCOMES)}")
        out.append(vals[2])
    if header is None or not out:
        raise ParameterError(f"{where}: no {'header' if header is None else 'rows'}; {allowed} and at least one row")
    return MeasuredPoints(np.array(P), np.array(D), np.array(out), str(path))


def _rows(reader, where: str, allowed: str):
    """The rows of ``reader``; a line that is not CSV (a field over csv's 128 KiB limit, a NUL)
    is one line naming it."""
    try:
        yield from reader
    except csv.Error as exc:
        raise ParameterError(f"{where} line {reader.line_num}: not CSV ({exc}); {allowed}") from None


def _short(v, n: int = 200):
    """``v`` (a text or a header list) cut for a message: a 1 MB field is not quoted whole."""
    if isinstance(v, list):
        v = [_short(x, 40) for x in v]
        return v if len(v) <= 10 else v[:10] + [f"... ({len(v) - 10} more)"]
    return v if len(v) <= n else v[:n] + f"... ({len(v)} characters)"
