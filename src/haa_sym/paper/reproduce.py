"""``haa-sym reproduce --out results/`` (``make paper``): every figure and table of Sec. 3-5.

Writes into the output directory, as data and as PNG:
  regions/fig{08..11}{a..d}.npz, fig08.png .. fig11.png   stability/PM/passivity maps (Figs. 8-11),
                                                        every point cross-checked by numpy eigvals
  table2.md, table2.csv                                 Table 2 with the worst phase excess per cell
  options_table2.csv                                    cells of Table 2 reproduced per option set
  fig12.png, fig12.csv                                  corrected phase of Z (Fig. 12)
  fig07.png, fig07.csv, fig07_step_info.csv            unit torque steps (Fig. 7) and their
                                                        step_info metrics
  contact.png, contact.csv                              stability and passivity against environment
                                                        stiffness (torque loop alone; Fig. 12's impedance)
  torque_bandwidth.png, torque_bandwidth.csv            torque bandwidth over beta and alpha, both legs
  verify.txt                                            python -m haa_sym.check.verify (p1 roots, margins)
  claims.json                                           every computed claim, machine-readable
  REPORT.md                                             all of it, "the paper says / we compute"
Everything is computed from ``model/hyq_haa.toml`` and ``model/paper.toml``; nothing is typed in.

The directory is built as a temporary sibling and swapped in when complete
(:class:`haa_sym.io.outputs.Transaction`): an interrupted or failed run leaves the previous
results as they were. An existing directory is replaced only if it holds nothing but such
outputs, so no other file is ever deleted.
"""
from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from haa_sym.analysis.boundaries.combined import boundaries
from haa_sym.analysis.contact import contact_intervals, intervals
from haa_sym.analysis.passivity import bands_beyond, corrected_phase
from haa_sym.analysis.regions import RegionMap, region_map
from haa_sym.analysis.sampled_port import deficit_lower_bound, passivity_excess, passivity_tolerance
from haa_sym.analysis.sweep import CHUNK, run_chunks
from haa_sym.analysis.torque import (p1_roots, step_response, torque_bandwidth, torque_bandwidth_map,
                                     torque_loop_margins)
from haa_sym.check import reference
from haa_sym.check.crosscheck import eigenvalue_crosscheck
from haa_sym.design.schedule import schedule
from haa_sym.errors import ParameterError
from haa_sym.io.budget import check_memory, sweep_bytes
from haa_sym.io.gridspec import grid
from haa_sym.io.outputs import Transaction, check_directory, csv_text as _csv, write_text
from haa_sym.io.progress import message, progress as progress_bar
from haa_sym.loop import ClosedLoop, LoopOptions
from haa_sym.model.params import Params, load_params
from haa_sym.paper import check_params, panel_params, paper_spec
from haa_sym.paper.report import table2_markdown, write_report
from haa_sym.paper.table2 import score_options, table2

__all__ = ["reproduce", "region_trends"]


# The names reproduce writes (regions/ holds only the maps): an existing output directory with
# anything else in it is not replaced.
_OUTPUT_NAMES = re.compile(r"fig\d\d(_step_info)?\.(png|csv)|table2\.(md|csv)|options_table2\.csv|contact\.(png|csv)"
                           r"|torque_bandwidth\.(png|csv)|schedule\.(png|csv)"
                           r"|verify\.txt|claims\.json|REPORT\.md|regions")
_REGION_NAMES = re.compile(r"fig\d\d[a-z]\.npz")


def foreign_entries(directory: Path) -> list[str]:
    """Entries of ``directory`` that are not outputs of :func:`reproduce` (relative paths)."""
    out = []
    for p in sorted(Path(directory).iterdir()):
        if not _OUTPUT_NAMES.fullmatch(p.name) or p.is_dir() != (p.name == "regions"):
            out.append(p.name)
        elif p.name == "regions":
            out += [f"regions/{q.name}" for q in sorted(p.iterdir())
                    if not (_REGION_NAMES.fullmatch(q.name) and q.is_file())]
    return out


def _replaceable(directory: Path) -> str | None:
    foreign = foreign_entries(directory)
    if foreign:
        shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
        return (f"holds files reproduce does not write ({shown}), which replacing it would delete; "
                "allowed: a new directory, an empty one or the results of an earlier reproduce")
    return None


def _write_text(path: Path, text: str) -> None:
    write_text(path, text)




def _json_default(x):
    if isinstance(x, complex):
        return [x.real, x.imag]
    return float(x)


def _log(msg: str) -> None:
    message(msg)


def _finite_or_none(x: float):
    """None (JSON null, an empty CSV cell) for a metric that is undefined (NaN)."""
    return float(x) if np.isfinite(x) else None


