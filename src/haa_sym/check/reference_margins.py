"""Independent exact-crossover reference for the phase-margin code of haa_sym (tests, checks).

Every gain crossover (|L| = 1) of

* the impedance loop, opened at the torque reference (``cut="T_ref"``), and
* the torque loop, opened at the PI output with the impedance loop closed (``cut="PI"``),

at given gain points, located to machine precision, with the phase margin at each.

Independence
------------
Nothing here uses the library's loop algebra (``ClosedLoop.loop_coefficients``, the generated
kernels, ``haa_sym.loop.statespace``) or its margin code (``haa_sym.analysis.margins``, ``haa_sym.analysis.sweep``).
The loop comes from the library's *reference* module (:mod:`haa_sym.check.reference`), which builds the sampled closed loop by its
own block interconnection with scipy (ZOH plant by ``cont2discrete``, FIR / bilinear filters,
``tf2ss`` blocks, an interconnection matrix). Its outputs are ``[T_meas, theta, port velocity,
y]`` and its inputs ``[T_dist, r]``; ``y`` returns to the cut point with negative sign, so the
loop transfer in the negative-feedback convention 1/(1 + L) is

    L(z) = C[3] (z I - A)^-1 B[:, 1] + D[3, 1],   z = exp(j omega Ts).

Method (per gain point)
-----------------------
1. ``A`` is balanced (diagonal similarity, ``scipy.linalg.matrix_balance``) and diagonalised once,
   A = V diag(lam) V^-1, giving the partial fractions L(z) = d + sum_i r_i / (z - lam_i) with
   residues r_i = (c V)_i (V^-1 b)_i. |L| on the grid then costs O(n) per frequency (evaluated in
   real arithmetic, in cache-sized chunks, as one BLAS product per chunk).
2. The residue evaluation is checked against a direct solve of (z I - A) x = b at 48 frequencies
   across the grid (error max |dL| / max(|L|, 1), i.e. on the scale of |L| = 1). If V is
   defective or so ill-conditioned that the check fails (error above :data:`RESIDUE_TOL`), the
   grid is evaluated instead by a triangular solve in the complex Schur form A = Q T Q^H (the
   Hessenberg-family fallback; backward stable, O(n^2) per frequency). Note: every actuator with
   the averaging velocity filter has a near-defective cluster of eigenvalues around z = 0 (the
   FIR's shift register perturbed by the loop), which makes cond(V) ~ 1e6 after balancing (1e10
   before): the residues are still good to ~1e-11..1e-7 on that scale, enough for the grid,
   since every number reported is refined on the exact solve (step 6).
3. |L|^2 is sampled on :data:`GRID_POINTS` = 200,000 log-spaced frequencies from ``omega_min``
   (0.1 rad/s) to Nyquist pi/Ts (exactly). Samples with | |L|^2 - 1 | within 40x the measured
   grid error are re-evaluated by the exact solve, so no sign is decided by rounding.
4. Hidden pairs at local extrema: at every local maximum of |L| below 1 and every local minimum
   above 1, |L| is maximised / minimised (``scipy.optimize.minimize_scalar``, bounded, on the two
   neighbouring samples, exact solve); an extremum that reaches the other side of 1 becomes an
   extra sample (so a brentq bracket opens on each side of it).
5. Near every pole of L (eigenvalue of A) and every invariant zero of (A, b, c, d) close to the
   unit circle, whose angle theta lies in the grid and whose resonance is narrow (half-width
   | 1 - |p| | / theta in ln(omega) below 20 grid steps: a wider one is resolved by the grid, so
   its extremum is a grid extremum of step 4 and cannot hide a pair between two samples), |L| is
   evaluated at the pole's/zero's angle and maximised (pole) / minimised (zero) over a window of
   a few half-widths plus a few grid steps; these become extra samples too.
6. Every sign change of log|L| between consecutive samples is refined by ``scipy.optimize.brentq``
   in log(omega) on the exact solve (xtol 1e-13), and the phase margin is taken there:
   PM = 180 + arg L, in degrees, wrapped to (-180, 180].

Summary per point (:class:`Crossovers`): ``distance_deg`` = min |PM| over the crossovers (inf when
there is none), ``pm_at_min_deg`` the signed PM at that crossover and ``omega_at_min`` its
frequency in rad/s (NaN when none). Crossovers below ``omega_min`` are not searched (as the
library's grids).

Cost: ~12 ms per point and loop on this machine (n = 10-12 states; ~7 ms of it the grid).

Public API
----------
:func:`crossovers_from_matrices`, :func:`reference_crossovers`, :func:`low_pm_reference`,
:func:`loop_matrices`, :func:`closed_loop_spectral_radius`, :func:`omega_grid`,
:class:`Crossovers`, :class:`LowPM`.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import scipy.linalg
import scipy.optimize

from haa_sym.check import reference
from haa_sym.loop import ClosedLoop

__all__ = ["GRID_POINTS", "OMEGA_MIN", "RESIDUE_TOL", "NEAR_TOL_DEG", "Crossovers", "LowPM",
           "omega_grid", "loop_matrices", "crossovers_from_matrices", "reference_crossovers",
           "low_pm_reference", "closed_loop_spectral_radius"]

GRID_POINTS = 200_000        #: frequencies of the search grid (log-spaced, omega_min .. pi/Ts)
OMEGA_MIN = 0.1              #: lowest frequency of the grid, rad/s (as the library's FrequencyGrid)
RESIDUE_TOL = 1e-6           #: largest relative error of the residue evaluation before the Schur fallback
NEAR_TOL_DEG = 0.05          #: |distance - threshold| below which a low-PM decision is "near"
_CHUNK = 8192                # frequencies per block of the residue evaluation (cache-sized)
_N_CHECK = 48                # check frequencies of the residue evaluation
_CIRCLE_BAND = 0.1           # poles/zeros with | |z| - 1 | below this get a resonance probe
_WIDE_STEPS = 20.0           # a pole/zero resonance wider than this many grid steps needs no probe
_XTOL = 1e-13                # brentq tolerance in log(omega)
_HUGE = 1e300                # log|L| stand-in at a pole on the unit circle


def loop_matrices(loop, P_gain, D_gain, beta=None, alpha=None, cut: str | None = "T_ref"):
    """``(A, B, C, D)`` of the reference closed loop at gain points, stacked over points.

    Parameters
    ----------
    loop : haa_sym.ClosedLoop
        Only its ``params`` and ``options`` are read (by the reference module).
    P_gain : array_like
        Impedance stiffness gains, Nm/rad (flat, any length k >= 1).
    D_gain : array_like
        Impedance damping gains, Nm s/rad (broadcast against ``P_gain``).
    beta, alpha : float, optional
        Torque-gain scale and velocity-compensation gain (dimensionless); default from params.
    cut : {"T_ref", "PI", None}
        Where the loop is opened; None: every loop closed.

    Returns
    -------
    A : (k, n, n) ndarray
    B : (k, n, 2) ndarray
    C : (k, 4, n) ndarray
    D : (k, 4, 2) ndarray
        Sampled closed loop (sampling time ``loop.params.controller.Ts`` s) at each point.

    Uses the module's vectorised ``_batch`` when it exists (one interconnection for all points,
    bit-identical to per-point ``closed_loop_matrices``), else ``closed_loop_matrices`` per point.
    """
    ref = reference
    P, D = np.broadcast_arrays(np.atleast_1d(np.asarray(P_gain, float)).ravel(),
                               np.atleast_1d(np.asarray(D_gain, float)).ravel())
    batch = getattr(ref, "_batch", None)
    if batch is not None:
        try:
            return tuple(np.asarray(m) for m in batch(loop, P, D, beta, alpha, cut))
        except TypeError:
            pass
    mats = [ref.closed_loop_matrices(loop, float(p), float(d), beta, alpha, cut=cut) for p, d in zip(P, D)]
    return tuple(np.stack([m[i] for m in mats]) for i in range(4))


def closed_loop_spectral_radius(loop, P_gain, D_gain, beta=None, alpha=None) -> np.ndarray:
    """max |eig A| of the closed loop (every loop closed) at gain points, dimensionless; < 1 is
    asymptotically stable. From the reference module's matrices."""
    A = loop_matrices(loop, P_gain, D_gain, beta, alpha, cut=None)[0]
    return np.abs(np.linalg.eigvals(A)).max(axis=-1)


