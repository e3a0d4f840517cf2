"""The phase margin: one rule, one primitive (Sec. 3.2 design targets, Sec. 4 maps, Figs. 8-11).

Every phase margin of the library comes from :func:`crossovers`: the maps (grid and curves),
the drawn 30 deg curves, the torque loop's design check, ``haa-sym margins`` and the scheduler.
For a loop transfer L (negative feedback, closed loop 1/(1 + L)) a *gain crossover* is a
frequency where |L| = 1; its phase margin is 180 + arg L there, wrapped to (-180, 180].

The rule (``AnalysisConventions.pm_rule``):

``distance`` (default)
    A point has a low phase margin when L passes closer than the threshold to -1 at *any*
    crossover: min over crossovers of |wrapped PM| < 30 deg. A crossover at -150 deg is as far
    from -1 as one at +150 deg; both are far.
``min_abs``
    The signed margin of the crossover with the smallest |PM| is compared with the threshold
    (the rule before issue 15: a crossover at -102 deg counted as "PM < 30").
``worst``
    The smallest signed margin over all crossovers is compared with the threshold.

With no crossover in the judged band (``omega_min`` to Nyquist) the margin is infinite and
never low.

How crossovers are located exactly
----------------------------------
The loop gain at the impedance gains x = (1, P_gain, D_gain) is, for fixed beta and alpha,
L_x = (N_0 + P_gain N_1 + D_gain N_2) / Den for both loops of :class:`~haa_sym.ClosedLoop`:

* ``L_imp`` (opened at the torque reference): Den = A, N = (0, B, C), with chi = A + P B + D C
  the characteristic polynomial (:func:`haa_sym.analysis.boundaries.affine_polynomials`);
* ``L_t`` (opened at the PI output, the velocity-compensation loop left closed, as
  ``codegen/kernels.py`` and the state space's cut "PI"): Den = chi at P_t = I_t = 0, N_0 = A -
  Den, N_1 = B, N_2 = C.

The polynomials are the loop's exact bilinear basis (rounded once), evaluated at s = j tan(omega
Ts/2) by a real Horner scheme (accurate at fast sampling, where z-polynomials crowd at z = 1).
The poles of L do not depend on (P_gain, D_gain) and are computed once per (beta, alpha).
Crossovers are found in three steps, vectorised over all points:

1. |L|^2 on the options' grid augmented with samples omega_f + k sigma_f around every lightly
   damped pole and zero (sigma_f its bandwidth): every sign change of |L|^2 - 1 is a bracket;
2. every sampled local maximum below 1 (a peak that may reach 1 between samples) and local
   minimum above 1 (a notch) is searched by golden sections, stopped on the other side of 1,
   which gives two brackets;
3. every bracket is refined by the Illinois method to 1e-12 in ln omega; the phase is read there.

Checked against an independent dense computation (the explicit closed loop of
:mod:`haa_sym.check.reference` on 200,000 frequencies plus its own poles, brentq): no crossover
missed on 1,853 points (3,219 crossovers) of the bundled actuators at beta 1, 3 and 7.6, Ts 10
us to 8 ms, N_av 50, both low-pass filters, a damping ratio of 1e-6, both loops
(tests/test_analysis_margins.py repeats a sample of it). Limits (not a certificate): a notch of L_t that
moves with the gains is not sampled; an extremum within ~1e-12 of |L|^2 = 1 may count as 0 or
2 crossovers.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from haa_sym.compiled.layout import gain_monomials
from haa_sym.errors import ParameterError
from haa_sym.loop import PM_RULES, loop_first
from haa_sym.loop.statespace import closed_loop_batch

__all__ = ["PM_THRESHOLD_DEG", "PM_RULES", "WHICH", "Crossovers", "PhaseMargins", "Margins", "crossovers",
           "phase_margins", "margins", "summarise", "low_phase_margin", "wrap_deg", "loop_polynomials"]

# Figs. 8-11: light grey = stable with a phase margin below 30 degrees.
PM_THRESHOLD_DEG = 30.0
WHICH = ("L_imp", "L_t")
# Illinois stops at this bracket width in log omega: 1e-12 relative in omega.
XTOL = 1e-12
# Feature offsets (multiples of the bandwidth sigma) sampled around each lightly damped pole or
# zero. A peak of a pole with bandwidth sigma is sampled at its top and at +-sigma/4, so the
# golden search starts from a bracket that holds the maximum.
FEATURE_OFFSETS = np.array([0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0])
# Features with sigma above this fraction of omega are resolved by the base grid (a damping
# ratio above ~0.3 gives a peak wider than 30 % of its frequency).
LIGHT_DAMPING = 0.3
# A local maximum of the samples below 1 is searched when |L|^2 > PEAK_FLOOR there; a local
# minimum above 1 when |L|^2 < NOTCH_CEIL. Peaks of poles are sampled at their top (above), so
# a sampled maximum 10 dB below 1 cannot hide a crossing; notches of zeros that move with the
# gains are not always sampled at their bottom, hence the wider window (40 dB).
PEAK_FLOOR = 0.1
NOTCH_CEIL = 1e4
# Golden-section steps at most: the bracket shrinks by 0.618 per step, to 5e-7 of its start
# after 30, where a smooth extremum is known to ~1e-12 in log|L|^2 (a tangency closer to
# |L| = 1 than that may go either way).
GOLDEN_STEPS = 30
# Points per chunk of the grid products (chunk x n_grid doubles per array).
CHUNK = 2048
# Worker threads, each taking an equal share of the points (numpy's products, ufuncs and
# Horner steps release the GIL; measured on this 2-core machine, see NOTES.md).
THREADS = min(2, os.cpu_count() or 1)



def wrap_deg(pm) -> np.ndarray:
    """180 + arg L style angles wrapped to (-180, 180] deg."""
    m = (np.asarray(pm, float) + 180.0) % 360.0 - 180.0
    return np.where(m == -180.0, 180.0, m)


@dataclass(frozen=True)
class Crossovers:
    """Every gain crossover of every point, flat: ``point`` (index of the gain point),
    ``omega`` (rad/s) and ``pm_deg`` (wrapped to (-180, 180]); sorted by point, then frequency."""

    n_points: int
    point: np.ndarray
    omega: np.ndarray
    pm_deg: np.ndarray

    def of(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(omega, pm_deg) of point ``i``."""
        sel = self.point == i
        return self.omega[sel], self.pm_deg[sel]


