"""The torque loop alone (Sec. 3.2-3.3, Fig. 7): unit torque step responses and bandwidth.

The impedance loop is open: the torque reference T_lref is the input, the measured torque the
output, with the PI of Eq. (7) and the velocity compensation of Eq. (6) closed.

Example
-------
>>> from haa_sym import load_params
>>> from haa_sym.torque import step_response
>>> s = step_response(load_params(), duration=0.3)              # doctest: +SKIP
>>> s.rise_time                                                 # doctest: +SKIP
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from haa_sym.loop import ClosedLoop, LoopOptions
from haa_sym.params import ParameterError, Params

__all__ = ["StepResponse", "step_response", "torque_bandwidth"]


@dataclass(frozen=True)
class StepResponse:
    """Samples ``t`` (s) and measured torque ``T`` (Nm) after a unit step of T_lref at t = 0."""

    t: np.ndarray
    T: np.ndarray

    def _cross(self, level: float) -> float:
        k = np.flatnonzero(self.T >= level)
        return float(self.t[k[0]]) if k.size else float("nan")

    @property
    def rise_time(self) -> float:
        """10 % to 90 % of the unit reference, s (NaN if not reached in the window)."""
        return self._cross(0.9) - self._cross(0.1)

    @property
    def overshoot(self) -> float:
        """max T - 1, as a fraction of the unit step."""
        return float(self.T.max() - 1.0)

    @property
    def settling_time(self) -> float:
        """Last time |T - 1| > 5 %, s (NaN if it never settles in the window)."""
        k = np.flatnonzero(np.abs(self.T - 1.0) > 0.05)
        if k.size == 0:
            return 0.0
        return float("nan") if k[-1] == self.T.size - 1 else float(self.t[k[-1] + 1])


def step_response(params: Params, *, duration: float = 0.3, options: LoopOptions | None = None,
                  beta: float | None = None, alpha: float | None = None,
                  loop: ClosedLoop | None = None) -> StepResponse:
    """Unit step of the torque reference with the impedance loop open (Fig. 7).

    Parameters
    ----------
    params : Params
        Plant and controller; K_L2 = 0 is the gravity-compensated free leg.
    duration : float
        Simulated time, s.
    beta, alpha : float, optional
        Torque-gain scale (Eq. 7) and velocity compensation (Eq. 6).

    Returns
    -------
    StepResponse
    """
    from haa_sym.reference import closed_loop_matrices
    if not np.isfinite(duration) or duration <= 0:
        raise ParameterError(f"duration = {duration!r}; allowed: a finite time > 0 (s)")
    loop = loop or ClosedLoop(params, options)
    A, B, C, D = closed_loop_matrices(loop, 0.0, 0.0, beta, alpha, cut="T_ref")
    Ts = params.controller.Ts
    n = int(round(duration / Ts)) + 1
    x = np.zeros(A.shape[0])
    T = np.empty(n)
    for k in range(n):
        T[k] = C[0] @ x + D[0, 1]
        x = A @ x + B[:, 1]
    return StepResponse(np.arange(n) * Ts, T)


def torque_bandwidth(params: Params, *, options: LoopOptions | None = None,
                     beta: float | None = None, alpha: float | None = None,
                     loop: ClosedLoop | None = None) -> float:
    """Lowest frequency (rad/s) where |T/T_lref| falls 3 dB below its low-frequency value.

    The paper defines the torque bandwidth with the leg free to move in the air (Sec. 3.3);
    pass K_L2 = 0 in ``params`` for that. NaN if |H_T| never drops 3 dB below Nyquist.

    Example
    -------
    >>> torque_bandwidth(load_params().with_values(K_L2=0.0))             # doctest: +SKIP
    30.36...
    """
    loop = loop or ClosedLoop(params, options)
    coef = loop.loop_coefficients(None, beta, alpha)
    mag = np.abs(coef.H_T)
    ref = mag[0]
    k = np.flatnonzero(mag < ref / np.sqrt(2))
    if k.size == 0:
        return float("nan")
    k = k[0]
    lw = np.log(coef.omega)
    m0, m1 = np.log(mag[k - 1] / ref), np.log(mag[k] / ref)
    target = -0.5 * np.log(2)
    t = (target - m0) / (m1 - m0)
    return float(np.exp(lw[k - 1] + t * (lw[k] - lw[k - 1])))
