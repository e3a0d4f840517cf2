"""A torque-gain schedule as embedded C: ``haa_schedule.h`` and ``haa_schedule.c``.

:func:`write_c` turns a :class:`~haa_sym.schedule_table.ScheduleTable` into plain C99 (``static
const double`` tables, no allocation, only libm) for the joint's low-level controller. The table,
its validation, the lookup rule (repeated in the generated header) and the lookup's Python twin
(:func:`lookup_beta`, :func:`lookup_alpha`, :func:`lookup_feasible`) are in
:mod:`haa_sym.schedule_table`; this module re-exports their names.

Reproducibility: the same table gives the same bytes (numbers printed with ``%.17g``, which
round-trips a double through a correctly rounding compiler such as gcc and clang; lines end in
``\\n``; meta in a fixed order). With floating-point contraction off (``-ffp-contract=off``,
gcc's default with ``-std=c99``) the C and the Python lookups perform the same IEEE operations
and agree exactly on a machine whose libm ``log`` is the one Python uses.

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

import numbers
import os
import re
from pathlib import Path

import numpy as np

from haa_sym.outputs import OutputError, Transaction, transaction
from haa_sym.params import ParameterError
# the table and the lookup's Python twin, importable from here as before
from haa_sym.schedule_table import (META_KEYS, ScheduleTable, lookup_alpha, lookup_beta,
                                    lookup_feasible)

__all__ = ["ScheduleTable", "META_KEYS", "HEADER", "SOURCE", "c_code", "write_c", "lookup_beta",
           "lookup_alpha", "lookup_feasible"]

HEADER = "haa_schedule.h"
SOURCE = "haa_schedule.c"
_SPACING_RTOL = 1e-9        # neighbour steps (or ratios) equal to this are "uniform" in the header


# ------------------------------------------------------------------------------------ emission

def _num(x: float) -> str:
    """A C double literal that reads back as ``x`` (``%.17g``, with a point when integral)."""
    s = "%.17g" % x
    return s if any(ch in s for ch in ".en") else s + ".0"


def _text(v) -> str:
    """Meta value as comment text: printable ASCII, escaped (a path may hold anything)."""
    if isinstance(v, dict):
        return ", ".join(f"{_text(k)} = {_text(x)}" for k, x in v.items())
    if isinstance(v, (list, tuple)):
        return ", ".join(_text(x) for x in v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, numbers.Integral):
        return str(int(v))
    if isinstance(v, numbers.Real):
        return repr(float(v))
    s = str(v).encode("ascii", "backslashreplace").decode("ascii")
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


def _wrap(comment_lines: list[str], width: int = 96) -> list[str]:
    out = []
    for line in comment_lines:
        indent = len(line) - len(line.lstrip(" "))
        words, cur = line.split(" ")[indent:], " " * indent
        # continuation lines align under a numbered item's text, or indent a listed line
        hang = indent + (3 if re.match(r"\d+\. ", line[indent:]) else 2 if indent else 0)
        for w in words:
            if len(cur) + len(w) + 1 > width and cur.strip():
                out.append(cur.rstrip())
                cur = " " * hang
            cur += w + " "
        out.append(cur.rstrip())
    return [(" * " + l).rstrip() for l in out]


def _array(name: str, ctype: str, size: str, values: list[str], per_line: int,
           row: int | None = None, row_label=None) -> list[str]:
    lines = [f"static const {ctype} {name}[{size}] = {{"]
    chunk = row or len(values)
    for r in range(0, len(values), chunk):
        seg = values[r:r + chunk]
        if row_label is not None:
            lines.append(f"    /* {row_label(r // chunk)} */")
        for s in range(0, len(seg), per_line):
            lines.append("    " + ", ".join(seg[s:s + per_line]) + ",")
    lines[-1] = lines[-1].rstrip(",")
    lines.append("};")
    return lines


def c_code(table: ScheduleTable) -> tuple[str, str]:
    """The text of ``haa_schedule.h`` and ``haa_schedule.c`` for ``table`` (byte-reproducible)."""
    if not isinstance(table, ScheduleTable):
        raise ParameterError(f"table = {table!r}; allowed: a haa_sym.schedule_c.ScheduleTable")
    c, (nP, nD) = table._c, table.shape
    has_alpha = table.alpha is not None
    fb_i, fb_j = divmod(table.fallback, nD)
    meta = table.meta
    prov = [f"{k}: {_text(meta[k])}" for k in META_KEYS]
    prov += [f"{_text(k)}: {_text(meta[k])}" for k in sorted(k for k in meta if k not in META_KEYS)]
    n_feas = int(table.feasible.sum())
    n_bytes = 8 * (2 * nP - 1 + nD + nP * nD * (2 if has_alpha else 1)) + nP * nD
    ab = "beta and alpha" if has_alpha else "beta"
    doc = [
        f"{HEADER} -- torque-gain schedule of the inner torque loop: {ab} over the impedance "
        f"(P_gain, D_gain). Generated by haa_sym {_text(meta['haa_sym_version'])} "
        "(haa_sym.schedule_c); do not edit.",
        "",
        "Provenance",
        *[f"  {p}" for p in prov],
        "",
        "Units",
        "  P_gain: Nm/rad, D_gain: Nms/rad (the impedance gains of Eq. 8 of Focchi et al. 2016).",
        "  beta: dimensionless, scales the file's torque PI gains: P_t = beta P_t0, I_t = beta I_t0 "
        "(Eq. 7).",
        *(["  alpha: dimensionless, scales the velocity compensation (Eq. 6); scheduled together "
           "with beta (the pair at a grid point was checked together)."] if has_alpha else []),
        "",
        "Grid",
        f"  P_gain: {_spacing(table.P_gain, 'Nm/rad', True)}.",
        f"  D_gain: {_spacing(table.D_gain, 'Nms/rad', False)}.",
        f"  Feasible points: {n_feas} of {nP * nD}. Tables: {n_bytes} bytes of static const data.",
        f"  Fallback point (the feasible point with the smallest beta, first in row-major order): "
        f"P_gain = {_text(c['P'][fb_i])}, D_gain = {_text(c['D'][fb_j])}, beta = "
        f"{_text(c['beta'][table.fallback])}"
        + (f", alpha = {_text(c['alpha'][table.fallback])}." if has_alpha else "."),
        "  Infeasible grid points hold the fallback point's values; they are never interpolated.",
        "",
        "Lookup rule (haa_schedule_beta" + (", haa_schedule_alpha" if has_alpha else "")
        + ", haa_schedule_feasible)",
        "  1. P_gain and D_gain are clamped to the grid's rectangle (a clamped point takes the "
        "edge's values). The cell has lower corner (i, j) with P[i] <= P_gain < P[i+1], D[j] <= "
        "D_gain < D[j+1] (the last cell on the upper edges). Bilinear weights in (log P_gain, "
        "D_gain): t = log(P_gain / P[i]) / log(P[i+1] / P[i]), u = (D_gain - D[j]) / (D[j+1] - "
        "D[j]); weights (1-t)(1-u), t(1-u), (1-t)u, tu for corners (i,j), (i+1,j), (i,j+1), "
        "(i+1,j+1). A corner is used when its weight is not zero (one at a grid point, two on a "
        "grid line, four inside a cell).",
        "  2. Every used corner feasible: bilinear interpolation (the table's value at a grid "
        "point, exactly; between the corners' values elsewhere; continuous in the impedance).",
        "  3. Some used corner infeasible: no interpolation; the entry of the used feasible corner "
        "with the smallest beta" + (" (alpha: that corner's)" if has_alpha else "")
        + ", or the fallback point's when no used corner is feasible. Near the edge of the "
        "feasible set the largest safe beta falls, and each candidate is a gain the table found "
        "safe at an adjacent impedance; interpolating towards a point where no gain qualifies "
        "would blend a safe gain with a meaningless one.",
        "  4. NaN in either argument: the fallback point's values (a gain must stay a finite "
        "number the torque loop can run with; the flag says it is not backed by the table).",
        "  5. haa_schedule_feasible returns 1 exactly when (P_gain, D_gain) is on the grid's "
        "rectangle and every used corner is feasible; 0 in cases 3 and 4 and outside the grid.",
        "  The table guarantees its grid points only: between them, bilinear interpolation of "
        "safe gains is safe where the largest safe beta is concave over the cell (the table's "
        "producer checks the cells or refines the grid).",
        "",
        "Build",
        "  Plain C99, no allocation, no state (reentrant), libm only (log): cc -std=c99 -c "
        f"{SOURCE}; link with -lm. Cost: two binary searches, one log, about 20 flops. With "
        "floating-point contraction off (-ffp-contract=off, gcc's default with -std=c99) the "
        "results are those of haa_sym.schedule_c.lookup_beta bit for bit (same libm log).",
    ]
    hdr = ["/*", *_wrap(doc), " */", "#ifndef HAA_SCHEDULE_H", "#define HAA_SCHEDULE_H", "",
           f"#define HAA_SCHEDULE_N_P_GAIN {nP}",
           f"#define HAA_SCHEDULE_N_D_GAIN {nD}",
           f"#define HAA_SCHEDULE_P_GAIN_MIN {_num(c['P'][0])}  /* Nm/rad */",
           f"#define HAA_SCHEDULE_P_GAIN_MAX {_num(c['P'][-1])}  /* Nm/rad */",
           f"#define HAA_SCHEDULE_D_GAIN_MIN {_num(c['D'][0])}  /* Nms/rad */",
           f"#define HAA_SCHEDULE_D_GAIN_MAX {_num(c['D'][-1])}  /* Nms/rad */",
           f"#define HAA_SCHEDULE_BETA_FALLBACK {_num(c['beta'][table.fallback])}",
           *([f"#define HAA_SCHEDULE_ALPHA_FALLBACK {_num(c['alpha'][table.fallback])}"]
             if has_alpha else []),
           f"#define HAA_SCHEDULE_HAS_ALPHA {int(has_alpha)}", "",
           "#ifdef __cplusplus", 'extern "C" {', "#endif", "",
           "/* beta at (P_gain Nm/rad, D_gain Nms/rad) by the lookup rule above. */",
           "double haa_schedule_beta(double P_gain, double D_gain);",
           *(["/* alpha at (P_gain, D_gain): the same weights, or the same corner, as beta. */",
              "double haa_schedule_alpha(double P_gain, double D_gain);"] if has_alpha else []),
           "/* 1 when (P_gain, D_gain) is on the grid and every corner used is feasible, else 0. */",
           "int haa_schedule_feasible(double P_gain, double D_gain);", "",
           "#ifdef __cplusplus", "}", "#endif", "", "#endif /* HAA_SCHEDULE_H */", ""]

    p_label = lambda i: f"P_gain = {_text(c['P'][i])} Nm/rad; D_gain index 0..{nD - 1}"
    src = [f"/* {SOURCE} -- see {HEADER} for the units, the grid and the lookup rule.",
           f" * Generated by haa_sym {_text(meta['haa_sym_version'])} (haa_sym.schedule_c); do not "
           "edit. */",
           "#include <math.h>", "", f'#include "{HEADER}"', "",
           "/* Grid, Nm/rad and Nms/rad; log_step[i] = log(P_gain[i+1] / P_gain[i]). */",
           *_array("haa_schedule_p_gain_", "double", "HAA_SCHEDULE_N_P_GAIN", [_num(v) for v in c["P"]], 4),
           *_array("haa_schedule_log_step_", "double", "HAA_SCHEDULE_N_P_GAIN - 1", [_num(v) for v in c["log_step"]], 4),
           *_array("haa_schedule_d_gain_", "double", "HAA_SCHEDULE_N_D_GAIN", [_num(v) for v in c["D"]], 4), "",
           "/* Row-major [P_gain index][D_gain index]; infeasible points hold the fallback point's "
           "values. */",
           *_array("haa_schedule_beta_", "double", "HAA_SCHEDULE_N_P_GAIN * HAA_SCHEDULE_N_D_GAIN", [_num(v) for v in c["beta"]], 4,
                   nD, p_label),
           *(_array("haa_schedule_alpha_", "double", "HAA_SCHEDULE_N_P_GAIN * HAA_SCHEDULE_N_D_GAIN", [_num(v) for v in c["alpha"]],
                    4, nD, p_label) if has_alpha else []),
           *_array("haa_schedule_feasible_", "unsigned char", "HAA_SCHEDULE_N_P_GAIN * HAA_SCHEDULE_N_D_GAIN",
                   [str(int(v)) for v in c["feasible"]], 16, nD, p_label), "",
           f"#define HAA_SCHEDULE_FALLBACK_INDEX_ {table.fallback}  /* flat index of the fallback point */", "",
           _C_BODY.strip("\n"),
           *(["", "double haa_schedule_alpha(double P_gain, double D_gain)", "{",
              "    return haa_schedule_value_(haa_schedule_alpha_, P_gain, D_gain);", "}"] if has_alpha else []),
           ""]
    return "\n".join(hdr), "\n".join(src)


_C_BODY = r"""
/* Largest k in [0, n-2] with x[k] <= v, for x[0] < v < x[n-1]. */
static int haa_schedule_bracket_(const double *x, int n, double v)
{
    int lo = 0, hi = n - 1;
    while (hi - lo > 1) {
        int mid = lo + (hi - lo) / 2;
        if (x[mid] <= v)
            lo = mid;
        else
            hi = mid;
    }
    return lo;
}

