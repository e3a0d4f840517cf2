"""A torque-gain schedule table, validated, and its lookup in Python (the twin of the emitted C).

A :class:`ScheduleTable` holds, on a grid of impedances (P_gain, D_gain) of Eq. (8), the largest
torque-loop gain scale beta (``P_t = beta P_t0``, ``I_t = beta I_t0``, Eq. 7), optionally the
velocity-compensation scale alpha (Eq. 6), and which grid points meet the requirements at all.
How the table is computed is not this module's business; :func:`haa_sym.design.schedule_c.write_c`
turns it into plain C99 (``static const double`` tables, no allocation, only libm) for the
joint's low-level controller, and :func:`lookup` is the same lookup in Python, operation for
operation.

The lookup rule (repeated in the generated header)
--------------------------------------------------
The table is read per *cell* (the rectangle between four neighbouring grid points), and a cell
is either *safe* (its producer verified the interpolated gains on it, see ``cell_safe`` and the
``cell_check`` meta text) or has *no safe gain*. The lookup returns a status the caller must read:

0. ``NAN`` (3): NaN in either argument. Nothing is written.
1. **Cell.** ``P_gain`` and ``D_gain`` are clamped to the grid's rectangle; the cell is the one
   whose lower corner ``(i, j)`` has ``P[i] <= P_gain < P[i+1]`` and ``D[j] <= D_gain < D[j+1]``
   (the last cell on the upper edges). Bilinear weights in (log P_gain, D_gain):
   ``t = log(P_gain / P[i]) / log(P[i+1] / P[i])``, ``u = (D_gain - D[j]) / (D[j+1] - D[j])``,
   weights ``(1-t)(1-u), t(1-u), (1-t)u, tu`` for the corners ``(i,j), (i+1,j), (i,j+1),
   (i+1,j+1)``.
2. ``NO_SAFE_GAIN`` (2): the cell is not safe. Nothing is written: the caller keeps the gains
   it runs with (if they were safe for the previous impedance, keep the previous impedance too)
   or stops the joint; there is no fallback gain, because no number is safe there.
3. Otherwise beta (and alpha) is the bilinear interpolation of the cell's four corner values
   (continuous over the safe cells; at a grid point the table's value, bit for bit), and the
   status is ``OK`` (0), or ``OUTSIDE`` (1) when the argument was clamped: the value is the one
   at the nearest point of the rectangle, verified there, not at the requested impedance.

Why this rule, as a control engineer: a controller evaluates the table between its grid points,
so a value is only handed out where the producer checked the interpolated gain itself, not only
the corners. Bilinear interpolation of safe corner gains is not safe in general: where the
largest safe beta curves upwards over a cell, or an unsafe pocket lies inside it, the
interpolation exceeds it. :func:`haa_sym.design.schedule.schedule` checks each cell on a dense
sub-grid and lowers the corner values until the check holds (the header states the density:
sampling verifies the sub-grid points, not the points between them). Next to a grid point where
no beta qualifies, no value of the cell is safe at that corner, so the whole cell has no safe
gain. A grid point belongs to one cell (rule 1): a feasible grid point whose cell is not safe
answers ``NO_SAFE_GAIN`` although the table holds a value for it.

Values held at grid points used by no safe cell: the input may hold anything there (NaN, a range
end); the emitted table holds 0.0. They are never read.

Example
-------
>>> import numpy as np
>>> P, D = np.geomspace(1.0, 2000.0, 4), np.array([1.0, 25.0, 50.0])
>>> beta = np.array([[8.0, 8.0, 8.0], [6.0, 7.0, 8.0], [2.0, 4.0, 5.0], [0.1, 1.0, 2.0]])
>>> feasible = np.ones((4, 3), bool); feasible[3, 0] = False
>>> meta = {"actuator": "hyq_haa.toml", "source": "model/hyq_haa.toml",
...         "requirements": "stable, phase margin >= 30 deg", "tolerances": "beta 1e-3",
...         "haa_sym_version": "0.1"}
>>> table = ScheduleTable(P, D, beta, feasible, meta)
>>> lookup(table, float(P[1]), 25.0)               # a grid point: the table's value
(0, 7.0, None)
>>> lookup(table, float(np.sqrt(P[1] * P[2])), 37.5)   # cell centre: mean of 4 corners
(0, 6.0, None)
>>> lookup(table, 1500.0, 10.0)                    # a cell with an infeasible corner
(2, None, None)
"""
from __future__ import annotations

