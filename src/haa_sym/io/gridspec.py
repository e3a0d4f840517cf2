"""Gain grids from text: the one syntax of every ``--P-gain`` / ``--D-gain`` flag and of
:func:`grid` (``log:START:STOP:N``, ``lin:START:STOP:N`` or a comma-separated list)."""
from __future__ import annotations

import re

import numpy as np

from haa_sym.errors import ParameterError
from haa_sym.io.budget import check_memory
from haa_sym.model.params import gain_array

__all__ = ["grid", "gain_axis", "GRID_SYNTAX"]

GRID_SYNTAX = ("'log:START:STOP:N' (0 < START <= STOP), 'lin:START:STOP:N' (0 <= START <= STOP) or a "
               "comma-separated list of numbers >= 0, all finite, N an integer >= 1")


def grid(spec: str, name: str = "grid") -> np.ndarray:
    """Gain grid from a spec: ``log:START:STOP:N``, ``lin:START:STOP:N`` or ``v1,v2,...``.

    >>> grid("lin:1:50:3")
    array([ 1. , 25.5, 50. ])
    """
    def bad(why):
        return ParameterError(f"{name} = {spec!r}: {why}; allowed: {GRID_SYNTAX}")

    def number(text, what=""):
        try:
            v = float(text)
        except ValueError:
            raise bad(f"{what}{text.strip()!r} is not a number") from None
        if not np.isfinite(v):
            raise bad(f"{what}{text.strip()} is not finite")
        if v < 0:
            raise bad(f"{what}{text.strip()} is negative")
        return v

    s = str(spec).strip()
    kind, _, rest = s.partition(":")
    if kind in ("log", "lin"):
        parts = rest.split(":")
        if len(parts) != 3:
            raise bad(f"expected 3 fields after '{kind}:' (START:STOP:N), got {len(parts)}")
        a, b = number(parts[0], "START = "), number(parts[1], "STOP = ")
        # ASCII digits only: str.isdigit also accepts "²", which int() then refuses
        if not re.fullmatch(r"[0-9]+", parts[2].strip()) or int(parts[2]) < 1:
            raise bad(f"N = {parts[2].strip()!r} is not an integer >= 1")
        n = int(parts[2])
        if a > b:
            raise bad(f"START = {a:g} is above STOP = {b:g} (reversed range)")
        if kind == "log" and a == 0:
            raise bad("START = 0: a log grid needs START > 0")
        check_memory(16 * n, f"{name} = {spec!r}: a grid of {n} points")
        return np.logspace(np.log10(a), np.log10(b), n) if kind == "log" else np.linspace(a, b, n)
    return np.array([number(v) for v in s.split(",")])


def gain_axis(spec, flag: str, name: str) -> np.ndarray:
    """The values of a gain flag (``--P-gain``, the explorer's fields): a grid spec, a list, or
    one value, which gets the gain rule's own message naming the unit (``name``: "P_gain" or
    "D_gain"; ``flag``: how messages call the input)."""
    try:
        value = float(spec)
    except (TypeError, ValueError):
        return grid(spec, flag)
    return gain_array(name, value, flag).reshape(1)
