"""The full region map against a python-control and a numpy baseline, side by side in one run.

The map: 200 x 200 points, P_gain log 1..20000 Nm/rad x D_gain lin 1..50 Nms/rad, nominal
(N_av = 4, closed-loop order 12) and N_av = 50 (order 58). Every path decides, at every point it
sees, the three things of the map (``haa_sym.analysis.regions``) by the map's own rules:

* stability: every closed-loop pole in |z| < 1;
* PM < 30 deg: the phase margin of the impedance loop L_imp (opened at the torque reference),
  180 + arg L_imp wrapped to (-180, 180] at every gain crossover |L_imp| = 1 in the band
  omega_min..Nyquist, judged by the options' ``pm_rule`` (default ``"distance"``: min over the
  crossovers of |PM| < 30 deg); judged on stable points only. haa_sym locates every crossover
  exactly (``haa_sym.analysis.margins``: bilinear polynomials, grid augmented around lightly
  damped poles and zeros, hidden pairs searched, Illinois to 1e-12 in ln omega). Until the
  loop-first API, haa_sym's maps (and these baselines) took the crossover of smallest |PM|
  interpolated between the samples of the frequency grid (``pm_rule = "min_abs"``): the
  maps' times now include locating the crossovers exactly, which costs more than that
  interpolation did, so they are not comparable with numbers measured before;
* passive: stable, and the phase of the port impedance Z = T_dist / port velocity, corrected by
  Colgate's exp(-j w Ts/2) (``haa_sym.analysis.sweep.colgate_factor``), within +-90 deg (+ the options'
  ``passivity_tol_deg``) at every frequency of the grid.

The frequency grid is the maps' (``loop.options.numerics.omega(Ts)``: 1000 log points from
0.1 rad/s to Nyquist) for every path. The baselines:

(1) python-control, per point, used competently: at each of ``N_SAMPLE`` points spread over the
    map (a jittered 5 x 4 lattice of grid indices), the closed loop is built once as a discrete
    ``control.StateSpace`` (dt = Ts) from the explicit closed-loop matrices
    (``ClosedLoop.to_statespace``), ``poles()`` decides stability; the phase margins come from
    python-control's own margin routine, ``control.stability_margins(L_imp, returnall=True)``
    (every crossover; method "best": python-control's own accuracy check sends these loops
    from the "poly" method, whose z-polynomials of degree 2n are tens of degrees off here, to
    its "frd" method, a smoothed spline of the response on python-control's default frequency
    range with its crossovers root-found; the crossovers outside omega_min..Nyquist dropped,
    the options' rule applied); ``control.frequency_response`` of T_dist -> port velocity (1/Z)
    on the maps' grid gives the phase of Z. Each point is timed once; an unstable point stops
    after ``poles()``, so the whole-map time is EXTRAPOLATED from the sample's mean times of
    stable and of unstable points, weighted by the numbers of stable and unstable points of the
    grid map.
(2) numpy, the whole map batched the best way numpy allows: stability from stacked
    ``numpy.linalg.eigvals`` of A(P, D) = A0 + P A1 + D A2 (built by broadcasting from the
    explicit closed loop of ``haa_sym.check.reference``; building A0, A1, A2 is not timed); the
    frequency responses from the state space too, but only at three gain points: every feedback
    path enters through the one input V_m, so the characteristic polynomial and the numerator
    of the port velocity are affine in (P, D) (matrix determinant lemma) and
    1 + L_imp = chi / chi(0, 0). Hence L_imp = P L_10 + D L_01 and
    Z = (1 + P L_10 + D L_01) / (M_00 + P (M_10 - M_00) + D (M_01 - M_00)) with
    M_k = (1 + L_k) H_v,k (H_v: T_dist -> port velocity) from ``numpy.linalg.solve`` at the
    1000 frequencies (per configuration, like haa_sym's cached loop coefficients: timed and
    printed apart, not in the map's time), then one small matrix product per chunk of points
    and the two reductions above written in plain numpy. The phase margins are exact, like
    haa_sym's: L_imp is sampled on the maps' grid augmented with samples omega_f + k sigma_f
    (k = 0, +-1/4, +-1/2, +-1, +-2, +-4) around every lightly damped pole of the opened loop
    (the eigenvalues of its A, per configuration, in the setup time), every sign change of |L_imp| - 1
    is a bracket, refined by the Illinois method to 1e-12 in ln omega with L_imp evaluated
    exactly at each trial frequency (C (zI - A)^-1 B of the opened loop, whose A, B do not
    depend on the gains: one stacked ``numpy.linalg.solve`` per Illinois step for all the
    brackets of a chunk). Unlike haa_sym it does not search for pairs of crossovers hidden
    between two samples (a peak of |L_imp| just above 1 not sampled) nor sample around the
    zeros: its disagreements are printed.
    Chunks run on the same threads as haa_sym's maps (``SWEEP_THREADS``, BLAS on one
    thread). Only stability is per point here; the issue's 1.4-6 ms per point evaluated each
    point's polynomials and was not batched.
(3) haa_sym: ``region_map(loop, P, D, method="grid")`` with the generated grid evaluators
    (certified Routh-Hurwitz test, exact phase margins, passivity sweep), and
    ``region_map(loop, P, D, method="curves")`` (the default), the map from the exact curves
    (stability, PM and passivity). The ``ClosedLoop`` is built once per configuration, outside
    every timing.

Every ratio printed names its baseline. Decisions of every path are compared with the grid map's
on every point they share, and disagreements are printed, not dropped. In-process timings are
the best of ``REPEATS`` except where one run already takes tens of seconds (numpy at N_av = 50:
one run; python-control: one timing per point). Prints a table, writes
``results_baselines.json`` into ``$HAA_SYM_BENCH_DIR`` (default ``bench-results/``, git-ignored). Usage: python benchmarks/bench_baselines.py
"""
from __future__ import annotations