@dataclass(frozen=True)
class PhaseMargins:
    """One phase margin per gain point (arrays of the points' shape).

    ``distance_deg``: min over crossovers of |wrapped PM| (inf where L never crosses 1);
    ``pm_deg``: the signed margin of that crossover (NaN where none); ``omega_c``: its frequency,
    rad/s (NaN where none); ``worst_deg``: the smallest signed margin (inf where none);
    ``n_crossovers``: how many crossovers the point has.
    """

    distance_deg: np.ndarray
    pm_deg: np.ndarray
    omega_c: np.ndarray
    worst_deg: np.ndarray
    n_crossovers: np.ndarray

    def low(self, rule: str = "distance", threshold_deg: float = PM_THRESHOLD_DEG) -> np.ndarray:
        """The points whose margin is below ``threshold_deg`` by ``rule`` (module docstring)."""
        return low_phase_margin(self, rule, threshold_deg)


def summarise(c: Crossovers, shape=None) -> PhaseMargins:
    """Per point: the crossover nearest -1 (smallest |PM|, the lower frequency on ties), the
    worst signed margin and the count."""
    n = c.n_points
    dist = np.full(n, np.inf)
    pm = np.full(n, np.nan)
    wc = np.full(n, np.nan)
    worst = np.full(n, np.inf)
    count = np.bincount(c.point, minlength=n) if c.point.size else np.zeros(n, int)
    if c.point.size:
        a = np.abs(c.pm_deg)
        order = np.lexsort((c.omega, a, c.point))
        first = order[np.unique(c.point[order], return_index=True)[1]]
        dist[c.point[first]] = a[first]
        pm[c.point[first]] = c.pm_deg[first]
        wc[c.point[first]] = c.omega[first]
        np.minimum.at(worst, c.point, c.pm_deg)
    shape = (n,) if shape is None else tuple(shape)
    return PhaseMargins(dist.reshape(shape), pm.reshape(shape), wc.reshape(shape), worst.reshape(shape),
                        count.reshape(shape))


