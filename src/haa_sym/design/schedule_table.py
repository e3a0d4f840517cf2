"""A torque-gain schedule table, validated, and its lookup in Python (the twin of the emitted C).

A :class:`ScheduleTable` holds, on a grid of impedances (P_gain, D_gain) of Eq. (8), the largest
torque-loop gain scale beta (``P_t = beta P_t0``, ``I_t = beta I_t0``, Eq. 7), optionally the
velocity-compensation scale alpha (Eq. 6), and which grid points meet the requirements at all.
How the table is computed is not this module's business; :func:`haa_sym.design.schedule_c.write_c`
turns it into plain C99 (``static const double`` tables, no allocation, only libm) for the
joint's low-level controller, and :func:`lookup_beta`, :func:`lookup_alpha`,
:func:`lookup_feasible` are the same lookup in Python, operation for operation.

The lookup rule (repeated in the generated header)
--------------------------------------------------
1. **Cell.** ``P_gain`` and ``D_gain`` are clamped to the grid's rectangle; the cell is the one
   whose lower corner ``(i, j)`` has ``P[i] <= P_gain < P[i+1]`` and ``D[j] <= D_gain < D[j+1]``
   (the last cell on the upper edges). Bilinear weights in (log P_gain, D_gain):
   ``t = log(P_gain / P[i]) / log(P[i+1] / P[i])``, ``u = (D_gain - D[j]) / (D[j+1] - D[j])``,
   weights ``(1-t)(1-u), t(1-u), (1-t)u, tu`` for the corners ``(i,j), (i+1,j), (i,j+1),
   (i+1,j+1)``. A corner is *used* when its weight is not zero: one corner at a grid point, two
   on a grid line, four inside a cell. Clamped points take the edge's values.
2. **Every used corner feasible:** the bilinear interpolation of beta (and alpha). At a grid
   point this is the table's value, bit for bit; between grid points it lies between the
   corners' values and is continuous in the impedance, so a user moving P_gain or D_gain online
   moves beta smoothly.
3. **Some used corner infeasible:** no interpolation. The result is the table entry of the used
   feasible corner with the smallest beta (its alpha with it: the pair was checked together);
   when no used corner is feasible, the *fallback point*, the feasible grid point with the
   smallest beta of the whole table (first in row-major order on ties). ``haa_schedule_feasible``
   returns 0.
4. **NaN in either argument:** the fallback point's beta (and alpha); feasible 0.
5. ``haa_schedule_feasible`` returns 1 exactly when the argument lies on the grid's rectangle
   (clamping not needed, no NaN) and every used corner is feasible: 1 means "the value comes
   from interpolating gains the table found safe at the surrounding impedances".

Why this rule, as a control engineer: the table gives, per grid point, the largest beta that
meets every requirement there. Interpolating towards a neighbour where *no* beta qualifies would
blend a safe gain with a number that means nothing, so an infeasible neighbour switches the
interpolation off and the smallest safe beta of the used neighbours is returned: near the edge
of the feasible set the largest safe beta falls (the torque bandwidth the impedance tolerates
shrinks), and each candidate is a gain the table found safe at an adjacent impedance. A gain
must stay a finite number the torque loop can run with (a NaN gain turns the motor voltage into
NaN), hence the fallback point for NaN and for cells without any feasible corner, with the
flag saying the value is not backed by the table. What no lookup rule can give: safety between
grid points. Bilinear interpolation of safe gains is safe where the largest safe beta is
concave over the cell; where it curves upwards the interpolation can exceed it by
O(h^2 x curvature). The table's producer must check the cells (e.g. their centres) or refine
the grid; the minimum over a cell's corners would be safe whenever the largest safe beta is
monotonic in P_gain and D_gain over the cell, but it is a staircase that jumps at every grid
line and does not return the table's values at the grid points.

Values held at infeasible grid points: the input table may hold anything there (NaN, a range
end); the emitted table holds the fallback point's beta and alpha. They are never interpolated
(rule 3) and keep every weighted sum finite.

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
>>> lookup_beta(table, float(P[1]), 25.0)            # a grid point: the table's value
7.0
>>> lookup_beta(table, float(np.sqrt(P[1] * P[2])), 37.5)   # cell centre: mean of 4 corners
6.0
>>> lookup_beta(table, 1500.0, 10.0), lookup_feasible(table, 1500.0, 10.0)  # rule 3
(1.0, 0)
"""
from __future__ import annotations

