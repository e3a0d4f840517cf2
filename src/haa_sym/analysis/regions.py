"""Stability, phase-margin and passivity regions in the (P_gain, D_gain) plane (Figs. 8-11, Sec. 4-5).

For every point of a P_gain x D_gain grid, with the torque-loop gains (beta, alpha) fixed:

``stable``            all closed-loop poles in |z| < 1 (generated Routh-Hurwitz test, Sec. 4);
``spectral_radius``   max |z| of those poles (eigenvalues; NaN unless ``radius=True``);
``low_pm``            stable with a phase margin below 30 deg by the options' rule (crossovers
                      located exactly, :mod:`haa_sym.analysis.margins`);
``phase_margin_deg``  the exact signed margin of the crossover nearest -1 of the loop chosen by
                      ``LoopOptions.pm_loop``, at every point decided point by point (NaN where
                      the loop is unstable, |L| never crosses 1, or the point was labelled
                      from the curves);
``passive``           stable and the corrected phase of Z(z) within +-90 deg up to Nyquist (Sec. 5;
                      ``passivity = "corrected_phase"``, the default), or the exact test's
                      dissipation deficit within its tolerance (``passivity = "exact"``);
``phase_excess_deg``  the worst excess of that phase beyond +-90 deg, deg (<= 0 inside; NaN if
                      unstable, and everywhere under ``passivity = "exact"``);
``dissipation_deficit`` the exact test's -min mu, dimensionless (<= 0 passive; -1 with the
                      controller off; NaN if unstable, and everywhere under the paper's test).

Crossovers are located exactly; the passivity excess is sampled on ``LoopOptions.omega``
(default 1000 log points, 0.1 rad/s to Nyquist): its values next to lightly damped poles
(radius > 0.999) are only as fine as that grid.

Example
-------
>>> from haa_sym import ClosedLoop, load_params, grid
>>> from haa_sym.analysis.regions import region_map
>>> m = region_map(ClosedLoop(load_params()), grid("log:1:20000:50"), grid("lin:1:50:25"))  # doctest: +SKIP
>>> m.stable.mean(), m.save("map.npz")                                           # doctest: +SKIP
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from haa_sym.analysis.boundaries.classify import classify_regions
from haa_sym.analysis.boundaries.curves import StabilityBoundary
from haa_sym.analysis.boundaries.stability import stability_boundary
from haa_sym.analysis.decide import decide_points
from haa_sym.analysis.margins import PM_THRESHOLD_DEG
from haa_sym.analysis.sweep import BLAS_THREADS, CHUNK
from haa_sym.errors import ParameterError
from haa_sym.io.budget import check_memory, sweep_bytes
from haa_sym.io.formats import load_npz, result_arrays, save_npz
from haa_sym.io.progress import progress as progress_bar
from haa_sym.model.params import gain_array
from haa_sym.loop import loop_first

__all__ = ["RegionMap", "region_map", "MAP_METHODS", "check_map_budget"]

# how a map is decided: from the exact boundaries (default) or point by point on the grid
MAP_METHODS = ("curves", "grid")


@dataclass(frozen=True)
class RegionMap:
    """Result of :func:`region_map`: the axes ``P_gain`` (n_P, Nm/rad) and ``D_gain`` (n_D,
    Nms/rad), decisions and values (n_P, n_D) indexed [i_P, i_D] (see the module docstring),
    and ``meta`` (what produced it: :meth:`ClosedLoop.provenance`)."""

    P_gain: np.ndarray
    D_gain: np.ndarray
    stable: np.ndarray
    low_pm: np.ndarray
    passive: np.ndarray
    spectral_radius: np.ndarray
    phase_margin_deg: np.ndarray
    phase_excess_deg: np.ndarray
    dissipation_deficit: np.ndarray
    refined: np.ndarray
    meta: dict = field(default_factory=dict)

    def save(self, path: str | Path, tx=None, field: str | None = None) -> Path:
        """Write an ``.npz`` (arrays + ``meta`` as a JSON string), all or nothing
        (:func:`haa_sym.io.formats.save_npz`)."""
        return save_npz(path, result_arrays(self), self.meta, tx, field)

    @classmethod
    def load(cls, path: str | Path) -> "RegionMap":
        arrays, meta = load_npz(path)
        # a map written before the exact test had its own field (issue 24) has no deficit
        arrays.setdefault("dissipation_deficit", np.full(np.shape(arrays["phase_excess_deg"]), np.nan))
        return cls(meta=meta, **arrays)


def check_map_budget(loop, n_P: int, n_D: int) -> None:
    """Refuse (:class:`ParameterError`) a map of ``n_P`` x ``n_D`` points that would exceed the
    memory budget, before any work: the gate of :func:`region_map`, also asked by callers that
    validate before they compute (the explorer)."""
    n_omega = loop.options.numerics.n_omega
    check_memory(sweep_bytes(n_P * n_D, n_omega, CHUNK),
                 f"a region map of {n_P} x {n_D} (P_gain x D_gain) points on n_omega = "
                 f"{n_omega} frequencies")


def _check_boundary(loop, b, beta: float, alpha: float) -> None:
    """Refuse a given stability boundary that is not of this loop's gains (beta, alpha, Ts) or order."""
    Ts = loop.params.controller.Ts
    ABC = getattr(b, "ABC", None)
    if not isinstance(b, StabilityBoundary) or ABC is None:
        raise ParameterError(f"boundary = {type(b).__name__}; allowed: a StabilityBoundary of stability_boundary()")
    if (b.beta, b.alpha, b.Ts) != (beta, alpha, Ts) or ABC.shape[1] != loop.basis.shape[0]:
        raise ParameterError(f"boundary of beta = {b.beta:g}, alpha = {b.alpha:g}, Ts = {b.Ts:g} s (order "
                             f"{ABC.shape[1] - 1}); allowed: the map's beta = {beta:g}, alpha = {alpha:g}, "
                             f"Ts = {Ts:g} s (order {loop.basis.shape[0] - 1})")