def low_phase_margin(pm: PhaseMargins, rule: str = "distance", threshold_deg: float = PM_THRESHOLD_DEG) -> np.ndarray:
    """The points of ``pm`` whose phase margin is below ``threshold_deg`` (deg) by ``rule``."""
    if rule == "distance":
        return pm.distance_deg < threshold_deg
    if rule == "min_abs":
        with np.errstate(invalid="ignore"):
            return pm.pm_deg < threshold_deg              # NaN (no crossover): False
    if rule == "worst":
        return pm.worst_deg < threshold_deg
    raise ParameterError(f"pm_rule = {rule!r}; allowed: {list(PM_RULES)}")


# ----------------------------------------------------------------------------- the loop polynomials
def _horner(c: np.ndarray, t: np.ndarray) -> np.ndarray:
    """sum_k c[:, k] t^k for ascending rows ``c`` (r, m) at points ``t`` (M,): shape (r, M)."""
    v = np.repeat(c[:, -1:], t.size, axis=1)
    for k in range(c.shape[1] - 2, -1, -1):
        v *= t
        v += c[:, k:k + 1]
    return v


@dataclass(frozen=True, eq=False)
class LoopPolynomials:
    """N_0, N_1, N_2 and Den of one loop at fixed (beta, alpha), and the band it is judged in.

    Attributes
    ----------
    coef : (4, d + 1) array
        Ascending coefficients in s of N_0, N_1, N_2, Den (common scale: max |Den_k| = 1); d even.
    Ts : float
        Sampling time, s.
    omega : (n,) array
        The augmented frequency grid, rad/s (increasing, within the base grid's band).
    features : (f, 2) array
        (omega_f, sigma_f) of every pole and zero of L in the band, rad/s.
    """

    coef: np.ndarray
    Ts: float
    omega: np.ndarray
    features: np.ndarray

    def __post_init__(self):
        d = self.coef.shape[1] - 1
        h = d // 2
        # q(j nu) = E(nu^2) + j nu O(nu^2), E_i = p_2i (-1)^i, O_i = p_(2i+1) (-1)^i
        even = self.coef[:, 0::2] * (-1.0) ** np.arange(h + 1)
        odd = np.zeros((4, h + 1))
        odd[:, :h] = self.coef[:, 1::2] * (-1.0) ** np.arange(h)
        # above nu = 1: q / nu^d = E'(w^2) + j w O'(w^2), w = 1/nu, the reversed coefficients
        # (d = 2h: nu^(2i - d) = w^(2(h - i)); nu^(2i + 1 - d) = w w^(2(h - 1 - i)))
        even_r = even[:, ::-1]
        odd_r = np.zeros((4, h + 1))
        odd_r[:, :h] = odd[:, h - 1::-1]
        object.__setattr__(self, "_small", np.vstack([even, odd]))
        object.__setattr__(self, "_large", np.vstack([even_r, odd_r]))

    def values(self, omega: np.ndarray) -> np.ndarray:
        """N_0, N_1, N_2, Den at z = exp(j omega Ts), each scaled by one common positive factor
        per frequency (it cancels in L); shape (4, M), complex. ``omega`` in rad/s, (M,)."""
        omega = np.asarray(omega, float)
        nu = np.tan(0.5 * omega * self.Ts)
        out = np.empty((4, nu.size), complex)
        small = nu <= 1.0
        if small.any():
            n = nu[small]
            v = _horner(self._small, n * n)
            out[:, small] = v[:4] + 1j * n * v[4:]
        if not small.all():
            w = 1.0 / nu[~small]
            v = _horner(self._large, w * w)
            out[:, ~small] = v[:4] + 1j * w * v[4:]
        return out

    def components(self, omega: np.ndarray) -> np.ndarray:
        """(l_0, l_1, l_2) with L_x = l_0 + P_gain l_1 + D_gain l_2 at ``omega``: (M, 3) complex."""
        v = self.values(omega)
        return (v[:3] / v[3]).T

    def gain(self, x: np.ndarray, omega: np.ndarray) -> np.ndarray:
        """L at gain rows ``x`` (M, 3) = (1, P_gain, D_gain), each at its own ``omega`` (M,)."""
        v = self.values(omega)
        return np.einsum("ij,ji->i", x, v[:3]) / v[3]


