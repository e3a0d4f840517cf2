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

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from haa_sym.compiled.layout import gain_monomials
from haa_sym.loop.closed_loop import ClosedLoop, LoopOptions
from haa_sym.errors import ParameterError
from haa_sym.model.params import Params, gain_array

# points of a drawn curve at the least (each run of the nu grid inside the box is resampled)
CURVE_POINTS = 200

__all__ = ["BoundaryCurve", "StabilityBoundary", "Boundaries", "boundaries", "affine_polynomials", "stability_boundary",
           "phase_margin_curves", "crossings", "classify_grid", "classify_regions",
           "RegionDecisions"]


@dataclass(frozen=True)
class BoundaryCurve:
    """One branch of the stability boundary.

    ``P_gain`` (Nm/rad), ``D_gain`` (Nms/rad) and ``omega`` (rad/s, the frequency of the
    closed-loop pole on the unit circle: theta/Ts) per point; ``kind`` is "z=1" (a real pole at
    z = 1, a straight line), "z=-1" (a real pole at z = -1, a straight line) or "complex" (a
    complex pair at z = exp(+-j omega Ts)).
    """

    kind: str
    P_gain: np.ndarray
    D_gain: np.ndarray
    omega: np.ndarray


@dataclass(frozen=True)
class StabilityBoundary:
    """The stability boundary of one configuration (fixed beta, alpha) in the gain plane."""

    curves: list
    beta: float
    alpha: float
    Ts: float
    meta: dict = field(default_factory=dict)
    # A, B, C of q = A + P_gain B + D_gain C (ascending in s), for exact crossings
    ABC: np.ndarray = field(default=None, repr=False)
    nu: np.ndarray = field(default=None, repr=False)

    def to_dict(self) -> dict:
        """Plain JSON-able data: the curves (P_gain Nm/rad, D_gain Nms/rad, omega rad/s, kind)
        and what produced them."""
        return {"boundary": "stability", "beta": self.beta, "alpha": self.alpha, "Ts": self.Ts,
                "meta": self.meta,
                "curves": [{"kind": c.kind, "P_gain": c.P_gain.tolist(), "D_gain": c.D_gain.tolist(),
                            "omega": c.omega.tolist()} for c in self.curves]}

    def save(self, path, tx=None, field: str | None = None):
        """Write :meth:`to_dict` as JSON (all or nothing, see :mod:`haa_sym.io.outputs`)."""
        import json
        from haa_sym.io.outputs import write_text
        return write_text(path, json.dumps(self.to_dict(), indent=1) + "\n", tx, field)


def affine_polynomials(loop: ClosedLoop, beta=None, alpha=None) -> np.ndarray:
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


def phase_margin_curves(params: Params, beta=None, alpha=None, *, pm_deg: float = 30.0,
                        options: LoopOptions | None = None, P_range=(0.0, 2e4), D_range=(0.0, 50.0),
                        n_nu: int = 4000, loop: ClosedLoop | None = None) -> list:
    """The gains where the impedance loop (opened at the torque reference) has a crossover with
    phase margin exactly ``pm_deg``: polylines (kind "pm=<pm_deg>") in the box, with the
    crossover frequency. Since 1 + L_imp = chi/a, L_imp = (P_gain b + D_gain c)/a and a crossover
    with margin phi is a + exp(-j phi)(P_gain b + D_gain c) = 0 at z = exp(j theta): a real 2 x 2
    solve per nu = tan(theta/2), as for the stability boundary (phi = 0)."""
    loop = loop or ClosedLoop(params, options)
    if loop.options.conventions.pm_loop != "impedance":
        raise ParameterError("phase_margin_curves: pm_loop = 'torque' is not covered yet; allowed: "
                             "pm_loop = 'impedance' (the maps' default)")
    ctrl = params.controller
    ABC = affine_polynomials(loop, beta, alpha)
    nu = np.logspace(-10, 10, n_nu)
    return _box_curves(lambda x: _rotated_branch(ABC, x, pm_deg), nu, ctrl.Ts, P_range, D_range,
                       f"pm={pm_deg:g}")