# claims / CSV name of each step_info key (python-control / MATLAB convention, see torque.py)
STEP_INFO_COLUMNS = (("rise_time_10_90_s", "RiseTime"), ("settling_time_2pct_s", "SettlingTime"),
                     ("overshoot_pct", "Overshoot"), ("peak_Nm", "Peak"), ("peak_time_s", "PeakTime"))


# --- Sec. 4 trends ------------------------------------------------------------------------------
def _quadrants(m, P_split: float, D_split: float):
    """Unstable / PM<30 cell counts in the four quadrants of the (P, D) plane split at
    ``P_split`` and ``D_split``. The paper's "low stiffness and damping" is the low/low quadrant,
    "large stiffness and/or large damping" the other three.
    """
    lowP = (m.P_gain <= P_split)[:, None]
    lowD = (m.D_gain <= D_split)[None, :]
    un = ~m.stable
    return {
        "unstable_lowP_lowD": int((un & lowP & lowD).sum()),
        "unstable_highP_lowD": int((un & ~lowP & lowD).sum()),
        "unstable_high_any": int((un & ~(lowP & lowD)).sum()),
        "unstable_total": int(un.sum()),
        "low_pm_total": int(m.low_pm.sum()),
        "passive_total": int(m.passive.sum()),
        "cells": int(m.stable.size),
    }


def quadrant_splits(spec: dict, P_grid, D_grid) -> dict:
    """Named ways to split "low" from "large" stiffness: the paper's locomotion range
    (Sec. 3.4, P_gain <= 2000 Nm/rad) and the geometric middle of the swept P range; damping is
    split at the middle of the swept D range."""
    D_mid = 0.5 * (D_grid.min() + D_grid.max())
    return {
        "locomotion": (float(spec["regions"]["locomotion_P_gain_max"]), D_mid),
        "log_middle": (float(np.sqrt(P_grid.min() * P_grid.max())), D_mid),
    }


def _trend(seq, key, direction):
    vals = [q[key] for q in seq]
    steps = list(zip(vals[:-1], vals[1:]))
    if direction == "up":
        ok = [b >= a for a, b in steps]
    else:
        ok = [b <= a for a, b in steps]
    return vals, sum(ok), len(ok)


def region_trends(stats: dict) -> list[dict]:
    """The qualitative claims of Sec. 4, each checked on the computed maps with the counts.

    ``stats`` maps a panel id ("8a", ...) to :func:`_quadrants` of its map (one split).
    """
    s = stats
    claims = []

    def add(text, ids, key, direction):
        vals, n_ok, n = _trend([s[i] for i in ids], key, direction)
        claims.append({"claim": text, "panels": ids, "measure": key, "values": vals,
                       "holds": n_ok == n, "steps_holding": f"{n_ok}/{n}"})

    beta = ["8a", "8b", "8c", "8d"]
    add("Fig. 8: as beta grows, the unstable region at low stiffness and damping shrinks",
        beta, "unstable_lowP_lowD", "down")
    add("Fig. 8: as beta grows, the unstable region at large stiffness and/or damping grows",
        beta, "unstable_high_any", "up")
    add("Fig. 9 (a)-(c): increasing alpha enlarges the unstable region",
        ["9a", "9b", "9c"], "unstable_total", "up")
    nav = ["10a", "8a", "10b", "10c", "10d"]   # N_av = 1, 4, 10, 20, 50
    add("Fig. 10: averaging more samples enlarges the unstable region at low stiffness",
        nav, "unstable_lowP_lowD", "up")
    add("Fig. 10: averaging more samples shrinks the unstable region at high stiffness, low damping",
        nav, "unstable_highP_lowD", "down")
    ts = ["11a", "11b", "11c"]
    add("Fig. 11 (a)-(c): the unstable region grows with the sampling time",
        ts, "unstable_total", "up")
    add("Fig. 11 (a)-(c): the PM < 30 deg region grows with the sampling time",
        ts, "low_pm_total", "up")
    leg = ["8a", "11d"]   # extended -> retracted
    add("Fig. 11 (d): the retracted leg has a larger unstable region at low damping and stiffness",
        leg, "unstable_lowP_lowD", "up")
    add("Fig. 11 (d): the retracted leg has a smaller unstable region at low damping, large stiffness",
        leg, "unstable_highP_lowD", "down")
    add("Fig. 11 (d): the retracted leg has a larger PM < 30 deg region",
        leg, "low_pm_total", "up")
    return claims


# --- the job -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Job:
    """What every section of the reproduction needs."""

    out: Path
    params: Params
    options: LoopOptions
    spec: dict
    quick: bool
    P_grid: np.ndarray
    D_grid: np.ndarray

    @property
    def claims(self) -> dict:
        return self.spec["claims"]

    def with_options(self, **change) -> LoopOptions:
        return self.options.replace(**change)