def _bilinear_features(p_ascending: np.ndarray, Ts: float) -> np.ndarray:
    """(omega, sigma) of the roots of a polynomial in s (ascending), as z = (1 + s)/(1 - s)."""
    p = np.trim_zeros(np.asarray(p_ascending, float)[::-1], "f")
    if p.size < 2 or not np.any(p):
        return np.empty((0, 2))
    s = np.roots(p)
    s = s[np.abs(s + 1) > 1e-9]                            # z = 0: the basis' padding roots
    return _z_features(s_to_z(s), Ts)


def s_to_z(s):
    """z = (1 + s)/(1 - s), inf where s = 1."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return (1 + s) / (1 - s)


def _z_features(z: np.ndarray, Ts: float) -> np.ndarray:
    z = z[np.isfinite(z) & (np.abs(z) > 0)]
    return np.stack([np.abs(np.angle(z)) / Ts, np.abs(np.log(np.abs(z))) / Ts], axis=1)


def _augmented_grid(base: np.ndarray, features: np.ndarray) -> np.ndarray:
    """``base`` plus samples omega_f + k sigma_f (k in +-FEATURE_OFFSETS) of the lightly damped
    features that are finer than the local grid step (coarser ones add nothing)."""
    lo, hi = base[0], base[-1]
    step = np.log(base[-1] / base[0]) / (base.size - 1)     # log step of the (log) base grid
    extra = []
    for w, sig in features:
        if not (lo < w < hi) or sig > LIGHT_DAMPING * w:
            continue
        k = FEATURE_OFFSETS[FEATURE_OFFSETS * sig < 2 * step * w]
        extra.append(w + sig * np.concatenate([-k[1:], k]))
    if not extra:
        return base.copy()
    w = np.concatenate([base] + extra)
    w = np.unique(w[(w >= lo) & (w <= hi)])
    # drop samples closer than a few ulps (equal for the root finder)
    keep = np.ones(w.size, bool)
    keep[1:] = np.diff(w) > 8 * np.finfo(float).eps * w[1:]
    return w[keep]



def loop_polynomials(loop, beta=None, alpha=None, which: str | None = None, omega=None) -> LoopPolynomials:
    """The :class:`LoopPolynomials` of ``loop`` at scalar ``beta``, ``alpha`` (default: the
    controller's), for ``which`` in {"L_imp", "L_t"} (default: the options' ``pm_loop``), on the
    base grid ``omega`` (rad/s; default the options' grid). Cached per loop and arguments."""
    if loop.basis is None:
        raise ParameterError("this ClosedLoop was built with basis=False: its phase margins need the "
                             "characteristic-polynomial basis; allowed: ClosedLoop(params, options)")
    ctrl = loop.params.controller
    beta = float(ctrl.beta if beta is None else beta)
    alpha = float(ctrl.alpha if alpha is None else alpha)
    which = _which(loop, which)
    base = loop.options.omega(ctrl.Ts) if omega is None else np.sort(np.asarray(omega, float).ravel())
    key = (which, beta, alpha, base.tobytes())
    cache = loop.__dict__.setdefault("_loop_polynomials", {})   # per loop: its basis and options
    if key in cache:
        return cache[key]
    g = [np.array(gain_monomials(np.array([P, D, beta, alpha]), loop.const), float)
         for P, D in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))]
    basis = loop.basis                                           # (cap + 1, 8), ascending in s
    A, B, C = basis @ g[0], basis @ (g[1] - g[0]), basis @ (g[2] - g[0])
    if which == "L_imp":
        polys = [np.zeros_like(A), B, C, A]
    else:
        # the cut at the PI output leaves the velocity-compensation loop closed: Den is chi at
        # P_t = I_t = 0 (beta = 0); the monomial differences g0 - g_vc are exact (equal terms
        # cancel to 0), so N_0 = A - Den has no cancellation
        g_vc = np.array(gain_monomials(np.array([0.0, 0.0, 0.0, alpha]), loop.const), float)
        polys = [basis @ (g[0] - g_vc), B, C, basis @ g_vc]
    coef = np.array(polys)
    if coef.shape[1] % 2 == 0:                                   # even degree (see values)
        coef = np.hstack([coef, np.zeros((4, 1))])
    coef = coef / np.max(np.abs(coef[3]))
    # poles of L: eigenvalues of the loop opened at the cut (independent of P_gain, D_gain)
    Acut = closed_loop_batch(loop, 0.0, 0.0, beta, alpha, cut="T_ref" if which == "L_imp" else "PI")[0][0]
    feats = [_z_features(np.linalg.eigvals(Acut), ctrl.Ts)]
    # zeros of the three numerator components: fixed zeros of L are common to them; for the
    # average filter the zeros that move with P_gain/D_gain stay on the rays of the roots of C
    feats += [_bilinear_features(p, ctrl.Ts) for p in coef[:3]]
    features = np.vstack(feats)
    poly = LoopPolynomials(coef, ctrl.Ts, _augmented_grid(base, features), features)
    if len(cache) > 64:
        cache.clear()
    cache[key] = poly
    return poly



