"""A torque-gain scheduler over the impedance range, robust to the leg (the paper's Sec. 6 outlook).

For every impedance (P_gain, D_gain) of a grid, the largest torque-gain scale beta (Eq. 7: the
torque PI gains are beta P_t0, beta I_t0) such that the requirements hold for every leg
configuration of the range (:mod:`haa_sym.analysis.robust`): by default the closed loop stable with an
impedance-loop phase margin of at least 30 deg; passivity at the port as an option. Optionally
alpha (Eq. 6) is scheduled too, from a set of values.

How beta is found
-----------------
beta runs over a logarithmic grid from ``beta_range[0]`` to ``beta_range[1]`` with ratio at most
``1 + beta_tol`` (the stated tolerance). Every ``coarse_step``-th value (ratio about 1.25) is
decided on the whole impedance grid at once, one map per (leg configuration, beta, alpha) from
the exact boundaries; each point's largest feasible coarse value and the next coarse value
bracket its answer, and every fine value inside the bracket is decided for the points that need
it. The answer is the largest feasible value found: feasible at every leg configuration, with
the next grid value (1 + beta_tol higher) infeasible for at least one unless it is the range's
end. A feasible island of beta narrower than one coarse step above an infeasible coarse value
is not searched (documented limit). The leg configurations double (2, 3, 5, 9, ...) until the
schedule no longer changes (``n_configurations`` says how many it took). Every answer is then
re-decided point by point at every leg configuration (the maps label segments of their rows from
a few probes) and lowered until it holds.

Between grid points
-------------------
A controller evaluates the table between its grid points (bilinear in log P_gain, D_gain, see
:mod:`haa_sym.design.schedule_table`), and bilinear interpolation of safe corner gains is not
safe in general. Every cell with four feasible corners is therefore checked on a sub-grid of
``(cell_subdivisions + 1)^2`` points (corners and edges included) at every leg configuration, at
the interpolated alpha and at the two values of the beta grid that bracket the interpolated beta
(both must meet the requirements: the check resolves beta to the stated tolerance, not finer).
Where a cell fails, its four corner values are lowered together by a number of beta-grid steps
bisected between the last failing and the last holding drop (a few passes, not one pass per
step: the README's harmonic-drive schedule needed over 125 one-step passes); shared corners take
the largest drop of their cells, the neighbouring cells are re-checked at the final corners, and
the lookup stays continuous. In round ``cell_rounds`` (default 3) the cells that still fail are
given up instead (no corner lowered, so nothing else changes): where feasibility is not monotone
in beta (passivity at intermediate beta), lowering a corner can make the next cell fail, a chain
that crossed the grid one cell a round. A cell that still fails with a corner at the range's bottom, and
every cell with an infeasible corner, has no safe gain (``cell_safe`` False; the C lookup answers ``HAA_SCHEDULE_NO_SAFE_GAIN``). This
is sampling: points between the sub-grid's are not verified.

At the range's limit
--------------------
``beta_at_limit`` marks the impedances whose answer is the range's top (``beta_range[1]``): there
the range, not the model, limits beta (the HyQ model has no actuator limits and accepts beta = 8
at low damping), and the torque bandwidth "gained" is the range's, not the drive's.

The torque bandwidth reported with each row is the paper's (Sec. 3.3): the -3 dB frequency of
torque tracking with the leg free in the air (the port body's stiffness set to 0), at the
scheduled beta and alpha, the file's nominal plant otherwise.

Large sweeps
------------
Every map is one task (one call of the evaluators on a whole gain grid; a task ships a few
numbers and returns one boolean array); so are the point check's decisions (one per beta and
leg configuration) and the torque bandwidths. Tasks run on dask: in-process (dask's threaded
scheduler) by default, on a local cluster of N processes (``scheduler="local:N"``), or on an
existing dask.distributed cluster (``scheduler`` = its address or a ``distributed.Client``),
where small calls go in groups, a few per worker (:meth:`haa_sym.io.tasks.TaskRunner.run`). The
result is the same, byte for byte.

Each task list waits for the one before it (a barrier: what to compute next depends on the
results), so on a cluster their number, not only their work, sets the time. The first task list
therefore also maps the configurations the doubling's second level will ask for and the beta = 1
comparison (both always needed), the first refinement also decides those configurations and each
point at its coarse answer (what the point check re-decides), and the torque bandwidths run
beside the cell check (:meth:`haa_sym.io.tasks.TaskRunner.start`): on the default grid 5 task
lists (maps, refinement, three cell-check passes) where there were 11, the same decisions.

Example
-------
>>> from haa_sym import ClosedLoop, load_params
>>> from haa_sym.design.schedule import schedule
>>> s = schedule(ClosedLoop(load_params()), [10.0, 300.0], [2.0, 20.0])      # doctest: +SKIP
>>> s.beta                                                                   # doctest: +SKIP
"""
from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import urllib.parse

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from haa_sym._version import version
from haa_sym.analysis.decide import decide_points
from haa_sym.analysis.regions import check_map_budget
from haa_sym.analysis.robust import (MAX_LEG_POINTS, _check_requirements, check_uncertainty, feasible_task,
                                     leg_configurations, leg_ends, leg_values, meets)
from haa_sym.analysis.torque import torque_bandwidth
from haa_sym.design.schedule_table import META_KEYS, ScheduleTable
from haa_sym.errors import ParameterError
from haa_sym.io.gridspec import grid
from haa_sym.io.outputs import write_text
from haa_sym.io.progress import message
from haa_sym.io.tasks import DEFAULT_CONNECT_TIMEOUT, TaskRunner, cluster, local_workers, scheduler_kind
from haa_sym.loop import ClosedLoop, loop_first
from haa_sym.model.params import Params, gain_array

__all__ = ["Schedule", "schedule", "beta_grid", "CSV_COLUMNS", "CSV_COLUMNS_UNCHECKED", "DEFAULT_P_GAIN",
           "DEFAULT_D_GAIN", "table_from_csv", "CSV_CELL_CHECK"]

# The columns of haa-sym schedule --out (docs/schedule.md, "The CSV"): the schedule at each grid
# point, then the cell-checked lookup table (what --c-out emits) so that the CSV alone rebuilds it.
CSV_COLUMNS = ("P_gain", "D_gain", "beta", "alpha", "torque_bandwidth_rad_s", "feasible", "beta_at_limit",
               "table_beta", "cell_safe", "table_meta")