# options varied one at a time around the defaults (the sensitivity table and the trend recount)
OPTION_VARIANTS = (("delay", (0, 1)), ("torque_damping", (True, False)),
                   ("filter", ("both", "impedance", "compensation")),
                   ("port", ("dtheta_L2", "dtheta_L1", "encoder_average")),
                   ("colgate", ("subtract", "add", "none")), ("pm_loop", ("impedance", "torque")),
                   ("pm_rule", ("min_abs", "worst")))
REGION_CAPTIONS = {8: "beta (alpha = 0.94, N_av = 4, Ts = 1 ms)", 9: "alpha (beta = 1, N_av = 4, Ts = 1 ms)",
                   10: "N_av (beta = 1, alpha = 0.94, Ts = 1 ms)",
                   11: "Ts (beta = 1, N_av = 4, alpha = 0.94) and retracted leg"}


def _variants(options: LoopOptions) -> list[tuple[str, dict]]:
    return [(f"{k} = {v}", {k: v}) for k, vals in OPTION_VARIANTS for v in vals if getattr(options, k) != v]


def _regions(job: _Job) -> dict:
    """Figs. 8-11: every panel's map (npz), its eigenvalue cross-check, the figures, the trends."""
    from haa_sym.io.plots import plot_region_panels, save_figure
    _log("regions: 16 maps (Figs. 8-11), decided from the exact curves, drawn with them")
    splits = quadrant_splits(job.spec, job.P_grid, job.D_grid)
    stats, panels_by_fig, crosscheck = {k: {} for k in splits}, {}, {}
    # how the phase-margin rule moves the light grey: every map again with the rule before
    # issue 15 (the signed margin of the crossover nearest -1 below 30 deg), PM only
    rules = {}
    for entry in job.spec["regions"]["panel"]:
        pid = f"{entry['figure']}{entry['panel']}"
        p = panel_params(job.params, entry)
        loop = ClosedLoop(p, job.options)
        m = region_map(loop, job.P_grid, job.D_grid)
        curves = boundaries(loop, P_range=(job.P_grid.min(), job.P_grid.max()),
                            D_range=(job.D_grid.min(), job.D_grid.max()), n_lines=31 if job.quick else 101) \
            if loop.options.conventions.pm_loop == "impedance" else None
        crosscheck[pid] = eigenvalue_crosscheck(m, loop, points="boundary")
        legacy = region_map(ClosedLoop(p, job.options.replace(pm_rule="min_abs")), job.P_grid, job.D_grid,
                            passivity=False)
        rules[pid] = {"rule": job.options.pm_rule, "low_pm": int(m.low_pm.sum()),
                      "low_pm_min_abs": int(legacy.low_pm.sum()), "stable": int(m.stable.sum()),
                      "differ": int((m.low_pm != legacy.low_pm).sum())}
        # the grid evaluators decide every point again (quick mode: the first panel of each figure)
        first = entry["figure"] not in panels_by_fig
        if m.meta["method"] == "curves" and (first or not job.quick):
            g = region_map(loop, job.P_grid, job.D_grid, method="grid")
            crosscheck[pid]["grid_disagree"] = {k: int((getattr(m, k) != getattr(g, k)).sum())
                                                for k in ("stable", "low_pm", "passive")}
        m = dataclasses.replace(m, meta={**m.meta, "figure": entry["figure"], "panel": entry["panel"],
                                         "title": entry["title"]})
        m.save(job.out / "regions" / f"fig{entry['figure']:02d}{entry['panel']}.npz")
        for split, (Ps, Ds) in splits.items():
            stats[split][pid] = _quadrants(m, Ps, Ds)
        panels_by_fig.setdefault(entry["figure"], []).append((m, f"({entry['panel']}) {entry['title']}", curves))
    for fig_no, items in panels_by_fig.items():
        save_figure(plot_region_panels([m for m, _, _ in items], [t for _, t, _ in items],
                                       f"Fig. {fig_no}: stability regions varying {REGION_CAPTIONS.get(fig_no, '')}",
                                       [c for _, _, c in items]),
                    job.out / f"fig{fig_no:02d}.png")
    return {"region_crosscheck": crosscheck, "region_pm_rules": rules, "region_splits": splits, "region_stats": stats,
            "region_trends": {k: region_trends(v) for k, v in stats.items()}}


def _option_sensitivity(job: _Job) -> dict:
    """How each option, changed alone, moves the nominal map."""
    _log("option sensitivity of the nominal map")
    sens = []
    for label, change in [("none (defaults)", {})] + _variants(job.options):
        m = region_map(ClosedLoop(job.params, job.with_options(**change)), job.P_grid, job.D_grid)
        sens.append({"change": label, "stable": int(m.stable.sum()), "low_pm": int(m.low_pm.sum()),
                     "passive": int(m.passive.sum()), "cells": int(m.stable.size)})
    return {"option_sensitivity": sens}