/* Rule 1: flat index of the cell's lower corner, corner weights, on-grid flag; 0 for NaN. */
static int haa_schedule_locate_(double P_gain, double D_gain, int *base, double w[4], int *inside)
{
    const double *P = haa_schedule_p_gain_, *D = haa_schedule_d_gain_;
    const int nP = HAA_SCHEDULE_N_P_GAIN, nD = HAA_SCHEDULE_N_D_GAIN;
    int i, j;
    double t, u;
    if (isnan(P_gain) || isnan(D_gain))
        return 0;
    if (!(P_gain > P[0])) {
        i = 0;
        t = 0.0;
    } else if (!(P_gain < P[nP - 1])) {
        i = nP - 2;
        t = 1.0;
    } else {
        i = haa_schedule_bracket_(P, nP, P_gain);
        t = log(P_gain / P[i]) / haa_schedule_log_step_[i];
        t = t > 1.0 ? 1.0 : t < 0.0 ? 0.0 : t;
    }
    if (!(D_gain > D[0])) {
        j = 0;
        u = 0.0;
    } else if (!(D_gain < D[nD - 1])) {
        j = nD - 2;
        u = 1.0;
    } else {
        j = haa_schedule_bracket_(D, nD, D_gain);
        u = (D_gain - D[j]) / (D[j + 1] - D[j]);
        u = u > 1.0 ? 1.0 : u < 0.0 ? 0.0 : u;
    }
    *inside = P_gain >= P[0] && P_gain <= P[nP - 1] && D_gain >= D[0] && D_gain <= D[nD - 1];
    *base = i * nD + j;
    w[0] = (1.0 - t) * (1.0 - u);
    w[1] = t * (1.0 - u);
    w[2] = (1.0 - t) * u;
    w[3] = t * u;
    return 1;
}

