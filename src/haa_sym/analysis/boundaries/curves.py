"""What the exact boundaries are made of: curves of (P_gain, D_gain) points, each point with
its critical frequency, and the three boundaries of one configuration as plain frozen data."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from haa_sym.io.formats import save_json

__all__ = ["BoundaryCurve", "StabilityBoundary", "Boundaries", "CURVE_POINTS"]

# points of a drawn curve at the least (each run of the nu grid inside the box is resampled)
CURVE_POINTS = 200


@dataclass(frozen=True)
class BoundaryCurve:
    """One branch of the stability boundary.

    ``P_gain`` (Nm/rad), ``D_gain`` (Nms/rad) and ``omega`` (rad/s, the frequency of the
    closed-loop pole on the unit circle: theta/Ts) per point; ``kind`` is "z=1" (a real pole at
    z = 1, a straight line), "z=-1" (a real pole at z = -1, a straight line) or "complex" (a
    complex pair at z = exp(+-j omega Ts)).
    """

    kind: str
    P_gain: np.ndarray
    D_gain: np.ndarray
    omega: np.ndarray


@dataclass(frozen=True)
class StabilityBoundary:
    """The stability boundary of one configuration (fixed beta, alpha) in the gain plane."""

    curves: list
    beta: float
    alpha: float
    Ts: float
    meta: dict = field(default_factory=dict)
    # A, B, C of q = A + P_gain B + D_gain C (ascending in s), for exact crossings
    ABC: np.ndarray = field(default=None, repr=False)
    nu: np.ndarray = field(default=None, repr=False)

    def to_dict(self) -> dict:
        """Plain JSON-able data: the curves (P_gain Nm/rad, D_gain Nms/rad, omega rad/s, kind)
        and what produced them."""
        return {"boundary": "stability", "beta": self.beta, "alpha": self.alpha, "Ts": self.Ts,
                "meta": self.meta,
                "curves": [{"kind": c.kind, "P_gain": c.P_gain.tolist(), "D_gain": c.D_gain.tolist(),
                            "omega": c.omega.tolist()} for c in self.curves]}

    def save(self, path, tx=None, field: str | None = None):
        """Write :meth:`to_dict` as JSON (all or nothing, see :mod:`haa_sym.io.formats`)."""
        return save_json(path, self.to_dict(), tx, field)


@dataclass(frozen=True)
class Boundaries:
    """The three boundaries of one configuration (fixed beta, alpha) in the gain plane.

    ``stability``: :class:`StabilityBoundary` (a closed-loop pole on the unit circle);
    ``phase_margin``: curves where the impedance loop has a crossover with margin ``pm_deg``;
    ``passivity``: curves where the corrected phase of Z reaches +-90 deg
    (:func:`haa_sym.analysis.boundaries.passivity.passivity_boundary`). Every curve point carries its
    critical frequency ``omega`` (rad/s) and every curve its ``kind``.
    """

    stability: StabilityBoundary
    phase_margin: list
    passivity: list
    pm_deg: float

    @property
    def curves(self) -> list:
        return list(self.stability.curves) + list(self.phase_margin) + list(self.passivity)

    def to_dict(self) -> dict:
        """Plain JSON-able data: per boundary its curves (P_gain Nm/rad, D_gain Nms/rad, omega
        rad/s, kind) and what produced them."""
        def curves(cs):
            return [{"kind": c.kind, "P_gain": c.P_gain.tolist(), "D_gain": c.D_gain.tolist(),
                     "omega": c.omega.tolist()} for c in cs]
        b = self.stability
        return {"beta": b.beta, "alpha": b.alpha, "Ts": b.Ts, "pm_deg": self.pm_deg, "meta": b.meta,
                "stability": curves(b.curves), "phase_margin": curves(self.phase_margin),
                "passivity": curves(self.passivity)}

    def save(self, path, tx=None, field: str | None = None):
        """Write :meth:`to_dict` as JSON (all or nothing, see :mod:`haa_sym.io.formats`)."""
        return save_json(path, self.to_dict(), tx, field)
