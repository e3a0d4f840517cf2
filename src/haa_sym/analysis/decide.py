"""The maps' decisions point by point: certified stability, the phase margin by the one rule of
:mod:`haa_sym.analysis.margins`, and passivity (Sec. 4-5). Region maps decided on the grid, the
segment probes of the maps decided from the curves and the scheduler all decide here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from haa_sym.analysis.margins import PM_THRESHOLD_DEG, phase_margins
from haa_sym.analysis.sampled_port import measure_fields, passivity_excess, passivity_tolerance
from haa_sym.analysis.sweep import BLAS_THREADS, blas_limits, run_chunks
from haa_sym.loop import loop_first

__all__ = ["PointDecisions", "decide_points"]


@dataclass(frozen=True)
class PointDecisions:
    """Per gain point (flat arrays): ``stable``; ``low_pm`` (stable with a phase margin below the
    threshold by the options' rule); ``passive`` (stable and the corrected phase of Z within
    +-90 deg plus the options' tolerance; False everywhere when passivity was not asked for);
    ``phase_margin_deg`` (the signed margin of the crossover nearest -1, exact; NaN where
    unstable or without crossover); ``phase_excess_deg`` (worst corrected phase of Z beyond
    +-90 deg, deg, with ``passivity = "corrected_phase"``) or ``dissipation_deficit`` (the exact
    test's -min mu, dimensionless, with ``passivity = "exact"``): the other NaN, both NaN where
    unstable or not asked for; ``refined`` (decided from eigenvalues, the
    generated test being uncertified there); ``spectral_radius`` (NaN unless asked for)."""

    stable: np.ndarray
    low_pm: np.ndarray
    passive: np.ndarray
    phase_margin_deg: np.ndarray
    phase_excess_deg: np.ndarray
    dissipation_deficit: np.ndarray
    refined: np.ndarray
    spectral_radius: np.ndarray


@loop_first
def decide_points(loop, P_gain, D_gain, beta=None, alpha=None, *, passivity: bool = True,
                  radius: bool = False, pm_threshold_deg: float = PM_THRESHOLD_DEG, bar=None,
                  blas_threads: int | None = BLAS_THREADS) -> PointDecisions:
    """Decide gain points of ``loop`` (P_gain, D_gain broadcast, flattened; beta, alpha scalars,
    default the controller's). Stability by the certified generated test
    (:meth:`ClosedLoop.stability`), the phase margin of the options' ``pm_loop`` with crossovers
    located exactly (:func:`haa_sym.analysis.margins.phase_margins`) judged by the options'
    ``pm_rule``, passivity by the maps' excess (:func:`haa_sym.analysis.sweep.phase_excess` on
    the options' frequency grid). Chunks of points run on two threads; ``bar`` (a progress bar)
    is updated per chunk."""
    P, D, beta, alpha = loop.gain_points(P_gain, D_gain, beta, alpha)
    conv = loop.options.conventions
    n = P.size
    stable, refined = np.zeros(n, bool), np.zeros(n, bool)
    rho, pm, ex = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    low = np.zeros(n, bool)

    def stability(sl):
        st = loop.stability(P[sl], D[sl], beta, alpha, radius=radius)
        stable[sl], rho[sl], refined[sl] = st.stable, st.spectral_radius, st.refined
    run_chunks(stability, n, blas_threads=blas_threads, bar=bar)
    # margins and the phase of Z mean something only for a stable loop; the margins' search
    # runs once over all of them (it chunks and threads itself: its golden-section and
    # Illinois steps are array operations whose per-call cost a chunk of 512 would repeat)
    ok = np.flatnonzero(stable)
    if ok.size:
        with blas_limits(blas_threads):
            m = phase_margins(loop, P[ok], D[ok], beta, alpha)
        pm[ok] = m.pm_deg
        low[ok] = m.low(conv.pm_rule, pm_threshold_deg)
    if passivity and ok.size:
        passivity_excess(loop, P[ok[:1]], D[ok[:1]], beta, alpha)     # the pieces, once
        def excess(sl):
            k = ok[sl]
            ex[k] = passivity_excess(loop, P[k], D[k], beta, alpha)[0]
        run_chunks(excess, ok.size, blas_threads=blas_threads)
    with np.errstate(invalid="ignore"):
        passive = stable & (ex <= passivity_tolerance(loop))
    m = measure_fields(loop, ex)
    return PointDecisions(stable, low, passive, pm, m["phase_excess_deg"], m["dissipation_deficit"], refined, rho)