/* Rules 2-4: -1 to interpolate, else the flat index whose entries are returned. */
static int haa_schedule_rule_(double P_gain, double D_gain, int *base, double w[4], int *inside)
{
    const int nD = HAA_SCHEDULE_N_D_GAIN;
    const int offset[4] = {0, nD, 1, nD + 1};
    int k, pick = -1, every = 1;
    if (!haa_schedule_locate_(P_gain, D_gain, base, w, inside))
        return HAA_SCHEDULE_FALLBACK_INDEX_;
    for (k = 0; k < 4; ++k) {
        int idx = *base + offset[k];
        if (!(w[k] > 0.0))
            continue;                            /* an unused corner */
        if (!haa_schedule_feasible_[idx]) {
            every = 0;
            continue;
        }
        if (pick < 0 || haa_schedule_beta_[idx] < haa_schedule_beta_[pick])
            pick = idx;
    }
    if (every)
        return -1;
    return pick >= 0 ? pick : HAA_SCHEDULE_FALLBACK_INDEX_;
}

static double haa_schedule_value_(const double *table, double P_gain, double D_gain)
{
    const int nD = HAA_SCHEDULE_N_D_GAIN;
    int base = 0, inside = 0;
    double w[4] = {0.0, 0.0, 0.0, 0.0};
    int k = haa_schedule_rule_(P_gain, D_gain, &base, w, &inside);
    if (k >= 0)
        return table[k];
    return w[0] * table[base] + w[1] * table[base + nD] + w[2] * table[base + 1]
           + w[3] * table[base + nD + 1];
}

