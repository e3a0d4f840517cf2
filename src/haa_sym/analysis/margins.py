"""Gain and phase margins from a sampled frequency response (plain functions over arrays).

Crossovers are located between grid points by linear interpolation of log|L| and of the
unwrapped phase in log(omega); use a grid fine enough for the loop at hand (the default grids
of the callers have >= 2000 points per sweep up to Nyquist).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from haa_sym.errors import ParameterError
from haa_sym.model.params import gain_array

__all__ = ["Margins", "stability_margins", "default_omega"]


@dataclass(frozen=True)
class Margins:
    """All crossovers of a loop transfer L (negative feedback, closed loop 1/(1+L)).

    ``gain_crossovers`` (rad/s) where |L| = 1, with ``phase_margins_deg`` = 180 + arg L there,
    wrapped to (-180, 180]; ``phase_crossovers`` (rad/s) where arg L = -180 (mod 360), with
    ``gain_margins_db`` = -20 log10 |L| there. ``pm_deg``: the smallest signed phase margin (NaN
    if |L| never crosses 1), the conservative value for a "PM > x at every crossover" design check
    (``verify``, the torque-loop bounds of the report); the region maps choose the crossover by
    ``LoopOptions.pm_rule`` instead. ``gm_db``: the smallest gain margin (inf if no phase crossover).
    """

    gain_crossovers: np.ndarray
    phase_margins_deg: np.ndarray
    phase_crossovers: np.ndarray
    gain_margins_db: np.ndarray

    @property
    def pm_deg(self) -> float:
        return float(self.phase_margins_deg.min()) if self.phase_margins_deg.size else float("nan")

    @property
    def gm_db(self) -> float:
        return float(self.gain_margins_db.min()) if self.gain_margins_db.size else float("inf")


def default_omega(Ts: float, n: int = 4000, w_min: float = 0.1) -> np.ndarray:
    """Log-spaced grid from ``w_min`` to just below Nyquist pi/Ts (rad/s)."""
    return np.logspace(np.log10(w_min), np.log10(np.pi / Ts * (1 - 1e-9)), n)


def _crossings(x: np.ndarray, y: np.ndarray, level: float):
    """Interpolated x where y crosses ``level`` (sign change between samples), and the weights."""
    s = y - level
    idx = np.flatnonzero((s[:-1] == 0) | (np.sign(s[:-1]) * np.sign(s[1:]) < 0))
    t = np.where(s[idx] == s[idx + 1], 0.0, s[idx] / (s[idx] - s[idx + 1]))
    return idx, t


def stability_margins(L: np.ndarray, omega: np.ndarray) -> Margins:
    """Margins of the loop transfer ``L`` sampled at increasing ``omega`` (rad/s).

    Example
    -------
    >>> w = np.logspace(-1, 3, 2000)
    >>> m = stability_margins(10 / (1j * w * (1j * w / 100 + 1)), w)
    >>> round(m.pm_deg, 1)
    84.3
    """
    L = np.asarray(L)
    omega = gain_array("omega", omega)
    if omega.ndim != 1 or L.shape != omega.shape or omega.size < 2:
        raise ParameterError(f"L has shape {L.shape} and omega {omega.shape}; allowed: two 1-D arrays "
                             "of the same length >= 2")
    if omega[0] <= 0 or np.any(np.diff(omega) <= 0):
        raise ParameterError("omega is not positive and increasing; allowed: increasing frequencies > 0 (rad/s)")
    lw = np.log(omega)
    with np.errstate(divide="ignore"):          # |L| = 0 (a zero gain) is -inf dB: no crossover
        mag = np.log10(np.abs(L))
    ph = np.degrees(np.unwrap(np.angle(L)))
    i, t = _crossings(lw, mag, 0.0)
    wc = np.exp(lw[i] + t * (lw[i + 1] - lw[i]))
    phc = ph[i] + t * (ph[i + 1] - ph[i])
    pm = (phc + 180.0 + 180.0) % 360.0 - 180.0
    pm = np.where(pm == -180.0, 180.0, pm)
    wp, gm = [], []
    for k in range(int(np.floor((ph.min() + 180) / 360)), int(np.ceil((ph.max() + 180) / 360)) + 1):
        j, u = _crossings(lw, ph, -180.0 + 360.0 * k)
        wp.extend(np.exp(lw[j] + u * (lw[j + 1] - lw[j])))
        gm.extend(-20 * (mag[j] + u * (mag[j + 1] - mag[j])))
    order = np.argsort(wp)
    return Margins(wc, pm, np.asarray(wp)[order], np.asarray(gm)[order])
