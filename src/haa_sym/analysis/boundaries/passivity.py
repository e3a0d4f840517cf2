"""The passivity boundary in the (P_gain, D_gain) plane: the envelope of one conic per frequency.

The port impedance is a ratio of two gain-affine forms, Z = (n . x)/(d . x) with x = (1, P_gain,
D_gain) (:class:`haa_sym.loop.closed_loop.LoopCoefficients`). Its corrected phase (Colgate, Sec. 5) is the
phase of W = (n . x) conj(d . x) exp(-j s omega Ts/2), and it lies within +-90 deg exactly when
f(omega; x) = Re W >= 0: at every frequency a quadratic form in x, i.e. a conic in the gain plane
(:func:`haa_sym.analysis.sweep.product_form`). The passive set is the intersection over omega of
{f >= 0} (and the stable set); its boundary is the envelope of the conics f(omega; x) = 0.

On a line D_gain = d the conic is a quadratic in P_gain, a P^2 + b P + c, with explicit roots
r(omega); the non-passive P_gain values are the union over omega of the intervals where the
quadratic is negative, so the boundary on that line is where a root curve r(omega) is extremal
in omega (dr/domega = 0: the tangency of the envelope) or where the frequency range ends
(``FrequencyGrid.omega_min`` and just below Nyquist, the range the grid maps judge). Each
extremum is bracketed on the options' frequency grid and refined by successive parabolic
interpolation in log omega; at the returned (P_gain, omega) the corrected phase is +-90 deg to
rounding, because P_gain is a root of that frequency's quadratic. A candidate that another
frequency covers (the phase is beyond +-90 deg there) is not on the boundary and is dropped, as
is one where the closed loop is unstable (Z has poles outside the circle: passivity is not
judged there, the stability boundary bounds the passive region).

At Nyquist Z is real and the corrected phase is +-90 deg for every gain, a frequency that
decides nothing (``NEUTRAL``); the grid stops just below it, and so do the conics.

Example
-------
>>> from haa_sym import ClosedLoop, load_params
>>> from haa_sym.analysis.boundaries.passivity import passivity_boundary
>>> curves = passivity_boundary(ClosedLoop(load_params()))                 # doctest: +SKIP
"""
from __future__ import annotations

import numpy as np

from haa_sym.loop import ClosedLoop, loop_first
from haa_sym.errors import ParameterError
from haa_sym.analysis.boundaries.curves import BoundaryCurve
from haa_sym.analysis.sampled_port import passivity_conics, passivity_excess

__all__ = ["passivity_boundary", "passivity_crossings", "NEUTRAL"]

# |Re W| below this fraction of |W|'s coefficients for every gain: the phase is +-90 deg whatever
# the gains (Z real at Nyquist, rounded), so that frequency bounds nothing
NEUTRAL = 1e-7
# a refined candidate is on the boundary when no grid frequency puts its phase further beyond
# +-90 deg than this (the accuracy for a passivity point)
ON_BOUNDARY_DEG = 1e-6
# Brent's method from the grid's bracket (one grid step, ~1.4e-2 in log omega by default) to
# 1e-10 in log omega: the root at the extremum is then exact to rounding (its error is quadratic)
REFINE_XTOL = 1e-10
# a candidate whose grid sample another grid frequency puts this far beyond +-90 deg is inside
# the non-passive set (the refinement moves a boundary point by far less)
PRUNE_DEG = 1e-2
REFINE_STEPS = 80
# the exact test's deficit in the units of the thresholds above (see _worst_excess)
EXACT_SCALE = 100.0


def _conics(loop: ClosedLoop, omega: np.ndarray, beta: float, alpha: float, cached: bool = False) -> np.ndarray:
    """Re W's coefficients on the monomials (1, P, D, P^2, P D, D^2), shape (6, n_omega); NaN
    columns at neutral frequencies."""
    W = passivity_conics(loop, omega, beta, alpha, cached=cached)
    Q = W.real.copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        neutral = np.abs(W.real).max(axis=0) <= NEUTRAL * np.abs(W).max(axis=0)
    Q[:, neutral] = np.nan
    return Q


