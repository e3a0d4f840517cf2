"""Out to the robot's controller (issue 25, item 3): the certified region of a map as ros2_control
parameters and as C.

The **certified region** is the set of impedance gains (P_gain Nm/rad, D_gain Nms/rad) of the
map's rectangle where the chosen requirements hold (``stable``; ``pm``: not "PM < 30 deg" by the
options' rule; ``passive``), decided as the maps decide (:func:`haa_sym.analysis.decide.decide_points`
and :func:`haa_sym.analysis.robust.meets`). It is tabulated row by row (:func:`certified_region`):

* on a row D_gain = d the region is a union of closed P_gain intervals. A decision changes only
  at the exact curves of :func:`haa_sym.analysis.boundaries.classify.row_cuts` (stability, +-30
  and 180 deg phase-margin loci, passivity candidates) or where a pair of crossovers appears.
  Every map grid point of the row and the middle of every stretch between consecutive grid
  points and cuts is decided; between two neighbours that disagree the change is located by
  bisection with the same decisions (to ``END_RTOL`` relative in P_gain), and the interval's end
  is the last point decided inside. So on a row the table follows the exact curves, not the grid.
* the rows are the map's D_gain values plus rows inserted by bisection where linear
  interpolation of the interval ends between two rows misses the ends of the row halfway by more
  than ``rtol`` (relative, in P_gain), or the number of intervals changes; rows closer than
  ``min_dD`` are not split further.

:func:`contains` (and its C twin ``haa_region_contains``) reads the table: outside the map's
rectangle or NaN: not contained; on a row: that row's intervals; between rows with equally many
intervals: the k-th interval's ends interpolated linearly in D_gain; between rows with different
counts (a topology change, within ``min_dD``): contained in both rows.

The **box** (:func:`largest_box`) is the axis-aligned rectangle [P_lo, P_hi] x [D_lo, D_hi]
inside the tabulated region (by :func:`contains`'s own rule between rows) of largest area in
the map's axes' scales (``BOX_MEASURES``: a ``log:`` axis is measured in log, any other in its
own units; default as the axes were given), then checked against the true decisions on its
corners, densely on its edges and on an interior grid (:func:`check_box`) and shrunk toward its
centre until that check passes (:func:`certified_box`).
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from haa_sym._version import version
from haa_sym.analysis.boundaries.classify import row_cuts
from haa_sym.analysis.boundaries.stability import stability_boundary
from haa_sym.analysis.decide import decide_points
from haa_sym.analysis.robust import _check_requirements, meets
from haa_sym.design.schedule_c import _num, _render, _rows, _text, check_c_directory
from haa_sym.design.schedule_c import write_c as write_schedule_c
from haa_sym.errors import ParameterError
from haa_sym.io.outputs import Transaction, transaction
from haa_sym.loop import loop_first
from haa_sym.model.params import gain_array

__all__ = ["RegionTable", "Box", "certified_region", "contains", "largest_box", "check_box", "certified_box",
           "params_yaml", "c_code", "write_c", "write_outputs", "HEADER", "SOURCE", "BOX_MEASURES",
           "REGION_RTOL", "END_RTOL", "EDGE_SAMPLES", "CONTROLLER_NAME"]

HEADER = "haa_region.h"
SOURCE = "haa_region.c"
# a row's interval end is located to this relative distance in P_gain (bisection on decisions)
END_RTOL = 1e-12
# between rows: interpolated ends within this relative distance of the halfway row's true ends
REGION_RTOL = 1e-3
# rows closer than this fraction of the D_gain range are not split further
MIN_DD_FRACTION = 1e-4
# points a bracket per round of the search for a decision's change
SECTIONS = 15
# the box's check: points per edge (and per side of the interior grid)
EDGE_SAMPLES = 400
INTERIOR_SAMPLES = 40
# each shrink round moves every side in by this fraction of the box's size (in its measure)
SHRINK_STEP = 0.005
MAX_SHRINK_ROUNDS = 200
BOX_MEASURES = ("log", "linear")
CONTROLLER_NAME = "joint_impedance_controller"


@dataclass(frozen=True)
class RegionTable:
    """The certified region row by row: ``D_rows`` (n,) Nms/rad ascending; row r's closed
    P_gain intervals are ``lo[start[r]:start[r+1]]``, ``hi[...]`` (Nm/rad, ascending, disjoint);
    ``P_range`` and ``D_range`` the map's rectangle; ``meta`` what produced it."""

    D_rows: np.ndarray
    start: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    P_range: tuple
    D_range: tuple
    meta: dict = field(default_factory=dict)

    def row(self, r: int) -> list:
        a, b = self.start[r], self.start[r + 1]
        return list(zip(self.lo[a:b].tolist(), self.hi[a:b].tolist()))