def _trend_alternatives(job: _Job, trends: list[dict], split: tuple[float, float]) -> dict:
    """Do the trends that fail with the defaults hold under another stability / PM option?"""
    _log("Sec. 4 trends under the options that change stability or the phase margin")
    failing = [i for i, t in enumerate(trends) if not t["holds"]]
    alt = {}
    for label, change in (_variants(job.options) if failing else []):
        if next(iter(change)) in ("port", "colgate"):
            continue                                       # passivity only: no effect on trends
        opt = job.with_options(**change)
        st = {f"{e['figure']}{e['panel']}": _quadrants(
            region_map(ClosedLoop(panel_params(job.params, e), opt), job.P_grid, job.D_grid, passivity=False), *split)
            for e in job.spec["regions"]["panel"]}
        tr = region_trends(st)
        alt[label] = {"holding": sum(t["holds"] for t in tr),
                      "rescued": [tr[i]["claim"] for i in failing if tr[i]["holds"]],
                      "lost": [t["claim"] for i, t in enumerate(tr) if not t["holds"] and i not in failing]}
    return {"trend_alternatives": alt}


def _table2(job: _Job) -> dict:
    """Table 2 (csv, md), the scores of every option combination, and what rescues each miss."""
    _log("Table 2 and option scores")
    cells = table2(job.params, job.options, job.spec)
    rows = [{"row": c.row, "column": c.column, "P_gain": c.P_gain, "D_gain": c.D_gain,
             "paper": c.paper, "computed": c.status, "agrees": c.agrees,
             "phase_excess_deg": round(c.phase_excess_deg, 4) if np.isfinite(c.phase_excess_deg) else "",
             "omega_worst_rad_s": round(c.omega_worst, 3) if np.isfinite(c.omega_worst) else ""}
            for c in cells]
    # labels hold commas ("P_gain = 200, D_gain = 10"), which genfromtxt would split on
    _write_text(job.out / "table2.csv", _csv([{**r, "row": r["row"].replace(", ", "; "),
                                                "column": r["column"].replace(", ", "; ")} for r in rows]))
    _write_text(job.out / "table2.md",
                "# Table 2: passivity (paper / computed)\n\n" + table2_markdown(rows, job.spec) + "\n")
    scores = score_options(job.params, job.spec, job.options)
    _write_text(job.out / "options_table2.csv", _csv([{**combo, "cells_reproduced": n, "cells": total}
                                                        for combo, n, total, _ in scores]))
    # for every cell the defaults miss: the best option set that gets it, and its total
    rescue = {}
    for c in cells:
        if not c.agrees:
            for combo, n, total, cc in scores:
                if any(x.row == c.row and x.column == c.column and x.agrees for x in cc):
                    rescue[f"{c.row} | {c.column}"] = {"options": combo, "agree": n, "cells": total}
                    break
    return {"table2": rows,
            "option_scores": [{"options": combo, "agree": n, "cells": total} for combo, n, total, _ in scores],
            "differing_cells_rescued_by": rescue}


def _exact_deficits(loop, P, D, tol: float):
    """The exact test's deficit at the points (P, D), as far as the comparison needs it:
    ``(deficit, omega, full)``. Every point is screened on every 16th frequency of the grid (a
    lower bound, :func:`haa_sym.analysis.sampled_port.deficit_lower_bound`: 1/16 of the cost);
    the points whose bound does not already exceed ``tol`` are evaluated on the whole grid (so
    every decision is the exact test's), then the points with the smallest bounds until the least
    deficit is certified (a full value below every remaining bound). ``full`` marks the points
    whose ``deficit`` and ``omega`` are the test's own; elsewhere they are the bound and its
    frequency (and the point is not passive)."""
    beta, alpha = loop.params.controller.beta, loop.params.controller.alpha
    val, w = np.full(P.size, np.nan), np.full(P.size, np.nan)
    full = np.zeros(P.size, bool)
    if P.size == 0:                                      # a map with no stable point
        return val, w, full

    def screen(sl):
        val[sl], w[sl] = deficit_lower_bound(loop, P[sl], D[sl], beta, alpha)

    def evaluate(idx):
        idx = idx[~full[idx]]

        def work(sl):
            val[idx[sl]], w[idx[sl]] = passivity_excess(loop, P[idx[sl]], D[idx[sl]], beta, alpha)
        run_chunks(work, idx.size, blas_threads=1)
        full[idx] = True
    # the aliasing sums and forms built once, before two threads would both build them
    deficit_lower_bound(loop, P[:1], D[:1], beta, alpha)
    run_chunks(screen, P.size, blas_threads=1)
    evaluate(np.flatnonzero(val <= tol))
    n = 64
    while not full.all():
        evaluate(np.argsort(np.where(full, np.inf, val))[:n])
        if full.all() or val[full].min() <= val[~full].min():
            break
        n *= 4
    return val, w, full