# ----------------------------------------------------------------------------------------------
# the grid
# ----------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=8)
def _grid(Ts: float, n: int, omega_min: float):
    w_nyq = math.pi / Ts
    if not 0 < omega_min < w_nyq:
        raise ValueError(f"omega_min = {omega_min} rad/s is not in (0, pi/Ts = {w_nyq})")
    lw = np.linspace(math.log(omega_min), math.log(w_nyq), n)
    w = np.exp(lw)
    w[-1] = w_nyq
    wt = w * Ts
    cos, sin = np.cos(wt), np.sin(wt)
    cos[-1], sin[-1] = -1.0, 0.0
    for a in (lw, w, cos, sin):
        a.setflags(write=False)
    return lw, w, cos, sin


def omega_grid(Ts: float, n: int = GRID_POINTS, omega_min: float = OMEGA_MIN) -> np.ndarray:
    """The search grid, rad/s: ``n`` log-spaced frequencies from ``omega_min`` to pi/``Ts``
    (``Ts`` in s), the last one exactly Nyquist. Read-only, cached."""
    return _grid(float(Ts), int(n), float(omega_min))[1]


def _scaled_error(L, L_exact) -> float:
    """max |L - L_exact| / max(|L_exact|, 1): the error of log|L| where |L| >= 1 and of |L| on
    the scale of 1 below (only the sign of |L| - 1 and extrema near 1 matter; the averaging
    filter's zeros at z = exp(j 2 pi k / N_av) make |L| -> 0 there, where a relative error is
    meaningless)."""
    return float(np.max(np.abs(L - L_exact) / np.maximum(np.abs(L_exact), 1.0)))


