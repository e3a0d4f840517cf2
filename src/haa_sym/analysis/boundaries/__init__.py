"""Exact boundaries in the gain plane by the parameter-space method (D-decomposition): stability
(``stability``), the outline of the low-phase-margin region (``stability.phase_margin_curves``),
passivity as the envelope of one conic per frequency (``passivity``), the three at once
(``combined``), and region maps classified from them (``classify``). Curves are plain data
(``curves``)."""
from haa_sym.analysis.boundaries.classify import RegionDecisions, classify_grid, classify_regions
from haa_sym.analysis.boundaries.combined import boundaries
from haa_sym.analysis.boundaries.curves import Boundaries, BoundaryCurve, StabilityBoundary
from haa_sym.analysis.boundaries.passivity import passivity_boundary, passivity_crossings
from haa_sym.analysis.boundaries.stability import affine_polynomials, crossings, phase_margin_curves, stability_boundary

__all__ = ["boundaries", "Boundaries", "BoundaryCurve", "StabilityBoundary", "RegionDecisions", "classify_grid",
           "classify_regions", "passivity_boundary", "passivity_crossings", "affine_polynomials", "crossings",
           "phase_margin_curves", "stability_boundary"]