def stability_boundary(params: Params, beta=None, alpha=None, *, options: LoopOptions | None = None,
                       P_range=(0.0, 2e4), D_range=(0.0, 50.0), n_nu: int = 4000,
                       loop: ClosedLoop | None = None) -> StabilityBoundary:
    """The stability boundary in the box ``P_range`` x ``D_range`` for fixed beta and alpha.

    Parameters
    ----------
    params : Params
    beta, alpha : float, optional
        Torque-gain scale (Eq. 7) and velocity compensation (Eq. 6); default the controller's.
    options : LoopOptions, optional
    P_range, D_range : (float, float)
        The box of impedance gains (Nm/rad, Nms/rad) in which the curves are kept.
    n_nu : int
        Samples of nu = tan(theta/2) on a log grid from 1e-10 to 1e10 (theta from 2e-10 rad to
        pi - 2e-10).

    Returns
    -------
    StabilityBoundary
    """
    loop = loop or ClosedLoop(params, options)
    ctrl = params.controller
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


@dataclass(frozen=True)
class Boundaries:
    """The three boundaries of one configuration (fixed beta, alpha) in the gain plane.

    ``stability``: :class:`StabilityBoundary` (a closed-loop pole on the unit circle);
    ``phase_margin``: curves where the impedance loop has a crossover with margin ``pm_deg``;
    ``passivity``: curves where the corrected phase of Z reaches +-90 deg
    (:func:`haa_sym.analysis.boundaries.passivity.passivity_boundary`). Every curve point carries its
    critical frequency ``omega`` (rad/s) and every curve its ``kind``.
    """

    stability: StabilityBoundary
    phase_margin: list
    passivity: list
    pm_deg: float

    @property
    def curves(self) -> list:
        return list(self.stability.curves) + list(self.phase_margin) + list(self.passivity)

    def to_dict(self) -> dict:
        """Plain JSON-able data: per boundary its curves (P_gain Nm/rad, D_gain Nms/rad, omega
        rad/s, kind) and what produced them."""
        def curves(cs):
            return [{"kind": c.kind, "P_gain": c.P_gain.tolist(), "D_gain": c.D_gain.tolist(),
                     "omega": c.omega.tolist()} for c in cs]
        b = self.stability
        return {"beta": b.beta, "alpha": b.alpha, "Ts": b.Ts, "pm_deg": self.pm_deg, "meta": b.meta,
                "stability": curves(b.curves), "phase_margin": curves(self.phase_margin),
                "passivity": curves(self.passivity)}

    def save(self, path, tx=None, field: str | None = None):
        """Write :meth:`to_dict` as JSON (all or nothing, see :mod:`haa_sym.io.outputs`)."""
        import json
        from haa_sym.io.outputs import write_text
        return write_text(path, json.dumps(self.to_dict(), indent=1) + "\n", tx, field)