# ----------------------------------------------------------------------------- search steps
def _illinois(f, a, b, fa, fb, xtol=XTOL, steps=80):
    """Illinois regula falsi on every bracket [a, b] (f(a), f(b) of opposite signs); only the
    unconverged brackets are evaluated at each step. Returns the midpoints."""
    a, b, fa, fb = (np.array(v, float) for v in (a, b, fa, fb))
    side = np.zeros(a.size, np.int8)
    act = np.flatnonzero(np.abs(b - a) > xtol)
    for _ in range(steps):
        if not act.size:
            break
        A, B, FA, FB = a[act], b[act], fa[act], fb[act]
        with np.errstate(invalid="ignore", divide="ignore"):
            x = (A * FB - B * FA) / (FB - FA)
        lo, hi = np.minimum(A, B), np.maximum(A, B)
        x = np.where(np.isfinite(x) & (x > lo) & (x < hi), x, 0.5 * (A + B))
        fx = f(act, x)
        with_a = np.sign(fx) == np.sign(FA)                    # x replaces a
        s = side[act]
        fb[act] = np.where(with_a, np.where(s == 1, 0.5 * FB, FB), fx)
        fa[act] = np.where(with_a, fx, np.where(s == -1, 0.5 * FA, FA))
        a[act] = np.where(with_a, x, A)
        b[act] = np.where(with_a, B, x)
        side[act] = np.where(with_a, 1, -1)
        done = (np.abs(b[act] - a[act]) <= xtol) | (fx == 0)
        exact = fx == 0
        a[act[exact]] = b[act[exact]] = x[exact]
        act = act[~done]
    return 0.5 * (a + b)


def _golden_cross(f, lo, hi, sign, steps=GOLDEN_STEPS):
    """For every bracket [lo, hi] search the maximum of sign * f (``sign`` +-1 per bracket) by
    golden sections, stopped at the first abscissa where sign * f > 0. Returns (found, x, f(x))."""
    g = 0.3819660112501051
    n = lo.size
    found = np.zeros(n, bool)
    xe, fe = np.full(n, np.nan), np.full(n, np.nan)
    a, b = lo.copy(), hi.copy()
    x1, x2 = a + g * (b - a), b - g * (b - a)
    idx = np.arange(n)
    sign = np.broadcast_to(np.asarray(sign, float), (n,)).copy()
    f1 = sign * f(idx, x1)
    f2 = sign * f(idx, x2)
    for _ in range(steps + 1):
        hit1, hit2 = f1 > 0, f2 > 0
        hit = hit1 | hit2
        if hit.any():
            j = idx[hit]
            found[j] = True
            xe[j] = np.where(hit1[hit], x1[hit], x2[hit])
            fe[j] = sign[hit] * np.where(hit1[hit], f1[hit], f2[hit])
            keep = ~hit
            idx, a, b, x1, x2, f1, f2, sign = (v[keep] for v in (idx, a, b, x1, x2, f1, f2, sign))
        live = (b - a) > XTOL                                # resolved: the extremum stays short of 1
        if not live.all():
            idx, a, b, x1, x2, f1, f2, sign = (v[live] for v in (idx, a, b, x1, x2, f1, f2, sign))
        if not idx.size:
            break
        left = f1 >= f2                                      # the maximum is in [a, x2]
        b = np.where(left, x2, b)
        a = np.where(left, a, x1)
        xn = np.where(left, a + g * (b - a), b - g * (b - a))
        fn = sign * f(idx, xn)
        x1, x2 = np.where(left, xn, x2), np.where(left, x1, xn)
        f1, f2 = np.where(left, fn, f2), np.where(left, f1, fn)
    return found, xe, fe


