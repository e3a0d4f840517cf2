"""A torque-gain schedule as embedded C: ``haa_schedule.h`` and ``haa_schedule.c``.

:func:`write_c` turns a :class:`~haa_sym.design.schedule_table.ScheduleTable` into plain C99 (``static
const double`` tables, no allocation, only libm) for the joint's low-level controller. The table,
its validation, the lookup rule (repeated in the generated header) and the lookup's Python twin
(:func:`lookup`) are in
:mod:`haa_sym.design.schedule_table`; this module re-exports their names.

The C text is in the templates ``haa_sym/design/templates/haa_schedule.h.in`` and
``haa_schedule.c.in`` (package data): readable C with ``string.Template`` placeholders
(``$name``), filled in by :func:`c_code` (the rules are at ``_render``).

Reproducibility: the same table gives the same bytes (the tables and the ``#define`` values
printed with ``%.17g``, which round-trips a double through a correctly rounding compiler such as
gcc and clang; lines end in ``\\n``; meta in a fixed order). The comments are for a reader and
independent of where the table came from: their numbers are rounded to 12 significant digits
(a computed grid's ``2000.0000000000002`` reads ``2000.0``, ``30.0`` stays ``30.0``) and an
absolute path in the meta shows as its file name. With floating-point contraction off
(``-ffp-contract=off``, gcc's default with ``-std=c99``) the C and the Python lookups perform the
same IEEE operations and agree exactly on a machine whose libm ``log`` is the one Python uses.

Example
-------
>>> import numpy as np
>>> P, D = np.geomspace(1.0, 2000.0, 4), np.array([1.0, 25.0, 50.0])
>>> beta = np.array([[8.0, 8.0, 8.0], [6.0, 7.0, 8.0], [2.0, 4.0, 5.0], [0.1, 1.0, 2.0]])
>>> feasible = np.ones((4, 3), bool); feasible[3, 0] = False
>>> meta = {"actuator": "hyq_haa.toml", "source": "model/hyq_haa.toml",
...         "requirements": "stable, phase margin >= 30 deg", "tolerances": "beta 1e-3",
...         "haa_sym_version": "0.1"}
>>> header, source = c_code(ScheduleTable(P, D, beta, feasible, meta))
>>> header.splitlines()[-1]
'#endif /* HAA_SCHEDULE_H */'
>>> write_c(ScheduleTable(P, D, beta, feasible, meta), "controller/")   # doctest: +SKIP
(PosixPath('controller/haa_schedule.h'), PosixPath('controller/haa_schedule.c'))
"""
from __future__ import annotations

import importlib.resources
import numbers
import os
import re
import string
from pathlib import Path

import numpy as np

from haa_sym.errors import OutputError, ParameterError
from haa_sym.io.outputs import Transaction, check_file, transaction
# the table and the lookup's Python twin, importable from here as before
from haa_sym.design.schedule_table import META_KEYS, NAN, NO_SAFE_GAIN, OK, OUTSIDE, ScheduleTable, lookup

__all__ = ["ScheduleTable", "META_KEYS", "HEADER", "SOURCE", "c_code", "write_c", "lookup", "OK", "OUTSIDE",
           "NO_SAFE_GAIN", "NAN"]

HEADER = "haa_schedule.h"
SOURCE = "haa_schedule.c"
_SPACING_RTOL = 1e-9        # neighbour steps (or ratios) equal to this are "uniform" in the header


# ------------------------------------------------------------------------------------ emission

def _num(x: float) -> str:
    """A C double literal that reads back as ``x`` (``%.17g``, with a point when integral)."""
    s = "%.17g" % x
    return s if any(ch in s for ch in ".en") else s + ".0"


# Significant digits of a number in a comment (as the schedule's CSV prints beta): enough for a
# reader, and float noise (2000.0000000000002 from a computed grid) disappears.
_COMMENT_DIGITS = 12
_SEGMENT = r"""[^\s,;)\]}"'\\/]+"""
# An absolute path in a meta text (a drive, home, POSIX or UNC path, at the start or after a space,
# '=', ',', ';', '(', '[', '{' or a quote): the comment shows its file name, so the header does not
# depend on where the source file was (nor on who built it).
_ABSOLUTE_PATH = re.compile(rf"""(?<![^\s=,;(\[{{"'])(?:(?:[A-Za-z]:|~)[\\/]{_SEGMENT}(?:[\\/]{_SEGMENT})*"""
                            rf"""|(?:/|\\\\){_SEGMENT}(?:[\\/]{_SEGMENT})+)[\\/]?""")