# the quadratic's coefficients on a line: D_gain = t (solve for P_gain) or P_gain = t (for D_gain),
# as indices of the monomials (1, P, D, P^2, P D, D^2): a = Q[i2], b = Q[i1] + Q[i11] t,
# c = Q[0] + Q[i0] t + Q[i00] t^2
_LINES = {"D_gain": (3, 1, 4, 2, 5), "P_gain": (5, 2, 4, 1, 3)}


def _roots(Q: np.ndarray, t: np.ndarray, along: str = "D_gain", pointwise: bool = False):
    """The two roots (sorted; NaN where complex, +-inf where a = 0) of every frequency's quadratic
    on the lines ``along`` = t: shapes (n_t, n_omega), or (n,) with ``pointwise`` (column k of Q
    on line t[k]). ``along`` = "D_gain" gives P_gain roots; "P_gain" gives D_gain roots."""
    i2, i1, i11, i0, i00 = _LINES[along]
    t = t if pointwise else t[:, None]
    a = Q[i2] + 0 * t
    b = Q[i1] + Q[i11] * t
    c = Q[0] + Q[i0] * t + Q[i00] * t * t
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = b * b - 4 * a * c
        q = -0.5 * (b + np.copysign(np.sqrt(disc), b))      # no cancellation (Numerical Recipes 5.6)
        r1, r2 = q / a, c / q
    return np.fmin(r1, r2), np.fmax(r1, r2)


def _candidates(r: np.ndarray, neutral: np.ndarray):
    """Samples of every root sequence r[row, :] that may bound the union over omega of the
    non-passive intervals: ``ext`` local extrema (``sign`` +1 max, -1 min); ``edge`` ends of a run
    of finite values at the edge of the frequency range (or next to a neutral frequency); and
    ``inner`` ends of a run inside the range, where the two roots meet between two samples: the
    root's extremum can lie between that meeting point and the next sample, unbracketed."""
    fin = np.isfinite(r)
    with np.errstate(invalid="ignore"):                # inf - inf where a root is at infinity
        up = np.diff(r, axis=1)
        ext = np.zeros_like(fin)
        ext[:, 1:-1] = fin[:, :-2] & fin[:, 1:-1] & fin[:, 2:] & (up[:, :-1] * up[:, 1:] <= 0) \
            & ~((up[:, :-1] == 0) & (up[:, 1:] == 0))
        sign = np.zeros(r.shape, int)
        sign[:, 1:-1] = np.where(up[:, :-1] > 0, 1, -1)
    at_edge = np.zeros(r.shape[1], bool)
    at_edge[[0, -1]] = True
    at_edge[1:] |= neutral[:-1]
    at_edge[:-1] |= neutral[1:]
    ends = fin.copy()
    ends[:, 1:-1] &= ~(fin[:, :-2] & fin[:, 2:])
    ends &= ~ext
    return ext, np.where(ext, sign, 0), ends & at_edge[None, :], ends & ~at_edge[None, :]


def passivity_crossings(loop: ClosedLoop, D_gain, P_range, beta: float, alpha: float) -> list:
    """For every line D_gain = d, P_gain values inside ``P_range`` where passivity may change: the
    candidate ends of the non-passive intervals on the options' frequency grid (unrefined, a
    superset: a classifier splits rows there and decides every segment)."""
    d = np.asarray(D_gain, float).ravel()
    Q = _conics(loop, loop.options.numerics.omega(loop.params.controller.Ts), beta, alpha, cached=True)
    out = [[] for _ in d]
    for r in _roots(Q, d):
        ext, _, edge, inner = _candidates(r, np.isnan(Q[0]))
        rows, idx = np.nonzero(ext | edge | inner)
        P = r[rows, idx]
        keep = (P >= P_range[0]) & (P <= P_range[1])
        for j, p in zip(rows[keep], P[keep]):
            out[j].append(p)
    return [np.unique(np.asarray(c, float)) for c in out]