def _wrap_pm(L: np.ndarray) -> np.ndarray:
    """180 + arg L in degrees, wrapped to (-180, 180]."""
    pm = np.degrees(np.angle(L)) + 180.0
    pm = (pm + 180.0) % 360.0 - 180.0
    return np.where(pm <= -180.0, 180.0, pm)


# ----------------------------------------------------------------------------------------------
# one loop: evaluators
# ----------------------------------------------------------------------------------------------
class _LoopTransfer:
    """L(z) = c (z I - A)^-1 b + d of one point, balanced; grid and exact evaluators."""

    def __init__(self, A, b, c, d, Ts):
        A = np.asarray(A, float)
        self.n = A.shape[0]
        self.Ts = float(Ts)
        if self.n:
            Ab, (s, _) = scipy.linalg.matrix_balance(A, permute=False, separate=True)
        else:
            Ab, s = A, np.ones(0)
        self.A = Ab
        self.b = np.asarray(b, float) / s
        self.c = np.asarray(c, float) * s
        self.d = float(d)
        self.eye = np.eye(self.n)
        self.n_exact = 0                      # exact evaluations made (cost accounting)

    # exact: a direct (LU, partial pivoting) solve per frequency
    def exact(self, omega) -> np.ndarray:
        """L at frequencies ``omega`` (rad/s) by a direct solve of (z I - A) x = b."""
        omega = np.atleast_1d(np.asarray(omega, float))
        self.n_exact += omega.size
        if not self.n:
            return np.full(omega.shape, self.d, complex)
        z = np.exp(1j * omega * self.Ts)
        M = z[:, None, None] * self.eye - self.A
        with np.errstate(all="ignore"):
            try:
                x = np.linalg.solve(M, np.broadcast_to(self.b[:, None], (z.size, self.n, 1)))[..., 0]
            except np.linalg.LinAlgError:        # a pole exactly on the unit circle at this omega
                x = np.stack([self._solve_one(m) for m in M])
        return x @ self.c + self.d

    def _solve_one(self, M):
        try:
            return np.linalg.solve(M, self.b)
        except np.linalg.LinAlgError:
            return np.full(self.n, np.inf + 0j)

    def exact_logmag(self, x: float) -> float:
        """log|L| at omega = exp(x) (x = ln(omega / (rad/s))); +huge at a pole."""
        self.n_exact += 1
        wt = math.exp(x) * self.Ts
        M = complex(math.cos(wt), math.sin(wt)) * self.eye - self.A
        try:
            L = self.c @ np.linalg.solve(M, self.b) + self.d
        except np.linalg.LinAlgError:
            return _HUGE
        a = abs(L)
        if not np.isfinite(a):
            return _HUGE
        return math.log(a) if a > 0 else -_HUGE

    # grid: residues (O(n) per frequency) or the Schur triangular solve (O(n^2))
    def grid_mag2(self, cos, sin, lw):
        """|L|^2 on the grid (``cos``, ``sin`` of omega Ts; ``lw`` = ln omega; its extrema are
        those of log|L|) and ``(method, error estimate)`` (see :func:`_scaled_error`)."""
        if not self.n:
            return np.full(cos.shape, self.d * self.d), ("constant", 0.0)
        check = np.unique(np.linspace(0, cos.size - 1, _N_CHECK).round().astype(int))
        L_ex = self.exact(np.exp(lw[check]))
        method, err = "residues", np.inf
        try:
            lam, V = np.linalg.eig(self.A)
            r = (self.c @ V) * np.linalg.solve(V, self.b)
            if np.all(np.isfinite(r)):
                err = _scaled_error(self._residue_eval(lam, r, cos[check], sin[check]), L_ex)
        except np.linalg.LinAlgError:
            pass
        if err <= RESIDUE_TOL:
            q = self._residue_eval(lam, r, cos, sin, mag2=True)
        else:
            method = "schur"
            L = self._schur_eval(cos + 1j * sin)
            err = _scaled_error(L[check], L_ex)
            with np.errstate(invalid="ignore", over="ignore"):
                q = L.real * L.real + L.imag * L.imag
        return q, (method, err)

    def _residue_eval(self, lam, r, cos, sin, mag2=False):
        """d + sum_i r_i/(z - lam_i), z = cos + j sin, in real arithmetic, chunked (one BLAS
        product per chunk and part); ``mag2``: its |.|^2 instead (real)."""
        a, b = lam.real[:, None], lam.imag[:, None]
        rr, ri = r.real, r.imag
        out = np.empty(cos.size, float if mag2 else complex)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for s in range(0, cos.size, _CHUNK):
                dr = cos[None, s:s + _CHUNK] - a
                di = sin[None, s:s + _CHUNK] - b
                m = dr * dr
                m += di * di
                np.reciprocal(m, out=m)            # 1/|z - lam|^2
                dr *= m
                di *= m                            # conj(1/(z - lam)) = (dr + j di)/|z - lam|^2
                re = rr @ dr + ri @ di + self.d
                im = ri @ dr - rr @ di
                if mag2:
                    re *= re
                    im *= im
                    re += im
                    out[s:s + _CHUNK] = re
                else:
                    out.real[s:s + _CHUNK] = re
                    out.imag[s:s + _CHUNK] = im
        return out

    def _schur_eval(self, z):
        """c (z I - A)^-1 b + d by back substitution in the complex Schur form, all z at once."""
        T, Q = scipy.linalg.schur(self.A, output="complex")
        y = Q.conj().T @ self.b
        cq = self.c @ Q
        n = self.n
        X = np.empty((n, z.size), complex)
        with np.errstate(divide="ignore", invalid="ignore"):
            X[n - 1] = y[n - 1] / (z - T[n - 1, n - 1])
            for k in range(n - 2, -1, -1):
                X[k] = (y[k] + T[k, k + 1:] @ X[k + 1:]) / (z - T[k, k])
        return cq @ X + self.d

    def circle_features(self):
        """(poles, zeros) of L: eigenvalues of A and finite invariant zeros of (A, b, c, d)."""
        lam = np.linalg.eigvals(self.A) if self.n else np.zeros(0, complex)
        zeros = np.zeros(0, complex)
        if self.n:
            M = np.block([[self.A, self.b[:, None]], [self.c[None, :], np.array([[self.d]])]])
            N = np.zeros_like(M)
            N[:self.n, :self.n] = self.eye
            with np.errstate(all="ignore"):
                ev = scipy.linalg.eigvals(M, N)
            zeros = ev[np.isfinite(ev)]
        return lam, zeros


