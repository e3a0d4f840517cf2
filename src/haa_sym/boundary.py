"""Exact stability boundaries in the (P_gain, D_gain) plane by the parameter-space method.

With the inner gains fixed (beta, alpha), the characteristic polynomial is affine in the
impedance gains (``haa_sym.layout``): chi(z) = a(z) + P_gain b(z) + D_gain c(z). On its exact
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
>>> from haa_sym.boundary import stability_boundary
>>> b = stability_boundary(load_params())                                   # doctest: +SKIP
>>> [c.kind for c in b.curves][:2]                                          # doctest: +SKIP
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from haa_sym.layout import gain_monomials
from haa_sym.loop import ClosedLoop, LoopOptions
from haa_sym.params import ParameterError, Params, gain_array

__all__ = ["BoundaryCurve", "StabilityBoundary", "affine_polynomials", "stability_boundary",
           "crossings", "classify_grid"]


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
        """Write :meth:`to_dict` as JSON (all or nothing, see :mod:`haa_sym.outputs`)."""
        import json
        from haa_sym.outputs import write_text
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


def _complex_branch(ABC: np.ndarray, nu: np.ndarray):
    """(P, D) with q(j nu) = 0 for every nu (NaN or inf where the 2 x 2 system is singular)."""
    re, im = _parts(ABC, nu)                          # (3, n_nu) each: rows A, B, C
    det = re[1] * im[2] - re[2] * im[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        P = (-re[0] * im[2] + re[2] * im[0]) / det
        D = (-re[1] * im[0] + re[0] * im[1]) / det
    return P, D


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
    (P0, P1), (D0, D1) = P_range, D_range
    curves = []
    nu = np.logspace(-10, 10, n_nu)
    P, D = _complex_branch(ABC, nu)
    omega = 2 * np.arctan(nu) / Ts
    inside = np.isfinite(P) & np.isfinite(D) & (P >= P0) & (P <= P1) & (D >= D0) & (D <= D1)
    # split into runs of consecutive samples inside the box
    idx = np.flatnonzero(inside)
    if idx.size:
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
        for r in runs:
            curves.append(BoundaryCurve("complex", P[r], D[r], omega[r]))
    # the two real-root lines, clipped to the box: a + P b + D c = 0
    for kind, (a, b, c), w in (("z=1", ABC[:, 0], 0.0), ("z=-1", ABC[:, -1], np.pi / Ts)):
        seg = _clip_line(a, b, c, P_range, D_range)
        if seg is not None:
            curves.append(BoundaryCurve(kind, seg[0], seg[1], np.full(2, w)))
    return StabilityBoundary(curves, beta, alpha, Ts, {"n_nu": n_nu, "P_range": list(P_range),
                                                      "D_range": list(D_range)}, ABC, nu)


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
    _, D = _complex_branch(ABC, nu)
    f = D[None, :] - d[:, None]                         # (n_D, n_nu)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(f[:, :-1]) & np.isfinite(f[:, 1:]) & (np.sign(f[:, :-1]) * np.sign(f[:, 1:]) <= 0)
    rows, i = np.nonzero(ok)
    lo, hi = np.log(nu[i]), np.log(nu[i + 1])
    f_lo = f[rows, i]
    for _ in range(64):                                 # bisection: the bracket shrinks to one ulp
        mid = 0.5 * (lo + hi)
        f_mid = _complex_branch(ABC, np.exp(mid))[1] - d[rows]
        left = np.sign(f_mid) * np.sign(f_lo) <= 0
        hi = np.where(left, mid, hi)
        lo, f_lo = np.where(left, lo, mid), np.where(left, f_lo, f_mid)
    Pc, Dc = _complex_branch(ABC, np.exp(0.5 * (lo + hi)))
    good = np.isfinite(Pc) & (np.abs(Dc - d[rows]) <= 1e-9 * (1 + np.abs(d[rows])))
    for j, P in zip(rows[good], Pc[good]):
        cuts[j].append(P)
    return [np.unique(np.asarray(c, float)) for c in cuts]


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