double haa_schedule_beta(double P_gain, double D_gain)
{
    return haa_schedule_value_(haa_schedule_beta_, P_gain, D_gain);
}

int haa_schedule_feasible(double P_gain, double D_gain)
{
    int base = 0, inside = 0;
    double w[4] = {0.0, 0.0, 0.0, 0.0};
    return haa_schedule_rule_(P_gain, D_gain, &base, w, &inside) < 0 && inside;
}
"""


def check_c_directory(directory: str | Path, field: str = "--c-out") -> Path:
    """``directory`` as a Path if it is an existing, writable directory; else an OutputError
    naming ``field`` (a command checks this before computing anything)."""
    d = Path(directory)
    allowed = "allowed: an existing, writable directory (it is not created)"
    if not d.is_dir():
        what = "does not exist" if not d.exists() else "is not a directory"
        raise OutputError(f"{field} {str(d)!r} {what}; {allowed}")
    if not os.access(d, os.W_OK | os.X_OK):
        raise OutputError(f"{field} {str(d)!r} is not writable; {allowed}")
    return d


def write_c(table: ScheduleTable, directory: str | Path, tx: Transaction | None = None,
            field: str = "--c-out") -> tuple[Path, Path]:
    """Write ``haa_schedule.h`` and ``haa_schedule.c`` for ``table`` into ``directory``.

    Both files appear together or neither changes (:mod:`haa_sym.outputs`); with ``tx`` they
    are staged in that transaction and appear when its owner commits (with the command's other
    outputs).

    Parameters
    ----------
    table : ScheduleTable
    directory : str or Path
        An existing, writable directory (it is not created).
    tx : haa_sym.outputs.Transaction, optional
    field : str, optional
        How messages name the directory (default ``--c-out``, the CLI option).

    Returns
    -------
    (Path, Path)
        The header and the source.

    Raises
    ------
    ParameterError
        (an :class:`haa_sym.outputs.OutputError`) naming ``field`` when ``directory`` is not an
        existing writable directory or a file cannot be written; nothing is written.
    """
    d = check_c_directory(directory, field)
    header, source = c_code(table)                  # every check before the first byte
    with transaction(tx) as t:
        for name, text in ((HEADER, header), (SOURCE, source)):
            with t.open(d / name, "wb", field) as fh:
                fh.write(text.encode("ascii"))
    return d / HEADER, d / SOURCE
