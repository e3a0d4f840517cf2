"""A region map's stability decisions against the eigenvalues of the independent closed loop
(:mod:`haa_sym.check.reference`): the reproduction's cross-check of every figure."""
from __future__ import annotations

import numpy as np

from haa_sym.check.reference import closed_loop_eigenvalues

__all__ = ["eigenvalue_crosscheck"]


def eigenvalue_crosscheck(m, loop, band: float = 1e-6, *,
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
