"""Passivity of the driving-port impedance Z(z) (Sec. 5, Table 2, Fig. 12).

Z(z) = T_dist / port velocity with every loop closed (the port velocity is
``LoopOptions.port``). Following the paper (after Colgate), a gain point is passive when the
closed loop is stable and the phase of Z, corrected by ``LoopOptions.colgate`` (default: minus
w Ts/2), stays within +-90 deg for every frequency up to Nyquist. The torque loop alone is the
impedance loop open, i.e. P_gain = D_gain = 0.

Example
-------
>>> from haa_sym import ClosedLoop, load_params
>>> from haa_sym.analysis.passivity import passivity
>>> r = passivity(ClosedLoop(load_params()), [0, 200], [0, 10])   # doctest: +SKIP
>>> r.status                                                    # doctest: +SKIP
array(['No', 'Yes'], dtype='<U8')
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from haa_sym.analysis.sampled_port import measure_fields, passivity_excess, passivity_tolerance
from haa_sym.analysis.sweep import BLAS_THREADS, CHUNK, colgate_factor, run_chunks
from haa_sym.io.budget import check_memory, sweep_bytes
from haa_sym.io.progress import progress as progress_bar
from haa_sym.loop import loop_first

__all__ = ["PassivityResult", "CorrectedPhase", "passivity", "corrected_phase", "bands_beyond", "status"]


def status(stable, passive) -> np.ndarray:
    """Table 2 wording per point: "Unstable", "Yes" (passive) or "No" (stable, not passive)."""
    stable, passive = np.broadcast_arrays(np.asarray(stable, bool), np.asarray(passive, bool))
    return np.where(~stable, "Unstable", np.where(passive, "Yes", "No"))


@dataclass(frozen=True)
class PassivityResult:
    """Per gain point: ``stable``, ``passive``, the measure of the options' test —
    ``phase_excess_deg`` (``passivity = "corrected_phase"``: worst corrected phase of Z beyond
    +-90 deg, deg; <= 0 inside) or ``dissipation_deficit`` (``passivity = "exact"``: -min mu of
    :mod:`haa_sym.analysis.sampled_port`, dimensionless; <= 0 passive), the other NaN, both NaN
    when unstable — and ``omega_worst`` (rad/s, where the measure is worst)."""

    stable: np.ndarray
    passive: np.ndarray
    phase_excess_deg: np.ndarray
    omega_worst: np.ndarray
    dissipation_deficit: np.ndarray

    @property
    def status(self) -> np.ndarray:
        return status(self.stable, self.passive)


@loop_first
def passivity(loop, P_gain=0.0, D_gain=0.0, *, beta: float | None = None, alpha: float | None = None,
              progress: bool | None = None, blas_threads: int | None = BLAS_THREADS) -> PassivityResult:
    """Passivity of Z(z) of ``loop`` at gain points (P_gain, D_gain broadcast together).

    Parameters
    ----------
    loop : ClosedLoop
        Plant, controller and options (port, Colgate correction, frequency grid, tolerance
        ``passivity_tol_deg``).
    P_gain, D_gain : array_like
        Impedance gains, Nm/rad and Nms/rad (Eq. 8); 0, 0 is the torque loop alone.
    beta, alpha : float, optional
        Torque-gain scale and velocity compensation; default the controller's.
    progress : bool or None
        Progress bar on stderr; None follows :func:`haa_sym.io.progress.set_progress`.
    blas_threads : int or None
        BLAS threads during the sweep; see :data:`haa_sym.analysis.sweep.BLAS_THREADS`.

    Returns
    -------
    PassivityResult
    """
    shape = np.broadcast_shapes(np.shape(P_gain), np.shape(D_gain))
    P, D, beta, alpha = loop.gain_points(P_gain, D_gain, beta, alpha)
    options = loop.options
    # chunked: one chunk's sweep at a time, plus the coefficients and the per-point results
    check_memory(sweep_bytes(P.size, options.numerics.n_omega, CHUNK),
                 f"passivity of {P.size} gain points on n_omega = {options.numerics.n_omega} frequencies")
    # the test's pieces built once, before the chunks share them
    passivity_excess(loop, P[:1], D[:1], beta, alpha)
    n = P.size
    stable = np.empty(n, bool)
    ex = np.empty(n)
    ww = np.empty(n)

    def work(sl):
        stable[sl] = loop.stability(P[sl], D[sl], beta, alpha).stable.ravel()
        ex[sl], ww[sl] = passivity_excess(loop, P[sl], D[sl], beta, alpha)
    with progress_bar(n, "passivity", "pt", progress) as bar:
        run_chunks(work, n, blas_threads=blas_threads, bar=bar)
    ex = np.where(stable, ex, np.nan)
    ww = np.where(stable, ww, np.nan)
    with np.errstate(invalid="ignore"):
        passive = stable & (ex <= passivity_tolerance(loop))
    m = measure_fields(loop, ex.reshape(shape))
    return PassivityResult(stable.reshape(shape), passive.reshape(shape), m["phase_excess_deg"],
                           ww.reshape(shape), m["dissipation_deficit"])


@dataclass(frozen=True)
class CorrectedPhase:
    """:func:`corrected_phase`: ``omega`` (rad/s) and ``phase_deg`` (deg, in (-180, 180],
    point_shape + (n_omega,)); unpacks as ``omega, phase_deg = corrected_phase(...)``."""

    omega: np.ndarray
    phase_deg: np.ndarray

    def __iter__(self):
        return iter((self.omega, self.phase_deg))


@loop_first
def corrected_phase(loop, P_gain=0.0, D_gain=0.0, *, omega=None, beta: float | None = None,
                    alpha: float | None = None) -> CorrectedPhase:
    """Phase of Z(z) of ``loop`` with Colgate's correction, degrees in (-180, 180], on ``omega``
    (rad/s; default the options' grid) at gain points (Fig. 12).

    Example
    -------
    >>> w, ph = corrected_phase(ClosedLoop(load_params()), 0.0, 0.0)   # torque loop alone  # doctest: +SKIP
    >>> bands_beyond(w, ph)                                                         # doctest: +SKIP
    [(11.57..., 59.17...)]
    """
    shape = np.broadcast_shapes(np.shape(P_gain), np.shape(D_gain))
    P, D, beta, alpha = loop.gain_points(P_gain, D_gain, beta, alpha)
    n_omega = loop.options.numerics.n_omega if omega is None else np.size(omega)
    check_memory(sweep_bytes(P.size, n_omega),
                 f"the phase of Z at {P.size} gain points on {n_omega} frequencies")
    coef = loop.loop_coefficients(omega, beta, alpha)
    Z = coef.evaluate("Z", P, D)
    c = colgate_factor(coef.omega, loop.params.controller.Ts, loop.options.conventions.colgate)
    return CorrectedPhase(coef.omega, np.degrees(np.angle(Z * c)).reshape(shape + coef.omega.shape))


def bands_beyond(omega, phase_deg, limit: float = 90.0) -> list[tuple[float, float]]:
    """Frequency intervals (rad/s) where |phase| > ``limit``, edges interpolated in log(omega).

    >>> [(round(a, 4), round(b, 4)) for a, b in bands_beyond([1.0, 2, 4, 8], [80.0, 100, 100, 80])]
    [(1.4142, 5.6569)]
    """
    omega = np.asarray(omega, float)
    s = np.abs(np.asarray(phase_deg, float)) - limit
    out, start = [], None
    lw = np.log(omega)
    for k in range(len(s)):
        if s[k] > 0 and start is None:
            start = omega[0] if k == 0 else float(np.exp(lw[k - 1] + s[k - 1] / (s[k - 1] - s[k]) * (lw[k] - lw[k - 1])))
        if s[k] <= 0 and start is not None:
            out.append((start, float(np.exp(lw[k - 1] + s[k - 1] / (s[k - 1] - s[k]) * (lw[k] - lw[k - 1])))))
            start = None
    if start is not None:
        out.append((start, float(omega[-1])))
    return out