def _root_at(loop, x, on_P_line, t, branch, beta, alpha):
    """Root ``branch`` (0 lower, 1 upper) at omega = exp(x) on the line P_gain = t (where
    ``on_P_line``) or D_gain = t, one frequency per candidate."""
    Q = _conics(loop, np.exp(x), beta, alpha)
    r = [_roots(Q, t, along, pointwise=True) for along in ("D_gain", "P_gain")]
    lo, hi = (np.where(on_P_line, r[1][k], r[0][k]) for k in (0, 1))
    return np.where(branch == 0, lo, hi)


def _meeting_points(loop, x_in, x_out, on_P_line, t, branch, beta, alpha, steps: int = 10):
    """Bisection in log omega between a sample with real roots (x_in) and one without (x_out):
    the last point found with real roots, within 2^-steps of the grid step of where they meet."""
    for _ in range(steps):
        x_mid = 0.5 * (x_in + x_out)
        real = np.isfinite(_root_at(loop, x_mid, on_P_line, t, branch, beta, alpha))
        x_in, x_out = np.where(real, x_mid, x_in), np.where(real, x_out, x_mid)
    return x_in


def _refine(loop, on_P_line, t, branch, sign, lw, beta, alpha, xtol: float = REFINE_XTOL):
    """The extremum of sign * r(omega) (r: root ``branch`` 0 = lower, 1 = upper, on the line
    P_gain = t where ``on_P_line``, else D_gain = t) in log omega inside the bracketing triples
    ``lw`` (n, 3; the middle point the highest), all candidates at once, by Brent's method
    (parabolic steps while they shrink the bracket, golden sections otherwise: a root next to
    where the two roots meet behaves like a square root, which defeats parabolas alone).
    Returns (root, omega) at the extremum, log omega located to ``xtol``."""
    def f(k, x):                                      # Brent minimises
        return -sign[k] * _root_at(loop, x, on_P_line[k], t[k], branch[k], beta, alpha)
    n = lw.shape[0]
    if n == 0:
        return np.zeros(0), np.zeros(0)
    a, b = lw[:, 0].copy(), lw[:, 2].copy()
    x = lw[:, 1].copy()
    fx = f(np.arange(n), x)
    w, v, fw, fv = x.copy(), x.copy(), fx.copy(), fx.copy()
    d, e = np.zeros(n), np.zeros(n)
    live = np.isfinite(fx)
    cgold = 0.3819660112501051
    for _ in range(REFINE_STEPS):
        k = np.flatnonzero(live)
        if not k.size:
            break
        xm = 0.5 * (a[k] + b[k])
        tol1 = xtol * (1 + np.abs(x[k]))
        tol2 = 2 * tol1
        done = np.abs(x[k] - xm) <= tol2 - 0.5 * (b[k] - a[k])
        live[k[done]] = False
        k, xm, tol1, tol2 = k[~done], xm[~done], tol1[~done], tol2[~done]
        if not k.size:
            break
        xk, wk, vk = x[k], w[k], v[k]
        e_old = e[k].copy()
        with np.errstate(invalid="ignore", divide="ignore"):    # an infinite f: no parabola
            r = (xk - wk) * (fx[k] - fv[k])
            q = (xk - vk) * (fx[k] - fw[k])
            p = (xk - vk) * q - (xk - wk) * r
            q = 2 * (q - r)
            p = np.where(q > 0, -p, p)
            q = np.abs(q)
            para = (np.abs(e_old) > tol1) & (np.abs(p) < np.abs(0.5 * q * e_old)) \
                & (p > q * (a[k] - xk)) & (p < q * (b[k] - xk))
            d_para = p / q
        golden_e = np.where(xk >= xm, a[k] - xk, b[k] - xk)
        e[k] = np.where(para, d[k], golden_e)
        dk = np.where(para, d_para, cgold * golden_e)
        u = xk + dk
        near_end = para & ((u - a[k] < tol2) | (b[k] - u < tol2))
        dk = np.where(near_end, np.copysign(tol1, xm - xk), dk)
        d[k] = dk
        u = np.where(np.abs(dk) >= tol1, xk + dk, xk + np.copysign(tol1, dk))
        fu = f(k, u)
        fu = np.where(np.isfinite(fu), fu, np.inf)
        better = fu <= fx[k]
        # a better point: the bracket closes on the old best, which becomes w
        a[k] = np.where(better & (u >= xk), xk, np.where(~better & (u < xk), u, a[k]))
        b[k] = np.where(better & (u < xk), xk, np.where(~better & (u >= xk), u, b[k]))
        to_w = ~better & ((fu <= fw[k]) | (wk == xk))
        to_v = ~better & ~to_w & ((fu <= fv[k]) | (vk == xk) | (vk == wk))
        v[k] = np.where(better | to_w, wk, np.where(to_v, u, vk))
        fv[k] = np.where(better | to_w, fw[k], np.where(to_v, fu, fv[k]))
        w[k] = np.where(better, xk, np.where(to_w, u, wk))
        fw[k] = np.where(better, fx[k], np.where(to_w, fu, fw[k]))
        x[k] = np.where(better, u, xk)
        fx[k] = np.where(better, fu, fx[k])
    return -sign * fx, np.exp(x)