def _file_name(match: re.Match) -> str:
    return re.split(r"[\\/]", match[0].rstrip("\\/"))[-1]


def _text(v) -> str:
    """Meta value as comment text: printable ASCII, escaped (a path may hold anything); numbers
    rounded to :data:`_COMMENT_DIGITS` digits, absolute paths as their file name. (The tables and
    the ``#define`` values are :func:`_num`: exact.)"""
    if isinstance(v, dict):
        return ", ".join(f"{_text(k)} = {_text(x)}" for k, x in v.items())
    if isinstance(v, (list, tuple)):
        return ", ".join(_text(x) for x in v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, numbers.Integral):
        return str(int(v))
    if isinstance(v, numbers.Real):
        return repr(float(f"{float(v):.{_COMMENT_DIGITS}g}"))
    s = _ABSOLUTE_PATH.sub(_file_name, str(v))
    s = s.encode("ascii", "backslashreplace").decode("ascii")
    s = "".join(ch if " " <= ch <= "~" else f"\\x{ord(ch):02x}" for ch in s)
    # no comment delimiters (-Wcomment), no trigraph (??/ would splice lines)
    return s.replace("*/", "* /").replace("/*", "/ *").replace("??", "?\\?")


def _spacing(x: np.ndarray, unit: str, log: bool) -> str:
    """How the header describes a grid axis (``log``: prefer "logarithmically spaced" when
    both descriptions fit, as for two points)."""
    head = f"{x.size} values from {_text(float(x[0]))} to {_text(float(x[-1]))} {unit}"
    ratio, step = x[1:] / x[:-1], np.diff(x)
    kinds = {"log": np.allclose(ratio, ratio[0], rtol=_SPACING_RTOL, atol=0),
             "lin": np.allclose(step, step[0], rtol=_SPACING_RTOL, atol=0)}
    for kind in (("log", "lin") if log else ("lin", "log")):
        if kinds[kind] and kind == "log":
            return f"{head}, logarithmically spaced (ratio {ratio[0]:.6g} between neighbours)"
        if kinds[kind]:
            return f"{head}, uniformly spaced (step {step[0]:.6g} {unit})"
    return f"{head}, not uniformly spaced (see the table in {SOURCE})"


def _hang(line: str) -> int:
    """Indentation of a comment line's continuation lines: under a numbered item's text, two
    more than an indented line, none for a line at the margin."""
    indent = len(line) - len(line.lstrip(" "))
    return indent + (3 if re.match(r"\d+\. ", line[indent:]) else 2 if indent else 0)


def _wrap(comment_lines: list[str], width: int = 96) -> list[str]:
    out = []
    for line in comment_lines:
        indent, hang = len(line) - len(line.lstrip(" ")), _hang(line)
        words, cur = line.split(" ")[indent:], " " * indent
        for w in words:
            if len(cur) + len(w) + 1 > width and cur.strip():
                out.append(cur.rstrip())
                cur = " " * hang
            cur += w + " "
        out.append(cur.rstrip())
    return [(" * " + l).rstrip() for l in out]


def _unwrap(lines: list[str]) -> list[str]:
    """The inverse of :func:`_wrap` on a template's comment (without its `` * ``): a line indented
    exactly as the continuation of the line before it (:func:`_hang`) continues that line."""
    out: list[str] = []
    hang = None
    for line in lines:
        indent = len(line) - len(line.lstrip(" "))
        if line and hang is not None and indent == hang:
            out[-1] += " " + line[indent:]
        else:
            out.append(line)
            hang = _hang(line) if line else None
    return out


# ------------------------------------------------------------------------------------ templates
# haa_sym/design/templates/haa_schedule.{h,c}.in: the C text with string.Template placeholders.
# ``$name`` inside a line takes a text value; a placeholder alone on its line (after spaces) takes
# a list of lines, each emitted with the placeholder's indentation (none for an empty list: the
# parts that exist only when alpha is scheduled). In the header, the comment from ``/*`` to
# `` */`` is re-wrapped at 96 columns after the substitution (each paragraph or item, with its
# continuation lines, is one line to wrap; see _unwrap), so values of any length wrap as before.

