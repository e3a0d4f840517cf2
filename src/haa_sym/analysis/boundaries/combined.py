"""The three exact boundaries of one configuration at once (``haa-sym boundary``)."""
from __future__ import annotations

from haa_sym.analysis.boundaries.curves import Boundaries, StabilityBoundary
from haa_sym.analysis.boundaries.passivity import REFINE_XTOL, passivity_boundary
from haa_sym.errors import ParameterError
from haa_sym.analysis.boundaries.stability import phase_margin_curves, stability_boundary
from haa_sym.loop import loop_first

__all__ = ["boundaries"]


@loop_first
def boundaries(loop, beta=None, alpha=None, *, P_range=(0.0, 2e4), D_range=(0.0, 50.0),
               pm_deg: float = 30.0, n_nu: int = 4000, n_lines: int = 101, passivity: bool = True,
               stability: StabilityBoundary | None = None, passivity_xtol: float = REFINE_XTOL) -> Boundaries:
    """Stability, phase-margin and passivity boundaries in the box ``P_range`` x ``D_range``.

    Parameters
    ----------
    loop : ClosedLoop
        Its options' ``pm_loop`` must be "impedance" for the phase-margin curves; the passivity
        boundary follows ``port``, ``colgate`` and the frequency range (``omega_min`` to Nyquist).
    beta, alpha : float, optional
        Torque-gain scale (Eq. 7) and velocity compensation (Eq. 6); default the controller's.
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
    stability : StabilityBoundary, optional
        This loop's stability boundary in this box at these gains, already computed (the
        explorer's map used it): taken as it is instead of computed again. Default: computed.
    passivity_xtol : float
        How closely the passivity boundary's tangencies are located in log omega
        (:func:`haa_sym.analysis.boundaries.passivity.passivity_boundary`'s ``xtol``; default
        1e-10, exact to rounding).

    Example
    -------
    >>> b = boundaries(ClosedLoop(load_params()), P_range=(1, 2e4), D_range=(1, 50))   # doctest: +SKIP
    >>> sorted({c.kind for c in b.curves})                                     # doctest: +SKIP
    """
    if stability is None:
        st = stability_boundary(loop, beta, alpha, P_range=P_range, D_range=D_range, n_nu=n_nu)
    else:
        ctrl = loop.params.controller
        want = (ctrl.beta if beta is None else float(beta), ctrl.alpha if alpha is None else float(alpha), ctrl.Ts,
                [float(v) for v in P_range], [float(v) for v in D_range], n_nu)
        have = (stability.beta, stability.alpha, stability.Ts, stability.meta.get("P_range"),
                stability.meta.get("D_range"), stability.meta.get("n_nu"))
        if have != want:
            raise ParameterError(f"stability: a boundary of (beta, alpha, Ts, P_range, D_range, n_nu) = {have}; "
                                 f"allowed: one of these boundaries' {want}")
        st = stability
    pm = phase_margin_curves(loop, st.beta, st.alpha, pm_deg=pm_deg, P_range=P_range, D_range=D_range,
                             n_nu=n_nu)
    ps = passivity_boundary(loop, st.beta, st.alpha, P_range=P_range, D_range=D_range,
                            n_lines=n_lines, xtol=passivity_xtol) if passivity else []
    st.meta.update(n_lines=n_lines)
    return Boundaries(st, pm, ps, pm_deg)