def _worst_excess(loop, P, D, beta, alpha, omega):
    """max over ``omega`` of |corrected phase of Z| - 90 deg at the points (P, D)."""
    ex = passivity_excess(loop, P, D, beta, alpha, omega)[0]
    # the thresholds below are in deg of the corrected phase; the exact test's deficit is a
    # fraction of the port's dissipation: EXACT_SCALE deg per unit (1e-6 deg -> 1e-8)
    return ex * EXACT_SCALE if loop.options.conventions.passivity == "exact" else ex


def _line_points(Q, omega, along, t):
    """Boundary candidates on the lines ``along`` = t: the ends of the frequency range as
    (line, root, omega, kind) arrays, and the extrema still to refine as (line, branch, sign,
    bracketing triple in log omega, column of the triple still to move to where the roots meet
    or -1) arrays."""
    lw = np.log(omega)
    line, root, w, kinds, todo = [], [], [], [], []
    for branch, r in enumerate(_roots(Q, t, along)):
        ext, sign, edge, inner = _candidates(r, np.isnan(Q[0]))
        j, i = np.nonzero(ext)
        todo.append((j, np.full(j.size, branch), sign[j, i], np.stack([lw[i - 1], lw[i], lw[i + 1]], 1),
                     np.full(j.size, -1)))
        # where the roots meet between samples i and i + s, the extremum may lie between that
        # point and sample i - s: the triple (i - s, i, meeting point) brackets it
        j, i = np.nonzero(inner)
        s = np.where((i > 0) & np.isfinite(r[j, np.maximum(i - 1, 0)]), 1, -1)
        ok = (i - s >= 0) & (i - s < omega.size) & (i + s >= 0) & (i + s < omega.size)
        j, i, s = j[ok], i[ok], s[ok]
        ok = np.isfinite(r[j, i - s])
        j, i, s = j[ok], i[ok], s[ok]
        tri = np.where((s > 0)[:, None], np.stack([lw[i - s], lw[i], lw[i + s]], 1),
                       np.stack([lw[i + s], lw[i], lw[i - s]], 1))
        todo.append((j, np.full(j.size, branch), np.where(r[j, i] > r[j, i - s], 1, -1), tri,
                     np.where(s > 0, 2, 0)))
        for i_end, kind in ((0, "passivity (omega_min)"), (omega.size - 1, "passivity (Nyquist)")):
            j = np.flatnonzero(edge[:, i_end])
            line.append(j), root.append(r[j, i_end]), w.append(np.full(j.size, omega[i_end]))
            kinds.append(np.full(j.size, kind))
    todo = tuple(np.concatenate([x[k] for x in todo]) for k in range(5))
    return [np.concatenate(v) for v in (line, root, w, kinds)], todo