def _exact_passivity(job: _Job) -> dict:
    """Issue 24: the exact sampled-data passivity test against the paper's corrected phase, on the
    stable points of every map of Figs. 8-11 (stability does not depend on the test) and on
    Table 2; the maps, figures and Table 2 above keep the paper's test."""
    _log("exact sampled-data passivity (issue 24) on the maps and Table 2")
    exact = job.with_options(passivity="exact")
    maps = {}
    for entry in job.spec["regions"]["panel"]:
        pid = f"{entry['figure']}{entry['panel']}"
        m = RegionMap.load(job.out / "regions" / f"fig{entry['figure']:02d}{entry['panel']}.npz")
        loop = ClosedLoop(panel_params(job.params, entry), exact)
        PP, DD = np.meshgrid(m.P_gain, m.D_gain, indexing="ij")
        st = np.flatnonzero(m.stable.ravel())
        P, D = PP.ravel()[st], DD.ravel()[st]
        try:
            deficit, w, full = _exact_deficits(loop, P, D, passivity_tolerance(loop))
        except ParameterError as e:
            maps[pid] = {"refused": str(e)}
            continue
        pe = deficit <= passivity_tolerance(loop)
        pp = m.passive.ravel()[st]
        row = {"points": int(m.stable.size), "stable": int(st.size), "passive_paper": int(pp.sum()),
               "passive_exact": int(pe.sum()), "paper_only": int((pp & ~pe).sum()),
               "exact_only": int((pe & ~pp).sum()),
               # passive points whose least mu is at the grid's lowest frequency: decided at its edge
               "passive_exact_at_omega_min": int((pe & (w <= loop.options.numerics.omega_min)).sum())}
        if pp.any():          # the paper's test's worst optimistic call found (the largest bound's point)
            k = np.flatnonzero(pp)[np.argmax(deficit[pp])]
            dk, wk = passivity_excess(loop, P[k:k + 1], D[k:k + 1], loop.params.controller.beta,
                                      loop.params.controller.alpha)
            row["worst_paper_passive"] = {"P_gain": float(P[k]), "D_gain": float(D[k]),
                                          "deficit": float(dk[0]), "omega_rad_s": float(wk[0])}
        if st.size:
            k = int(np.argmin(deficit))
            row["least_deficit"] = {"P_gain": float(P[k]), "D_gain": float(D[k]),
                                    "deficit": float(deficit[k]), "omega_rad_s": float(w[k])}
        if (pe & ~pp).any():               # how far the paper's test is from calling them passive
            paper = ClosedLoop(loop.params, job.options)
            ex, _ = passivity_excess(paper, P[pe & ~pp], D[pe & ~pp], paper.params.controller.beta,
                                     paper.params.controller.alpha)
            row["exact_only_paper_excess_deg_max"] = float(np.max(ex))
        maps[pid] = row
    paper_cells = table2(job.params, job.options, job.spec)
    cells = []
    for c, x in zip(paper_cells, table2(job.params, exact, job.spec)):
        cells.append({"row": c.row, "column": c.column, "P_gain": c.P_gain, "D_gain": c.D_gain, "paper": c.paper,
                      "corrected_phase": c.status, "exact": x.status,
                      "phase_excess_deg": _finite_or_none(c.phase_excess_deg),
                      "dissipation_deficit": _finite_or_none(x.dissipation_deficit),
                      "omega_worst_exact_rad_s": _finite_or_none(x.omega_worst)})
    return {"exact_passivity": {"maps": maps, "table2": cells, "tolerance": exact.passivity_tol_exact,
                                "tolerance_deg": job.options.passivity_tol_deg}}


def _fig12(job: _Job, loop: ClosedLoop) -> dict:
    """Fig. 12: corrected phase of Z, torque loop alone and impedance loop closed; the bands."""
    from haa_sym.io.plots import plot_corrected_phase, save_figure
    params, options = job.params, job.options
    w_fine = options.omega(params.controller.Ts, 4 * options.numerics.n_omega)
    w, ph_t = corrected_phase(loop, 0.0, 0.0, omega=w_fine)
    P12, D12 = job.claims["fig12_gains"]
    _, ph_i = corrected_phase(loop, P12, D12, omega=w_fine)
    save_figure(plot_corrected_phase(
        [(w, ph_t, f"torque loop alone (beta = {params.controller.beta:g}, alpha = {params.controller.alpha:g})"),
         (w, ph_i, f"impedance loop closed (P_gain = {P12:g}, D_gain = {D12:g})")],
        "Fig. 12: corrected phase of Z(z)"), job.out / "fig12.png")
    _write_text(job.out / "fig12.csv", _csv([{"omega_rad_s": f"{a:.6g}", "phase_torque_loop_deg": f"{b:.6f}",
                                              "phase_impedance_loop_deg": f"{c:.6f}"}
                                             for a, b, c in zip(w, ph_t, ph_i)]))
    return {"z_band_torque_loop": bands_beyond(w, ph_t), "z_band_impedance_loop": bands_beyond(w, ph_i)}


