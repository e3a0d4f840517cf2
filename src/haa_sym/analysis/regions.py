"""Stability, phase-margin and passivity regions in the (P_gain, D_gain) plane (Figs. 8-11, Sec. 4-5).

For every point of a P_gain x D_gain grid, with the torque-loop gains (beta, alpha) fixed:

``stable``            all closed-loop poles in |z| < 1 (generated Routh-Hurwitz test, Sec. 4);
``spectral_radius``   max |z| of those poles (eigenvalues; NaN unless ``radius=True``);
``phase_margin_deg``  phase margin of the loop chosen by ``LoopOptions.pm_loop`` (NaN where the
                      loop is unstable or |L| never crosses 1);
``passive``           stable and the corrected phase of Z(z) within +-90 deg up to Nyquist (Sec. 5);
``phase_excess_deg``  the worst excess of that phase beyond +-90 deg (<= 0 inside; NaN if unstable).

Frequency work is sampled on ``LoopOptions.omega`` (default 1000 log points, 0.1 rad/s to
Nyquist). Decisions are insensitive to that grid (measured: identical stable / PM < 30 / passive
maps with 1000 and 16000 points at N_av = 4 and 50, Ts = 1 and 8 ms; PM within 0.5 deg); the
excess values next to lightly damped poles (radius > 0.999) are only as fine as the grid.

Example
-------
>>> from haa_sym import load_params
>>> from haa_sym.analysis.regions import region_map, grid
>>> m = region_map(load_params(), grid("log:1:20000:50"), grid("lin:1:50:25"))   # doctest: +SKIP
>>> m.stable.mean(), m.save("map.npz")                                           # doctest: +SKIP
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from haa_sym.io.budget import check_memory, sweep_bytes
from haa_sym.loop.closed_loop import ClosedLoop, LoopOptions
from haa_sym.errors import ParameterError
from haa_sym.model.params import Params, gain_array
from haa_sym.io.progress import progress as progress_bar
from haa_sym.analysis.sweep import BLAS_THREADS, SWEEP_THREADS, blas_limits, gain_rows, phase_excess, phase_margins

__all__ = ["RegionMap", "region_map", "grid", "decide_points", "PM_THRESHOLD_DEG", "MAP_METHODS", "save_npz"]

# Figs. 8-11: light grey = stable with a phase margin below 30 degrees.
PM_THRESHOLD_DEG = 30.0
# how a map is decided: from the exact boundaries (default) or point by point on the grid
MAP_METHODS = ("curves", "grid")
CHUNK = 512


def grid(spec: str, name: str = "grid") -> np.ndarray:
    """Gain grid from a spec: ``log:START:STOP:N``, ``lin:START:STOP:N`` or ``v1,v2,...``.

    >>> grid("lin:1:50:3")
    array([ 1. , 25.5, 50. ])
    """
    def bad(why):
        return ParameterError(f"{name} = {spec!r}: {why}; allowed: 'log:START:STOP:N' (0 < START <= "
                              "STOP), 'lin:START:STOP:N' (0 <= START <= STOP) or a comma-separated list "
                              "of numbers >= 0, all finite, N an integer >= 1")

    def number(text, what=""):
        try:
            v = float(text)
        except ValueError:
            raise bad(f"{what}{text.strip()!r} is not a number") from None
        if not np.isfinite(v):
            raise bad(f"{what}{text.strip()} is not finite")
        if v < 0:
            raise bad(f"{what}{text.strip()} is negative")
        return v

    s = str(spec).strip()
    kind, _, rest = s.partition(":")
    if kind in ("log", "lin"):
        parts = rest.split(":")
        if len(parts) != 3:
            raise bad(f"expected 3 fields after '{kind}:' (START:STOP:N), got {len(parts)}")
        a, b = number(parts[0], "START = "), number(parts[1], "STOP = ")
        if not parts[2].strip().isdigit() or int(parts[2]) < 1:
            raise bad(f"N = {parts[2].strip()!r} is not an integer >= 1")
        n = int(parts[2])
        if a > b:
            raise bad(f"START = {a:g} is above STOP = {b:g} (reversed range)")
        if kind == "log" and a == 0:
            raise bad("START = 0: a log grid needs START > 0")
        check_memory(16 * n, f"{name} = {spec!r}: a grid of {n} points")
        return np.logspace(np.log10(a), np.log10(b), n) if kind == "log" else np.linspace(a, b, n)
    return np.array([number(v) for v in s.split(",")])


@dataclass
class RegionMap:
    """Result of :func:`region_map`; arrays are (n_P, n_D), indexed [i_P, i_D]."""

    P_gain: np.ndarray
    D_gain: np.ndarray
    stable: np.ndarray
    spectral_radius: np.ndarray
    phase_margin_deg: np.ndarray
    passive: np.ndarray
    phase_excess_deg: np.ndarray
    refined: np.ndarray
    meta: dict = field(default_factory=dict)
    # the decision itself when the map was classified from the curves (no per-point margins)
    low_pm_decided: np.ndarray | None = None

    @property
    def low_pm(self) -> np.ndarray:
        """Stable with a phase margin below 30 deg (the light grey of Figs. 8-11)."""
        if self.low_pm_decided is not None:
            return self.low_pm_decided
        with np.errstate(invalid="ignore"):
            return self.stable & (self.phase_margin_deg < PM_THRESHOLD_DEG)

    def arrays(self) -> dict:
        out = {k: getattr(self, k) for k in ("P_gain", "D_gain", "stable", "spectral_radius",
                                             "phase_margin_deg", "passive", "phase_excess_deg",
                                             "refined")}
        out["low_pm"] = self.low_pm
        return out

    def save(self, path: str | Path, tx=None, field: str | None = None) -> Path:
        """Write an ``.npz`` (arrays + ``meta`` as a JSON string), atomically (see :func:`save_npz`)."""
        return save_npz(path, self.arrays(), self.meta, tx, field)

    @classmethod
    def load(cls, path: str | Path) -> "RegionMap":
        with np.load(path) as f:
            data = {k: f[k] for k in f.files}
        meta = json.loads(str(data.pop("meta")))
        low_pm = data.pop("low_pm", None)
        return cls(meta=meta, low_pm_decided=low_pm if meta.get("method") == "curves" else None, **data)


def save_npz(path: str | Path, arrays: dict, meta: dict, tx=None, field: str | None = None) -> Path:
    """``np.savez`` of ``arrays`` and ``meta`` (a JSON string) to ``path``: never partial.

    Written through the :class:`haa_sym.io.outputs.Transaction` ``tx`` (committed with the other
    outputs of its command), or on its own, atomically, when ``tx`` is None.
    """
    from haa_sym.io.outputs import transaction
    with transaction(tx) as t, t.open(path, "wb", field) as fh:
        np.savez(fh, meta=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    return Path(path)


def region_map(params: Params, P_gain, D_gain, *, options: LoopOptions | None = None,
               beta: float | None = None, alpha: float | None = None, radius: bool = False,
               progress: bool | None = None, backend: str = "auto",
               loop: ClosedLoop | None = None, passivity: bool = True,
               blas_threads: int | None = BLAS_THREADS, method: str = "curves") -> RegionMap:
    """Stability, phase margin and passivity on the grid ``P_gain`` x ``D_gain``.

    Parameters
    ----------
    params : Params
        Plant and controller (``haa_sym.load_params``); ``Ts``, ``N_av`` come from here.
    P_gain : (n_P,) array_like
        Impedance stiffness values, Nm/rad (Eq. 8).
    D_gain : (n_D,) array_like
        Impedance damping values, Nms/rad (Eq. 8).
    options : LoopOptions, optional
        Modelling options (delay, port, Colgate correction, PM loop and rule, frequency grid).
    beta, alpha : float, optional
        Torque-gain scale (Eq. 7) and velocity compensation (Eq. 6); default from ``params``.
    radius : bool
        Also compute the spectral radius, from the eigenvalues of the explicit closed loop
        (default False: it costs a stacked ``numpy.linalg.eigvals``, 10-100x the decision).
    progress : bool or None
        Progress bar on stderr; None follows :func:`haa_sym.io.progress.set_progress` (by default
        a bar on a terminal when the map takes more than 2 s).
    backend : {"auto", "compiled", "vm"}
        Evaluators of the generated code (``meta["backend"]`` records the one that ran).
    loop : ClosedLoop, optional
        Reuse an already built closed loop of the same params and options.
    passivity : bool
        Compute the passivity excess (default); False leaves ``passive`` False and
        ``phase_excess_deg`` NaN, for callers that need stability and phase margin only (it
        halves a map's cost).
    blas_threads : int or None
        BLAS threads during the sweep (threadpoolctl); None leaves BLAS alone. Default
        :data:`haa_sym.analysis.sweep.BLAS_THREADS` (1, and why).
    method : {"curves", "grid"}
        "curves" (default): every D_gain row is split where the exact boundaries cross it
        (:func:`haa_sym.analysis.boundaries.stability.classify_regions`) and each segment decided once; the
        decisions equal the grid's (tested on every point); ``phase_margin_deg`` and
        ``phase_excess_deg`` are NaN (not computed per point); the curves themselves come from
        :func:`haa_sym.analysis.boundaries.stability.boundaries`. "grid": every point decided by the generated
        evaluators, with its phase margin and passivity excess (the cross-check).

    Returns
    -------
    RegionMap
        Arrays (n_P, n_D) and ``meta`` (parameters, options, beta, alpha, generated-code hash).

    Example
    -------
    >>> m = region_map(load_params(), [200, 20000], [10, 50])           # doctest: +SKIP
    >>> m.stable                                                          # doctest: +SKIP
    array([[ True,  True], [ True,  True]])
    """
    options = options or LoopOptions()
    P = gain_array("P_gain", P_gain).ravel()
    D = gain_array("D_gain", D_gain).ravel()
    for name, arr in (("P_gain", P), ("D_gain", D)):
        if arr.size == 0:
            raise ParameterError(f"{name} is empty; allowed: at least one value")
    if method not in MAP_METHODS:
        raise ParameterError(f"method = {method!r}; allowed: {list(MAP_METHODS)}")
    ctrl = params.controller
    beta = float(gain_array("beta", ctrl.beta if beta is None else beta))
    alpha = float(gain_array("alpha", ctrl.alpha if alpha is None else alpha))
    n_omega = (loop.options if loop is not None else options).n_omega
    check_memory(sweep_bytes(P.size * D.size, n_omega, CHUNK),
                 f"a region map of {P.size} x {D.size} (P_gain x D_gain) points on n_omega = "
                 f"{n_omega} frequencies")
    if loop is None:
        loop = ClosedLoop(params, options, backend)
    # the phase-margin curves are those of the impedance loop; the torque loop's margin
    # (pm_loop = "torque") is decided on the grid
    if method == "curves" and loop.options.conventions.pm_loop == "impedance":
        return _map_from_curves(params, loop, P, D, beta, alpha, radius, passivity, progress)
    coef = loop.loop_coefficients(None, beta, alpha)
    L = coef.L_imp if options.conventions.pm_loop == "impedance" else coef.L_t
    PP, DD = np.meshgrid(P, D, indexing="ij")
    n = PP.size
    out = {k: np.empty(n) for k in ("rho", "pm", "excess")}
    stable = np.empty(n, bool)
    refined = np.empty(n, bool)

    def work(sl):
        st = loop.stability(PP.flat[sl], DD.flat[sl], beta, alpha, radius=radius)
        stable[sl], out["rho"][sl], refined[sl] = st.stable, st.spectral_radius, st.refined
        X = gain_rows(PP.flat[sl], DD.flat[sl])
        pm = np.full(X.shape[0], np.nan)
        ok = np.flatnonzero(st.stable)
        pm[ok] = phase_margins(X[ok], L, coef.omega, options.conventions.pm_rule)[0]
        out["pm"][sl] = pm
        # Z(z) of an unstable loop has poles outside the circle: not passive, no phase to judge
        ex = np.full(X.shape[0], np.nan)
        if passivity:
            ex[ok] = phase_excess(X[ok], coef.Z_num, coef.Z_den, coef.omega, ctrl.Ts, options.conventions.colgate)[0]
        out["excess"][sl] = ex
        return sl.stop - sl.start

    # chunks small enough for the (chunk x n_omega) products to stay in cache (measured: 512
    # points beat 2048 by ~30%), shared by SWEEP_THREADS threads (each writes its own slices)
    chunks = [slice(s, min(s + CHUNK, n)) for s in range(0, n, CHUNK)]
    with blas_limits(blas_threads), progress_bar(n, "region map", "pt", progress) as bar:
        if SWEEP_THREADS > 1 and len(chunks) > 1:
            from concurrent.futures import ThreadPoolExecutor
            with ThreadPoolExecutor(SWEEP_THREADS) as pool:
                for done in pool.map(work, chunks):
                    bar.update(done)
        else:
            for sl in chunks:
                bar.update(work(sl))
    shape = PP.shape
    with np.errstate(invalid="ignore"):
        passive = stable & (out["excess"] <= options.conventions.passivity_tol_deg)
    return RegionMap(P_gain=P, D_gain=D, stable=stable.reshape(shape),
                     spectral_radius=out["rho"].reshape(shape),
                     phase_margin_deg=out["pm"].reshape(shape), passive=passive.reshape(shape),
                     phase_excess_deg=out["excess"].reshape(shape), refined=refined.reshape(shape),
                     meta=run_meta(params, options, beta=beta, alpha=alpha, backend=loop.backend,
                                   method="grid"))


def decide_points(loop: ClosedLoop, P_gain, D_gain, beta: float, alpha: float, *,
                  pm_deg: float = PM_THRESHOLD_DEG, passivity: bool = True):
    """``(stable, low_pm, passive)`` at gain points (flat arrays of equal size), the maps'
    decisions point by point: certified stability, the impedance loop's phase margin by the
    options' rule (``low_pm``: stable with PM < ``pm_deg``) and passivity (stable, excess within
    ``passivity_tol_deg``; all False when ``passivity`` is False). One loop-coefficient
    evaluation for (beta, alpha), then per point products on the frequency grid."""
    P = np.asarray(P_gain, float).ravel()
    D = np.asarray(D_gain, float).ravel()
    conv = loop.options.conventions
    coef = loop.loop_coefficients(beta=beta, alpha=alpha)
    L = coef.L_imp if conv.pm_loop == "impedance" else coef.L_t
    st = loop.stability(P, D, beta, alpha).stable.ravel()
    X = gain_rows(P[st], D[st])
    pm, passive = np.full(P.size, np.nan), np.zeros(P.size, bool)
    n = X.shape[0]
    pm_st, ex = np.empty(n), np.full(n, np.nan)

    def work(sl):
        pm_st[sl] = phase_margins(X[sl], L, coef.omega, conv.pm_rule)[0]
        if passivity:
            ex[sl] = phase_excess(X[sl], coef.Z_num, coef.Z_den, coef.omega, loop.params.controller.Ts,
                                  conv.colgate)[0]
    # chunks in cache, on SWEEP_THREADS threads (numpy releases the GIL), as region_map's sweep
    chunks = [slice(s, min(s + CHUNK, n)) for s in range(0, n, CHUNK)]
    if SWEEP_THREADS > 1 and len(chunks) > 1:
        from concurrent.futures import ThreadPoolExecutor
        with blas_limits(BLAS_THREADS), ThreadPoolExecutor(SWEEP_THREADS) as pool:
            list(pool.map(work, chunks))
    else:
        for sl in chunks:
            work(sl)
    pm[st] = pm_st
    with np.errstate(invalid="ignore"):
        passive[st] = ex <= conv.passivity_tol_deg
        return st, st & (pm < pm_deg), passive


def _map_from_curves(params, loop, P, D, beta, alpha, radius, passivity, progress) -> RegionMap:
    """``region_map(method="curves")``: the decisions from the exact boundaries."""
    from haa_sym.analysis.boundaries.stability import classify_regions, stability_boundary
    box = dict(P_range=(float(P.min()), float(P.max())), D_range=(float(D.min()), float(D.max())))
    shape = (P.size, D.size)
    with progress_bar(P.size * D.size, "region map (from the curves)", "pt", progress) as bar:
        b = stability_boundary(params, beta, alpha, loop=loop, **box)
        r = classify_regions(loop, b, P, D, pm_deg=PM_THRESHOLD_DEG, passivity=passivity)
        rho = np.full(shape, np.nan)
        if radius:
            PP, DD = np.meshgrid(P, D, indexing="ij")
            rho = loop.stability(PP, DD, beta, alpha, radius=True).spectral_radius.reshape(shape)
        bar.update(P.size * D.size)
    nan = np.full(shape, np.nan)
    passive = r.passive if passivity else np.zeros(shape, bool)
    return RegionMap(P_gain=P, D_gain=D, stable=r.stable, spectral_radius=rho, phase_margin_deg=nan,
                     passive=passive, phase_excess_deg=nan.copy(), refined=np.zeros(shape, bool),
                     meta=run_meta(params, loop.options, beta=beta, alpha=alpha, backend=loop.backend,
                                   method="curves"),
                     low_pm_decided=r.low_pm)


def run_meta(params: Params, options: LoopOptions, *, backend: str = "auto", **extra) -> dict:
    """What produced a result: parameters, options, versions, the generated-code hash and the
    backend that evaluated it ("compiled" or "vm", ``backend`` = "auto" resolved)."""
    from haa_sym._version import __version__
    from haa_sym.compiled.generated import evaluators
    ev = evaluators(backend)
    return {"params": params.to_dict(), "options": options.resolved(params.plant.topology).to_dict(),
            "haa_sym": __version__,
            "generated_source_sha256": ev.code.manifest["source_sha256"], **extra,
            "backend": ev.backend}


def eigenvalue_crosscheck(m: RegionMap, loop: ClosedLoop, band: float = 1e-6, *,
                          points: str = "all", stride: int = 3) -> dict:
    """Check map points against numpy eigenvalues of the explicit closed loop.

    The closed-loop matrices come from ``haa_sym.check.reference`` (independent of the generated code)
    and go through stacked ``numpy.linalg.eigvals`` calls.

    Parameters
    ----------
    points : {"all", "boundary"}
        Every point, or the points where a wrong decision could hide: every point with a grid
        neighbour of the other decision (both sides of every stability boundary the grid shows)
        plus every ``stride``-th point in both directions (an island the grid resolves contains
        a point of that lattice or touches a boundary). "boundary" costs about 1/stride^2 of "all".

    Returns
    -------
    dict
        ``points`` in the map, ``checked``, ``decided`` (|rho - 1| > band among the checked),
        ``disagree`` among those, ``refined`` (points the map decided from eigenvalues) and the
        largest radius difference where the map has radii.
    """
    from haa_sym.check.reference import closed_loop_eigenvalues
    if points not in ("all", "boundary"):
        raise ValueError(f"points = {points!r}; allowed: 'all', 'boundary'")
    beta, alpha = m.meta.get("beta"), m.meta.get("alpha")
    PP, DD = np.meshgrid(m.P_gain, m.D_gain, indexing="ij")
    sel = np.ones(m.stable.shape, bool)
    if points == "boundary":
        st = m.stable
        sel = np.zeros(st.shape, bool)
        sel[::stride, ::stride] = True
        for axis in (0, 1):
            edge = np.diff(st, axis=axis) != 0
            lo = [slice(None)] * 2
            hi = [slice(None)] * 2
            lo[axis], hi[axis] = slice(None, -1), slice(1, None)
            sel[tuple(lo)] |= edge
            sel[tuple(hi)] |= edge
    P, D = PP[sel], DD[sel]
    ctrl = loop.params.controller
    pts = np.stack([P, D, np.full(P.size, ctrl.beta if beta is None else beta),
                    np.full(P.size, ctrl.alpha if alpha is None else alpha)])
    rho = np.abs(closed_loop_eigenvalues(loop, pts)).max(axis=1)
    decided = np.abs(rho - 1) > band
    stable = m.stable[sel]
    with np.errstate(invalid="ignore"):
        diff = np.abs(m.spectral_radius[sel] - rho)
    return {"points": int(m.stable.size), "checked": int(P.size), "decided": int(decided.sum()),
            "disagree": int((stable[decided] != (rho < 1)[decided]).sum()),
            "refined": int(m.refined.sum()),
            "max_radius_diff": float(np.nanmax(diff)) if np.isfinite(diff).any() else None}