@loop_first
def region_map(loop, P_gain, D_gain, *, beta: float | None = None, alpha: float | None = None,
               radius: bool = False, passivity: bool = True, method: str = "curves",
               progress: bool | None = None, blas_threads: int | None = BLAS_THREADS,
               boundary: StabilityBoundary | None = None) -> RegionMap:
    """Stability, phase margin and passivity of ``loop`` on the grid ``P_gain`` x ``D_gain``.

    Parameters
    ----------
    loop : ClosedLoop
        The closed loop: plant, controller and options (port, Colgate correction, PM loop and
        rule, frequency grid) all come from it.
    P_gain : (n_P,) array_like
        The grid's impedance stiffness axis, Nm/rad (Eq. 8).
    D_gain : (n_D,) array_like
        The grid's impedance damping axis, Nms/rad (Eq. 8).
    beta, alpha : float, optional
        Torque-gain scale (Eq. 7) and velocity compensation (Eq. 6); default the controller's.
    radius : bool
        Also compute the spectral radius, from the eigenvalues of the explicit closed loop
        (default False: it costs a stacked ``numpy.linalg.eigvals``, 10-100x the decision).
    passivity : bool
        Decide passivity (default); False leaves ``passive`` False and ``phase_excess_deg`` NaN
        (it halves a map's cost).
    method : {"curves", "grid"}
        "curves" (default): every D_gain row is split where the exact boundaries cross it
        (:func:`haa_sym.analysis.boundaries.classify.classify_regions`) and each segment is
        decided from a few points; the decisions equal the grid's (tested on every point);
        ``phase_margin_deg`` and ``phase_excess_deg`` hold the values of the points decided one
        by one, NaN elsewhere. "grid": every point decided by
        :func:`haa_sym.analysis.decide.decide_points` (the cross-check). A loop whose options'
        ``pm_loop`` is "torque" is decided on the grid (the curves are the impedance loop's).
    progress : bool or None
        Progress bar on stderr; None follows :func:`haa_sym.io.progress.set_progress`.
    blas_threads : int or None
        BLAS threads during the sweep (threadpoolctl); None leaves BLAS alone.
    boundary : StabilityBoundary, optional
        The stability boundary of this loop at the same beta and alpha
        (:func:`haa_sym.analysis.boundaries.stability.stability_boundary`, any box: the rows'
        crossings are located from its polynomials, not its drawn curves), for a caller that
        also draws it (the explorer): "curves" then does not compute it again. Default: computed
        here.

    Returns
    -------
    RegionMap

    Example
    -------
    >>> m = region_map(ClosedLoop(load_params()), [200, 20000], [10, 50])   # doctest: +SKIP
    >>> m.stable                                                          # doctest: +SKIP
    array([[ True,  True], [ True,  True]])
    """
    P = gain_array("P_gain", P_gain).ravel()
    D = gain_array("D_gain", D_gain).ravel()
    for name, arr in (("P_gain", P), ("D_gain", D)):
        if arr.size == 0:
            raise ParameterError(f"{name} is empty; allowed: at least one value")
    if method not in MAP_METHODS:
        raise ParameterError(f"method = {method!r}; allowed: {list(MAP_METHODS)}")
    _, _, beta, alpha = loop.gain_points(0.0, 0.0, beta, alpha)
    check_map_budget(loop, P.size, D.size)
    if boundary is not None:
        _check_boundary(loop, boundary, beta, alpha)
    shape = (P.size, D.size)
    if method == "curves" and loop.options.conventions.pm_loop == "impedance":
        with progress_bar(P.size * D.size, "region map (from the curves)", "pt", progress) as bar:
            b = boundary if boundary is not None else \
                stability_boundary(loop, beta, alpha, P_range=(float(P.min()), float(P.max())),
                                   D_range=(float(D.min()), float(D.max())))
            r = classify_regions(loop, b, P, D, pm_deg=PM_THRESHOLD_DEG, passivity=passivity)
            rho = np.full(shape, np.nan)
            if radius:
                PP, DD = np.meshgrid(P, D, indexing="ij")
                rho = loop.stability(PP, DD, beta, alpha, radius=True).spectral_radius.reshape(shape)
            bar.update(P.size * D.size)
        return RegionMap(P, D, r.stable, r.low_pm, r.passive, rho, r.phase_margin_deg, r.phase_excess_deg,
                         r.dissipation_deficit, np.zeros(shape, bool), loop.provenance(beta=beta, alpha=alpha, method="curves"))
    PP, DD = np.meshgrid(P, D, indexing="ij")
    with progress_bar(PP.size, "region map", "pt", progress) as bar:
        d = decide_points(loop, PP, DD, beta, alpha, passivity=passivity, radius=radius, bar=bar,
                          blas_threads=blas_threads)
    return RegionMap(P, D, *(v.reshape(shape) for v in (d.stable, d.low_pm, d.passive, d.spectral_radius,
                                                        d.phase_margin_deg, d.phase_excess_deg, d.dissipation_deficit,
                                                        d.refined)),
                     loop.provenance(beta=beta, alpha=alpha, method="grid"))