def _contact(job: _Job) -> dict:
    """Stability and passivity against the environment stiffness (Sec. 5): the torque loop alone,
    which the paper finds not passive and unstable for 72-3500 Nm/rad, and the impedance loop
    closed at the gains of Fig. 12, which it finds passive (so stable with any passive spring)."""
    from haa_sym.io.plots import gains_text, plot_contact, save_figure
    K = grid(job.claims["contact_K_L2_grid"] if not job.quick else "log:1:100000:80", "K_L2")
    # the scan brackets every change of stability and passivity; Brent's method locates each end
    loop = ClosedLoop(job.params, job.options, basis=False)
    r = contact_intervals(loop, (K.min(), K.max()), n_scan=K.size)
    P12, D12 = job.claims["fig12_gains"]
    ri = contact_intervals(loop, (K.min(), K.max()), n_scan=K.size, P_gain=P12, D_gain=D12)

    def num(v, fmt):
        return "" if np.isnan(v) else format(v, fmt)      # empty: unstable (NaN in genfromtxt)
    _write_text(job.out / "contact.csv", _csv([
        {"K_L2": f"{k:.6g}", "stable": bool(rho < 1), "spectral_radius": f"{rho:.9f}",
         "phase_excess_deg": num(ex, ".9g"), "stable_impedance": bool(rho_i < 1),
         "spectral_radius_impedance": f"{rho_i:.9f}", "phase_excess_impedance_deg": num(ex_i, ".9g")}
        for k, rho, ex, rho_i, ex_i in zip(r.K_env, r.spectral_radius, r.phase_excess_deg,
                                           ri.spectral_radius, ri.phase_excess_deg)]))
    save_figure(plot_contact(r.K_env, r.spectral_radius, job.claims["contact_unstable_K_L2"], r.unstable,
                             excess=r.phase_excess_deg, not_passive=r.not_passive, tol=r.passivity_tol_deg,
                             title="Contact with an environment spring (Sec. 5)",
                             gains=gains_text(0.0, 0.0, job.params.controller.beta, job.params.controller.alpha)),
                job.out / "contact.png")
    return {"contact_K_L2_range": [float(K.min()), float(K.max())],
            "contact_unstable_K_L2": r.unstable, "contact_not_passive_K_L2": r.not_passive,
            "contact_impedance": {"P_gain": P12, "D_gain": D12, "unstable_K_L2": ri.unstable,
                                  "not_passive_K_L2": ri.not_passive}}


def _beta_threshold(job: _Job, loop: ClosedLoop) -> dict:
    """The torque gain beyond which the stiff impedance (P 20000, D 50) is unstable."""
    bt = job.claims["beta_threshold"]
    betas = grid(bt["grid"], "beta")
    sb = loop.stability(bt["P_gain"], bt["D_gain"], betas)
    above = (betas > bt["stable_at"]) & ~sb.stable
    return {"beta_unstable_intervals": intervals(betas, ~sb.stable),
            "beta_check": {
                "stable_at": bt["stable_at"],
                "computed_stable_at": bool(loop.stability(bt["P_gain"], bt["D_gain"], bt["stable_at"]).stable),
                "unstable_from": bt["unstable_from"],
                "computed_unstable_for_all_beta_from": bool((~sb.stable[betas >= bt["unstable_from"]]).all()),
                "first_unstable_beta_above_stable_at": float(betas[above][0]) if above.any() else None}}