# ----------------------------------------------------------------------------------------------
# results
# ----------------------------------------------------------------------------------------------
@dataclass
class Crossovers:
    """Every gain crossover of one loop at one gain point.

    Attributes
    ----------
    omega_c : ndarray
        Crossover frequencies |L(exp(j omega Ts))| = 1, increasing, rad/s.
    pm_deg : ndarray
        Phase margin 180 + arg L at each, degrees, wrapped to (-180, 180].
    distance_deg : float
        min |pm_deg|, degrees; inf when |L| never crosses 1 in [omega_min, pi/Ts].
    pm_at_min_deg : float
        Signed phase margin at that crossover, degrees (NaN when none).
    omega_at_min : float
        Its frequency, rad/s (NaN when none).
    method : str
        Grid evaluator used: "residues" (partial fractions) or "schur" (fallback).
    grid_error : float
        Measured relative error of the grid evaluation against the direct solve (dimensionless).
    n_probes : int
        Extra samples added at extrema and near poles/zeros (hidden-pair search).
    n_exact : int
        Direct solves made (refinement cost).
    """

    omega_c: np.ndarray
    pm_deg: np.ndarray
    distance_deg: float
    pm_at_min_deg: float
    omega_at_min: float
    method: str = "residues"
    grid_error: float = 0.0
    n_probes: int = 0
    n_exact: int = 0
    notes: list = field(default_factory=list)

    @property
    def pairs(self) -> list[tuple[float, float]]:
        """[(omega_c rad/s, PM deg), ...] in increasing frequency."""
        return [(float(w), float(p)) for w, p in zip(self.omega_c, self.pm_deg)]

    def to_dict(self) -> dict:
        """JSON-ready dict (inf/NaN as None)."""
        def num(v):
            v = float(v)
            return v if math.isfinite(v) else None
        return {"crossovers": [[float(w), float(p)] for w, p in zip(self.omega_c, self.pm_deg)],
                "distance_deg": num(self.distance_deg), "pm_deg": num(self.pm_at_min_deg),
                "omega_c": num(self.omega_at_min), "method": self.method,
                "grid_error": num(self.grid_error)}


