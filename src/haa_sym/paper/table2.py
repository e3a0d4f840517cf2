"""Table 2 of the paper: passivity of the torque loop and of the impedance loop, cell by cell.

The rows, columns and the paper's statuses are data in ``model/paper.toml``; this module
computes our status and worst phase excess per cell, and scores option combinations by how many
of the 45 cells they reproduce (how the defaults of :class:`haa_sym.loop.closed_loop.LoopOptions` were chosen).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from haa_sym.loop import COLGATE, FILTERS, PORTS, ClosedLoop, LoopOptions
from haa_sym.paper import panel_params, paper_spec
from haa_sym.model.params import Params
from haa_sym.analysis.passivity import passivity

__all__ = ["Cell", "table2", "score_options", "OPTION_GRID"]

# The options that change a Table 2 cell (pm_loop / pm_rule only affect the region maps).
OPTION_GRID = {"delay": (0, 1), "torque_damping": (True, False), "filter": FILTERS, "port": PORTS,
               "colgate": COLGATE}


@dataclass(frozen=True)
class Cell:
    row: str
    column: str
    P_gain: float
    D_gain: float
    status: str               # "Yes" / "No" / "Unstable"
    paper: str
    phase_excess_deg: float   # NaN when unstable or under passivity = "exact"
    omega_worst: float        # rad/s, NaN when unstable
    dissipation_deficit: float = float("nan")   # passivity = "exact" only (docs/passivity.md)

    @property
    def agrees(self) -> bool:
        return self.status == self.paper


def table2(params: Params, options: LoopOptions | None = None, spec: dict | None = None) -> list[Cell]:
    """All cells of Table 2 (rows x columns of ``model/paper.toml``), computed with ``options``.

    Example
    -------
    >>> cells = table2(load_params())                                       # doctest: +SKIP
    >>> sum(c.agrees for c in cells), len(cells)                            # doctest: +SKIP
    (44, 45)
    """
    spec = spec or paper_spec()
    t = spec["table2"]
    options = options or LoopOptions()
    cells = []
    P = np.array([g[0] for g in t["gains"]])
    D = np.array([g[1] for g in t["gains"]])
    for row in t["row"]:
        p = panel_params(params, row)
        r = passivity(ClosedLoop(p, options), P, D)
        for j, col in enumerate(t["columns"]):
            cells.append(Cell(row["label"], col, float(P[j]), float(D[j]), str(r.status[j]),
                              row["paper"][j], float(r.phase_excess_deg[j]), float(r.omega_worst[j]),
                              float(r.dissipation_deficit[j])))
    return cells


def score_options(params: Params, spec: dict | None = None, base: LoopOptions | None = None):
    """Cells of Table 2 reproduced by every combination of :data:`OPTION_GRID`.

    Returns a list of ``(options_dict, n_agree, n_cells, cells)`` sorted best first (ties keep
    the grid order, which lists the defaults first); ``cells`` are that combination's cells.
    """
    spec = spec or paper_spec()
    base = base or LoopOptions()
    out = []
    keys = list(OPTION_GRID)
    for values in itertools.product(*(OPTION_GRID[k] for k in keys)):
        combo = dict(zip(keys, values))
        opt = base.replace(**combo)
        cells = table2(params, opt, spec)
        out.append((combo, sum(c.agrees for c in cells), len(cells), cells))
    return sorted(out, key=lambda r: -r[1])