def _squared_forms(l: np.ndarray) -> np.ndarray:
    """Rows Q (6, M) with |x . l|^2 = (1, P, D, P^2, P D, D^2) . Q for l (M, 3) complex."""
    def re(i, j):
        return (l[:, i] * np.conj(l[:, j])).real
    return np.stack([re(0, 0), 2 * re(0, 1), 2 * re(0, 2), re(1, 1), 2 * re(1, 2), re(2, 2)])


def _crossovers_one(poly: LoopPolynomials, X: np.ndarray):
    """(rows, omega, pm_deg) of every crossover of the gain rows ``X`` (n, 3) at one (beta, alpha)."""
    w = poly.omega
    lw = np.log(w)
    Q = _squared_forms(poly.components(w))
    tiny = np.finfo(float).tiny

    def logmag2(rows, x):                                   # log |L|^2 at log-frequency x
        L = poly.gain(X[rows], np.exp(x))
        return np.log(np.maximum((L * np.conj(L)).real, tiny))

    r_all, a_all, b_all = [], [], []
    fa_all, fb_all = [], []
    ext = []
    for c0 in range(0, X.shape[0], CHUNK):
        Xc = X[c0:c0 + CHUNK]
        P, D = Xc[:, 1:2], Xc[:, 2:3]
        M = np.hstack([Xc[:, :1], P, D, P * P, P * D, D * D])
        mag2 = M @ Q                                         # |L|^2, (chunk, n_grid)
        n_w = mag2.shape[1]
        # 1. sign changes of |L|^2 - 1 on the augmented grid
        above = mag2 > 1.0
        flat = np.flatnonzero(above[:, 1:] != above[:, :-1])
        r, k = np.divmod(flat, n_w - 1)
        r_all.append(r + c0); a_all.append(lw[k]); b_all.append(lw[k + 1])
        fa_all.append(_log(mag2[r, k])); fb_all.append(_log(mag2[r, k + 1]))
        # 2. hidden pairs: a sampled local extremum near 1 on the far side of 1 (a peak below
        # 1, a notch above) may cross 1 between its neighbours
        up = mag2[:, 1:] > mag2[:, :-1]
        flat = np.flatnonzero(up[:, :-1] != up[:, 1:])     # few per row: filter them afterwards
        r, k = np.divmod(flat, n_w - 2)
        k = k + 1
        peak = up[r, k - 1]
        m = mag2[r, k]
        keep = np.where(peak, (m < 1.0) & (m > PEAK_FLOOR), (m > 1.0) & (m < NOTCH_CEIL))
        r, k, peak = r[keep], k[keep], peak[keep]
        ext.append((r + c0, k, peak, _log(mag2[r, k - 1]), _log(mag2[r, k + 1])))
    # golden sections on all candidates of all chunks at once (the steps are python-level)
    if ext:
        rows, k, peak, f0, f1 = (np.concatenate(v) for v in zip(*ext))
        sign = np.where(peak, 1.0, -1.0)
        found, xe, fe = _golden_cross(lambda i, x: logmag2(rows[i], x), lw[k - 1], lw[k + 1], sign)
        rows, k, xe, fe, f0, f1 = (v[found] for v in (rows, k, xe, fe, f0, f1))
        r_all += [rows, rows]
        a_all += [lw[k - 1], xe]; b_all += [xe, lw[k + 1]]
        fa_all += [f0, fe]; fb_all += [fe, f1]
    rows = np.concatenate(r_all)
    if not rows.size:
        return rows, np.empty(0), np.empty(0)
    a, b = np.concatenate(a_all), np.concatenate(b_all)
    fa, fb = np.concatenate(fa_all), np.concatenate(fb_all)
    # 3. refine: log |L|^2 is nearly linear in log omega at a crossover (Illinois converges fast)
    x = _illinois(lambda i, x: logmag2(rows[i], x), a, b, fa, fb)
    omega = np.exp(x)
    L = poly.gain(X[rows], omega)
    return rows, omega, wrap_deg(np.degrees(np.angle(L)) + 180.0)