@loop_first
def passivity_boundary(loop: ClosedLoop, beta: float | None = None, alpha: float | None = None, *,
                       P_range=(0.0, 2e4), D_range=(0.0, 50.0), n_lines: int = 101,
                       xtol: float = REFINE_XTOL) -> list:
    """The passivity boundary in the box, as polylines.

    The boundary is located on ``n_lines`` lines D_gain = const (evenly spaced) and on
    ``n_lines`` lines P_gain = const (log-spaced when P_range starts above 0), so that its parts
    nearly parallel to one family are resolved by the other; each family gives its own
    polylines (``meta`` of the caller says so).

    Parameters
    ----------
    loop : ClosedLoop
    beta, alpha : float, optional
        Inner gains (default the controller's).
    P_range, D_range : (float, float)
        The box of impedance gains, Nm/rad and Nms/rad.
    n_lines : int
        Lines per family.
    xtol : float
        How closely each tangency is located in log omega (default ``REFINE_XTOL``, 1e-10: the
        root exact to rounding). A point is a root of its frequency's quadratic whatever
        ``xtol``; a looser one (the explorer's drawing: 1e-6) moves it along the boundary by
        about xtol^2 relative, and it must still pass the same on-boundary check.

    Returns
    -------
    list of :class:`haa_sym.analysis.boundaries.stability.BoundaryCurve`
        ``omega`` (rad/s) is the frequency where the corrected phase of Z reaches +-90 deg;
        ``kind`` is "passivity" (a tangency of the envelope), "passivity (omega_min)" or
        "passivity (Nyquist)" (the edge of the judged frequency range bounds the set).
    """
    ctrl = loop.params.controller
    beta = ctrl.beta if beta is None else float(beta)
    alpha = ctrl.alpha if alpha is None else float(alpha)
    if isinstance(n_lines, bool) or not isinstance(n_lines, int) or n_lines < 2:
        raise ParameterError(f"n_lines = {n_lines!r}; allowed: an integer >= 2")
    if not (isinstance(xtol, (int, float)) and not isinstance(xtol, bool) and 0 < xtol <= 1e-3):
        raise ParameterError(f"xtol = {xtol!r}; allowed: a number in (0, 1e-3] (log omega)")
    omega = loop.options.numerics.omega(ctrl.Ts)
    Q = _conics(loop, omega, beta, alpha, cached=True)
    box = {"P_gain": tuple(P_range), "D_gain": tuple(D_range)}
    lines = {"D_gain": np.linspace(D_range[0], D_range[1], n_lines),
             "P_gain": np.geomspace(P_range[0], P_range[1], n_lines) if P_range[0] > 0
             else np.linspace(P_range[0], P_range[1], n_lines)}
    found, todo = {}, {}
    for along, t in lines.items():
        found[along], todo[along] = _line_points(Q, omega, along, t)
    # every extremum of every line refined together: one frequency evaluation per step
    fam = np.concatenate([np.full(v[0].size, a == "P_gain") for a, v in todo.items()])
    j = np.concatenate([v[0] for v in todo.values()])
    t = np.concatenate([lines[a][v[0]] for a, v in todo.items()])
    branch, sign, tri, col = (np.concatenate([v[k] for v in todo.values()]) for k in (1, 2, 3, 4))
    # only candidates that can be on the boundary: in the box (with room for the refinement to
    # move them) and not inside the non-passive set at their grid sample (another grid frequency
    # puts that point beyond +-90 deg by more than PRUNE_DEG)
    i = np.clip(np.searchsorted(np.log(omega), tri[:, 1]), 0, omega.size - 1)
    r0 = [_roots(Q[:, i], t, along, pointwise=True) for along in ("D_gain", "P_gain")]
    r0 = np.where(branch == 0, np.where(fam, r0[1][0], r0[0][0]), np.where(fam, r0[1][1], r0[0][1]))
    lo = np.where(fam, D_range[0], P_range[0])
    hi = np.where(fam, D_range[1], P_range[1])
    span = hi - lo
    keep = np.isfinite(r0) & (r0 >= lo - 0.05 * span) & (r0 <= hi + 0.05 * span)
    P0, D0 = np.where(fam, t, r0), np.where(fam, r0, t)
    k = np.flatnonzero(keep)
    keep[k] = _worst_excess(loop, P0[k], D0[k], beta, alpha, omega) <= PRUNE_DEG
    fam, j, t, branch, sign, tri, col = (v[keep] for v in (fam, j, t, branch, sign, tri, col))
    k = np.flatnonzero(col >= 0)
    if k.size:
        tri[k, col[k]] = _meeting_points(loop, tri[k, 1], tri[k, col[k]], fam[k], t[k], branch[k], beta, alpha)
    x, wx = _refine(loop, fam, t, branch, sign, tri, beta, alpha, xtol)
    for along, f in found.items():
        m = fam == (along == "P_gain")
        n = int(m.sum())
        f[0], f[1], f[2] = np.concatenate([f[0], j[m]]), np.concatenate([f[1], x[m]]), np.concatenate([f[2], wx[m]])
        f[3] = np.concatenate([f[3], np.full(n, "passivity")])
        lo, hi = box["P_gain" if along == "D_gain" else "D_gain"]
        keep = np.isfinite(f[1]) & (f[1] >= lo) & (f[1] <= hi)
        found[along] = [v[keep] for v in f]
    P = np.concatenate([lines[a][f[0]] if a == "P_gain" else f[1] for a, f in found.items()])
    D = np.concatenate([lines[a][f[0]] if a == "D_gain" else f[1] for a, f in found.items()])
    if not P.size:
        return []
    # on the boundary: no grid frequency puts the phase beyond +-90 deg (no other conic covers
    # the point), and the loop is stable there
    ok = _worst_excess(loop, P, D, beta, alpha, omega) <= ON_BOUNDARY_DEG
    ok &= loop.stability(P, D, beta, alpha).stable
    curves, start = [], 0
    for j, r, w, kinds in found.values():
        sl = slice(start, start + j.size)
        start += j.size
        k = ok[sl]
        Pk, Dk = P[sl][k], D[sl][k]
        curves += _polylines(j[k], Pk, Dk, r[k], w[k], kinds[k], BoundaryCurve)
    return curves