def _summary(omega_c, pm):
    if pm.size == 0:
        return math.inf, math.nan, math.nan
    i = int(np.argmin(np.abs(pm)))            # ties: the lowest frequency
    return float(abs(pm[i])), float(pm[i]), float(omega_c[i])


# ----------------------------------------------------------------------------------------------
# the core: one point
# ----------------------------------------------------------------------------------------------
def crossovers_from_matrices(A, B, C, D, Ts: float, *, n_grid: int = GRID_POINTS,
                             omega_min: float = OMEGA_MIN, out: int = 3, inp: int = 1) -> Crossovers:
    """Every gain crossover of L(z) = C[out] (zI - A)^-1 B[:, inp] + D[out, inp].

    Parameters
    ----------
    A, B, C, D : array_like
        Discrete state space (one point), sampling time ``Ts``.
    Ts : float
        Sampling time, s.
    n_grid : int
        Points of the log search grid from ``omega_min`` to pi/Ts (default 200,000).
    omega_min : float
        Lowest frequency searched, rad/s (default 0.1).
    out, inp : int
        Output and input index of the loop transfer (3 and 1 for the reference module's cuts).

    Returns
    -------
    Crossovers
        All crossovers with omega_min <= omega_c <= pi/Ts (rad/s) and their wrapped phase
        margins (deg), plus the min-|PM| summary.
    """
    A = np.asarray(A, float)
    tf = _LoopTransfer(A, np.asarray(B, float)[:, inp], np.asarray(C, float)[out], np.asarray(D, float)[out, inp], Ts)
    lw, w, cos, sin = _grid(float(Ts), int(n_grid), float(omega_min))
    # f: |L|^2 on the grid (above 1 and extrema as log|L|; the probes below are log|L|, whose
    # sign is that of f - 1; |L|^2 - 1 would flatten to -1 where |L| << 1, and rounding would
    # then make spurious extrema)
    f, (method, err) = tf.grid_mag2(cos, sin, lw)
    notes = []
    # samples the grid evaluation cannot decide (within its error of |L| = 1, or not finite)
    tol = max(40.0 * err, 1e-10)
    bad = np.flatnonzero(~np.isfinite(f) | (np.abs(f - 1.0) < tol))
    if bad.size:
        with np.errstate(invalid="ignore", over="ignore"):
            a = np.abs(tf.exact(w[bad]))
            f[bad] = np.where(np.isfinite(a), a * a, _HUGE)
    g = tf.exact_logmag
    lo_x, hi_x = lw[0], lw[-1]
    probes_x, probes_f = [], []

    def add_probe(x, fx):
        probes_x.append(float(x))
        probes_f.append(float(fx))

    # 4. local extrema on the wrong side of |L| = 1 (a pair of crossovers may hide there)
    df = np.diff(f)
    inner = np.arange(1, f.size - 1)
    is_max = (df[:-1] >= 0) & (df[1:] < 0) & (f[1:-1] < 1)
    is_min = (df[:-1] <= 0) & (df[1:] > 0) & (f[1:-1] > 1)
    for k, sign in [(k, 1.0) for k in inner[is_max]] + [(k, -1.0) for k in inner[is_min]]:
        res = scipy.optimize.minimize_scalar(lambda x: -sign * g(x), bounds=(lw[k - 1], lw[k + 1]),
                                             method="bounded", options={"xatol": 1e-12})
        fx = -sign * res.fun
        if sign * fx > 0:                      # the maximum exceeds 1 / the minimum dips below 1
            add_probe(res.x, fx)
    # 5. resonances narrower than the grid: poles (peaks) and zeros (notches) near the circle
    poles, zeros = tf.circle_features()
    h = (hi_x - lo_x) / (f.size - 1)           # grid step in ln(omega)
    for feats, sign in ((poles, 1.0), (zeros, -1.0)):
        for p in feats:
            rho = abs(p)
            if not abs(rho - 1.0) < _CIRCLE_BAND:
                continue
            theta = abs(math.atan2(p.imag, p.real))
            wp = theta / tf.Ts
            if not (w[0] <= wp <= w[-1]):
                continue
            xp = math.log(wp)
            width = abs(1.0 - rho) / max(theta, 1e-300)     # resonance half-width, in ln(omega)
            if width > _WIDE_STEPS * h:
                continue          # resolved by the grid: its extremum is a grid extremum (step 4)
            half = 4.0 * width + 3.0 * h                         # window, in ln(omega)
            a_x, b_x = max(lo_x, xp - half), min(hi_x, xp + half)
            add_probe(xp, g(xp))
            if b_x > a_x:
                res = scipy.optimize.minimize_scalar(lambda x: -sign * g(x), bounds=(a_x, b_x),
                                                     method="bounded", options={"xatol": 1e-13})
                add_probe(res.x, -sign * res.fun)
    n_probes = len(probes_x)
    # 6. every sign change between consecutive samples (grid and probes), refined by brentq;
    # the probes split their grid intervals (inserted by searchsorted, the grid stays sorted)
    pos = f > 1
    change = pos[1:] != pos[:-1]
    brackets = []
    if probes_x:
        px, pf = np.asarray(probes_x), np.asarray(probes_f)
        o = np.argsort(px)
        px, pf = px[o], pf[o]
        kk = np.clip(np.searchsorted(lw, px, side="right") - 1, 0, f.size - 2)
        for k in np.unique(kk):
            sel = kk == k
            xs = np.concatenate([[lw[k]], px[sel], [lw[k + 1]]])
            ps = np.concatenate([[pos[k]], pf[sel] > 0, [pos[k + 1]]])
            j = np.flatnonzero(ps[1:] != ps[:-1])
            brackets += list(zip(xs[j], xs[j + 1]))
            change[k] = False
    brackets += list(zip(lw[:-1][change], lw[1:][change]))
    roots = []
    for a_x, b_x in brackets:
        if b_x <= a_x:
            continue
        fa, fb = g(a_x), g(b_x)
        if fa == 0.0:
            roots.append(a_x)
            continue
        if (fa > 0) == (fb > 0):                # the grid's sign was wrong (cannot happen after
            notes.append(f"no bracket at omega {math.exp(a_x):.6g}")   # the re-evaluation)
            continue
        roots.append(scipy.optimize.brentq(g, a_x, b_x, xtol=_XTOL, rtol=4 * np.finfo(float).eps))
    roots = np.unique(np.asarray(roots, float))
    if roots.size > 1:                          # one root found from two brackets (a probe on it)
        keep = np.concatenate([[True], np.diff(roots) > 10 * _XTOL])
        roots = roots[keep]
    omega_c = np.exp(roots)
    L = tf.exact(omega_c) if roots.size else np.zeros(0, complex)
    pm = _wrap_pm(L)
    dist, pm_min, w_min = _summary(omega_c, pm)
    return Crossovers(omega_c, pm, dist, pm_min, w_min, method, err, n_probes, tf.n_exact, notes)