import bisect
import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from haa_sym.errors import ParameterError

__all__ = ["ScheduleTable", "META_KEYS", "lookup_beta", "lookup_alpha", "lookup_feasible"]

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
        points. None (default): alpha is not scheduled and no ``haa_schedule_alpha`` is emitted.

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
    # Derived (the tables as emitted, see "Values held at infeasible grid points"):
    fallback: int = field(init=False, repr=False)          # flat index of the fallback point
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
        for name, value in (("P_gain", P), ("D_gain", D), ("beta", beta), ("feasible", feas),
                            ("alpha", alpha)):
            if value is not None:
                value.flags.writeable = False
            object.__setattr__(self, name, value)
        object.__setattr__(self, "meta", meta)
        flat = np.where(feas, beta, np.inf).ravel()
        fb = int(np.argmin(flat))                  # first smallest in row-major order
        object.__setattr__(self, "fallback", fb)
        # The emitted tables as Python floats: the lookup twin reads exactly these.
        fill = lambda a: np.where(feas, a, a.ravel()[fb]).ravel().tolist()
        object.__setattr__(self, "_c", {
            "P": P.tolist(), "D": D.tolist(),
            "log_step": [math.log(b / a) for a, b in zip(P.tolist(), P.tolist()[1:])],
            "beta": fill(beta), "alpha": None if alpha is None else fill(alpha),
            "feasible": feas.ravel().tolist(),
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
    """``(base, weights, inside)`` of rule 1, or None for NaN: exactly the C ``locate``."""
    P, D = c["P"], c["D"]
    if math.isnan(P_gain) or math.isnan(D_gain):
        return None
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
    return i * nD + j, w, inside


def _rule(table: ScheduleTable, P_gain: float, D_gain: float):
    """``(k, cell)``: k = -1 to interpolate in ``cell``, else the flat index whose entries are
    returned (rules 3 and 4); exactly the C ``rule``."""
    c = table._c
    cell = _locate(c, float(P_gain), float(D_gain))
    if cell is None:
        return table.fallback, None
    base, w, _ = cell
    nD = len(c["D"])
    pick, every = -1, True
    for k, off in enumerate((0, nD, 1, nD + 1)):
        if not w[k] > 0.0:
            continue                                  # an unused corner
        idx = base + off
        if not c["feasible"][idx]:
            every = False
            continue
        if pick < 0 or c["beta"][idx] < c["beta"][pick]:
            pick = idx
    if every:
        return -1, cell
    return (pick if pick >= 0 else table.fallback), cell


def _value(table: ScheduleTable, values: list, P_gain: float, D_gain: float) -> float:
    k, cell = _rule(table, P_gain, D_gain)
    if k >= 0:
        return values[k]
    base, w, _ = cell
    nD = len(table._c["D"])
    return (w[0] * values[base] + w[1] * values[base + nD] + w[2] * values[base + 1]
            + w[3] * values[base + nD + 1])


def lookup_beta(table: ScheduleTable, P_gain: float, D_gain: float) -> float:
    """beta at (P_gain Nm/rad, D_gain Nms/rad) by the rule of the module docstring; the same
    IEEE operations as the emitted ``haa_schedule_beta``."""
    return _value(table, table._c["beta"], P_gain, D_gain)


def lookup_alpha(table: ScheduleTable, P_gain: float, D_gain: float) -> float:
    """alpha at (P_gain, D_gain), as ``haa_schedule_alpha`` (the table must schedule alpha)."""
    if table.alpha is None:
        raise ParameterError("lookup_alpha: this ScheduleTable has no alpha table; allowed: a "
                             "table built with alpha")
    return _value(table, table._c["alpha"], P_gain, D_gain)


def lookup_feasible(table: ScheduleTable, P_gain: float, D_gain: float) -> int:
    """1 when (P_gain, D_gain) is on the grid and every used corner is feasible, else 0
    (rule 5), as ``haa_schedule_feasible``."""
    k, cell = _rule(table, P_gain, D_gain)
    return int(k < 0 and cell[2])