def _template(name: str) -> str:
    path = importlib.resources.files("haa_sym.design") / "templates" / f"{name}.in"
    return path.read_text(encoding="ascii")


def _fill(lines: list[str], values: dict) -> list[str]:
    text = {k: v for k, v in values.items() if isinstance(v, str)}
    out = []
    for line in lines:
        m = re.fullmatch(r"( *)\$([A-Za-z_][A-Za-z0-9_]*)", line)
        if m and isinstance(values.get(m[2]), list):
            out += [m[1] + item if item else "" for item in values[m[2]]]
        else:
            out.append(string.Template(line).substitute(text))
    return out


def _render(name: str, values: dict, wrap_comment: bool = False) -> str:
    """The template ``name`` + ``.in`` with ``values`` substituted (every placeholder a value,
    every value a placeholder: a template and this module cannot drift apart silently)."""
    template = _template(name)
    names = set(string.Template(template).get_identifiers())
    if names != set(values):
        raise RuntimeError(f"the template {name}.in and haa_sym.design.schedule_c disagree: placeholders "
                           f"without a value {sorted(names - set(values))}, values without a "
                           f"placeholder {sorted(set(values) - names)}")
    lines = template.split("\n")
    head: list[str] = []
    if wrap_comment:
        end = lines.index(" */")
        comment = [line[3:] if line.startswith(" * ") else "" for line in lines[1:end]]
        if lines[0] != "/*" or any(not (line.startswith(" * ") or line == " *") for line in lines[1:end]):
            raise RuntimeError(f"the template {name}.in: its comment must start with a line '/*' and "
                               "continue with lines ' * TEXT' or ' *' up to ' */'")
        head = ["/*", *_wrap(_fill(_unwrap(comment), values)), " */"]
        lines = lines[end + 1:]
    return "\n".join(head + _fill(lines, values))


def _rows(values: list[str], per_line: int, row: int | None = None, row_label=None) -> list[str]:
    """An initializer's lines: ``per_line`` values a line, a comment line before each row of
    ``row`` values when ``row_label`` is given, no comma after the last value."""
    lines = []
    chunk = row or len(values)
    for r in range(0, len(values), chunk):
        seg = values[r:r + chunk]
        if row_label is not None:
            lines.append(f"/* {row_label(r // chunk)} */")
        for s in range(0, len(seg), per_line):
            lines.append(", ".join(seg[s:s + per_line]) + ",")
    lines[-1] = lines[-1].rstrip(",")
    return lines