import bisect
import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from haa_sym.errors import ParameterError

__all__ = ["ScheduleTable", "META_KEYS", "lookup", "STATUS", "OK", "OUTSIDE", "NO_SAFE_GAIN", "NAN"]

# The lookup's status (the C enum haa_schedule_status has the same numbers and names).
OK, OUTSIDE, NO_SAFE_GAIN, NAN = 0, 1, 2, 3
STATUS = {OK: "HAA_SCHEDULE_OK", OUTSIDE: "HAA_SCHEDULE_OUTSIDE", NO_SAFE_GAIN: "HAA_SCHEDULE_NO_SAFE_GAIN",
          NAN: "HAA_SCHEDULE_NAN"}

# Provenance every emitted header states (values: text, numbers, booleans, or a flat list or
# dict of these); other keys are printed after them, sorted.
META_KEYS = ("actuator", "source", "requirements", "tolerances", "haa_sym_version")


@dataclass(frozen=True, eq=False)
class ScheduleTable:
    """A torque-gain schedule on an impedance grid, validated (see the module docstring).

    Parameters
    ----------
    P_gain : array_like, shape (n_P,)
        Stiffness grid of Eq. (8), Nm/rad: at least 2 finite values > 0, strictly increasing
        (logarithmic spacing is usual but not required; interpolation is in log P_gain).
    D_gain : array_like, shape (n_D,)
        Damping grid, Nms/rad: at least 2 finite values >= 0, strictly increasing.
    beta : array_like, shape (n_P, n_D)
        Largest torque-loop gain scale per grid point (dimensionless, Eq. 7): finite and > 0 at
        every feasible point; ignored (any value, NaN included) at infeasible ones.
    feasible : array_like of bool, shape (n_P, n_D)
        True where ``beta`` meets every requirement; at least one point.
    meta : dict
        Provenance printed in the header: every key of :data:`META_KEYS` (actuator, source
        file, requirements, tolerances, haa_sym version), values text, numbers, booleans or a
        flat list or dict of these; more keys allowed.
    alpha : array_like, shape (n_P, n_D), optional
        Velocity-compensation scale scheduled with beta (Eq. 6): finite and >= 0 at feasible
        points. None (default): alpha is not scheduled and the lookup writes no alpha.
    cell_safe : array_like of bool, shape (n_P - 1, n_D - 1), optional
        Per cell (lower corner ``(i, j)``): True where the producer verified the interpolated
        gains over the cell (state how in ``meta["cell_check"]``); only cells whose four corners
        are feasible may be True. None (default): every cell with four feasible corners, and
        the header says the cells were not checked unless ``meta["cell_check"]`` says otherwise.

    Raises
    ------
    ParameterError
        Naming the field, the value (and grid point) and what is allowed.
    """

    P_gain: np.ndarray
    D_gain: np.ndarray
    beta: np.ndarray
    feasible: np.ndarray
    meta: dict
    alpha: np.ndarray | None = None
    cell_safe: np.ndarray | None = None
    # Derived (the tables as emitted, see "Values held at grid points used by no safe cell"):
    _c: dict = field(init=False, repr=False)

    def __post_init__(self):
        P = _grid("P_gain", self.P_gain, 0.0, strict=True, unit="Nm/rad")
        D = _grid("D_gain", self.D_gain, 0.0, strict=False, unit="Nms/rad")
        shape = (P.size, D.size)
        feas = _mask(self.feasible, shape)
        beta = _table("beta", self.beta, shape, feas, P, D, "a finite number > 0",
                      lambda v: np.isfinite(v) & (v > 0))
        alpha = None if self.alpha is None else _table(
            "alpha", self.alpha, shape, feas, P, D, "a finite number >= 0",
            lambda v: np.isfinite(v) & (v >= 0))
        meta = _meta(self.meta)
        corners = feas[:-1, :-1] & feas[1:, :-1] & feas[:-1, 1:] & feas[1:, 1:]
        cells = corners.copy() if self.cell_safe is None else _cells(self.cell_safe, corners, P, D)
        for name, value in (("P_gain", P), ("D_gain", D), ("beta", beta), ("feasible", feas),
                            ("alpha", alpha), ("cell_safe", cells)):
            if value is not None:
                value.flags.writeable = False
            object.__setattr__(self, name, value)
        object.__setattr__(self, "meta", meta)
        used = np.zeros(shape, bool)               # grid points read by some safe cell
        for di in (0, 1):
            for dj in (0, 1):
                used[di:di + cells.shape[0], dj:dj + cells.shape[1]] |= cells
        # The emitted tables as Python floats: the lookup twin reads exactly these.
        fill = lambda a: np.where(used, a, 0.0).ravel().tolist()
        object.__setattr__(self, "_c", {
            "P": P.tolist(), "D": D.tolist(),
            "log_step": [math.log(b / a) for a, b in zip(P.tolist(), P.tolist()[1:])],
            "beta": fill(beta), "alpha": None if alpha is None else fill(alpha),
            "cell_safe": cells.ravel().tolist(),
        })

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_P, n_D)``."""
        return (self.P_gain.size, self.D_gain.size)


# ---------------------------------------------------------------------------------- validation

def _where(P, D, i, j) -> str:
    return f"(P_gain = {float(P[i])!r} Nm/rad, D_gain = {float(D[j])!r} Nms/rad)"


def _grid(name: str, value, low: float, strict: bool, unit: str) -> np.ndarray:
    allowed = (f"at least 2 finite values {'>' if strict else '>='} {low:g} {unit}, strictly "
               "increasing")
    try:
        x = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"ScheduleTable.{name} = {value!r} is not an array of numbers; "
                             f"allowed: {allowed}") from None
    if x.ndim != 1 or x.size < 2:
        raise ParameterError(f"ScheduleTable.{name} has shape {x.shape}; allowed: {allowed}")
    bad = ~np.isfinite(x) | ((x <= low) if strict else (x < low))
    if bad.any():
        k = int(np.argmax(bad))
        raise ParameterError(f"ScheduleTable.{name}[{k}] = {float(x[k])!r}; allowed: {allowed}")
    down = np.diff(x) <= 0
    if down.any():
        k = int(np.argmax(down)) + 1
        raise ParameterError(f"ScheduleTable.{name}[{k}] = {float(x[k])!r} is not greater than "
                             f"{name}[{k - 1}] = {float(x[k - 1])!r}; allowed: {allowed}")
    return x


def _mask(value, shape) -> np.ndarray:
    allowed = f"booleans (or 0/1) of shape {shape} (n_P, n_D), at least one true"
    try:
        m = np.array(value)
    except (TypeError, ValueError):
        m = np.array(None)
    if m.shape != shape:
        raise ParameterError(f"ScheduleTable.feasible has shape {m.shape}; allowed: {allowed}")
    if m.dtype != bool:
        ok = m.dtype.kind in "iuf" and bool(np.isin(m, (0, 1)).all())
        if not ok:
            bad = [v for v in m.ravel().tolist() if not (isinstance(v, numbers.Real) and v in (0, 1))]
            raise ParameterError(f"ScheduleTable.feasible holds {bad[0]!r}; allowed: {allowed}")
        m = m.astype(bool)
    if not m.any():
        raise ParameterError(f"ScheduleTable.feasible: no grid point is feasible (nothing to "
                             f"schedule); allowed: {allowed}")
    return m.copy()


def _cells(value, corners, P, D) -> np.ndarray:
    shape = corners.shape
    allowed = (f"booleans (or 0/1) of shape {shape} (n_P - 1, n_D - 1), True only where the cell's "
               "four corners are feasible")
    m = np.array(value)
    if m.shape != shape or not (m.dtype == bool or (m.dtype.kind in "iuf" and bool(np.isin(m, (0, 1)).all()))):
        raise ParameterError(f"ScheduleTable.cell_safe has shape {m.shape} and type {m.dtype}; allowed: {allowed}")
    m = m.astype(bool)
    bad = m & ~corners
    if bad.any():
        i, j = (int(k) for k in np.argwhere(bad)[0])
        raise ParameterError(f"ScheduleTable.cell_safe[{i}, {j}] = True at the cell with lower corner "
                             f"{_where(P, D, i, j)}, which has an infeasible corner; allowed: {allowed}")
    return m.copy()


def _table(name, value, shape, feas, P, D, allowed, ok) -> np.ndarray:
    try:
        x = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"ScheduleTable.{name} is not an array of numbers; allowed: "
                             f"shape {shape} (n_P, n_D), {allowed} at every feasible point") from None
    if x.shape != shape:
        raise ParameterError(f"ScheduleTable.{name} has shape {x.shape}; allowed: shape {shape} "
                             "(n_P, n_D), like feasible")
    with np.errstate(invalid="ignore"):
        bad = feas & ~ok(x)
    if bad.any():
        i, j = (int(k) for k in np.argwhere(bad)[0])
        raise ParameterError(f"ScheduleTable.{name}[{i}, {j}] = {float(x[i, j])!r} at the feasible point "
                             f"{_where(P, D, i, j)}; allowed: {allowed} at every feasible point")
    return x


def _scalar_ok(v) -> bool:
    return isinstance(v, (str, bool, numbers.Real))


def _meta(value) -> dict:
    allowed = (f"a dict with the keys {list(META_KEYS)} (more allowed), values text, numbers, "
               "booleans, or a flat list or dict of these")
    if not isinstance(value, dict):
        raise ParameterError(f"ScheduleTable.meta = {value!r}; allowed: {allowed}")
    missing = [k for k in META_KEYS if k not in value]
    if missing:
        raise ParameterError(f"ScheduleTable.meta lacks {missing}; allowed: {allowed}")
    for k, v in value.items():
        if not isinstance(k, str):
            raise ParameterError(f"ScheduleTable.meta key {k!r} is not text; allowed: {allowed}")
        inner = (list(v.keys()) + list(v.values()) if isinstance(v, dict)
                 else list(v) if isinstance(v, (list, tuple)) else [v])
        if not all(_scalar_ok(x) for x in inner):
            raise ParameterError(f"ScheduleTable.meta[{k!r}] = {v!r}; allowed: {allowed}")
    return dict(value)


# --------------------------------------------------------------------- the lookup (Python twin)

def _locate(c: dict, P_gain: float, D_gain: float):
    """``(i, j, weights, inside)`` of rule 1: exactly the C ``locate``."""
    P, D = c["P"], c["D"]
    nP, nD = len(P), len(D)
    if not P_gain > P[0]:
        i, t = 0, 0.0
    elif not P_gain < P[nP - 1]:
        i, t = nP - 2, 1.0
    else:
        i = bisect.bisect_right(P, P_gain) - 1
        t = math.log(P_gain / P[i]) / c["log_step"][i]
        t = 1.0 if t > 1.0 else 0.0 if t < 0.0 else t
    if not D_gain > D[0]:
        j, u = 0, 0.0
    elif not D_gain < D[nD - 1]:
        j, u = nD - 2, 1.0
    else:
        j = bisect.bisect_right(D, D_gain) - 1
        u = (D_gain - D[j]) / (D[j + 1] - D[j])
        u = 1.0 if u > 1.0 else 0.0 if u < 0.0 else u
    inside = P[0] <= P_gain <= P[nP - 1] and D[0] <= D_gain <= D[nD - 1]
    w = ((1.0 - t) * (1.0 - u), t * (1.0 - u), (1.0 - t) * u, t * u)
    return i, j, w, inside


def _interpolate(values: list, base: int, nD: int, w) -> float:
    return (w[0] * values[base] + w[1] * values[base + nD] + w[2] * values[base + 1]
            + w[3] * values[base + nD + 1])


def lookup(table: ScheduleTable, P_gain: float, D_gain: float):
    """``(status, beta, alpha)`` at (P_gain Nm/rad, D_gain Nms/rad) by the rule of the module
    docstring, the same IEEE operations as the emitted ``haa_schedule_lookup``. ``beta`` and
    ``alpha`` are None where the C writes nothing (``NO_SAFE_GAIN``, ``NAN``; alpha also when
    it is not scheduled); status one of :data:`OK`, :data:`OUTSIDE`, :data:`NO_SAFE_GAIN`,
    :data:`NAN`."""
    c = table._c
    P_gain, D_gain = float(P_gain), float(D_gain)
    if math.isnan(P_gain) or math.isnan(D_gain):
        return NAN, None, None
    i, j, w, inside = _locate(c, P_gain, D_gain)
    nD = len(c["D"])
    if not c["cell_safe"][i * (nD - 1) + j]:
        return NO_SAFE_GAIN, None, None
    base = i * nD + j
    beta = _interpolate(c["beta"], base, nD, w)
    alpha = None if c["alpha"] is None else _interpolate(c["alpha"], base, nD, w)
    return (OK if inside else OUTSIDE), beta, alpha