import sys
import time
import warnings
from concurrent.futures import ThreadPoolExecutor

import control as ct
import numpy as np

from timing import REPEATS, Run, best
from haa_sym import ClosedLoop, grid, load_params, region_map
from haa_sym.analysis.margins import PM_THRESHOLD_DEG
from haa_sym.analysis.sweep import BLAS_THREADS, CHUNK, SWEEP_THREADS, blas_limits, colgate_factor
from haa_sym.check.reference import closed_loop_matrices

N_SAMPLE = 20                      # python-control points per configuration (5 x 4 lattice)
BAND = 1e-6                        # |rho - 1| below this: a pole on the circle, not compared
CONFIGS = (("nominal (N_av = 4)", {}), ("N_av = 50", {"N_av": 50}))
XTOL = 1e-12                       # Illinois stops at this bracket width in ln omega
# offsets (multiples of the bandwidth sigma) sampled around each lightly damped pole of L_imp
POLE_OFFSETS = np.array([0.0, 0.25, 0.5, 1.0, 2.0, 4.0])


def chunked(fn, n, chunk=CHUNK):
    """fn(slice) over [0, n) in chunks on SWEEP_THREADS threads, BLAS on BLAS_THREADS: the
    resources haa_sym's region map uses."""
    chunks = [slice(s, min(s + chunk, n)) for s in range(0, n, chunk)]
    with blas_limits(BLAS_THREADS), ThreadPoolExecutor(SWEEP_THREADS) as pool:
        list(pool.map(fn, chunks))


# --- the map's rules, written in plain numpy for the baselines ---------------------------------

def wrap_deg(pm):
    """Angles (deg) wrapped to (-180, 180]."""
    m = (np.asarray(pm, float) + 180.0) % 360.0 - 180.0
    return np.where(m == -180.0, 180.0, m)


def judge(point, omega_c, margin, n, rule):
    """Per point of ``n``, from its crossovers (flat ``point`` index, frequency ``omega_c``,
    wrapped margin deg): the signed margin of the crossover nearest -1 (smallest |PM|, the
    lower frequency on ties; NaN without crossover) and whether the margin is below
    PM_THRESHOLD_DEG by ``rule`` ("distance": min |PM|; "min_abs": that signed margin;
    "worst": the smallest signed margin)."""
    pm, low = np.full(n, np.nan), np.zeros(n, bool)
    if point.size == 0:
        return pm, low
    a = np.abs(margin)
    order = np.lexsort((omega_c, a, point))
    first = order[np.unique(point[order], return_index=True)[1]]
    pm[point[first]] = margin[first]
    if rule == "distance":
        low[point[first]] = a[first] < PM_THRESHOLD_DEG
    elif rule == "min_abs":
        low[point[first]] = margin[first] < PM_THRESHOLD_DEG
    else:
        worst = np.full(n, np.inf)
        np.minimum.at(worst, point, margin)
        low = worst < PM_THRESHOLD_DEG
    return pm, low