@dataclass(frozen=True)
class Box:
    """An axis-aligned box of gains, Nm/rad and Nms/rad, and how it was found."""

    P_lo: float
    P_hi: float
    D_lo: float
    D_hi: float
    P_measure: str
    D_measure: str
    shrink_rounds: int = 0
    checked_points: int = 0

    @property
    def centre(self) -> tuple[float, float]:
        """The centre in the box's measures (geometric mean on a log measure): the default gains."""
        def mid(a, b, m):
            return float(np.sqrt(a * b)) if m == "log" else 0.5 * (a + b)
        return mid(self.P_lo, self.P_hi, self.P_measure), mid(self.D_lo, self.D_hi, self.D_measure)


def _verdict(loop, P, D, req) -> np.ndarray:
    """The requirements at gain points, decided as the maps decide them."""
    P, D = np.broadcast_arrays(np.asarray(P, float), np.asarray(D, float))
    if P.size == 0:
        return np.zeros(0, bool)
    d = decide_points(loop, P.ravel(), D.ravel(), passivity="passive" in req)
    return meets(d, req)


def _mid(a, b):
    """Midpoint of a P_gain stretch: geometric where both ends are positive (the curves are
    smooth in log P_gain), else arithmetic."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    with np.errstate(invalid="ignore"):
        return np.where((a > 0) & (b > 0), np.sqrt(a * b), 0.5 * (a + b))


def _rows_of(loop, boundary, D_values, P_grid, req) -> list:
    """The intervals [(lo, hi), ...] of the region on each row D_gain = d (see the module docstring)."""
    P0, P1 = float(P_grid[0]), float(P_grid[-1])
    cuts = row_cuts(loop, boundary, D_values, (P0, P1), passivity="passive" in req)
    probes, rows = [], []
    for j, d in enumerate(D_values):
        c = cuts[j][(cuts[j] > P0) & (cuts[j] < P1)]
        bp = np.unique(np.concatenate([P_grid, c]))
        x = np.unique(np.concatenate([P_grid, _mid(bp[:-1], bp[1:])]))
        probes.append(x)
        rows.append(np.full(x.size, d))
    x_all, d_all = np.concatenate(probes), np.concatenate(rows)
    v_all = _verdict(loop, x_all, d_all, req)
    # neighbours that disagree: bisect between them, all rows at once, on the decisions themselves
    idx = np.flatnonzero((v_all[:-1] != v_all[1:]) & (d_all[:-1] == d_all[1:]))
    a, b, d = x_all[idx].copy(), x_all[idx + 1].copy(), d_all[idx]
    va = v_all[idx]
    # K-section (K points a bracket per call: a call's fixed cost dominates a few points' decisions)
    frac = np.arange(1, SECTIONS + 1) / (SECTIONS + 1)
    for _ in range(200):
        open_ = np.flatnonzero(np.abs(b - a) > END_RTOL * np.maximum(np.abs(a), np.abs(b)))
        if not open_.size:
            break
        aa, bb = a[open_, None], b[open_, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            pts = np.where(aa > 0, aa * (bb / np.where(aa > 0, aa, 1.0)) ** frac, aa + (bb - aa) * frac)
        pts = np.concatenate([aa, pts, bb], axis=1)
        v = _verdict(loop, pts[:, 1:-1], np.broadcast_to(d[open_, None], (open_.size, SECTIONS)),
                     req).reshape(open_.size, SECTIONS)
        changed = np.concatenate([v != va[open_, None], np.ones((open_.size, 1), bool)], axis=1)
        k = np.argmax(changed, axis=1) + 1                 # first point past the change
        rows_ = np.arange(open_.size)
        a[open_], b[open_] = pts[rows_, k - 1], pts[rows_, k]
    # the change's location, from its inside side: the last point decided inside
    end = np.where(va, a, b)
    out, k, off = [], 0, 0
    for x in probes:
        v = v_all[off:off + x.size]
        ivs, s = [], (float(x[0]) if v[0] else None)
        while k < idx.size and idx[k] < off + x.size - 1:
            if va[k]:
                ivs.append((s, float(end[k])))
            else:
                s = float(end[k])
            k += 1
        if v[-1]:
            ivs.append((s, float(x[-1])))
        out.append(ivs)
        off += x.size
    return out


def _interp_ok(ra, rb, rm, rtol) -> bool:
    """The halfway row ``rm`` is the linear interpolation of rows ``ra`` and ``rb`` within ``rtol``."""
    if not (len(ra) == len(rb) == len(rm)):
        return False
    for (a0, a1), (b0, b1), (m0, m1) in zip(ra, rb, rm):
        for p, q, t in ((a0, b0, m0), (a1, b1, m1)):
            if abs(0.5 * p + 0.5 * q - t) > rtol * max(abs(t), 1e-300):
                return False
    return True


@loop_first
def certified_region(loop, P_gain, D_gain, requirements=("stable", "pm"), *, rtol: float = REGION_RTOL,
                     min_dD: float | None = None) -> RegionTable:
    """Tabulate the region of ``loop`` where ``requirements`` hold, on the map's rectangle.

    Parameters
    ----------
    loop : ClosedLoop
        Its options' ``pm_loop`` must be "impedance" (the exact curves are the impedance loop's).
    P_gain, D_gain : (n,) array_like
        The map's axes, Nm/rad and Nms/rad (at least 2 values each): every grid point is decided,
        the rectangle they span is the table's domain, and every D_gain value is a row.
    requirements : sequence of {"stable", "pm", "passive"}
        "stable" and any of the others (as ``haa-sym schedule --require``).
    rtol : float
        Relative tolerance in P_gain of the interpolation between rows (default ``REGION_RTOL``).
    min_dD : float, optional
        Rows closer than this (Nms/rad) are not split; default ``MIN_DD_FRACTION`` of the range.

    Returns
    -------
    RegionTable
    """
    req = _check_requirements(requirements)
    P = np.unique(gain_array("P_gain", P_gain).ravel())
    D = np.unique(gain_array("D_gain", D_gain).ravel())
    for name, arr in (("P_gain", P), ("D_gain", D)):
        if arr.size < 2:
            raise ParameterError(f"{name}: {arr.size} distinct value(s); allowed: at least 2 (the region's "
                                 "table spans the map's rectangle)")
    if loop.options.conventions.pm_loop != "impedance":
        raise ParameterError(f"option pm_loop = {loop.options.conventions.pm_loop!r}; allowed: 'impedance' "
                             "(the region follows the impedance loop's exact curves)")
    if not (np.isfinite(rtol) and 0 < rtol < 1):
        raise ParameterError(f"rtol = {rtol!r}; allowed: 0 < rtol < 1")
    min_dD = MIN_DD_FRACTION * float(D[-1] - D[0]) if min_dD is None else float(min_dD)
    _, _, beta, alpha = loop.gain_points(0.0, 0.0, None, None)
    b = stability_boundary(loop, beta, alpha, P_range=(float(P[0]), float(P[-1])),
                           D_range=(float(D[0]), float(D[-1])))
    rows = dict(zip(D.tolist(), _rows_of(loop, b, D, P, req)))
    gaps = list(zip(D[:-1].tolist(), D[1:].tolist()))
    inserted = 0
    while gaps:
        mids = np.array([0.5 * (a + c) for a, c in gaps])
        got = _rows_of(loop, b, mids, P, req)
        nxt = []
        for (a, c), m, rm in zip(gaps, mids.tolist(), got):
            if _interp_ok(rows[a], rows[c], rm, rtol):
                continue
            rows[m] = rm
            inserted += 1
            if 0.5 * (c - a) > min_dD:
                nxt += [(a, m), (m, c)]
        gaps = nxt
    D_rows = np.array(sorted(rows))
    ivs = [rows[d] for d in D_rows.tolist()]
    start = np.concatenate([[0], np.cumsum([len(r) for r in ivs])]).astype(int)
    lo = np.array([a for r in ivs for a, _ in r], float)
    hi = np.array([c for r in ivs for _, c in r], float)
    meta = {"requirements": list(req), "beta": beta, "alpha": alpha, "rtol": rtol, "min_dD": min_dD,
            "end_rtol": END_RTOL, "map_rows": int(D.size), "inserted_rows": inserted,
            "map_P_gain": [float(P[0]), float(P[-1]), int(P.size)],
            "map_D_gain": [float(D[0]), float(D[-1]), int(D.size)]}
    return RegionTable(D_rows, start, lo, hi, (float(P[0]), float(P[-1])), (float(D[0]), float(D[-1])), meta)


def _in_row(t: RegionTable, r: np.ndarray, P: np.ndarray) -> np.ndarray:
    out = np.zeros(P.shape, bool)
    for k in range(int(np.diff(t.start).max(initial=0))):
        has = t.start[r] + k < t.start[r + 1]
        i = np.where(has, t.start[r] + k, 0)
        out |= has & (t.lo[i] <= P) & (P <= t.hi[i])
    return out


def contains(table: RegionTable, P_gain, D_gain) -> np.ndarray:
    """Whether the gain points lie in the tabulated region: the Python twin of the emitted C's
    ``haa_region_contains`` (the same IEEE operations, in the same order; see the module docstring)."""
    t = table
    P, D = np.broadcast_arrays(np.asarray(P_gain, float), np.asarray(D_gain, float))
    P, D = P.ravel(), D.ravel()
    n = t.D_rows.size
    with np.errstate(invalid="ignore"):
        inside = (P >= t.P_range[0]) & (P <= t.P_range[1]) & (D >= t.D_range[0]) & (D <= t.D_range[1])
    Dc = np.where(inside, D, t.D_rows[0])
    r = np.clip(np.searchsorted(t.D_rows, Dc, side="right") - 1, 0, n - 1)
    on_row = (r == n - 1) | ~(Dc > t.D_rows[r])
    r1 = np.minimum(r + 1, n - 1)
    out = np.where(on_row, _in_row(t, r, P), False)
    between = inside & ~on_row
    u = (Dc - t.D_rows[r]) / np.where(r1 > r, t.D_rows[r1] - t.D_rows[r], 1.0)
    na, nb = t.start[r + 1] - t.start[r], t.start[np.minimum(r1 + 1, n)] - t.start[r1]
    same = na == nb
    both = _in_row(t, r, P) & _in_row(t, r1, P)
    interp = np.zeros(P.shape, bool)
    for k in range(int(np.diff(t.start).max(initial=0))):
        has = k < na
        ia, ib = np.where(has, t.start[r] + k, 0), np.where(has, t.start[r1] + k, 0)
        lo = (1.0 - u) * t.lo[ia] + u * t.lo[ib]
        hi = (1.0 - u) * t.hi[ia] + u * t.hi[ib]
        interp |= has & (lo <= P) & (P <= hi)
    out = np.where(between, np.where(same, interp, both), out)
    return out & inside


def _intersect(a: list, b: list) -> list:
    out, i, j = [], 0, 0
    while i < len(a) and j < len(b):
        lo, hi = max(a[i][0], b[j][0]), min(a[i][1], b[j][1])
        if lo <= hi:
            out.append((lo, hi))
        if a[i][1] < b[j][1]:
            i += 1
        else:
            j += 1
    return out


def _slab(ra: list, rb: list) -> list:
    """The P_gain values contained for every D_gain between two neighbouring rows by
    :func:`contains`'s rule (interpolated ends: inside both ends' inner envelope)."""
    if len(ra) != len(rb):
        return _intersect(ra, rb)
    return [(max(a0, b0), min(a1, b1)) for (a0, a1), (b0, b1) in zip(ra, rb) if max(a0, b0) <= min(a1, b1)]


def _length(lo: float, hi: float, measure: str) -> float:
    return float(np.log(hi / lo)) if measure == "log" else hi - lo


def largest_box(table: RegionTable, P_measure: str = "log", D_measure: str = "linear") -> Box:
    """The axis-aligned box of largest area (P_gain length times D_gain length, each in its
    ``measure``: "log" or "linear") inside the tabulated region by :func:`contains`'s rule; its
    D_gain ends are rows of the table. Raises ParameterError when no box of positive area exists."""
    for name, m in (("P_measure", P_measure), ("D_measure", D_measure)):
        if m not in BOX_MEASURES:
            raise ParameterError(f"{name} = {m!r}; allowed: {list(BOX_MEASURES)}")
    if P_measure == "log" and table.P_range[0] <= 0:
        raise ParameterError(f"P_measure = 'log' with P_gain from {table.P_range[0]:g}; allowed: a P_gain axis "
                             "above 0 (or the linear measure)")
    if D_measure == "log" and table.D_range[0] <= 0:
        raise ParameterError(f"D_measure = 'log' with D_gain from {table.D_range[0]:g}; allowed: a D_gain axis "
                             "above 0 (or the linear measure)")
    rows = [table.row(r) for r in range(table.D_rows.size)]
    D = table.D_rows.tolist()
    best, arg = 0.0, None
    for j0 in range(len(rows)):
        S = rows[j0]
        for j1 in range(j0 + 1, len(rows)):
            S = _intersect(S, _slab(rows[j1 - 1], rows[j1]))
            if not S:
                break
            h = _length(D[j0], D[j1], D_measure)
            w, iv = max((_length(a, b, P_measure), (a, b)) for a, b in S)
            if w * h > best:
                best, arg = w * h, (iv[0], iv[1], D[j0], D[j1])
    if arg is None:
        raise ParameterError(f"requirements {'+'.join(table.meta.get('requirements', []))}: no box of positive "
                             "area lies inside the region on the map; allowed: a map (--P-gain, --D-gain) or "
                             "requirements where the region spans two rows")
    return Box(*arg, P_measure, D_measure)


def _spaced(a: float, b: float, n: int, measure: str) -> np.ndarray:
    return np.geomspace(a, b, n) if measure == "log" else np.linspace(a, b, n)


def box_samples(box: Box, n_edge: int = EDGE_SAMPLES, n_interior: int = INTERIOR_SAMPLES):
    """The points :func:`check_box` decides: every edge at ``n_edge`` points (corners included,
    spaced in the box's measures) and an ``n_interior`` x ``n_interior`` interior grid."""
    Pe = _spaced(box.P_lo, box.P_hi, n_edge, box.P_measure)
    De = _spaced(box.D_lo, box.D_hi, n_edge, box.D_measure)
    Pi = _spaced(box.P_lo, box.P_hi, n_interior, box.P_measure)
    Di = _spaced(box.D_lo, box.D_hi, n_interior, box.D_measure)
    PP, DD = np.meshgrid(Pi, Di, indexing="ij")
    P = np.concatenate([Pe, Pe, np.full(n_edge, box.P_lo), np.full(n_edge, box.P_hi), PP.ravel()])
    D = np.concatenate([np.full(n_edge, box.D_lo), np.full(n_edge, box.D_hi), De, De, DD.ravel()])
    return P, D


@loop_first
def check_box(loop, box: Box, requirements, n_edge: int = EDGE_SAMPLES) -> np.ndarray:
    """The points of :func:`box_samples` that fail the requirements (decided as the maps
    decide them), as an (m, 2) array of (P_gain, D_gain); empty when the box holds."""
    req = _check_requirements(requirements)
    P, D = box_samples(box, n_edge)
    ok = _verdict(loop, P, D, req)
    return np.stack([P[~ok], D[~ok]], axis=1)


def _shrunk(box: Box, f: float) -> Box:
    def side(a, b, m):
        if m == "log":
            r = (b / a) ** f
            return a * r, b / r
        d = (b - a) * f
        return a + d, b - d
    P_lo, P_hi = side(box.P_lo, box.P_hi, box.P_measure)
    D_lo, D_hi = side(box.D_lo, box.D_hi, box.D_measure)
    return Box(P_lo, P_hi, D_lo, D_hi, box.P_measure, box.D_measure, box.shrink_rounds + 1)


@loop_first
def certified_box(loop, table: RegionTable, requirements, P_measure: str = "log", D_measure: str = "linear",
                  n_edge: int = EDGE_SAMPLES) -> Box:
    """:func:`largest_box`, shrunk toward its centre (every side by ``SHRINK_STEP`` of the box's
    size a round) until :func:`check_box` passes; ``shrink_rounds`` says how often."""
    box = largest_box(table, P_measure, D_measure)
    for _ in range(MAX_SHRINK_ROUNDS):
        if check_box(loop, box, requirements, n_edge).size == 0:
            n = box_samples(box, n_edge)[0].size
            return Box(box.P_lo, box.P_hi, box.D_lo, box.D_hi, box.P_measure, box.D_measure,
                       box.shrink_rounds, n)
        box = _shrunk(box, SHRINK_STEP)
    raise ParameterError(f"the largest box of the region failed the check of its edges after {MAX_SHRINK_ROUNDS} "
                         "shrink rounds; allowed: a finer map (--P-gain, --D-gain) or a smaller --region-rtol")


# ------------------------------------------------------------------------------------ the YAML

_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _yaml_float(x: float) -> str:
    """A float that YAML 1.1 (PyYAML) and 1.2 both read as a float: a point always, a signed exponent."""
    s = repr(float(x))
    if "e" in s and "." not in s.split("e")[0]:
        s = s.replace("e", ".0e")
    return s if any(ch in s for ch in ".e") else s + ".0"


def params_yaml(box: Box, meta: dict, controller: str = CONTROLLER_NAME) -> str:
    """The ``generate_parameter_library`` YAML: one top-level entry ``controller`` with
    ``stiffness`` (Nm/rad) and ``damping`` (Nms/rad), each ``type: double``, ``default_value``
    (the box's centre in its measures), ``description`` and ``validation: {bounds<>: [lo, hi]}``
    (the box). ``meta``: "actuator", "source", "requirements" (text), "configuration"."""
    if not isinstance(controller, str) or not _IDENTIFIER.fullmatch(controller):
        raise ParameterError(f"--controller {controller!r}; allowed: a C++ identifier ([A-Za-z_][A-Za-z0-9_]*), "
                             "the namespace generate_parameter_library generates")
    P0, D0 = box.centre
    where = (f"the largest axis-aligned box [{box.P_lo:.6g}, {box.P_hi:.6g}] Nm/rad x [{box.D_lo:.6g}, "
             f"{box.D_hi:.6g}] Nms/rad (area in {box.P_measure} P_gain x {box.D_measure} D_gain) inside the "
             f"region where {meta['requirements']} hold for {meta['actuator']} ({meta['source']}"
             + (f", configuration {meta['configuration']}" if meta.get("configuration") else "")
             + f"), by haa_sym {version()}; the region itself is haa_region_contains() in haa_region.c; "
             + (f"the torque-gain schedule ({meta['schedule']}) is haa_schedule_lookup() in haa_schedule.c; "
                if meta.get("schedule") else "")
             + "default: the box's centre")
    lines = [f"# generate_parameter_library parameters of a joint impedance controller, written by haa_sym "
             f"{version()} (haa-sym export-ros2).",
             "# The bounds are a box inside the certified region, not the region: check the pair (stiffness, "
             "damping)", "# with haa_region_contains() (haa_region.h) before using it.", f"{controller}:"]
    for name, unit, lo, hi, default, what in (
            ("stiffness", "Nm/rad", box.P_lo, box.P_hi, P0, "Joint impedance stiffness P_gain"),
            ("damping", "Nms/rad", box.D_lo, box.D_hi, D0, "Joint impedance damping D_gain")):
        lines += [f"  {name}:", "    type: double", f"    default_value: {_yaml_float(default)}",
                  f"    description: {json.dumps(f'{what}, {unit}. Bounds: ' + where)}",
                  "    validation:", f"      bounds<>: [{_yaml_float(lo)}, {_yaml_float(hi)}]"]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------ the C

def c_code(table: RegionTable, box: Box, meta: dict) -> tuple[str, str]:
    """The text of ``haa_region.h`` and ``haa_region.c`` (templates ``design/templates/haa_region.{h,c}.in``;
    byte-reproducible: the tables as ``%.17g``). ``meta``: "actuator", "source", "requirements"
    (text), "configuration" (or None), "map" (text)."""
    t = table
    n, m = t.D_rows.size, t.lo.size
    prov = [f"actuator: {_text(meta['actuator'])}", f"source: {_text(meta['source'])}"]
    if meta.get("configuration"):
        prov.append(f"configuration: {_text(meta['configuration'])}")
    prov += [f"requirements: {_text(meta['requirements'])}", f"map: {_text(meta['map'])}",
             f"beta: {_text(t.meta['beta'])}, alpha: {_text(t.meta['alpha'])}"]
    header = _render(HEADER, {
        "version": _text(version()), "provenance": prov,
        "n_rows": str(n), "n_map_rows": str(t.meta["map_rows"]), "n_intervals": str(m),
        "rtol": _text(t.meta["rtol"]), "min_dd": _text(t.meta["min_dD"]), "end_rtol": _text(t.meta["end_rtol"]),
        "p_gain_min": _num(t.P_range[0]), "p_gain_max": _num(t.P_range[1]),
        "d_gain_min": _num(t.D_range[0]), "d_gain_max": _num(t.D_range[1]),
        "box_p_lo": _num(box.P_lo), "box_p_hi": _num(box.P_hi), "box_d_lo": _num(box.D_lo),
        "box_d_hi": _num(box.D_hi), "box_measure": f"{box.P_measure} P_gain x {box.D_measure} D_gain",
        "n_bytes": str(8 * (n + 2 * m) + 4 * (n + 1)),
    }, wrap_comment=True)
    source = _render(SOURCE, {
        "version": _text(version()),
        "d_rows": _rows([_num(v) for v in t.D_rows], 4),
        "row_start": _rows([str(int(v)) for v in t.start], 12),
        "lo": _rows([_num(v) for v in t.lo], 4) if m else ["0.0"],
        "hi": _rows([_num(v) for v in t.hi], 4) if m else ["0.0"],
    })
    return header, source


def write_c(table: RegionTable, box: Box, meta: dict, directory, tx: Transaction | None = None,
            field: str = "--c-out") -> tuple[Path, Path]:
    """Write ``haa_region.h`` and ``haa_region.c`` into ``directory`` (both or neither; with ``tx``
    staged in that transaction)."""
    d = check_c_directory(directory, field, names=(HEADER, SOURCE))
    header, source = c_code(table, box, meta)
    with transaction(tx) as t:
        for name, text in ((HEADER, header), (SOURCE, source)):
            with t.open(d / name, "wb", field) as fh:
                fh.write(text.encode("ascii"))
    return d / HEADER, d / SOURCE


def write_outputs(yaml_path, c_dir, table: RegionTable, box: Box, meta: dict,
                  controller: str = CONTROLLER_NAME, schedule=None) -> None:
    """The YAML and the C together, all or nothing (:class:`haa_sym.io.outputs.Transaction`);
    ``schedule`` (a :class:`~haa_sym.design.schedule_table.ScheduleTable`, optional): its lookup
    ``haa_schedule.{h,c}`` into ``c_dir`` too, by the schedule's own writer
    (:func:`haa_sym.design.schedule_c.write_c`), and named in the YAML's descriptions."""
    text = params_yaml(box, meta, controller)
    with Transaction() as tx:
        if yaml_path is not None:
            tx.write_text(yaml_path, text, "--out")
        if c_dir is not None:
            write_c(table, box, meta, c_dir, tx)
            if schedule is not None:
                write_schedule_c(schedule, c_dir, tx)