# The columns of the CSVs written before the lookup's columns existed: still read, as an unchecked table.
CSV_COLUMNS_UNCHECKED = CSV_COLUMNS[:7]
# HyQ's locomotion range (the issue): P_gain log 1..2000 Nm/rad, D_gain 1..50 Nms/rad
DEFAULT_P_GAIN = "log:1:2000:30"
DEFAULT_D_GAIN = "lin:1:50:20"
COARSE_RATIO = 1.25
# Sub-grid of the cell check: 4 subdivisions, 5 x 5 points a cell (corners and edges included).
# Halving the spacing quarters the bilinear error a smooth boundary can hide between samples;
# at 5 x 5 the off-grid test (tests/test_design_schedule_safety.py) finds no unsafe beta, and the check
# costs about half the schedule's own time on the default HyQ grid (docs/model.md).
CELL_SUBDIVISIONS = 4
# Rounds of the cell check (module docstring, "Between grid points"): in the last one, cells that
# still fail are given up instead of lowering corners that other cells share. The README's
# harmonic-drive schedule (passivity required) needed 2 rounds for its own failures, then ran a
# chain of single cells, one round (about 9 passes, 40-90 s) each (docs/schedule.md).
CELL_ROUNDS = 3


def beta_grid(beta_range=(0.1, 8.0), beta_tol: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """The fine beta grid (log, ratio <= 1 + beta_tol, both ends included) and the indices of
    its coarse values (ratio about 1.25, both ends included)."""
    lo, hi = (float(v) for v in beta_range)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise ParameterError(f"beta_range = {lo:g}:{hi:g}; allowed: 0 < LO < HI (a range of the "
                             "torque-gain scale beta, Eq. 7)")
    if not (np.isfinite(beta_tol) and 1e-4 <= beta_tol <= 0.25):
        raise ParameterError(f"beta_tol = {beta_tol!r}; allowed: 1e-4 <= beta_tol <= 0.25 (relative step)")
    n = int(np.ceil(np.log(hi / lo) / np.log1p(beta_tol))) + 1
    fine = np.geomspace(lo, hi, n)
    step = max(1, int(round(np.log(COARSE_RATIO) / np.log(fine[1] / fine[0])))) if n > 1 else 1
    coarse = np.unique(np.append(np.arange(0, n, step), n - 1))
    return fine, coarse


@dataclass(frozen=True)
class Schedule:
    """The schedule on the impedance grid; arrays (n_P, n_D).

    ``beta`` and ``alpha`` (NaN where ``feasible`` is False), ``torque_bandwidth_rad_s`` (rad/s,
    the leg free in the air, at the scheduled gains), ``feasible``; ``beta_fixed_feasible``:
    whether beta = 1 (the file's tuning) meets the requirements at every leg configuration;
    ``n_configurations``, ``converged`` and ``history`` of the leg doubling; ``meta``: what
    produced it. ``beta_at_limit``: feasible with beta at the range's top (the range, not the
    model, limits it). ``table_beta`` (n_P, n_D): the corner values the lookup interpolates,
    ``<= beta`` (lowered by the cell check; NaN where infeasible); ``cell_safe`` (n_P - 1,
    n_D - 1): the cells whose interpolated gains passed the check.
    """

    P_gain: np.ndarray
    D_gain: np.ndarray
    beta: np.ndarray
    alpha: np.ndarray
    torque_bandwidth_rad_s: np.ndarray
    feasible: np.ndarray
    n_configurations: int
    converged: bool
    history: list
    meta: dict = field(default_factory=dict)
    beta_fixed_feasible: np.ndarray = None
    beta_at_limit: np.ndarray = None
    table_beta: np.ndarray = None
    cell_safe: np.ndarray = None

    def csv_text(self) -> str:
        """One row per grid point, columns :data:`CSV_COLUMNS` (docs/schedule.md, "The CSV"): the
        schedule (empty numbers where infeasible), then the lookup table :meth:`table` emits
        (``table_beta``, ``cell_safe``, ``table_meta`` on the first row), exactly."""
        lines = [",".join(CSV_COLUMNS)]
        n_P, n_D = self.feasible.shape
        # the header provenance of table() and whether alpha is scheduled, as one JSON object (its
        # floats round-trip): read back, the lookup's header is table()'s
        meta = {"alpha_scheduled": bool(self.meta.get("alpha_scheduled")), "provenance": self._table_meta()}
        meta["provenance"]["source"] = Path(meta["provenance"]["source"]).name   # no machine's path in the data
        quoted = _meta_cell(meta)
        for i, P in enumerate(self.P_gain):
            for j, D in enumerate(self.D_gain):
                ok = bool(self.feasible[i, j])
                num = (lambda v: f"{v:.12g}" if ok and np.isfinite(v) else "")
                # the shortest text that reads back as the same double: alpha and table_beta are
                # the lookup's values, which must come back bit for bit (beta is for reading)
                exact = (lambda v: repr(float(v)) if ok and np.isfinite(v) else "")
                cell = ("" if i == n_P - 1 or j == n_D - 1 else "true" if self.cell_safe[i, j] else "false")
                # the grid exactly (17 digits round-trip): fed back to the C lookup, a grid point
                # must hit the table's grid point, not a neighbour's cell
                lines.append(f"{P:.17g},{D:.17g},{num(self.beta[i, j])},{exact(self.alpha[i, j])},"
                             f"{num(self.torque_bandwidth_rad_s[i, j])},{'true' if ok else 'false'},"
                             f"{'true' if self.beta_at_limit[i, j] else 'false'},{exact(self.table_beta[i, j])},"
                             f"{cell},{quoted if i == j == 0 else ''}")
        return "\n".join(lines) + "\n"

    def save_csv(self, path, tx=None, field: str | None = None):
        """Write :meth:`csv_text` (all or nothing, :mod:`haa_sym.io.outputs`)."""
        return write_text(path, self.csv_text(), tx, field)

    def table(self):
        """The schedule as a :class:`haa_sym.design.schedule_c.ScheduleTable` (for the embedded C)."""
        if not self.feasible.any():
            raise ParameterError("the schedule has no feasible point, so there is no gain to emit; "
                                 "allowed: a beta range or requirements that some impedance meets")
        alpha = self.alpha if self.meta.get("alpha_scheduled") else None
        return ScheduleTable(self.P_gain, self.D_gain, self.table_beta, self.feasible, self._table_meta(),
                             alpha=alpha, cell_safe=self.cell_safe)

    def _table_meta(self) -> dict:
        """The lookup header's provenance (:data:`haa_sym.design.schedule_table.META_KEYS` and more)."""
        m = self.meta
        return {"actuator": m["actuator"], "source": m["source"], "requirements": list(m["requirements"]),
                "tolerances": {"beta_tol": m["beta_tol"], "pm_deg": 30.0},
                "haa_sym_version": m["haa_sym"], "leg": list(m["leg"]), "leg_mode": m["leg_mode"],
                "leg_configurations": int(self.n_configurations), "beta_range": list(m["beta_range"]),
                "cell_check": m["cell_check"]}


#: What the header of a lookup rebuilt from a CSV without the lookup's columns
#: (:data:`CSV_COLUMNS_UNCHECKED`, written before they existed) says about its cells: such a CSV
#: holds the schedule at the grid points only (its ``beta``), not the cell-checked corner values.
CSV_CELL_CHECK = ("not checked: the table was rebuilt from the schedule's CSV, which holds beta at the grid points "
                  "(not the corner values the cell check lowered, nor its safe cells); the cell-checked table is "
                  "haa-sym schedule --c-out's")


# Characters of the table_meta JSON written as %XX: the delimiter, numpy.genfromtxt's comment
# mark, and the escape itself. The cell then needs no CSV quoting, and every CSV of the project
# reads with numpy.genfromtxt (tests/test_paper_reproduce.py), pandas and the csv module alike.
_META_ESCAPED = ",#%"


def _meta_cell(obj: dict) -> str:
    """``table_meta``'s cell: ``obj`` as JSON (ASCII), :data:`_META_ESCAPED` as ``%XX``."""
    return "".join(f"%{ord(c):02X}" if c in _META_ESCAPED else c for c in json.dumps(obj))


def _csv_rows(text: str, where: str):
    """``(header, [(line number, cells)])`` of a CSV text, blank lines skipped, cells stripped."""
    try:
        rows = [(n, [c.strip() for c in r]) for n, r in _numbered(csv.reader(io.StringIO(text, newline="")))
                if any(c.strip() for c in r)]
    except csv.Error as exc:
        raise ParameterError(f"{where}: not a CSV file ({exc}); allowed: a CSV of haa-sym schedule --out") from None
    return (rows[0][1] if rows else []), rows[1:]


def _numbered(reader):
    """``(first line number of the row, row)`` for each row of a ``csv.reader``."""
    start = 1
    for row in reader:
        yield start, row
        start = reader.line_num + 1


def table_from_csv(text: str, source: str, meta: dict, field: str = "--schedule") -> ScheduleTable:
    """A :class:`ScheduleTable` from the text of :meth:`Schedule.csv_text` (``haa-sym schedule
    --out``; docs/schedule.md, "The CSV").

    With the columns :data:`CSV_COLUMNS`: the cell-checked table :meth:`Schedule.table` builds,
    the same arrays (``table_beta``, ``feasible``, ``alpha`` where the schedule scheduled it,
    ``cell_safe``) and the CSV's provenance (``table_meta``), its ``source`` naming the CSV and
    the parameter file the schedule read; ``meta`` is not used. With the older columns
    :data:`CSV_COLUMNS_UNCHECKED`: the grid, ``beta`` and ``feasible``; ``alpha`` where the
    feasible rows do not all share one value; the cells those with four feasible corners,
    unchecked (:data:`CSV_CELL_CHECK`), and ``meta`` (:data:`META_KEYS` of
    :mod:`haa_sym.design.schedule_table`) the header's provenance, ``source`` added.

    Raises
    ------
    ParameterError
        One line naming ``field``, the file, the row (its line number) or column at fault and
        what is allowed.
    """
    where = f"{field} {source!r}"
    header, body = _csv_rows(text, where)
    checked = tuple(header) == CSV_COLUMNS
    if not checked and tuple(header) != CSV_COLUMNS_UNCHECKED:
        raise ParameterError(f"{where}: header {','.join(header)[:80]!r}; allowed: a CSV of haa-sym schedule --out, "
                             f"columns {','.join(CSV_COLUMNS)} (or, from a CSV written before the lookup's columns "
                             f"existed, the first {len(CSV_COLUMNS_UNCHECKED)} of them: an unchecked table)")
    columns = CSV_COLUMNS if checked else CSV_COLUMNS_UNCHECKED
    rows = []
    for n, cells in body:
        line = ",".join(cells)
        try:
            if len(cells) != len(columns) or cells[5] not in ("true", "false"):
                raise ValueError
            ok = cells[5] == "true"
            P, D = float(cells[0]), float(cells[1])
            beta = float(cells[2]) if ok else math.nan
            alpha = float(cells[3]) if ok and cells[3] else math.nan
        except ValueError:
            raise ParameterError(f"{where}: row {n} {line[:80]!r}; allowed: {len(columns)} columns, numbers "
                                 "P_gain, D_gain, beta (and alpha) where feasible is true, feasible true or false")
        if checked:
            tb = _table_beta(cells, ok, f"{where}: row {n}: table_beta")
            if cells[8] not in ("true", "false", ""):
                raise ParameterError(f"{where}: row {n}: cell_safe = {cells[8]!r}; allowed: true or false (the cell "
                                     "whose lowest P_gain and D_gain corner is this point), empty on the last "
                                     "P_gain and the last D_gain of the grid")
            rows.append((P, D, beta, alpha, ok, tb, cells[8], cells[9], n))
        else:
            rows.append((P, D, beta, alpha, ok, beta, "", "", n))
    P = np.array(sorted({r[0] for r in rows}))
    D = np.array(sorted({r[1] for r in rows}))
    if len(rows) != P.size * D.size:
        raise ParameterError(f"{where}: {len(rows)} rows for {P.size} P_gain x {D.size} D_gain values; allowed: "
                             "one row per point of a rectangular grid")
    shape = (P.size, D.size)
    beta, alpha, table_beta = np.full(shape, math.nan), np.full(shape, math.nan), np.full(shape, math.nan)
    feasible, seen = np.zeros(shape, bool), np.zeros(shape, bool)
    cell_safe = np.zeros((P.size - 1, D.size - 1), bool)
    provenance = []
    for Pv, Dv, b, a, ok, tb, safe, tm, n in rows:
        i, j = int(np.searchsorted(P, Pv)), int(np.searchsorted(D, Dv))
        if seen[i, j]:
            raise ParameterError(f"{where}: the point P_gain {Pv!r}, D_gain {Dv!r} twice; allowed: each point once")
        seen[i, j], beta[i, j], alpha[i, j], feasible[i, j], table_beta[i, j] = True, b, a, ok, tb
        if not checked:
            continue
        last = i == P.size - 1 or j == D.size - 1
        if (safe == "") != last:
            raise ParameterError(f"{where}: row {n}: cell_safe = {safe!r} at P_gain {Pv!r}, D_gain {Dv!r}; allowed: "
                                 + ("empty on the last P_gain and the last D_gain of the grid (no cell starts there)"
                                    if last else "true or false (the cell whose lowest corner this point is)"))
        if safe == "true":
            cell_safe[i, j] = True
        if tm:
            provenance.append((n, tm))
    if checked:
        _check_cells_csv(cell_safe, feasible, rows, P, D, where)
        meta, alpha_scheduled = _table_meta_csv(provenance, source, where)
    else:
        meta = {**meta, "source": source, "cell_check": CSV_CELL_CHECK}
        a_ok = alpha[feasible]
        alpha_scheduled = a_ok.size and np.all(np.isfinite(a_ok)) and np.ptp(a_ok) > 0
        cell_safe = None
    try:
        return ScheduleTable(P, D, table_beta, feasible, meta, alpha=alpha if alpha_scheduled else None,
                             cell_safe=cell_safe)
    except ParameterError as exc:
        raise ParameterError(f"{where}: {exc}") from None


def _table_beta(cells: list, ok: bool, what: str) -> float:
    """A row's ``table_beta``: where feasible, a finite number > 0 that is not above the row's
    beta (compared at beta's 12 digits, as the CSV prints it: rounding keeps the order); empty
    where infeasible."""
    text = cells[7]
    if not ok:
        if text:
            raise ParameterError(f"{what} = {text!r} at an infeasible point (feasible false); allowed: empty")
        return math.nan
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        raise ParameterError(f"{what} = {text!r} at a feasible point; allowed: a finite number > 0 (the corner "
                             "value the lookup interpolates)")
    if float(f"{v:.12g}") > float(cells[2]):
        raise ParameterError(f"{what} = {text!r} is above the row's beta = {cells[2]}; allowed: at most beta (the "
                             "cell check only lowers corner values)")
    return v


def _check_cells_csv(cell_safe, feasible, rows, P, D, where) -> None:
    """A safe cell needs four feasible corners (else no beta qualifies at one: no safe gain)."""
    corners = feasible[:-1, :-1] & feasible[1:, :-1] & feasible[:-1, 1:] & feasible[1:, 1:]
    bad = cell_safe & ~corners
    if bad.any():
        i, j = (int(k) for k in np.argwhere(bad)[0])
        n = next(r[8] for r in rows if r[0] == P[i] and r[1] == D[j])
        raise ParameterError(f"{where}: row {n}: cell_safe = 'true' at P_gain {float(P[i])!r}, D_gain "
                             f"{float(D[j])!r}, but a corner of its cell is infeasible; allowed: true only where "
                             "the cell's four corners are feasible")


def _table_meta_csv(provenance: list, source: str, where: str) -> tuple[dict, bool]:
    """The lookup header's provenance from the CSV's ``table_meta`` (one row's JSON object), its
    ``source`` naming the CSV and the parameter file the schedule read; and whether alpha is
    scheduled."""
    allowed = ("one row (the first, as written) with a JSON object {\"alpha_scheduled\": true or false, "
               "\"provenance\": {...}}, its ',' '#' '%' written %2C %23 %25, the others empty")
    if len(provenance) != 1:
        raise ParameterError(f"{where}: table_meta in {len(provenance)} rows"
                             + (f" ({', '.join(str(n) for n, _ in provenance[:4])})" if provenance else "")
                             + f"; allowed: {allowed}")
    n, text = provenance[0]
    try:
        obj = json.loads(urllib.parse.unquote(text, errors="strict"))
    except ValueError:
        obj = None
    if not (isinstance(obj, dict) and set(obj) == {"alpha_scheduled", "provenance"}
            and isinstance(obj["alpha_scheduled"], bool) and isinstance(obj["provenance"], dict)
            and isinstance(obj["provenance"].get("source"), str)):
        raise ParameterError(f"{where}: row {n}: table_meta = {text[:60]!r}; allowed: {allowed}, the provenance "
                             "with a source")
    meta = dict(obj["provenance"])
    missing = [k for k in META_KEYS if k not in meta]
    if missing:
        raise ParameterError(f"{where}: row {n}: table_meta's provenance lacks {missing}; allowed: the keys "
                             f"{list(META_KEYS)} of the lookup header's provenance (more allowed)")
    meta["source"] = f"{source} (haa-sym schedule --out of {meta['source']}, cell-checked)"
    return meta, obj["alpha_scheduled"]


# ------------------------------------------------------------------------------ the tasks
# Module-level functions of plain data: what a dask worker runs (one point set; one map is
# haa_sym.analysis.robust.feasible_task).

def _task_points(params, config, P, D, beta, alpha, requirements, options):
    loop = ClosedLoop(params.with_values(**config), options)
    return meets(decide_points(loop, P, D, beta, alpha, passivity="passive" in requirements), requirements)


#: Seconds to connect to a --scheduler and finish dask's handshake (read at each call: tests lower it).
CONNECT_TIMEOUT = DEFAULT_CONNECT_TIMEOUT


def _Runner(scheduler, progress):
    """The task runner of :mod:`haa_sym.io.tasks` with this module's CONNECT_TIMEOUT."""
    return TaskRunner(scheduler, progress, connect_timeout=CONNECT_TIMEOUT)


def _key(config: dict) -> tuple:
    """A leg configuration as a dict key."""
    return tuple(sorted(config.items()))


def _verify(runner, params, configs, P, D, fine, alphas, best_k, req, options, decided=None):
    """Re-decide every answer point by point (:func:`haa_sym.analysis.decide.decide_points`, the
    maps' own rule with exactly located crossovers) at every leg configuration, and lower a
    point's beta until it holds: the maps decide whole segments from a few probes. Every
    (beta, configuration) group of a round is a task (:func:`_task_points`), every alpha's in
    the same task list. ``decided`` ({(configuration key, beta index, alpha index): {flat point
    index: bool}}): decisions of :func:`_task_points` made before (the refinement's), reused and
    extended; a point's decision does not depend on the others decided with it. Returns the new
    indices and how many points were lowered."""
    decided = {} if decided is None else decided
    PP, DD = np.meshgrid(P, D, indexing="ij")
    PP, DD = PP.ravel(), DD.ravel()
    best_k = best_k.copy()
    lowered = set()
    config_keys = [_key(c) for c in configs]
    todo = {a: np.flatnonzero(best_k[a] >= 0) for a in range(alphas.size)}
    while any(t.size for t in todo.values()):
        jobs = []
        for a, t in todo.items():
            for k in np.unique(best_k[a, t]).tolist():
                pts = t[best_k[a, t] == k]
                for c in configs:
                    done = decided.setdefault((_key(c), k, a), {})
                    missing = [p for p in pts.tolist() if p not in done]
                    if missing:
                        jobs.append((c, k, a, missing))
        res = runner.run(_task_points, [(params, c, PP[m], DD[m], float(fine[k]), float(alphas[a]), req, options)
                                        for c, k, a, m in jobs], "schedule: point check")
        for (c, k, a, m), r in zip(jobs, res):
            decided[(_key(c), k, a)].update(zip(m, np.asarray(r, bool).tolist()))
        for a, t in todo.items():
            ok = np.array([all(decided[(ck, int(best_k[a, p]), a)][p] for ck in config_keys) for p in t.tolist()],
                          bool)
            bad = t[~ok] if t.size else t
            lowered.update(bad.tolist())
            best_k[a, bad] -= 1                 # -1: no beta of the range is left
            todo[a] = bad[best_k[a, bad] >= 0]
    return best_k, len(lowered)


def _task_bandwidth(params, options, backend, beta, alpha):
    return torque_bandwidth(ClosedLoop(params, options, backend, basis=False), beta=beta, alpha=alpha)


def _check_cells(runner, params, configs, P, D, fine, K, alpha_pt, req, options, n_sub, max_rounds=None):
    """The cell check (module docstring, "Between grid points"). ``K`` (n_P, n_D): beta-grid
    index per grid point (-1 infeasible), ``alpha_pt`` its alpha. Returns the lowered indices,
    the safe cells, how many cells failed the check at first, how many grid points were lowered,
    how many cells were given up, and the passes (task lists run).

    A round checks the cells to check at the current corners. Each failing cell then searches
    its own drop ``s`` (beta-grid steps, the four corners lowered together, as one step a pass
    used to): ``s = 1`` and the bottom (the lowest corner at the range's end) are tried in one
    pass; a cell failing at the bottom has no safe gain; otherwise ``s`` is bisected between
    the last failing and the last holding drop, all cells in the same passes. Each grid point
    then takes the largest drop of the failing cells it is a corner of, and every cell touching
    a lowered point is checked again in the next round: a cell is safe only when it held at
    its final corners, whatever the search found. A drop of 125 steps costs about 9 passes
    instead of 125. In round ``max_rounds`` (:data:`CELL_ROUNDS`; None: no bound) the cells
    that fail are given up without lowering anything, so no other cell changes and the check
    ends: where feasibility is not monotone in beta (passivity), a lowered corner can make the
    next cell fail, and such chains crossed the grid one cell a round."""
    K = K.copy()
    safe = (K[:-1, :-1] >= 0) & (K[1:, :-1] >= 0) & (K[:-1, 1:] >= 0) & (K[1:, 1:] >= 0)
    s = np.arange(n_sub + 1) / n_sub
    tt, uu = (x.ravel() for x in np.meshgrid(s, s, indexing="ij"))
    W = np.stack([(1 - tt) * (1 - uu), tt * (1 - uu), (1 - tt) * uu, tt * uu], axis=1)
    # The sub-grid's P and D values, made once: a sub-point is named by its global sub-grid
    # indices (cell i's t-th P value is index i * n_sub + t), so that neighbouring cells share
    # their edge points' decisions (edges exactly the grid's values).
    ti, ui = (np.rint(x * n_sub).astype(np.int64) for x in (tt, uu))
    log_step = np.log(P[1:] / P[:-1])
    P_sub, D_sub = np.empty((P.size - 1) * n_sub + 1), np.empty((D.size - 1) * n_sub + 1)
    for i in range(P.size - 1):
        P_sub[i * n_sub + ti] = np.where(tt == 1, P[i + 1], P[i] * np.exp(tt * log_step[i]))
    for j in range(D.size - 1):
        D_sub[j * n_sub + ui] = np.where(uu == 1, D[j + 1], D[j] + uu * (D[j + 1] - D[j]))
    # A decision (beta index k, alpha, P index, D index) -> "meets at every configuration" is
    # kept as one integer code, sorted, with its answer: a pass's sub-points are made, looked up
    # and grouped as arrays (the cell check's Python between its passes is on the critical path
    # of a cluster run, issue 27: 0.39 s on the default grid when made point by point).
    alpha_ids: dict = {}                     # alpha (a float) -> its number in the codes
    dims = (fine.size, P_sub.size, D_sub.size)
    codes, answers = np.empty(0, np.int64), np.empty(0, bool)
    failed_once, lowered_pts, given_up = set(), set(), 0
    passes = [0]

    def corners(i, j):
        return [i, i + 1, i, i + 1], [j, j, j + 1, j + 1]

    def sub_codes(Q):
        """The decisions' codes of probes ``Q`` ((n, 3): i, j, drop), (n, 2 * sub-points): each
        sub-point at the two beta-grid values bracketing its interpolated beta."""
        I, J, drop = Q[:, 0], Q[:, 1], Q[:, 2]
        ci, cj = np.stack([I, I + 1, I, I + 1], 1), np.stack([J, J, J + 1, J + 1], 1)
        b = fine[K[ci, cj] - drop[:, None]] @ W.T
        al = alpha_pt[ci, cj]
        A = np.repeat(al[:, :1], tt.size, axis=1)       # one alpha exactly: one decision call per beta
        for r in np.flatnonzero(np.any(al != al[:, :1], axis=1)):
            A[r] = W @ al[r]
        klo = np.clip(np.searchsorted(fine, b * (1 + 1e-12), side="right") - 1, 0, fine.size - 1)
        on_grid = np.abs(fine[klo] - b) <= 1e-12 * b          # a corner: its own grid value
        khi = np.where(on_grid, klo, np.minimum(klo + 1, fine.size - 1))
        values, inverse = np.unique(A, return_inverse=True)
        ids = np.array([alpha_ids.setdefault(x, len(alpha_ids)) for x in values.tolist()], np.int64)
        a_id = ids[inverse.reshape(A.shape)]
        gp, gd = I[:, None] * n_sub + ti, J[:, None] * n_sub + ui
        if len(alpha_ids) * math.prod(dims) >= 2 ** 63:        # pragma: no cover - far beyond any budget
            raise ParameterError("the cell check's sub-grid is too large to name its points; allowed: fewer "
                                 "grid points, beta values or cell_subdivisions")
        return np.concatenate([((a_id * dims[0] + k) * dims[1] + gp) * dims[2] + gd for k in (klo, khi)], axis=1)

    def lookup(q):
        """(found, answer) of codes ``q``."""
        at = np.minimum(np.searchsorted(codes, q), max(codes.size - 1, 0))
        found = (codes[at] == q) if codes.size else np.zeros(q.shape, bool)
        return found, (answers[at] if codes.size else found) & found

    def holds(probes):
        """{(i, j, drop): the cell's sub-grid meets the requirements with its corners lowered
        by ``drop``}, deciding what is not decided yet in one pass (one task list)."""
        nonlocal codes, answers
        qs = sorted(probes)
        q = sub_codes(np.array(qs, np.int64).reshape(-1, 3))
        found, _ = lookup(q)
        need = np.unique(q[~found])
        if need.size:
            passes[0] += 1
            gd = need % dims[2]
            gp = need // dims[2] % dims[1]
            k = need // (dims[2] * dims[1]) % dims[0]
            a = np.array(list(alpha_ids), float)[need // (dims[2] * dims[1] * dims[0])]
            order = np.lexsort((gd, gp, a, k))              # by beta, then alpha, P, D
            need, gd, gp, k, a = need[order], gd[order], gp[order], k[order], a[order]
            cut = np.flatnonzero((np.diff(k) != 0) | (np.diff(a) != 0)) + 1
            groups = np.split(np.arange(need.size), cut)
            tasks = [(params, c, P_sub[gp[g]], D_sub[gd[g]], float(fine[k[g[0]]]), float(a[g[0]]), req, options)
                     for g in groups for c in configs]
            res = runner.run(_task_points, tasks, f"schedule: cells (pass {passes[0]})")
            ok = np.concatenate([np.logical_and.reduce([np.asarray(r, bool)
                                                        for r in res[n * len(configs):(n + 1) * len(configs)]])
                                 for n in range(len(groups))])
            codes, answers = np.concatenate([codes, need]), np.concatenate([answers, ok])
            order = np.argsort(codes, kind="stable")
            codes, answers = codes[order], answers[order]
        _, ok = lookup(q)
        return dict(zip(qs, ok.all(axis=1).tolist()))

    todo = {(int(i), int(j)) for i, j in np.argwhere(safe)}
    rounds = 0
    while todo:
        ok = holds({(i, j, 0) for i, j in todo})
        failing = sorted((i, j) for (i, j, _), o in ok.items() if not o)
        failed_once.update(failing)
        rounds += 1
        if max_rounds is not None and rounds >= max_rounds:
            for c in failing:
                safe[c] = False
            given_up += len(failing)
            if failing:
                message(f"schedule: cell check round {rounds} (the last, cell_rounds): {len(todo)} cells checked, "
                        f"{len(failing)} failed and given up (no safe gain); {passes[0]} passes")
            break
        # bisection of each failing cell's drop: lo fails, hi holds (None: not found yet)
        lo = {c: 0 for c in failing}
        bottom = {c: int(K[corners(*c)].min()) for c in failing}
        hi: dict = {}
        for c in failing:
            if bottom[c] == 0:                      # nothing left to lower: no safe gain here
                safe[c] = False
                given_up += 1
        search = [c for c in failing if bottom[c] > 0]
        if search:
            ok = holds({(*c, d) for c in search for d in {1, bottom[c]}})
            for c in search:
                if ok[(*c, 1)]:
                    hi[c] = 1
                elif ok[(*c, bottom[c])]:
                    lo[c], hi[c] = 1, bottom[c]
                else:
                    safe[c] = False
                    given_up += 1
        while True:
            open_ = [c for c in hi if hi[c] - lo[c] > 1]
            if not open_:
                break
            mid = {c: (lo[c] + hi[c]) // 2 for c in open_}
            ok = holds({(*c, mid[c]) for c in open_})
            for c in open_:
                if ok[(*c, mid[c])]:
                    hi[c] = mid[c]
                else:
                    lo[c] = mid[c]
        if failing:
            message(f"schedule: cell check round {rounds}: {len(todo)} cells checked, {len(failing)} failed, "
                    f"{len(failing) - len(hi)} given up, drops of {sorted(set(hi.values()))} beta steps; "
                    f"{passes[0]} passes so far")
        drop = np.zeros(K.shape, int)
        for c, d in hi.items():
            ci, cj = corners(*c)
            drop[ci, cj] = np.maximum(drop[ci, cj], d)
        K -= drop
        todo = set()
        for i, j in np.argwhere(drop > 0):
            lowered_pts.add((int(i), int(j)))
            todo.update((a, b) for a in (i - 1, i) for b in (j - 1, j)
                        if 0 <= a < safe.shape[0] and 0 <= b < safe.shape[1] and safe[a, b])
    return K, safe, len(failed_once), len(lowered_pts), given_up, passes[0]


def _free_in_the_air(params: Params) -> Params:
    """The file's plant with the port body's stiffness to ground at 0 (Sec. 3.3: the torque
    bandwidth with the leg free to move in the air); unchanged if the port has none."""
    key = f"K_{params.plant.topology.port}"
    return params.with_values(**{key: 0.0}) if key in params.plant.topology.parameter_keys else params


@loop_first
def schedule(loop, P_gain=None, D_gain=None, *, beta_range=(0.1, 8.0), beta_tol: float = 0.02,
             alpha=None, alpha_values=None, requirements=("stable", "pm"), leg=None,
             leg_mode: str = "segment", uncertainty=None, scheduler=None, progress: bool | None = None,
             max_per_axis: int = MAX_LEG_POINTS, cell_subdivisions: int = CELL_SUBDIVISIONS,
             cell_rounds: int | None = CELL_ROUNDS) -> Schedule:
    """The largest robust beta (and alpha) for every impedance of the grid.

    Parameters
    ----------
    loop : ClosedLoop
        The actuator, controller (``P_t0``, ``I_t0``, ``Ts``, ``N_av`` ...) and options; its
        parameters' configurations give the leg range.
    P_gain, D_gain : array_like, optional
        The impedance grid, Nm/rad and Nms/rad (default log 1..2000 x lin 1..50, 30 x 20).
    beta_range : (float, float)
        Range of the torque-gain scale beta (Eq. 7), 0 < lo < hi.
    beta_tol : float
        Relative step of the beta grid: the stated tolerance of the answer.
    alpha : float, optional
        Velocity compensation (Eq. 6) when not scheduled (default the controller's).
    alpha_values : sequence of float, optional
        Schedule alpha too, from these values: per impedance the largest robust beta over them,
        ties broken by the larger torque bandwidth.
    requirements : sequence of {"stable", "pm", "passive"}
    leg, leg_mode
        The leg range (:func:`haa_sym.analysis.robust.leg_configurations`).
    uncertainty : dict, optional
        ``{key: (lo, hi)}``, plant keys in SI units (an identification's confidence box): beta
        must hold for every value in the box too, sampled like the leg range's box and refined
        by the same doubling (:mod:`haa_sym.analysis.robust`, docs/uncertainty.md).
    scheduler : None, str or distributed.Client
        None: dask's threaded scheduler in this process; an address ("tcp://host:port") or a
        Client: that dask.distributed cluster.
    progress : bool or None
        Progress bars on stderr.
    cell_subdivisions : int
        Density of the cell check (module docstring, "Between grid points"): each cell is
        checked on (cell_subdivisions + 1)^2 points; default :data:`CELL_SUBDIVISIONS` (5 x 5).
    cell_rounds : int or None
        Rounds of the cell check; in the last, cells that still fail are given up (no safe
        gain) instead of lowering shared corners; default :data:`CELL_ROUNDS` (3); None: until
        no cell fails.

    Returns
    -------
    Schedule
    """
    loop.require("torque_loop", "schedule (the torque-gain scheduler)")
    params, options = loop.params, loop.options
    P = gain_array("P_gain", grid(DEFAULT_P_GAIN) if P_gain is None else P_gain).ravel()
    D = gain_array("D_gain", grid(DEFAULT_D_GAIN) if D_gain is None else D_gain).ravel()
    for name, arr in (("P_gain", P), ("D_gain", D)):
        if arr.size < 2 or np.any(np.diff(arr) <= 0):
            raise ParameterError(f"{name}: {arr.size} value(s); allowed: at least 2, strictly increasing")
    if P[0] <= 0:
        raise ParameterError(f"P_gain starts at {P[0]:g}; allowed: P_gain > 0 (the schedule interpolates in log P_gain)")
    # every task's map is P x D: refused here, before the cluster, dask's import and the task
    # list (the tasks' own gate in region_map said the same after 1-3 s of them)
    check_map_budget(loop, P.size, D.size)
    req = _check_requirements(requirements)
    if isinstance(cell_subdivisions, bool) or not isinstance(cell_subdivisions, (int, np.integer)) \
            or not 1 <= cell_subdivisions <= 64:
        raise ParameterError(f"cell_subdivisions = {cell_subdivisions!r}; allowed: an integer 1..64 (sub-grid "
                             "intervals per cell side of the cell check)")
    if cell_rounds is not None and (isinstance(cell_rounds, bool) or not isinstance(cell_rounds, (int, np.integer))
                                    or not 1 <= cell_rounds <= 10_000):
        raise ParameterError(f"cell_rounds (--cell-rounds) = {cell_rounds!r}; allowed: an integer 1..10000 or None (rounds of the "
                             "cell check)")
    fine, coarse = beta_grid(beta_range, beta_tol)
    ctrl = params.controller
    if alpha_values is None:
        alphas = np.array([ctrl.alpha if alpha is None else float(alpha)])
    else:
        alphas = gain_array("alpha_values", alpha_values).ravel()
        if alphas.size == 0:
            raise ParameterError("alpha_values is empty; allowed: at least one value >= 0")
    ends = leg_ends(params, leg)
    leg_configurations(params, 2, leg=leg, leg_mode=leg_mode, uncertainty=uncertainty)   # checks them now
    # local:N: one cluster for the whole schedule (both runners below), stopped whatever happens
    local = contextlib.ExitStack()
    spec, scheduler = scheduler, local.enter_context(cluster(scheduler))
    try:
        runner = _Runner(scheduler, progress)
        maps: dict = {}                     # (config key, beta index, alpha index) -> (n_P, n_D) bool
        points: dict = {}                   # (config key, beta index, alpha index) -> {flat index: bool}

        key_of = _key

        alpha_1 = float(ctrl.alpha if alpha is None else alpha)
        fixed_maps: dict = {}               # config key -> (n_P, n_D) bool at beta = 1, alpha_1

        def map_round(configs, fixed_configs=()):
            """One task list: the coarse maps of ``configs`` and the beta = 1 maps of
            ``fixed_configs`` not computed yet."""
            todo = [(c, k, a) for c in configs for k in coarse for a in range(alphas.size)
                    if (key_of(c), k, a) not in maps]
            todo_1 = list({key_of(c): c for c in fixed_configs if key_of(c) not in fixed_maps}.values())
            res = runner.run(feasible_task, [(params, c, P, D, float(fine[k]), float(alphas[a]), req, options)
                                             for c, k, a in todo]
                             + [(params, c, P, D, 1.0, alpha_1, req, options) for c in todo_1], "schedule: maps")
            for (c, k, a), r in zip(todo, res):
                maps[(key_of(c), k, a)] = np.asarray(r, bool)
            for c, r in zip(todo_1, res[len(todo):]):
                fixed_maps[key_of(c)] = np.asarray(r, bool)

        def solve(configs, ahead=()):
            """Each point's largest beta feasible at every configuration of ``configs``; the fine
            values of its bracket are decided for ``ahead`` too (the next doubling's new
            configurations, whose brackets are mostly the same), in the same task list."""
            map_round(configs)
            n_pts = P.size * D.size
            best_k = np.full((alphas.size, n_pts), -1)
            needs, todo = [], []
            for a in range(alphas.size):
                F = np.ones((coarse.size, n_pts), bool)
                for c in configs:
                    F &= np.stack([maps[(key_of(c), k, a)].ravel() for k in coarse])
                any_ok = F.any(axis=0)
                top = coarse.size - 1 - np.argmax(F[::-1], axis=0)          # largest feasible coarse
                kc = np.where(any_ok, top, -1)
                best_k[a] = np.where(any_ok, coarse[np.maximum(kc, 0)], -1)
                # fine values inside each point's bracket (coarse[kc], coarse[kc + 1])
                need: dict = {}
                for p in np.flatnonzero(any_ok & (kc < coarse.size - 1)):
                    for k in range(coarse[kc[p]] + 1, coarse[kc[p] + 1]):
                        need.setdefault(k, []).append(p)
                needs.append(need)
                # and at each point's coarse answer (the answer when no fine value above it holds),
                # which the point check (_verify) decides next: in this task list, so that the
                # point check usually finds every decision made and runs no task list of its own
                check = dict(need)
                for p in np.flatnonzero(any_ok):
                    check.setdefault(int(coarse[kc[p]]), []).append(p)
                for c in [*configs, *ahead]:
                    for k, pts in check.items():
                        done = points.setdefault((key_of(c), k, a), {})
                        missing = [p for p in pts if p not in done]
                        if missing:
                            todo.append((c, k, a, missing))
            # every alpha's refinement in one task list (the grid's points made after the maps,
            # whose tasks check the memory budget first)
            PP, DD = (x.ravel() for x in np.meshgrid(P, D, indexing="ij"))
            res = runner.run(_task_points, [(params, c, PP[m], DD[m], float(fine[k]), float(alphas[a]), req, options)
                                            for c, k, a, m in todo], "schedule: refine")
            for (c, k, a, m), r in zip(todo, res):
                points[(key_of(c), k, a)].update(zip(m, np.asarray(r, bool).tolist()))
            for a, need in enumerate(needs):
                for k in sorted(need):
                    got = [points[(key_of(c), k, a)] for c in configs]
                    ok = np.array([all(g[p] for g in got) for p in need[k]])
                    pts = np.array(need[k])
                    best_k[a, pts[ok]] = np.maximum(best_k[a, pts[ok]], k)
            return best_k

        try:
            n = 2
            configs = leg_configurations(params, n, leg=leg, leg_mode=leg_mode, uncertainty=uncertainty)
            # Speculation without waste: the doubling always goes on to 3 configurations per axis
            # (it compares two levels), and the beta = 1 comparison is made at the last level,
            # which holds the level-3 configurations. So the first task list maps them all, and
            # the first refinement decides the level-3 configurations at the level-2 brackets:
            # 2 task lists where there were 5 (each a barrier of the cluster).
            ahead = leg_configurations(params, 3, leg=leg, leg_mode=leg_mode, uncertainty=uncertainty) \
                if 3 <= max_per_axis else configs
            map_round(ahead, ahead)
            new = [c for c in ahead if key_of(c) not in {key_of(x) for x in configs}]
            current = solve(configs, new)
            history = [(len(configs), int((current.max(axis=0) >= 0).sum()))]
            converged = False
            while 2 * n - 1 <= max_per_axis:
                n = 2 * n - 1
                configs = leg_configurations(params, n, leg=leg, leg_mode=leg_mode, uncertainty=uncertainty)
                nxt = solve(configs)
                history.append((len(configs), int((nxt.max(axis=0) >= 0).sum())))
                same = np.array_equal(nxt, current)
                current = nxt
                if same:
                    converged = True
                    break
            current, lowered = _verify(runner, params, configs, P, D, fine, alphas, current, req, options, points)
            # beta = 1 (the file's own torque gains) at the file's alpha, for the comparison (the
            # level-3 configurations' maps were made in the first task list)
            map_round([], configs)
            fixed = np.logical_and.reduce([fixed_maps[key_of(c)] for c in configs])
            # the torque bandwidths the table reports (and ties between alphas need), as tasks:
            # the leg free in the air, at each point's largest beta and every alpha reaching it,
            # and at beta = 1
            free_params = _free_in_the_air(params)
            pairs = sorted({(int(current[:, p].max()), a) for p in np.flatnonzero(current.max(axis=0) >= 0)
                            for a in range(alphas.size) if current[a, p] == current[:, p].max()})
            # started, not waited for: with one alpha the cell check does not need them; on the
            # command's own local:N cluster they run in the background, in the workers' idle time
            # at the end of each of the cell check's passes (no barrier between the two, and none
            # added to the passes). Not on a cluster given by address: dask's priorities hold
            # across its clients, and another client's work would always go first
            # (docs/schedule.md, "Measured after the fifth round")
            bandwidths = runner.start(_task_bandwidth, [(free_params, options, loop.backend, float(fine[k]),
                                                         float(alphas[a])) for k, a in pairs]
                                      + [(free_params, options, loop.backend, 1.0, alpha_1)], "schedule: bandwidths",
                                      background=local_workers(spec) is not None)
            bw: dict = {}

            def collected() -> dict:
                """{(beta index, alpha index): bandwidth, "beta_1": at beta = 1}, waited for once."""
                if not bw:
                    res = bandwidths()
                    bw.update(zip(pairs, res[:-1]), beta_1=res[-1])
                return bw

            # per point: the alpha with the largest beta, ties to the larger torque bandwidth
            n_pts = P.size * D.size
            beta_out, alpha_out, bw_out = np.full(n_pts, np.nan), np.full(n_pts, np.nan), np.full(n_pts, np.nan)
            a_out = np.zeros(n_pts, int)
            feasible = current.max(axis=0) >= 0
            for p in np.flatnonzero(feasible):
                kmax = current[:, p].max()
                cand = [a for a in range(alphas.size) if current[a, p] == kmax]
                a = max(cand, key=lambda a: (collected()[(kmax, a)], -a)) if len(cand) > 1 else cand[0]
                beta_out[p], alpha_out[p], a_out[p] = fine[kmax], alphas[a], a
            shape = (P.size, D.size)
            K = np.full(n_pts, -1)
            K[feasible] = current.max(axis=0)[feasible]
            K = K.reshape(shape)
            K_table, cell_safe, n_failed, n_lowered_pts, n_given_up, n_passes = _check_cells(
                runner, params, configs, P, D, fine, K, np.nan_to_num(alpha_out.reshape(shape)), req, options,
                int(cell_subdivisions), None if cell_rounds is None else int(cell_rounds))
            for p in np.flatnonzero(feasible):
                bw_out[p] = collected()[(int(current[:, p].max()), int(a_out[p]))]
            bw_1 = collected()["beta_1"]
        finally:
            runner.close()
    finally:
        local.close()
    table_beta = np.where(K_table >= 0, fine[np.maximum(K_table, 0)], np.nan)
    at_limit = feasible.reshape(shape) & (K == fine.size - 1)
    meta = {"actuator": str((getattr(params, "about", None) or {}).get("name", params.source)),
            "source": str(params.source), "requirements": list(req), "beta_range": [float(fine[0]), float(fine[-1])],
            "beta_tol": float(beta_tol), "beta_grid": int(fine.size), "coarse_values": int(coarse.size),
            "alpha_scheduled": alpha_values is not None, "alpha_values": alphas.tolist(),
            "leg": list(ends), "leg_mode": leg_mode, "leg_values": leg_values(params, leg, leg_mode, uncertainty),
            "uncertainty": {k: list(v) for k, v in check_uncertainty(params, uncertainty, leg).items()}
            if uncertainty else None,
            "haa_sym": version(),
            "scheduler": "dask threads (in-process)" if spec is None else scheduler_kind(spec),
            "torque_bandwidth_beta_1_rad_s": bw_1, "lowered_by_point_check": lowered,
            "cell_subdivisions": int(cell_subdivisions), "cells_failed_check": n_failed,
            "grid_points_lowered_by_cell_check": n_lowered_pts, "cells_given_up": n_given_up,
            "cells_safe": int(cell_safe.sum()), "cells": int(cell_safe.size), "cell_check_passes": n_passes,
            "cell_rounds": cell_rounds,
            "beta_at_limit": int(at_limit.sum()),
            "cell_check": f"Each cell with four feasible corners was checked on a {cell_subdivisions + 1} x "
                          f"{cell_subdivisions + 1} sub-grid (corners and edges included) at {len(configs)} leg "
                          f"configurations ({ends[0]}..{ends[1]}, {leg_mode}), at the interpolated alpha and "
                          "at the two beta-grid values bracketing the interpolated beta (ratio "
                          f"{fine[1] / fine[0]:.4g}), with the requirements {'+'.join(req)} decided exactly "
                          "(haa_sym.analysis.decide.decide_points); a failing cell's corner values were "
                          "lowered together by a drop bisected between a failing and a holding one, and every "
                          "cell was checked again at its final corners; cells still failing in round "
                          f"{cell_rounds} were given up. Points between the sub-grid's are not verified: sampling "
                          "cannot guarantee them.",
            "options": options.to_dict()}
    return Schedule(P, D, beta_out.reshape(shape), alpha_out.reshape(shape), bw_out.reshape(shape),
                    feasible.reshape(shape), len(configs), converged, history, meta,
                    fixed.reshape(shape), at_limit, table_beta, cell_safe)