# ----------------------------------------------------------------------------------------------
# gain points
# ----------------------------------------------------------------------------------------------
def reference_crossovers(loop, P_gain, D_gain, beta=None, alpha=None, cut: str = "T_ref", *,
                         n_grid: int = GRID_POINTS, omega_min: float = OMEGA_MIN) -> list[Crossovers]:
    """All gain crossovers of a loop at gain points.

    Parameters
    ----------
    loop : haa_sym.ClosedLoop
        Carries ``params`` and ``options`` (build it with ``basis=False``).
    P_gain : array_like
        Impedance stiffness, Nm/rad.
    D_gain : array_like
        Impedance damping, Nm s/rad (broadcast against ``P_gain``).
    beta, alpha : float, optional
        Torque-gain scale and velocity-compensation gain (dimensionless); default from params.
    cut : {"T_ref", "PI"}
        "T_ref": the impedance loop opened at the torque reference; "PI": the torque loop opened
        at the PI output (impedance loop closed).
    n_grid : int
        Search-grid size (default 200,000).
    omega_min : float
        Lowest frequency searched, rad/s (default 0.1).

    Returns
    -------
    list of Crossovers
        One per point, in the flattened order of the broadcast gains.
    """
    if cut not in ("T_ref", "PI"):
        raise ValueError(f"cut = {cut!r}; allowed: 'T_ref' (impedance loop) or 'PI' (torque loop)")
    A, B, C, D = loop_matrices(loop, P_gain, D_gain, beta, alpha, cut)
    Ts = loop.params.controller.Ts
    return [crossovers_from_matrices(A[i], B[i], C[i], D[i], Ts, n_grid=n_grid, omega_min=omega_min)
            for i in range(A.shape[0])]


