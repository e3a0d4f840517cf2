"""Exact stability boundaries in the (P_gain, D_gain) plane by the parameter-space method.

With the inner gains fixed (beta, alpha), the characteristic polynomial is affine in the
impedance gains (``haa_sym.compiled.layout``): chi(z) = a(z) + P_gain b(z) + D_gain c(z). On its exact
bilinear transform (z = (1 + s)/(1 - s), the basis of :class:`haa_sym.ClosedLoop`), a closed-loop
pole crosses the unit circle at z = exp(j theta) exactly when q(s) = A(s) + P B(s) + D C(s)
vanishes at s = j nu, nu = tan(theta/2) (D-decomposition, Neimark; Ackermann's parameter-space
method):

* theta = 0 (a real pole at z = 1, nu = 0): the straight line A(0) + P B(0) + D C(0) = 0;
* theta = pi (a real pole at z = -1, nu -> infinity): the line of the leading coefficients;
* 0 < theta < pi (a complex pair): Re and Im of q(j nu) = 0, one real 2 x 2 linear solve per nu,
  with the odd part divided by nu so that the solve stays well conditioned as nu -> 0, where the
  poles of a fast-sampled loop crowd.

nu runs over a logarithmic grid, which resolves the crowding at z = 1 that a uniform grid in
theta misses (toolchain facts). The curves are returned as polylines with the critical
frequency omega = theta/Ts of every point. A grid is classified from the curves by locating,
on every grid row, where the curves cross it and deciding one point per segment between
crossings with the certified generated test (:meth:`ClosedLoop.stability`).

Example
-------
>>> from haa_sym import load_params
>>> from haa_sym.analysis.boundaries.stability import stability_boundary
>>> b = stability_boundary(load_params())                                   # doctest: +SKIP
>>> [c.kind for c in b.curves][:2]                                          # doctest: +SKIP
"""
from __future__ import annotations

import numpy as np

from haa_sym.analysis.margins import phase_margins
from haa_sym.analysis.boundaries.curves import CURVE_POINTS, BoundaryCurve, StabilityBoundary
from haa_sym.analysis.rootfind import illinois
from haa_sym.compiled.layout import gain_monomials
from haa_sym.errors import ParameterError
from haa_sym.model.params import gain_array
from haa_sym.loop import loop_first

__all__ = ["affine_polynomials", "stability_boundary", "phase_margin_curves", "crossings"]


def affine_polynomials(loop, beta=None, alpha=None) -> np.ndarray:
    """``(3, cap + 1)``: ascending coefficients in s of A, B, C with q = A + P_gain B + D_gain C,
    the bilinear transform of chi (exact basis of ``loop``, rounded once) at fixed beta, alpha."""
    ctrl = loop.params.controller
    beta = float(gain_array("beta", ctrl.beta if beta is None else beta))
    alpha = float(gain_array("alpha", ctrl.alpha if alpha is None else alpha))
    # chi is affine in (P_gain, D_gain): its monomials at (0,0), (1,0), (0,1) give A, B, C exactly
    g = [np.array(gain_monomials(np.array([P, D, beta, alpha]), loop.const), dtype=float)
         for P, D in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))]
    return np.stack([loop.basis @ g[0], loop.basis @ (g[1] - g[0]), loop.basis @ (g[2] - g[0])])


def _horner(c: np.ndarray, x: np.ndarray) -> np.ndarray:
    """sum_k c[:, k] x^k for ascending rows c (r, n) at points x (N,): shape (r, N)."""
    v = np.zeros((c.shape[0], x.size))
    for coef in c.T[::-1]:
        v = v * x + coef[:, None]
    return v