def _which(loop, which):
    if which is None:
        which = {"impedance": "L_imp", "torque": "L_t"}[loop.options.conventions.pm_loop]
    if which not in WHICH:
        raise ParameterError(f"which = {which!r}; allowed: {list(WHICH)} or None (the options' pm_loop)")
    if which == "L_t":
        loop.require("torque_loop", "the torque loop's phase margin (pm_loop = 'torque', which = 'L_t')")
    return which


def _log(v):
    return np.log(np.maximum(v, np.finfo(float).tiny))


def _threaded(poly: LoopPolynomials, X: np.ndarray) -> list:
    """:func:`_crossovers_one` on THREADS equal shares of the points, rows made global."""
    n = X.shape[0]
    k = max(1, min(THREADS, n // CHUNK))
    if k == 1:
        return [_crossovers_one(poly, X)]
    bounds = np.linspace(0, n, k + 1).astype(int)
    with ThreadPoolExecutor(k) as ex:
        outs = list(ex.map(lambda j: _crossovers_one(poly, X[bounds[j]:bounds[j + 1]]), range(k)))
    return [(r + bounds[j], w, pm) for j, (r, w, pm) in enumerate(outs)]


@loop_first
def crossovers(loop, P_gain, D_gain, beta=None, alpha=None, *, which: str | None = None,
               omega=None) -> Crossovers:
    """Every gain crossover |L| = 1 of ``loop`` at gain points, located exactly.

    Parameters
    ----------
    loop : ClosedLoop
    P_gain, D_gain : array_like
        Impedance stiffness (Nm/rad) and damping (Nms/rad) of Eq. (8), broadcast together
        (flattened in C order).
    beta, alpha : float, optional
        Torque-gain scale (Eq. 7) and velocity-compensation gain (Eq. 6); default the
        controller's.
    which : {"L_imp", "L_t"}, optional
        The impedance loop opened at the torque reference or the torque loop opened at the PI
        output; default the options' ``pm_loop``.
    omega : array_like, optional
        Base frequency grid, rad/s (default the options' grid, ``omega_min`` to Nyquist); it
        also sets the band in which crossovers are sought. It is augmented around every lightly
        damped pole and zero of L.

    Returns
    -------
    Crossovers
        Flat arrays sorted by point, then frequency; frequencies to 1e-12 relative.
    """
    P, D, beta, alpha = loop.gain_points(P_gain, D_gain, beta, alpha)
    X = np.stack([np.ones_like(P), P, D], axis=1)
    n = X.shape[0]
    if n == 0:
        return Crossovers(0, np.empty(0, int), np.empty(0), np.empty(0))
    parts = _threaded(loop_polynomials(loop, beta, alpha, which, omega), X)
    point = np.concatenate([p[0] for p in parts]).astype(int)
    w = np.concatenate([p[1] for p in parts])
    pm = np.concatenate([p[2] for p in parts])
    order = np.lexsort((w, point))
    return Crossovers(n, point[order], w[order], pm[order])


@loop_first
def phase_margins(loop, P_gain, D_gain, beta=None, alpha=None, *, which: str | None = None,
                  omega=None) -> PhaseMargins:
    """The phase margin of ``loop`` at gain points (P_gain, D_gain broadcast; arrays of their
    shape): the crossover nearest to -1 (:func:`summarise` of :func:`crossovers`, same
    parameters)."""
    shape = np.broadcast_shapes(np.shape(P_gain), np.shape(D_gain))
    return summarise(crossovers(loop, P_gain, D_gain, beta, alpha, which=which, omega=omega), shape)


@dataclass(frozen=True)
class Margins:
    """All margins of one loop at one gain point (as MATLAB's ``allmargin``).

    ``gain_crossovers`` (rad/s) where |L| = 1, with ``phase_margins_deg`` = 180 + arg L there,
    wrapped to (-180, 180]; ``phase_crossovers`` (rad/s) where arg L = -180 deg (mod 360), with
    ``gain_margins_db`` = -20 log10 |L| there: a positive value is the gain increase that
    reaches instability there, a negative one a gain *reduction* (|L| > 1 at that phase
    crossover: the loop is stable only while the gain stays above it).
    """

    gain_crossovers: np.ndarray
    phase_margins_deg: np.ndarray
    phase_crossovers: np.ndarray
    gain_margins_db: np.ndarray

    @property
    def distance_deg(self) -> float:
        """min |PM| over the crossovers (the margin of the ``distance`` rule; inf if none)."""
        return float(np.abs(self.phase_margins_deg).min()) if self.phase_margins_deg.size else float("inf")

    @property
    def pm_deg(self) -> float:
        """The signed margin of the crossover nearest -1 (NaN if |L| never crosses 1)."""
        if not self.phase_margins_deg.size:
            return float("nan")
        return float(self.phase_margins_deg[np.argmin(np.abs(self.phase_margins_deg))])

    @property
    def gm_db(self) -> float:
        """The gain margin nearest 0 dB (the smallest |GM|; inf if no phase crossover)."""
        if not self.gain_margins_db.size:
            return float("inf")
        return float(self.gain_margins_db[np.argmin(np.abs(self.gain_margins_db))])


def _phase_crossovers(poly: LoopPolynomials, x: np.ndarray):
    """Frequencies (rad/s) where arg L = -180 deg at the gain row ``x`` (3,), and |L| there:
    sign changes of Im(N conj Den) with Re < 0 on the augmented grid, refined by Illinois in
    ln omega."""
    w = poly.omega
    v = poly.values(w)
    h = np.einsum("i,ij->j", x, v[:3]) * np.conj(v[3])
    im, re = h.imag, h.real
    k = np.flatnonzero((np.sign(im[:-1]) * np.sign(im[1:]) <= 0) & ((re[:-1] < 0) | (re[1:] < 0))
                       & ~((im[:-1] == 0) & (im[1:] == 0)))
    if not k.size:
        return np.empty(0), np.empty(0)
    lw = np.log(w)

    def f(idx, xx):
        vv = poly.values(np.exp(xx))
        return (np.einsum("i,ij->j", x, vv[:3]) * np.conj(vv[3])).imag
    xr = _illinois(f, lw[k], lw[k + 1], im[k], im[k + 1])
    omega = np.exp(xr)
    L = poly.gain(np.broadcast_to(x, (omega.size, 3)), omega)
    keep = L.real < 0
    return omega[keep], np.abs(L[keep])


@loop_first
def margins(loop, P_gain: float = 0.0, D_gain: float = 0.0, beta=None, alpha=None, *,
            which: str | None = None, omega=None) -> Margins:
    """Every gain and phase crossover of the loop ``which`` (default the options' ``pm_loop``)
    at one gain point, located exactly (:func:`crossovers`; the phase crossovers by Illinois on
    Im L between samples of the same augmented grid), in the band of ``omega`` (rad/s; default
    the options' grid, :func:`crossovers`)."""
    P, D, beta, alpha = loop.gain_points(P_gain, D_gain, beta, alpha)
    if P.size != 1:
        raise ParameterError(f"P_gain has {P.size} values; allowed: one gain point")
    c = crossovers(loop, P, D, beta, alpha, which=which, omega=omega)
    wp, magp = _phase_crossovers(loop_polynomials(loop, beta, alpha, which, omega), np.array([1.0, P[0], D[0]]))
    return Margins(c.omega, c.pm_deg, wp, -20 * np.log10(magp))
