"""Region maps classified from the exact curves: on every grid row the curves' crossings split
the P_gain axis into segments, and a few decided points label each segment."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from haa_sym.analysis.boundaries.curves import StabilityBoundary
from haa_sym.analysis.boundaries.passivity import passivity_crossings
from haa_sym.analysis.boundaries.stability import _branch_crossings, _rotated_branch, crossings
from haa_sym.analysis.decide import decide_points
from haa_sym.analysis.margins import PM_THRESHOLD_DEG
from haa_sym.model.params import gain_array

__all__ = ["classify_grid", "classify_regions", "row_cuts", "RegionDecisions"]


def classify_grid(loop, boundary: StabilityBoundary, P_gain, D_gain) -> np.ndarray:
    """Stability of every (P_gain, D_gain) grid point (shape (n_P, n_D)) from the boundary.

    On every grid column (fixed D_gain) the exact crossings of the boundary split the P_gain
    axis into segments whose points share their stability; one certified decision per segment
    (:meth:`ClosedLoop.stability`, all segments of all columns in one call) labels them all.
    """
    P = gain_array("P_gain", P_gain).ravel()
    D = gain_array("D_gain", D_gain).ravel()
    segs, reps = [], []
    for j, cuts in enumerate(crossings(boundary, D)):
        seg = np.searchsorted(cuts, P)                     # segment of every grid point
        labels, first = np.unique(seg, return_index=True)
        segs.append((labels, seg))
        reps.append(first)
    n = [r.size for r in reps]
    Pr = np.concatenate([P[r] for r in reps])
    Dr = np.concatenate([np.full(k, D[j]) for j, k in enumerate(n)])
    st = loop.stability(Pr, Dr, boundary.beta, boundary.alpha).stable
    out = np.empty((P.size, D.size), bool)
    start = 0
    for j, (labels, seg) in enumerate(segs):
        out[:, j] = st[start:start + n[j]][np.searchsorted(labels, seg)]
        start += n[j]
    return out


def row_cuts(loop, boundary: StabilityBoundary, D_gain, P_range, *, pm_deg: float = PM_THRESHOLD_DEG,
             passivity: bool = True) -> list:
    """For every row D_gain = d, the sorted P_gain values inside ``P_range`` where a map's decision
    may change along the row: the crossings of the stability boundary, of the loci where a
    crossover has a margin of exactly +pm_deg, -pm_deg or 180 deg, and (``passivity``) the
    candidate ends of the non-passive intervals
    (:func:`haa_sym.analysis.boundaries.passivity.passivity_crossings`). A decision can also change
    where a pair of crossovers appears or where the passivity excess crosses the options'
    tolerance; those are not here (callers decide points on both sides)."""
    D = gain_array("D_gain", D_gain).ravel()
    ABC, nu = boundary.ABC, boundary.nu
    P_range = (float(P_range[0]), float(P_range[1]))
    cuts = crossings(boundary, D)
    # crossovers count from omega_min to Nyquist (FrequencyGrid), as the margins locate them
    w = loop.options.numerics.omega(boundary.Ts)
    nu_w = np.tan(w * boundary.Ts / 2)
    nu_pm = np.geomspace(nu_w[0], nu_w[-1], nu.size)
    extra = [_branch_crossings(lambda x, *a: _rotated_branch(ABC, x, phi, *a), nu_pm, D, P_range)
             for phi in (pm_deg, -pm_deg, 180.0)]
    if passivity:
        extra.append(passivity_crossings(loop, D, P_range, boundary.beta, boundary.alpha))
    for j in range(D.size):
        cuts[j] = np.unique(np.concatenate([cuts[j]] + [np.asarray(e[j], float) for e in extra]))
    return cuts


@dataclass(frozen=True)
class RegionDecisions:
    """Decisions of every grid point (arrays (n_P, n_D)): ``stable``, ``low_pm`` (stable with a
    phase margin below the threshold by the options' rule), ``passive`` (stable and the corrected
    phase of Z within +-90 deg up to the options' tolerance; False everywhere when not asked
    for), and at the points decided one by one (the segments' probes and the segments decided
    point by point; NaN elsewhere) their exact ``phase_margin_deg`` and the passivity measure,
    ``phase_excess_deg`` or ``dissipation_deficit`` by the options' test (the other NaN)."""

    stable: np.ndarray
    low_pm: np.ndarray
    passive: np.ndarray
    phase_margin_deg: np.ndarray
    phase_excess_deg: np.ndarray
    dissipation_deficit: np.ndarray