def _parts(p: np.ndarray, nu: np.ndarray):
    """Re q(j nu) and Im q(j nu)/nu for the ascending rows p, each equation scaled by a positive
    power of nu that keeps it in range (a row scale does not change a linear system's solution)."""
    k = np.arange(p.shape[1])
    even = p[:, 0::2] * (-1.0) ** (k[0::2] // 2)           # Re q(j nu) = sum even_k nu^(2k)
    odd = p[:, 1::2] * (-1.0) ** (k[1::2] // 2)            # Im q(j nu) = nu sum odd_k nu^(2k)
    nu2 = nu * nu
    small = nu <= 1
    re, im = np.empty((p.shape[0], nu.size)), np.empty((p.shape[0], nu.size))
    re[:, small], im[:, small] = _horner(even, nu2[small]), _horner(odd, nu2[small])
    u = 1 / nu2[~small]                                    # nu > 1: the reversed polynomials in 1/nu^2
    re[:, ~small] = _horner(even[:, ::-1], u)
    im[:, ~small] = _horner(odd[:, ::-1], u)
    return re, im


def _complex_branch(ABC: np.ndarray, nu: np.ndarray, with_det: bool = False):
    """(P, D) with q(j nu) = 0 for every nu (NaN or inf where the 2 x 2 system is singular)."""
    re, im = _parts(ABC, nu)                          # (3, n_nu) each: rows A, B, C
    det = re[1] * im[2] - re[2] * im[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        P = (-re[0] * im[2] + re[2] * im[0]) / det
        D = (-re[1] * im[0] + re[0] * im[1]) / det
    return (P, D, det) if with_det else (P, D)


def _complex_values(p: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """q(j nu) for the ascending rows p (r, m), each column scaled by one positive real factor
    (nu^-(m-1) where nu > 1) that keeps it in range; shape (r, n_nu), complex."""
    m = p.shape[1]
    jk = (1j) ** np.arange(m)
    out = np.empty((p.shape[0], nu.size), complex)
    small = nu <= 1
    v = np.zeros((p.shape[0], small.sum()), complex)
    for c in (p * jk)[:, ::-1].T:                     # Horner in nu, coefficients p_k j^k
        v = v * nu[small] + c[:, None]
    out[:, small] = v
    u = 1 / nu[~small]                                # nu > 1: sum_k p_k j^k nu^(k - m + 1)
    v = np.zeros((p.shape[0], u.size), complex)
    for c in (p * jk).T:                              # reversed: Horner in 1/nu
        v = v * u + c[:, None]
    out[:, ~small] = v
    return out


def _rotated_branch(ABC: np.ndarray, nu: np.ndarray, phi_deg: float, with_det: bool = False):
    """(P, D) with A(j nu) + exp(-j phi) (P B(j nu) + D C(j nu)) = 0: the loop gain
    L_imp = (P b + D c)/a equals -exp(j phi) at z = exp(j theta), a crossover with phase margin
    phi (1 + exp(-j phi) L = 0)."""
    A, B, C = _complex_values(ABC, nu)
    w = np.exp(-1j * np.deg2rad(phi_deg))
    B, C = w * B, w * C
    det = B.real * C.imag - C.real * B.imag
    with np.errstate(divide="ignore", invalid="ignore"):
        P = (-A.real * C.imag + C.real * A.imag) / det
        D = (-B.real * A.imag + A.real * B.imag) / det
    return (P, D, det) if with_det else (P, D)


@loop_first
def phase_margin_curves(loop, beta=None, alpha=None, *, pm_deg: float = 30.0, P_range=(0.0, 2e4),
                        D_range=(0.0, 50.0), n_nu: int = 4000, outline: bool = True) -> list:
    """The outline of the low-phase-margin region of the impedance loop (opened at the torque
    reference) in the box: polylines (kind "pm=+30" / "pm=-30") with the crossover frequency.

    Since 1 + L_imp = chi/a, L_imp = (P_gain b + D_gain c)/a, and a crossover with margin phi
    is a + exp(-j phi)(P_gain b + D_gain c) = 0 at z = exp(j theta): a real 2 x 2 solve per
    nu = tan(theta/2), as for the stability boundary (phi = 0). The low-PM region of the
    "distance" rule (:mod:`haa_sym.analysis.margins`) is bounded by the loci phi = +pm_deg and
    phi = -pm_deg; with ``outline`` (default) only the parts that bound it are kept: a locus
    point where the loop is unstable, or where another crossover passes nearer to -1, lies
    inside the region's complement or its interior and is dropped (the polyline is split
    there). ``outline=False`` returns the loci whole.
    """
    if loop.options.conventions.pm_loop != "impedance":
        raise ParameterError("phase_margin_curves: pm_loop = 'torque' is not covered yet; allowed: "
                             "pm_loop = 'impedance' (the maps' default)")
    ctrl = loop.params.controller
    beta = ctrl.beta if beta is None else float(beta)
    alpha = ctrl.alpha if alpha is None else float(alpha)
    ABC = affine_polynomials(loop, beta, alpha)
    nu = np.logspace(-10, 10, n_nu)
    out = []
    for phi in (pm_deg, -pm_deg):
        curves = _box_curves(lambda x: _rotated_branch(ABC, x, phi), nu, ctrl.Ts, P_range, D_range,
                             f"pm={phi:+g}")
        out += [p for c in curves for p in (_outline(loop, c, beta, alpha, pm_deg) if outline else [c])]
    return out


# A locus point bounds the low-PM region when its own crossover is the nearest to -1: no other
# crossover nearer by more than this (deg; the located crossovers agree to ~1e-9 deg).
_OUTLINE_TOL_DEG = 1e-6


def _outline(loop, c: BoundaryCurve, beta: float, alpha: float, pm_deg: float) -> list:
    """The runs of curve ``c`` (a +-pm_deg locus) where the loop is stable and no crossover is
    nearer to -1 than pm_deg: the outline of the low-PM region."""
    st = loop.stability(c.P_gain, c.D_gain, beta, alpha).stable
    m = phase_margins(loop, c.P_gain, c.D_gain, beta, alpha, which="L_imp")
    keep = st & (m.distance_deg >= pm_deg - _OUTLINE_TOL_DEG)
    idx = np.flatnonzero(keep)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if idx.size else []
    return [BoundaryCurve(c.kind, c.P_gain[r], c.D_gain[r], c.omega[r]) for r in runs if r.size >= 2]


@loop_first
def stability_boundary(loop, beta=None, alpha=None, *, P_range=(0.0, 2e4), D_range=(0.0, 50.0),
                       n_nu: int = 4000) -> StabilityBoundary:
    """The stability boundary in the box ``P_range`` x ``D_range`` for fixed beta and alpha.

    Parameters
    ----------
    loop : ClosedLoop
    beta, alpha : float, optional
        Torque-gain scale (Eq. 7) and velocity compensation (Eq. 6); default the controller's.
    P_range, D_range : (float, float)
        The box of impedance gains (Nm/rad, Nms/rad) in which the curves are kept.
    n_nu : int
        Samples of nu = tan(theta/2) on a log grid from 1e-10 to 1e10 (theta from 2e-10 rad to
        pi - 2e-10).

    Returns
    -------
    StabilityBoundary
    """
    ctrl = loop.params.controller
    Ts = ctrl.Ts
    beta = ctrl.beta if beta is None else float(beta)
    alpha = ctrl.alpha if alpha is None else float(alpha)
    if n_nu < 10:
        raise ParameterError(f"n_nu = {n_nu!r}; allowed: an integer >= 10")
    ABC = affine_polynomials(loop, beta, alpha)
    curves = []
    nu = np.logspace(-10, 10, n_nu)
    curves += _box_curves(lambda x: _complex_branch(ABC, x), nu, Ts, P_range, D_range, "complex")
    # the two real-root lines, clipped to the box: a + P b + D c = 0
    for kind, (a, b, c), w in (("z=1", ABC[:, 0], 0.0), ("z=-1", ABC[:, -1], np.pi / Ts)):
        seg = _clip_line(a, b, c, P_range, D_range)
        if seg is not None:
            curves.append(BoundaryCurve(kind, seg[0], seg[1], np.full(2, w)))
    return StabilityBoundary(curves, beta, alpha, Ts, {"n_nu": n_nu, "P_range": list(P_range),
                                                      "D_range": list(D_range)}, ABC, nu)


def _box_curves(branch, nu: np.ndarray, Ts: float, P_range, D_range, kind: str,
                min_points: int = CURVE_POINTS) -> list:
    """The parts of the branch ``nu -> (P, D)`` inside the box as polylines: each run of samples
    inside is extended to where the branch leaves the box (the Illinois method in log nu on the
    distance to the box's edge, between the run's end and the neighbour outside, when that
    neighbour is finite) and resampled on at least
    ``min_points`` log-spaced nu, so that a curve reaches the box's edge and a small box is drawn
    as finely as a large one."""
    (P0, P1), (D0, D1) = P_range, D_range

    def inside(P, D):
        return np.isfinite(P) & np.isfinite(D) & (P >= P0) & (P <= P1) & (D >= D0) & (D <= D1)
    P, D = branch(nu)
    ok = inside(P, D)
    idx = np.flatnonzero(ok)
    if not idx.size:
        return []
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    first = np.array([r[0] for r in runs])
    last = np.array([r[-1] for r in runs])
    # every run end and its neighbour outside the box, all at once
    end = np.concatenate([first, last])
    nb = np.concatenate([first - 1, last + 1])
    valid = (nb >= 0) & (nb < nu.size)
    nb = np.clip(nb, 0, nu.size - 1)
    valid &= np.isfinite(P[nb]) & np.isfinite(D[nb])
    spanP, spanD = max(P1 - P0, 1e-300), max(D1 - D0, 1e-300)

    def slack(x):
        """Distance inside the box (negative outside), in box widths: continuous in log nu."""
        Px, Dx = branch(np.exp(x))
        g = np.minimum(np.minimum(Px - P0, P1 - Px) / spanP, np.minimum(Dx - D0, D1 - Dx) / spanD)
        return np.where(np.isfinite(g), g, -1.0)
    a, _ = illinois(slack, np.log(nu[end]), np.log(nu[nb]))      # slack(a) >= 0 > slack(b)
    ends = np.where(valid, a, np.log(nu[end]))
    lo, hi = ends[:first.size], ends[first.size:]
    out = []
    for r, x0, x1 in zip(runs, lo, hi):
        x = np.exp(np.linspace(x0, x1, max(min_points, r.size)))
        Pr, Dr = branch(x)
        keep = inside(Pr, Dr)
        if keep.any():
            out.append(BoundaryCurve(kind, Pr[keep], Dr[keep], 2 * np.arctan(x[keep]) / Ts))
    return out


def _clip_line(a, b, c, P_range, D_range):
    """The segment of a + b P + c D = 0 inside the box, as ([P0, P1], [D0, D1]); None if outside."""
    (P0, P1), (D0, D1) = P_range, D_range
    pts = []
    if c != 0:
        for P in (P0, P1):
            D = -(a + b * P) / c
            if D0 <= D <= D1:
                pts.append((P, D))
    if b != 0:
        for D in (D0, D1):
            P = -(a + c * D) / b
            if P0 <= P <= P1:
                pts.append((P, D))
    pts = sorted(set(pts))
    if len(pts) < 2:
        return None
    return np.array([pts[0][0], pts[-1][0]]), np.array([pts[0][1], pts[-1][1]])


def crossings(boundary: StabilityBoundary, D_gain) -> list:
    """For every D_gain = d, the P_gain values where a closed-loop pole is on the unit circle.

    On the line D_gain = d, q = (A + d C) + P_gain B. The real-root lines give one P each; a
    complex crossing is a root nu of D(nu) = d on the complex branch, bracketed between samples
    of the nu grid and located by bisection in log nu (all brackets of all rows at once, to the
    last bit). A sign change of D(nu) - d across a pole of D(nu) (where the 2 x 2 system is
    singular) is not a crossing and is dropped.
    """
    ABC, nu = boundary.ABC, boundary.nu
    d = np.asarray(D_gain, float).ravel()
    cuts = [[] for _ in d]
    for a, b, c in (ABC[:, 0], ABC[:, -1]):            # the real-root lines z = 1 and z = -1
        if b != 0:
            for j, P in enumerate(-(a + c * d) / b):
                cuts[j].append(P)
    for j, P in enumerate(_branch_crossings(lambda x, *a: _complex_branch(ABC, x, *a), nu, d)):
        cuts[j].extend(P)
    return [np.unique(np.asarray(c, float)) for c in cuts]


def _brackets(Pn: np.ndarray, D: np.ndarray, det: np.ndarray, d: np.ndarray, P_range=None):
    """The pairs (row j, nu interval i) where D(nu) - d[j] changes sign or vanishes between samples
    i and i + 1 (both finite, no pole of D(nu) between them, and with ``P_range`` a P span
    meeting it), ordered by row then interval: the same pairs as testing every row against every
    interval, found instead from the rows sorted by d (d[j] in [min, max] of D's two samples),
    so that the cost grows with the brackets rather than with n_D x n_nu."""
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(D[:-1]) & np.isfinite(D[1:])
        # where the 2 x 2 determinant changes sign, D(nu) passes a pole, not the value d
        ok &= np.sign(det[:-1]) * np.sign(det[1:]) > 0
        if P_range is not None:
            # a crossing matters only inside the grid's P range, where P(nu) is continuous
            # between the bracket's ends: skip brackets whose P span misses the range
            lo_P, hi_P = np.fmin(Pn[:-1], Pn[1:]), np.fmax(Pn[:-1], Pn[1:])
            ok &= np.isfinite(lo_P) & (hi_P >= P_range[0]) & (lo_P <= P_range[1])
    i = np.flatnonzero(ok)
    order = np.argsort(d, kind="stable")
    ds = d[order]
    first = np.searchsorted(ds, np.fmin(D[i], D[i + 1]), "left")
    stop = np.searchsorted(ds, np.fmax(D[i], D[i + 1]), "right")
    n = np.maximum(stop - first, 0)
    ii = np.repeat(i, n)
    k = np.arange(n.sum()) + np.repeat(first - (np.cumsum(n) - n), n)
    rows = order[k]
    s = np.lexsort((ii, rows))
    return rows[s], ii[s]


def _branch_crossings(branch, nu: np.ndarray, d: np.ndarray, P_range=None) -> list:
    """For each d, the P of ``branch(nu) -> (P, D)`` where D(nu) = d: brackets on the nu grid,
    then the Illinois variant of regula falsi in log nu (all brackets at once; superlinear, the
    bracket kept) until the bracket is 1e-13 wide in log nu or 60 steps; sign changes across
    poles of D(nu) are dropped."""
    cuts = [[] for _ in d]
    Pn, D, det = branch(nu, True)
    rows, i = _brackets(Pn, D, det, d, P_range)
    lo, hi = np.log(nu[i]), np.log(nu[i + 1])
    f_lo, f_hi = D[i] - d[rows], D[i + 1] - d[rows]
    side = np.zeros(rows.size, int)                     # which end moved last (Illinois)
    x = 0.5 * (lo + hi)
    live = np.ones(rows.size, bool)
    for _ in range(60):
        if not live.any():
            break
        k = np.flatnonzero(live)                        # only the brackets still moving
        with np.errstate(invalid="ignore", divide="ignore"):
            xn = (lo[k] * f_hi[k] - hi[k] * f_lo[k]) / (f_hi[k] - f_lo[k])
        xn = np.where(np.isfinite(xn) & (xn > lo[k]) & (xn < hi[k]), xn, 0.5 * (lo[k] + hi[k]))
        f_x = branch(np.exp(xn))[1] - d[rows[k]]
        left = np.sign(f_x) * np.sign(f_lo[k]) <= 0     # the root is in [lo, x]
        f_lo[k] = np.where(~left, f_x, np.where(side[k] == -1, 0.5 * f_lo[k], f_lo[k]))
        f_hi[k] = np.where(left, f_x, np.where(side[k] == 1, 0.5 * f_hi[k], f_hi[k]))
        lo[k], hi[k] = np.where(left, lo[k], xn), np.where(left, xn, hi[k])
        side[k] = np.where(left, -1, 1)
        done = (np.abs(xn - x[k]) <= 1e-14 * (1 + np.abs(xn))) | (f_x == 0) | (hi[k] - lo[k] <= 1e-13)
        x[k] = xn
        live[k[done]] = False
    Pc, Dc = branch(np.exp(x))
    good = np.isfinite(Pc) & (np.abs(Dc - d[rows]) <= 1e-9 * (1 + np.abs(d[rows])))
    for j, P in zip(rows[good], Pc[good]):
        cuts[j].append(P)
    return cuts