def _fig7(job: _Job) -> dict:
    """Fig. 7: unit torque steps, K_L2 = 0 and 11.2, with and without velocity compensation."""
    from haa_sym.io.plots import plot_steps, save_figure
    c = job.claims
    panels, steps = [], []
    for K_L2 in c["fig7_K_L2"]:
        p7 = ClosedLoop(job.params.with_values(K_L2=K_L2), job.options, basis=False)
        lines = []
        for a, ls in zip(c["fig7_alpha"], ("-", "--")):
            s = step_response(p7, duration=c["fig7_duration_s"], alpha=a)
            lines.append((s, f"alpha = {a:g}", ls))
            info = s.info
            steps.append({"K_L2": K_L2, "alpha": a, "final_value": s.final_value,
                          **{key: _finite_or_none(info[k]) for key, k in STEP_INFO_COLUMNS},
                          "T_at_end": float(s.T[-1]),
                          "bandwidth_rad_s": torque_bandwidth(p7, alpha=a)})
        panels.append((f"K_L2 = {K_L2:g} Nm/rad", lines))
    save_figure(plot_steps(panels, "Fig. 7: unit torque steps (extended leg)"), job.out / "fig07.png")
    # long format: one row per sample and curve, so the header names no parameter values
    _write_text(job.out / "fig07.csv", _csv([
        {"K_L2": f"{K:g}", "alpha": f"{a:g}", "t_s": f"{t:.4f}", "T_Nm": f"{T:.6f}"}
        for (_, lines), K in zip(panels, c["fig7_K_L2"])
        for (s, _, _), a in zip(lines, c["fig7_alpha"])
        for t, T in zip(s.t, s.T)]))
    # empty cell: not reached / not settled within the window (NaN in numpy.genfromtxt)
    _write_text(job.out / "fig07_step_info.csv", _csv([
        {k: "" if v is None else v for k, v in row.items()} for row in steps]))
    return {"fig7": steps}


def _torque_loop_corners(job: _Job) -> dict:
    """p1 roots and torque-loop margins at the leg-inertia / stiffness bounds, numerically."""
    params = job.params
    corners = []
    for cfg in sorted(params.configurations):
        for K in sorted({0.0, *(p.get("K_L2") for p in params.configurations.values() if "K_L2" in p),
                         params.plant.K_L2}):
            pc = params.configuration(cfg).with_values(K_L2=K)
            mg = torque_loop_margins(ClosedLoop(pc, job.options))
            corners.append({"configuration": cfg, "J_L2": pc.plant.J_L2, "K_L2": K,
                            "p1_roots": [complex(z) for z in p1_roots(pc)],
                            "pm_deg": mg.pm_deg if np.isfinite(mg.pm_deg) else None,
                            "gain_crossover_rad_s": [float(x) for x in mg.gain_crossovers],
                            "gm_db": mg.gm_db if np.isfinite(mg.gm_db) else None,
                            "phase_crossover_rad_s": [float(x) for x in mg.phase_crossovers]})
    return {"torque_loop_corners": corners}