def _polylines(line, P, D, x, w, kinds, BoundaryCurve, jump: float = 0.5) -> list:
    """Join the points of neighbouring lines into polylines: each open polyline continues with the
    nearest point (root ``x`` and omega, both within ``jump`` in log) of the same kind on the
    next line."""
    order = np.lexsort((x, line))
    line, P, D, x, w, kinds = line[order], P[order], D[order], x[order], w[order], kinds[order]
    done, open_ = [], []              # polylines as lists of indices
    for j in np.unique(line):
        idx = list(np.flatnonzero(line == j))
        nxt = []
        for poly in open_:
            k = poly[-1]
            if line[k] != j - 1:
                done.append(poly)
                continue
            best, dist = None, jump
            for m in idx:
                if kinds[m] != kinds[k]:
                    continue
                dm = max(abs(np.log(max(x[m], 1e-300) / max(x[k], 1e-300))), abs(np.log(w[m] / w[k])))
                if dm < dist:
                    best, dist = m, dm
            if best is None:
                done.append(poly)
            else:
                idx.remove(best)
                nxt.append(poly + [best])
        open_ = nxt + [[m] for m in idx]
    done += open_
    return [BoundaryCurve(str(kinds[p[0]]), P[p], D[p], w[p]) for p in sorted(done, key=lambda p: (line[p[0]], x[p[0]]))]