def excess_deg(W: np.ndarray) -> np.ndarray:
    """max over omega of |phase of W| - 90 deg, per row of ``W`` (k, n_omega), W any complex
    array with the phase of the corrected Z (Z exp(-j w Ts/2), or num conj(den) exp(-j w Ts/2))."""
    return np.degrees(np.abs(np.angle(W)).max(axis=1)) - 90.0


# --- (1) python-control, per point --------------------------------------------------------------

def sample_indices(n_P: int, n_D: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Grid indices of N_SAMPLE points spread over the map: one per cell of a 5 x 4 lattice,
    jittered inside it."""
    rng = np.random.default_rng(seed)
    cP, cD = 5, N_SAMPLE // 5
    iP = ((np.arange(cP)[:, None] + rng.uniform(0.1, 0.9, (cP, cD))) * n_P / cP).astype(int)
    iD = ((np.arange(cD)[None, :] + rng.uniform(0.1, 0.9, (cP, cD))) * n_D / cD).astype(int)
    return iP.ravel(), iD.ravel()


def control_point(loop: ClosedLoop, P: float, D: float, omega: np.ndarray, colgate: np.ndarray):
    """One point with python-control: (stable, PM deg, low PM, passivity excess deg)."""
    closed = loop.to_statespace(P, D)                            # every loop closed
    stable = bool(np.all(np.abs(closed.poles()) < 1))
    if not stable:
        return False, np.nan, False, np.nan
    L = loop.to_statespace(P, D, cut="T_ref")["y", "r"]
    with warnings.catch_warnings():                              # "falling back to 'frd'"
        warnings.simplefilter("ignore", UserWarning)
        _, pm, _, _, wgc, _ = ct.stability_margins(L, returnall=True)
    pm, wgc = np.atleast_1d(np.asarray(pm, float)), np.atleast_1d(np.asarray(wgc, float))
    keep = np.isfinite(pm) & (wgc >= omega[0]) & (wgc <= np.pi / loop.params.controller.Ts)
    pm_c, low = judge(np.zeros(int(keep.sum()), int), wgc[keep], wrap_deg(pm[keep]), 1,
                      loop.options.conventions.pm_rule)
    H_v = ct.frequency_response(closed["port_velocity", "T_dist"], omega).complex
    return True, float(pm_c[0]), bool(low[0]), float(excess_deg((colgate / H_v)[None])[0])


def python_control_baseline(loop, P_grid, D_grid, omega, colgate):
    iP, iD = sample_indices(P_grid.size, D_grid.size)
    times, res = [], []
    for i, j in zip(iP, iD):
        t = time.perf_counter()
        res.append(control_point(loop, P_grid[i], D_grid[j], omega, colgate))
        times.append(time.perf_counter() - t)
    st, pm, low, ex = (np.array(v) for v in zip(*res))
    return np.array(times), iP, iD, st, pm, low, ex


# --- (2) numpy, the whole map batched ----------------------------------------------------------

def numpy_model(loop):
    """The gain-independent state-space data of the numpy baseline (not timed: the model)."""
    m = {key: closed_loop_matrices(loop, P, D) for key, (P, D) in
         (("00", (0.0, 0.0)), ("10", (1.0, 0.0)), ("01", (0.0, 1.0)))}
    A0 = m["00"][0]
    return {"A": (A0, m["10"][0] - A0, m["01"][0] - A0), "closed": m,
            "cut": {key: closed_loop_matrices(loop, P, D, cut="T_ref") for key, (P, D) in
                    (("10", (1.0, 0.0)), ("01", (0.0, 1.0)))}}


def _response(ABCD, z, out, inp):
    A, B, C, D = ABCD
    X = np.linalg.solve(z[:, None, None] * np.eye(A.shape[0]) - A,
                        np.broadcast_to(B[:, inp], (z.size, A.shape[0]))[..., None])[..., 0]
    return X @ C[out] + D[out, inp]


def cut_loop(model):
    """L_imp's two gain components (l_10, l_01) as (A, b, c, d): C (zI - A)^-1 B + D of the loop
    opened at the torque reference (its state matrix, B and the feedthrough do not depend on
    the gains: one solve per frequency gives both)."""
    (A, B, C1, D1), (A2, _, C2, D2) = model["cut"]["10"], model["cut"]["01"]
    assert np.array_equal(A, A2)
    return A, B[:, 1], np.stack([C1[3], C2[3]]), np.array([D1[3, 1], D2[3, 1]])


def cut_response(cl, z):
    """(l_10, l_01) at the points ``z`` (m,): (m, 2) complex, one stacked
    ``numpy.linalg.solve`` of (zI - A) x = b."""
    A, b, c, d = cl
    X = np.linalg.solve(z[:, None, None] * np.eye(A.shape[0]) - A,
                        np.broadcast_to(b, (z.size, A.shape[0]))[..., None])[..., 0]
    return X @ c.T + d


def augmented_grid(cl, omega, Ts):
    """The maps' grid plus omega_f + k sigma_f around every lightly damped pole of L_imp
    (sigma_f < 0.3 omega_f), within the grid's band."""
    z = np.linalg.eigvals(cl[0])
    z = z[np.abs(z) > 0]
    w, sig = np.abs(np.angle(z)) / Ts, np.abs(np.log(np.abs(z))) / Ts
    keep = (w > omega[0]) & (w < omega[-1]) & (sig < 0.3 * w)
    k = np.concatenate([-POLE_OFFSETS[1:], POLE_OFFSETS])
    extra = (w[keep, None] + sig[keep, None] * k).ravel()
    out = np.unique(np.concatenate([omega, extra]))
    return out[(out >= omega[0]) & (out <= omega[-1])]


def numpy_responses(model, omega, Ts):
    """Per configuration: the gain-affine coefficients on x = (1, P, D) of L_imp = x.Lc on the
    augmented grid ``w_aug`` and of Z = x.Zn / x.Zd on the maps' grid, and the opened loop
    for the exact crossovers."""
    cl = cut_loop(model)
    w_aug = augmented_grid(cl, omega, Ts)
    l = cut_response(cl, np.exp(1j * w_aug * Ts))
    Lc = np.stack([np.zeros(w_aug.size, complex), l[:, 0], l[:, 1]], axis=1)
    z = np.exp(1j * omega * Ts)
    L = {"00": np.zeros(z.size, complex)}
    for key in ("10", "01"):
        L[key] = _response(model["cut"][key], z, 3, 1)          # r -> y, loop opened at T_ref
    # port velocity per unit T_dist, times chi / chi(0, 0) = 1 + L: affine in (P, D)
    M = {key: (1 + L[key]) * _response(model["closed"][key], z, 2, 0) for key in ("00", "10", "01")}
    Zn = np.stack([np.ones(z.size, complex), L["10"], L["01"]], axis=1)
    Zd = np.stack([M["00"], M["10"] - M["00"], M["01"] - M["00"]], axis=1)
    return {"Lc": Lc, "w_aug": w_aug, "cl": cl, "Zn": Zn, "Zd": Zd}


def numpy_stability(model, P, D):
    """Spectral radius of every point by stacked eigvals (chunked, threaded)."""
    A0, A1, A2 = model["A"]
    rho = np.empty(P.size)

    def work(sl):
        A = A0 + P[sl, None, None] * A1 + D[sl, None, None] * A2
        rho[sl] = np.abs(np.linalg.eigvals(A)).max(axis=1)
    chunked(work, P.size)
    return rho


def illinois(f, a, b, fa, fb):
    """Illinois regula falsi on every bracket [a, b] (f(a), f(b) of opposite signs) to XTOL;
    ``f(i, x)`` evaluates the brackets ``i`` at ``x``. Returns the last iterates."""
    a, b, fa, fb = (np.array(v, float) for v in (a, b, fa, fb))
    act = np.flatnonzero(np.abs(b - a) > XTOL)
    for _ in range(100):
        if not act.size:
            break
        A, B, FA, FB = a[act], b[act], fa[act], fb[act]
        with np.errstate(invalid="ignore", divide="ignore"):
            x = (A * FB - B * FA) / (FB - FA)
        x = np.where(np.isfinite(x) & (x > np.minimum(A, B)) & (x < np.maximum(A, B)), x, 0.5 * (A + B))
        fx = f(act, x)
        flip = np.sign(fx) != np.sign(FB)                      # the root is between x and b
        a[act] = np.where(flip, B, A)
        fa[act] = np.where(flip, FB, 0.5 * FA)
        b[act], fb[act] = x, fx
        act = act[(np.abs(x - a[act]) > XTOL) & (fx != 0)]
    return b


def numpy_margins(responses, P, D, stable, omega, colgate, rule, Ts):
    """PM (signed, of the crossover nearest -1), low PM by ``rule`` and passivity excess on the
    stable points (NaN / False elsewhere), from :func:`numpy_responses`."""
    Lc, w_aug, cl, Zn, Zd = (responses[k] for k in ("Lc", "w_aug", "cl", "Zn", "Zd"))
    lw = np.log(w_aug)
    idx = np.flatnonzero(stable)
    pm, ex, low = np.full(P.size, np.nan), np.full(P.size, np.nan), np.zeros(P.size, bool)

    def work(sl):
        i = idx[sl]
        X = np.stack([np.ones(i.size), P[i], D[i]], axis=1)
        L = X @ Lc.T
        logmag = np.log(np.maximum((L * np.conj(L)).real, np.finfo(float).tiny))
        above = logmag > 0
        r, k = np.nonzero(above[:, 1:] != above[:, :-1])

        def f(j, x):
            l = cut_response(cl, np.exp(1j * np.exp(x) * Ts))
            Lx = X[r[j], 1] * l[:, 0] + X[r[j], 2] * l[:, 1]
            return np.log(np.maximum((Lx * np.conj(Lx)).real, np.finfo(float).tiny))
        x = illinois(f, lw[k], lw[k + 1], logmag[r, k], logmag[r, k + 1])
        l = cut_response(cl, np.exp(1j * np.exp(x) * Ts))
        Lx = X[r, 1] * l[:, 0] + X[r, 2] * l[:, 1]
        pm[i], low[i] = judge(r, np.exp(x), wrap_deg(np.degrees(np.angle(Lx)) + 180.0), i.size, rule)
        ex[i] = excess_deg((X @ Zn.T) * np.conj(X @ Zd.T) * colgate)
    chunked(work, idx.size)
    return pm, low, ex


# --- comparison ------------------------------------------------------------------------------

def compare(name, ref, stable, low_pm, passive, pm=None, ex=None, skip=None):
    """Disagreements of one path with the grid map ``ref`` on the points given (flat arrays
    aligned with ``ref``'s flat points; ``skip``: points not compared, e.g. |rho - 1| < BAND)."""
    keep = np.ones(stable.shape, bool) if skip is None else ~skip
    out = {"path": name, "compared": int(keep.sum())}
    for key, mine in (("stable", stable), ("low_pm", low_pm), ("passive", passive)):
        bad = np.flatnonzero(keep & (mine != ref[key]))
        out[f"{key}_disagree"] = int(bad.size)
        out[f"{key}_disagree_points"] = [[float(ref["P"][i]), float(ref["D"][i])] for i in bad[:10]]
    for key, mine in (("pm", pm), ("excess", ex)):
        if mine is not None:
            both = keep & np.isfinite(mine) & np.isfinite(ref[key])
            out[f"max_abs_{key}_diff_deg"] = float(np.abs(mine - ref[key])[both].max()) if both.any() else None
    return out


def run_config(label, changes, P_grid, D_grid):
    params = load_params().with_values(**changes)
    loop = ClosedLoop(params)
    ctrl, conv = params.controller, loop.options.conventions
    omega = loop.options.numerics.omega(ctrl.Ts)
    colgate = colgate_factor(omega, ctrl.Ts, conv.colgate)
    PP, DD = np.meshgrid(P_grid, D_grid, indexing="ij")
    P, D = PP.ravel(), DD.ravel()
    n = P.size
    region_map(loop, P_grid[:4], D_grid[:4], method="grid", progress=False)   # load outside timing

    # (3) haa_sym
    t_stab, _ = best(lambda: loop.stability(P, D))
    t_grid, m = best(lambda: region_map(loop, P_grid, D_grid, method="grid", progress=False))
    t_curves, c = best(lambda: region_map(loop, P_grid, D_grid, method="curves", progress=False))
    ref = {"P": P, "D": D, "stable": m.stable.ravel(), "low_pm": m.low_pm.ravel(),
           "passive": m.passive.ravel(), "pm": m.phase_margin_deg.ravel(), "excess": m.phase_excess_deg.ravel()}

    # (2) numpy
    model = numpy_model(loop)
    rep = REPEATS if loop.degree < 30 else 1
    # like haa_sym's loop coefficients and loop polynomials (computed once per loop and cached),
    # the three-point responses, L_imp's poles and augmented grid are per-configuration data:
    # timed apart, not in the map's time
    t_np_setup, responses = best(lambda: numpy_responses(model, omega, ctrl.Ts))
    t_eig, rho = best(lambda: numpy_stability(model, P, D), rep)
    np_stable = rho < 1
    t_np_freq, (np_pm, np_low, np_ex) = best(lambda: numpy_margins(responses, P, D, np_stable, omega,
                                                                   colgate, conv.pm_rule, ctrl.Ts), rep)
    with np.errstate(invalid="ignore"):
        np_pas = np_stable & (np_ex <= conv.passivity_tol_deg)
    on_circle = np.abs(rho - 1) < BAND

    # (1) python-control
    times, iP, iD, pc_st, pc_pm, pc_low, pc_ex = python_control_baseline(loop, P_grid, D_grid, omega, colgate)
    flat = iP * D_grid.size + iD
    sub = {k: v[flat] for k, v in ref.items()}
    with np.errstate(invalid="ignore"):
        pc_pas = pc_st & (pc_ex <= conv.passivity_tol_deg)
    # unstable points stop after poles(): extrapolate each kind by its count in the grid map
    n_st = int(m.stable.sum())
    t_pc_st = float(times[pc_st].mean()) if pc_st.any() else float(times.mean())
    t_pc_un = float(times[~pc_st].mean()) if (~pc_st).any() else float(times.mean())
    t_pc_map = t_pc_st * n_st + t_pc_un * (n - n_st)

    t_np = t_eig + t_np_freq
    row = {
        "config": label, "points": n, "closed_loop_order": loop.degree, "n_omega": omega.size,
        "repeats": {"haa_sym": REPEATS, "numpy": rep, "python_control": 1},
        "haa_sym_stability_map_s": t_stab,
        "haa_sym_full_map_grid_s": t_grid,
        "haa_sym_full_map_curves_s": t_curves,
        "pm_rule": conv.pm_rule,
        "numpy_augmented_grid_points": int(responses["w_aug"].size),
        "numpy_eigvals_stability_s": t_eig,
        "numpy_freq_responses_pm_passivity_s": t_np_freq,
        "numpy_full_map_s": t_np,
        "numpy_setup_per_configuration_s": t_np_setup,
        "numpy_per_point_ms": 1e3 * t_np / n,
        "python_control_per_point_s": t_pc_map / n,
        "python_control_per_stable_point_s": t_pc_st,
        "python_control_per_unstable_point_s": t_pc_un,
        "python_control_sample_points": N_SAMPLE,
        "python_control_sample_stable": int(pc_st.sum()),
        "python_control_full_map_extrapolated_s": t_pc_map,
        "ratios": {
            "grid map vs python-control per point (extrapolated)": t_pc_map / t_grid,
            "curves map vs python-control per point (extrapolated)": t_pc_map / t_curves,
            "grid map vs numpy stacked eigvals + batched freq responses": t_np / t_grid,
            "curves map vs numpy stacked eigvals + batched freq responses": t_np / t_curves,
            "stability map vs numpy stacked eigvals (stability only)": t_eig / t_stab,
        },
        "agreement_with_grid_map": [
            compare("curves map", ref, c.stable.ravel(), c.low_pm.ravel(), c.passive.ravel(),
                    c.phase_margin_deg.ravel(), c.phase_excess_deg.ravel()),
            compare("numpy", ref, np_stable, np_low, np_pas, np_pm, np_ex, skip=on_circle),
            compare("python-control sample", sub, pc_st, pc_low, pc_pas, pc_pm, pc_ex),
        ],
        "numpy_points_on_circle_not_compared": int(on_circle.sum()),
        "curves_map_vs_numpy_eigvals_stable_disagree": int(((c.stable.ravel() != np_stable) & ~on_circle).sum()),
        "map_fractions": {"stable": float(m.stable.mean()), "low_pm": float(m.low_pm.mean()),
                          "passive": float(m.passive.mean())},
    }
    return row


def print_row(r):
    print(f"\n{r['config']}: closed-loop order {r['closed_loop_order']}, {r['points']} points, "
          f"{r['n_omega']} frequencies")
    print(f"  haa_sym full map, grid evaluators             {r['haa_sym_full_map_grid_s']:9.3f} s")
    print(f"  haa_sym full map, curves                      {r['haa_sym_full_map_curves_s']:9.3f} s")
    print(f"  haa_sym stability map only                    {r['haa_sym_stability_map_s']:9.3f} s")
    print(f"  numpy, whole map batched                      {r['numpy_full_map_s']:9.3f} s  "
          f"(eigvals {r['numpy_eigvals_stability_s']:.3f} s + freq. responses "
          f"{r['numpy_freq_responses_pm_passivity_s']:.3f} s; {r['numpy_per_point_ms']:.3f} ms/point)")
    print(f"  numpy setup per configuration                 {r['numpy_setup_per_configuration_s']:9.3f} s  "
          "(responses at 3 gain points, L_imp's poles and augmented grid of "
          f"{r['numpy_augmented_grid_points']} frequencies; not in the map time, like haa_sym's cached "
          "loop coefficients)")
    print(f"  python-control per point                      {r['python_control_per_point_s']:9.3f} s  "
          f"({r['python_control_per_stable_point_s']:.3f} s stable, "
          f"{r['python_control_per_unstable_point_s']:.4f} s unstable; "
          f"{r['python_control_sample_points']} points, {r['python_control_sample_stable']} stable)")
    print(f"  python-control whole map, EXTRAPOLATED        {r['python_control_full_map_extrapolated_s']:9.0f} s")
    print(f"  (PM < 30 by pm_rule = {r['pm_rule']!r}, crossovers located exactly by haa_sym and numpy; "
          "python-control: stability_margins)")
    for name, v in r["ratios"].items():
        print(f"  ratio {name:60s} {v:10.1f} x")
    for a in r["agreement_with_grid_map"]:
        diffs = ", ".join(f"{k[8:]} {a[k]:.2g}" for k in a if k.startswith("max_abs") and a[k] is not None)
        print(f"  vs grid map, {a['path']:22s} on {a['compared']:5d} points: disagree stable "
              f"{a['stable_disagree']}, PM<30 {a['low_pm_disagree']}, passive {a['passive_disagree']}"
              + (f"; {diffs}" if diffs else ""))
        for key in ("stable", "low_pm", "passive"):
            if a[f"{key}_disagree"]:
                print(f"    {key} disagrees at (P, D) = {a[f'{key}_disagree_points']}")
    print(f"  curves map vs numpy eigvals: stability disagrees on "
          f"{r['curves_map_vs_numpy_eigvals_stable_disagree']} points "
          f"({r['numpy_points_on_circle_not_compared']} within {BAND:g} of |z| = 1 not compared)")


def main() -> int:
    run = Run("bench_baselines.py")
    P_grid, D_grid = grid("log:1:20000:200"), grid("lin:1:50:200")
    rows = []
    for label, changes in CONFIGS:
        rows.append(run_config(label, changes, P_grid, D_grid))
        print_row(rows[-1])
    out = run.write("results_baselines.json",
                    {"grid": "200 x 200, P_gain log 1..20000, D_gain lin 1..50", "rows": rows})
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