def boundaries(params: Params, beta=None, alpha=None, *, options: LoopOptions | None = None,
               P_range=(0.0, 2e4), D_range=(0.0, 50.0), pm_deg: float = 30.0, n_nu: int = 4000,
               n_lines: int = 101, passivity: bool = True, loop: ClosedLoop | None = None) -> Boundaries:
    """Stability, phase-margin and passivity boundaries in the box ``P_range`` x ``D_range``.

    Parameters
    ----------
    params : Params
    beta, alpha : float, optional
        Torque-gain scale (Eq. 7) and velocity compensation (Eq. 6); default the controller's.
    options : LoopOptions, optional
        ``pm_loop`` must be "impedance" for the phase-margin curves; the passivity boundary
        follows ``port``, ``colgate`` and the frequency range (``omega_min`` to Nyquist).
    P_range, D_range : (float, float)
        The box, Nm/rad and Nms/rad.
    pm_deg : float
        Phase-margin threshold, deg (30: the paper's).
    n_nu : int
        Samples of nu = tan(theta/2) for the stability and phase-margin curves.
    n_lines : int
        Lines of each family on which the passivity boundary is located.
    passivity : bool
        Compute the passivity boundary (default).

    Example
    -------
    >>> b = boundaries(load_params(), P_range=(1, 2e4), D_range=(1, 50))        # doctest: +SKIP
    >>> sorted({c.kind for c in b.curves})                                     # doctest: +SKIP
    """
    from haa_sym.analysis.boundaries.passivity import passivity_boundary
    loop = loop or ClosedLoop(params, options)
    st = stability_boundary(params, beta, alpha, P_range=P_range, D_range=D_range, n_nu=n_nu, loop=loop)
    pm = phase_margin_curves(params, st.beta, st.alpha, pm_deg=pm_deg, P_range=P_range, D_range=D_range,
                             n_nu=n_nu, loop=loop)
    ps = passivity_boundary(loop, st.beta, st.alpha, P_range=P_range, D_range=D_range,
                            n_lines=n_lines) if passivity else []
    st.meta.update(n_lines=n_lines)
    return Boundaries(st, pm, ps, pm_deg)


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
    from haa_sym.analysis.rootfind import illinois
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


def _branch_crossings(branch, nu: np.ndarray, d: np.ndarray, P_range=None) -> list:
    """For each d, the P of ``branch(nu) -> (P, D)`` where D(nu) = d: brackets on the nu grid,
    then the Illinois variant of regula falsi in log nu (all brackets at once; superlinear, the
    bracket kept) until the bracket is 1e-13 wide in log nu or 60 steps; sign changes across
    poles of D(nu) are dropped."""
    cuts = [[] for _ in d]
    Pn, D, det = branch(nu, True)
    f = D[None, :] - d[:, None]                         # (n_D, n_nu)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(f[:, :-1]) & np.isfinite(f[:, 1:]) & (np.sign(f[:, :-1]) * np.sign(f[:, 1:]) <= 0)
        # where the 2 x 2 determinant changes sign, D(nu) passes a pole, not the value d
        ok &= (np.sign(det[:-1]) * np.sign(det[1:]) > 0)[None, :]
        if P_range is not None:
            # a crossing matters only inside the grid's P range, where P(nu) is continuous
            # between the bracket's ends: skip brackets whose P span misses the range
            lo_P, hi_P = np.fmin(Pn[:-1], Pn[1:]), np.fmax(Pn[:-1], Pn[1:])
            ok &= (np.isfinite(lo_P) & (hi_P >= P_range[0]) & (lo_P <= P_range[1]))[None, :]
    rows, i = np.nonzero(ok)
    lo, hi = np.log(nu[i]), np.log(nu[i + 1])
    f_lo, f_hi = f[rows, i], f[rows, i + 1]
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


def classify_grid(loop: ClosedLoop, boundary: StabilityBoundary, P_gain, D_gain) -> np.ndarray:
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


class RegionDecisions(NamedTuple):
    """Decisions of every grid point (arrays (n_P, n_D)): ``stable``, ``low_pm`` (stable with a
    phase margin below the threshold) and ``passive`` (stable and the corrected phase of Z within
    +-90 deg up to the options' tolerance; None when not asked for)."""

    stable: np.ndarray
    low_pm: np.ndarray
    passive: np.ndarray | None