class LowPM(NamedTuple):
    """Low-phase-margin decisions of :func:`low_pm_reference` (flat arrays, one per point).

    ``low``: distance (min |wrapped PM|, deg) < threshold. ``near``: |distance - threshold| <
    ``near_tol`` deg (do not compare ``low`` there). ``low_signed``: the signed PM at the
    min-|PM| crossover < threshold (the maps' ``pm_rule = "min_abs"`` decision, which also calls
    a crossover with PM = -100 deg low); ``near_signed``: that decision is within ``near_tol`` of
    flipping (the signed PM near the threshold, or two crossovers whose |PM| differ by less than
    ``2 near_tol`` with different decisions). ``distance_deg`` (inf: no crossover),
    ``pm_deg`` (NaN: none), ``omega_c`` rad/s (NaN: none), ``crossovers``: the full results.
    """

    low: np.ndarray
    near: np.ndarray
    distance_deg: np.ndarray
    pm_deg: np.ndarray
    omega_c: np.ndarray
    low_signed: np.ndarray
    near_signed: np.ndarray
    crossovers: list


def low_pm_reference(params, options, P_gain, D_gain, beta=None, alpha=None, threshold: float = 30.0,
                     *, near_tol: float = NEAR_TOL_DEG, cut: str | None = None, loop=None,
                     n_grid: int = GRID_POINTS) -> LowPM:
    """Reference low-phase-margin decisions at gain points.

    Parameters
    ----------
    params : haa_sym.Params
    options : haa_sym.LoopOptions or None
        Loop structure; ``conventions.pm_loop`` picks the loop ("impedance": cut at T_ref,
        "torque": cut at the PI output) unless ``cut`` is given.
    P_gain : array_like
        Impedance stiffness, Nm/rad.
    D_gain : array_like
        Impedance damping, Nm s/rad.
    beta, alpha : float, optional
        Torque-gain scale and velocity-compensation gain; default from params.
    threshold : float
        Phase-margin threshold, degrees (default 30, the maps' PM_THRESHOLD_DEG).
    near_tol : float
        Half-width of the undecidable band around the threshold, degrees (default 0.05).
    cut : {"T_ref", "PI"}, optional
        Override of the loop.
    loop : haa_sym.ClosedLoop, optional
        Reuse a loop built from ``params``/``options`` (with ``basis=False``).
    n_grid : int
        Search-grid size (default 200,000).

    Returns
    -------
    LowPM
        ``low`` = min |wrapped PM| < threshold (False when |L| never crosses 1), ``near``, and the
        per-point numbers; see :class:`LowPM`. Stability is not judged here (the maps decide PM
        only at stable points; see :func:`closed_loop_spectral_radius`).
    """
    if loop is None:
        loop = ClosedLoop(params, options, basis=False)
    if cut is None:
        cut = "T_ref" if loop.options.conventions.pm_loop == "impedance" else "PI"
    res = reference_crossovers(loop, P_gain, D_gain, beta, alpha, cut, n_grid=n_grid)
    dist = np.array([r.distance_deg for r in res])
    pm = np.array([r.pm_at_min_deg for r in res])
    wc = np.array([r.omega_at_min for r in res])
    low = dist < threshold
    near = np.abs(dist - threshold) < near_tol
    with np.errstate(invalid="ignore"):
        low_signed = pm < threshold
    near_signed = np.zeros(len(res), bool)
    for i, r in enumerate(res):
        if not r.pm_deg.size:
            continue
        a = np.abs(r.pm_deg)
        if abs(r.pm_at_min_deg - threshold) < near_tol:
            near_signed[i] = True
        # the rule could pick another crossover with a different decision
        rivals = (a - a.min() < 2 * near_tol) & ((r.pm_deg < threshold) != low_signed[i])
        near_signed[i] |= bool(rivals.any())
    return LowPM(low, near, dist, pm, wc, low_signed, near_signed, res)