def classify_regions(loop, boundary: StabilityBoundary, P_gain, D_gain, *, pm_deg: float = PM_THRESHOLD_DEG,
                     passivity: bool = True) -> RegionDecisions:
    """Stability, PM < ``pm_deg`` and passivity of every grid point from the exact curves.

    On every D_gain row the crossings of the stability boundary, of the loci where a crossover
    has a margin of exactly +pm_deg, -pm_deg or 180 deg, and of the passivity boundary
    (:func:`haa_sym.analysis.boundaries.passivity.passivity_crossings`, on the options' frequency
    grid) split the P_gain axis into segments; points are decided by
    :func:`haa_sym.analysis.decide.decide_points` (certified stability, the exact phase margin by
    the options' rule, the maps' passivity excess). A decision can also change where a pair of
    crossovers appears (|L| touches 1), or where the passivity excess crosses the options'
    tolerance rather than +-90 deg; those are not curves here, so each segment's first, middle
    and last grid points are decided, and a segment whose points disagree is decided point by
    point.
    """
    P = gain_array("P_gain", P_gain).ravel()
    D = gain_array("D_gain", D_gain).ravel()
    beta, alpha = boundary.beta, boundary.alpha
    cuts = row_cuts(loop, boundary, D, (P.min(), P.max()), pm_deg=pm_deg, passivity=passivity)

    # every segment of every row gets one id; with P sorted, a segment's points are consecutive
    order = np.argsort(P, kind="stable")
    Ps = P[order]
    sizes = np.array([c.size + 1 for c in cuts])
    offset = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    gid = np.stack([np.searchsorted(c, Ps) + o for c, o in zip(cuts, offset)], axis=1)   # (n_P, n_D)
    flat = gid.T.ravel()                                   # column by column: non-decreasing ids
    ids, first, count = np.unique(flat, return_index=True, return_counts=True)
    n = flat.size
    val = [np.zeros(n, bool) for _ in range(3)]            # stable, low_pm, passive
    num = [np.full(n, np.nan) for _ in range(3)]           # phase margin, phase excess, deficit

    def decide(idx):
        d = decide_points(loop, Ps[idx % P.size], D[idx // P.size], beta, alpha, passivity=passivity,
                          pm_threshold_deg=pm_deg)
        for v, x in zip(val + num, (d.stable, d.low_pm, d.passive, d.phase_margin_deg, d.phase_excess_deg,
                                       d.dissipation_deficit)):
            v[idx] = x
    # each segment's first, middle and last grid point
    probe = np.stack([first, first + count // 2, first + count - 1], axis=1)        # (n_seg, 3)
    cand = np.unique(probe)
    decide(cand)
    # a segment whose probes agree takes their label; one whose probes differ (crossovers
    # appeared inside it, the excess crossed the tolerance) is decided point by point
    agree = np.all([(v[probe] == v[probe[:, :1]]).all(axis=1) for v in val], axis=0)
    seg_of = np.searchsorted(ids, flat)
    known = np.zeros(n, bool)
    known[cand] = True
    ok = agree[seg_of] & ~known
    for v in val:
        v[ok] = v[first[seg_of[ok]]]
    todo = np.flatnonzero(~agree[seg_of] & ~known)
    if todo.size:
        decide(todo)
    out = []
    for v in val + num:
        o = np.empty((P.size, D.size), v.dtype)
        o[order] = v.reshape(D.size, P.size).T
        out.append(o)
    return RegionDecisions(*out)