def _torque_bandwidth(job: _Job) -> dict:
    """Torque bandwidth (leg free in the air, K_L2 = 0, Sec. 3.3) over beta and alpha for both
    legs, next to the torque-loop stability it trades against."""
    from haa_sym.io.plots import plot_torque_bandwidth, save_figure
    B = np.linspace(0.1, 8.0, 8 if job.quick else 25)
    A = np.linspace(0.0, 1.2, 5 if job.quick else 13)
    panels, rows, summary = [], [], {}
    for cfg in sorted(job.params.configurations):
        pc = job.params.configuration(cfg).with_values(K_L2=0.0)
        bw, st = torque_bandwidth_map(ClosedLoop(pc, job.options), B, A)
        panels.append((f"{cfg} leg", B, A, bw, st))
        rows += [{"configuration": cfg, "beta": f"{b:.6g}", "alpha": f"{a:.6g}", "stable": bool(st[i, j]),
                  "torque_bandwidth_rad_s": f"{bw[i, j]:.6g}"} for i, b in enumerate(B) for j, a in enumerate(A)]
        k = np.nanargmax(np.where(st, bw, np.nan))
        summary[cfg] = {"max_bandwidth_rad_s": float(bw.flat[k]), "at_beta": float(B[k // A.size]),
                        "at_alpha": float(A[k % A.size]), "unstable_fraction": float(1 - st.mean())}
    _write_text(job.out / "torque_bandwidth.csv", _csv(rows))
    save_figure(plot_torque_bandwidth(panels, "Torque bandwidth (leg free, K_L2 = 0) against beta and alpha"),
                job.out / "torque_bandwidth.png")
    return {"torque_bandwidth": summary}


def _schedule(job: _Job) -> dict:
    """The paper's outlook (Sec. 6): the torque-gain schedule over the locomotion impedances,
    robust to the leg, against the fixed beta = 1 of the paper's tuning."""
    from haa_sym.io.plots import plot_schedule, save_figure
    P = grid("log:5:2000:4" if job.quick else "log:1:2000:30", "P_gain")
    D = grid("lin:1:50:3" if job.quick else "lin:1:50:20", "D_gain")
    s = schedule(ClosedLoop(job.params, job.options), P, D, beta_tol=0.1 if job.quick else 0.02)
    _write_text(job.out / "schedule.csv", s.csv_text())
    save_figure(plot_schedule(s, "Torque-gain schedule (stable, PM >= 30 deg for every leg configuration)"),
                job.out / "schedule.png")
    bw1 = s.meta["torque_bandwidth_beta_1_rad_s"]
    both = s.feasible & s.beta_fixed_feasible
    gain = s.torque_bandwidth_rad_s[both] / bw1
    return {"schedule": {"grid": f"{P.size} x {D.size}", "points": int(s.feasible.size),
                         "P_range": [float(P[0]), float(P[-1])], "D_range": [float(D[0]), float(D[-1])],
                         "feasible": int(s.feasible.sum()), "beta_1_safe": int(s.beta_fixed_feasible.sum()),
                         "beta_1_unsafe_where_schedule_safe": int((s.feasible & ~s.beta_fixed_feasible).sum()),
                         "no_robust_beta": int((~s.feasible).sum()),
                         "bandwidth_beta_1_rad_s": bw1,
                         "bandwidth_gain_median": float(np.median(gain)) if gain.size else None,
                         "bandwidth_gain_range": [float(gain.min()), float(gain.max())] if gain.size else None,
                         "beta_range": s.meta["beta_range"], "beta_tol": s.meta["beta_tol"],
                         "leg": s.meta["leg"], "leg_configurations": s.n_configurations,
                         "lowered_by_point_check": s.meta["lowered_by_point_check"]}}


def _verify(job: _Job) -> tuple[dict, str]:
    """``python -m haa_sym.check.verify`` in its own process: the numeric runtime never imports sympy."""
    src = job.params.source
    proc = subprocess.run([sys.executable, "-m", "haa_sym.check.verify"] +
                          (["--params", src] if Path(src).is_file() else []),
                          capture_output=True, text=True)
    _write_text(job.out / "verify.txt", proc.stdout + proc.stderr)
    return {"verify_exit_status": proc.returncode}, proc.stdout


def reproduce(out: str | Path = "results", params: Params | None = None,
              options: LoopOptions | None = None, quick: bool = False,
              spec: dict | None = None, field: str | None = None) -> dict:
    """Compute and write everything listed in the module docstring; returns the claims dict.

    ``out`` is replaced as a whole when everything is computed (see the module docstring); its
    missing parent directories are created (and removed again on failure). ``quick`` uses coarse grids (for tests); the report says so.
    ``field`` names ``out`` in error messages (e.g. ``--out``).
    """
    t_start = time.time()
    params = params or load_params()
    options = (options or LoopOptions()).resolved(params.plant.topology)
    spec = spec or paper_spec()
    check_params(params, spec)           # the paper's configurations and keys, before any work
    if params.drive.delay_drive:         # the maps' cross-check builds the drive's delay exactly, or refuses
        reference.plant_matrices(params)
    reg = spec["regions"]
    out = check_directory(out, field, _replaceable)
    P_grid = grid("log:1:20000:40" if quick else reg["P_gain"], "P_gain")
    D_grid = grid("lin:1:50:20" if quick else reg["D_gain"], "D_gain")
    # the largest pieces, before minutes of work: a region map and the fine Fig. 12 sweep
    check_memory(max(sweep_bytes(P_grid.size * D_grid.size, options.numerics.n_omega, CHUNK),
                     sweep_bytes(1, 4 * options.numerics.n_omega)),
                 f"reproduce (region maps of {P_grid.size} x {D_grid.size} points, n_omega = {options.numerics.n_omega})")
    with Transaction() as tx:
        stage = tx.directory(out, field, _replaceable)
        (stage / "regions").mkdir()
        job = _Job(out=stage, params=params, options=options, spec=spec, quick=quick,
                   P_grid=P_grid, D_grid=D_grid)
        loop = ClosedLoop(params, options)
        result: dict = {"meta": loop.provenance(quick=quick)}
        # one bar over the sections (stderr; shown on a terminal after 2 s, see haa_sym.io.progress)
        with progress_bar(13, "reproduce", "section") as bar:
            def run(section, *args):
                result.update(section(job, *args))
                bar.update(1)
            run(_regions)
            run(_option_sensitivity)
            run(_trend_alternatives, result["region_trends"]["locomotion"],
                result["region_splits"]["locomotion"])
            run(_table2)
            run(_exact_passivity)
            _log("Fig. 12, contact stiffness, beta threshold, Fig. 7, torque-loop bounds, verify")
            run(_fig12, loop)
            run(_contact)
            run(_beta_threshold, loop)
            run(_fig7)
            run(_torque_loop_corners)
            run(_torque_bandwidth)
            run(_schedule)
            verify_status, verify_text = _verify(job)
            result.update(verify_status)
            bar.update(1)
        result["elapsed_s"] = round(time.time() - t_start, 1)
        _write_text(job.out / "claims.json", json.dumps(result, indent=1, default=_json_default) + "\n")
        write_report(job.out, result, spec, options, verify_text)
    _log(f"wrote {out}/REPORT.md in {result['elapsed_s']} s")
    return result