def c_code(table: ScheduleTable) -> tuple[str, str]:
    """The text of ``haa_schedule.h`` and ``haa_schedule.c`` for ``table`` (byte-reproducible)."""
    if not isinstance(table, ScheduleTable):
        raise ParameterError(f"table = {table!r}; allowed: a haa_sym.design.schedule_c.ScheduleTable")
    c, (nP, nD) = table._c, table.shape
    has_alpha = table.alpha is not None
    meta = table.meta
    prov = [f"{k}: {_text(meta[k])}" for k in META_KEYS]
    prov += [f"{_text(k)}: {_text(meta[k])}" for k in sorted(k for k in meta if k not in META_KEYS
                                                                     and k != "cell_check")]
    n_cells = (nP - 1) * (nD - 1)
    n_bytes = 8 * (2 * nP - 1 + nD + nP * nD * (2 if has_alpha else 1)) + n_cells
    version = _text(meta["haa_sym_version"])
    # what the producer verified between grid points (its own words), or that nothing was
    check = meta.get("cell_check")
    cell_check = _text(check) if check is not None else (
        "Nothing: the table's producer did not state a check of the cells; a cell is marked safe "
        "when its four corners are feasible, and the interpolated gains between them are not verified.")
    header = _render(HEADER, {
        "scheduled": "beta and alpha" if has_alpha else "beta", "version": version,
        "provenance": prov,
        "alpha_units": ["alpha: dimensionless, scales the velocity compensation (Eq. 6); "
                        "scheduled together with beta and interpolated with the same weights."]
                       if has_alpha else [],
        "p_gain_grid": _spacing(table.P_gain, "Nm/rad", True),
        "d_gain_grid": _spacing(table.D_gain, "Nms/rad", False),
        "n_feasible": str(int(table.feasible.sum())), "n_points": str(nP * nD),
        "n_safe": str(int(table.cell_safe.sum())), "n_cells": str(n_cells),
        "n_bytes": str(n_bytes), "cell_check": cell_check,
        "n_p_gain": str(nP), "n_d_gain": str(nD),
        "p_gain_min": _num(c["P"][0]), "p_gain_max": _num(c["P"][-1]),
        "d_gain_min": _num(c["D"][0]), "d_gain_max": _num(c["D"][-1]),
        "has_alpha": str(int(has_alpha)),
    }, wrap_comment=True)

    p_label = lambda i: f"P_gain = {_text(c['P'][i])} Nm/rad; D_gain index 0..{nD - 1}"
    cell_label = lambda i: f"cells from P_gain = {_text(c['P'][i])} Nm/rad; D_gain cell 0..{nD - 2}"
    table_rows = lambda key: _rows([_num(v) for v in c[key]], 4, nD, p_label)
    size = "HAA_SCHEDULE_N_P_GAIN * HAA_SCHEDULE_N_D_GAIN"
    source = _render(SOURCE, {
        "version": version,
        "p_gain": _rows([_num(v) for v in c["P"]], 4),
        "log_step": _rows([_num(v) for v in c["log_step"]], 4),
        "d_gain": _rows([_num(v) for v in c["D"]], 4),
        "beta": table_rows("beta"),
        "alpha_table": [f"static const double haa_schedule_alpha_[{size}] = {{",
                        *("    " + line for line in table_rows("alpha")), "};"] if has_alpha else [],
        "cell_safe": _rows([str(int(v)) for v in c["cell_safe"]], 16, nD - 1, cell_label),
        "alpha_write": ["if (alpha)", "    *alpha = haa_schedule_interpolate_(haa_schedule_alpha_, base, w);"]
                       if has_alpha else ["(void)alpha;                            /* alpha is not scheduled */"],
    })
    return header, source


def check_c_directory(directory: str | Path, field: str = "--c-out", names: tuple = (HEADER, SOURCE)) -> Path:
    """``directory`` as a Path if it is a writable directory or can be created (the rule of every
    output path, :mod:`haa_sym.io.outputs`) and its files ``names`` (default the schedule's) may be
    written; else an OutputError naming ``field`` (a command checks this before computing anything)."""
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise OutputError(f"{field} {str(d)!r} is not a directory; allowed: a directory (created if missing)")
    if d.is_dir() and not os.access(d, os.W_OK | os.X_OK):
        raise OutputError(f"{field} {str(d)!r} is not writable; allowed: a writable directory")
    for name in names:                     # missing: its existing ancestors must allow creating it;
        check_file(d / name, field)        # existing: not one of the command's inputs
    return d


def write_c(table: ScheduleTable, directory: str | Path, tx: Transaction | None = None,
            field: str = "--c-out") -> tuple[Path, Path]:
    """Write ``haa_schedule.h`` and ``haa_schedule.c`` for ``table`` into ``directory``.

    Both files appear together or neither changes (:mod:`haa_sym.io.outputs`); with ``tx`` they
    are staged in that transaction and appear when its owner commits (with the command's other
    outputs).

    Parameters
    ----------
    table : ScheduleTable
    directory : str or Path
        A writable directory; created with any missing parents when the files are committed
        (and removed again, if it was created, when the transaction rolls back).
    tx : haa_sym.io.outputs.Transaction, optional
    field : str, optional
        How messages name the directory (default ``--c-out``, the CLI option).

    Returns
    -------
    (Path, Path)
        The header and the source.

    Raises
    ------
    ParameterError
        (an :class:`haa_sym.io.outputs.OutputError`) naming ``field`` when ``directory`` is not an
        writable directory (nor can be created) or a file cannot be written; nothing is written.
    """
    d = check_c_directory(directory, field)
    header, source = c_code(table)                  # every check before the first byte
    with transaction(tx) as t:
        for name, text in ((HEADER, header), (SOURCE, source)):
            with t.open(d / name, "wb", field) as fh:
                fh.write(text.encode("ascii"))
    return d / HEADER, d / SOURCE