def classify_regions(loop: ClosedLoop, boundary: StabilityBoundary, P_gain, D_gain, *,
                     pm_deg: float = 30.0, passivity: bool = True) -> RegionDecisions:
    """Stability, PM < ``pm_deg`` and passivity of every grid point from the exact curves.

    On every D_gain row the crossings of the stability boundary, of the phase-margin curves
    (margin ``pm_deg`` and the wrap of the margin at 180 deg) and of the passivity boundary
    (:func:`haa_sym.analysis.boundaries.passivity.passivity_crossings`, on the options' frequency grid)
    split the P_gain axis into segments; one point per segment is decided (certified
    stability, the phase margin of the maps: ``haa_sym.analysis.sweep.phase_margins`` with the options'
    rule, and the maps' passivity excess) and labels its segment. The margin can also change
    where a pair of crossovers appears (|L| touches 1) or where the rule switches crossover
    (``min_abs``: two with equal |PM|), and the passivity decision where the worst phase
    crosses the options' tolerance rather than +-90 deg; those are not curves here, so each
    segment's first, middle and last grid points are decided, and a segment whose points
    disagree is decided point by point.
    """
    from haa_sym.analysis.boundaries.passivity import passivity_crossings
    from haa_sym.analysis.regions import decide_points
    P = gain_array("P_gain", P_gain).ravel()
    D = gain_array("D_gain", D_gain).ravel()
    ABC, nu = boundary.ABC, boundary.nu
    beta, alpha = boundary.beta, boundary.alpha
    cuts = crossings(boundary, D)
    # the maps see crossovers on their frequency grid only (FrequencyGrid: omega_min to Nyquist)
    w = loop.options.numerics.omega(boundary.Ts)
    nu_w = np.tan(w * boundary.Ts / 2)
    nu_pm = np.geomspace(nu_w[0], nu_w[-1], nu.size)
    extra = [_branch_crossings(lambda x, *a: _rotated_branch(ABC, x, phi, *a), nu_pm, D, (P.min(), P.max()))
             for phi in (pm_deg, 180.0)]
    if passivity:
        extra.append(passivity_crossings(loop, D, (P.min(), P.max()), beta, alpha))
    for j in range(D.size):
        cuts[j] = np.unique(np.concatenate([cuts[j]] + [np.asarray(e[j], float) for e in extra]))

    def decide(Pq, Dq):
        return decide_points(loop, Pq, Dq, beta, alpha, pm_deg=pm_deg, passivity=passivity)
    # every segment of every row gets one id; with P sorted, a segment's points are consecutive
    order = np.argsort(P, kind="stable")
    Ps = P[order]
    sizes = np.array([c.size + 1 for c in cuts])
    offset = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    gid = np.stack([np.searchsorted(c, Ps) + o for c, o in zip(cuts, offset)], axis=1)   # (n_P, n_D)
    flat = gid.T.ravel()                                   # column by column: non-decreasing ids
    ids, first, count = np.unique(flat, return_index=True, return_counts=True)
    # each segment's first, middle and last grid point
    probe = np.stack([first, first + count // 2, first + count - 1], axis=1)        # (n_seg, 3)
    cand = np.unique(probe)
    rows, cols = cand % P.size, cand // P.size
    dec = decide(Ps[rows], D[cols])
    val = [np.empty(flat.size, bool) for _ in range(3)]
    for v, d in zip(val, dec):
        v[cand] = d
    # a segment whose probes agree takes their label; one whose probes differ (the chosen
    # crossover switched inside it, crossovers appeared, the excess crossed the tolerance) is
    # decided point by point
    agree = np.all([(v[probe] == v[probe[:, :1]]).all(axis=1) for v in val], axis=0)
    seg_of = np.searchsorted(ids, flat)
    known = np.zeros(flat.size, bool)
    known[cand] = True
    ok = agree[seg_of]
    for v in val:
        v[ok] = v[first[seg_of[ok]]]
    todo = np.flatnonzero(~ok & ~known)
    if todo.size:
        for v, d in zip(val, decide(Ps[todo % P.size], D[todo // P.size])):
            v[todo] = d
    out = []
    for v in val:
        o = np.empty((P.size, D.size), bool)
        o[order] = v.reshape(D.size, P.size).T
        out.append(o)
    return RegionDecisions(out[0], out[1], out[2] if passivity else None)
