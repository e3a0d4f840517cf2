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

from haa_sym.budget import check_memory, sweep_bytes
from haa_sym.loop import ClosedLoop, LoopOptions
from haa_sym.params import ParameterError, Params, gain_points

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
    _, _, beta, alpha = gain_points(0.0, 0.0, beta, alpha)
    Ts = params.controller.Ts
    n = int(round(duration / Ts)) + 1
    check_memory(16 * n, f"duration = {duration!r} s: a step response of {float(n):.4g} samples")
    loop = loop or ClosedLoop(params, options)
    A, B, C, D = closed_loop_matrices(loop, 0.0, 0.0, beta, alpha, cut="T_ref")
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
    _, _, beta, alpha = gain_points(0.0, 0.0, beta, alpha)
    loop = loop or ClosedLoop(params, options)
    check_memory(sweep_bytes(1, loop.options.n_omega), f"the torque loop on n_omega = {loop.options.n_omega} frequencies")
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


def p1_roots(params: Params) -> np.ndarray:
    """Roots (1/s) of p1 of Eq. (3)-(4), computed numerically from the plant (no sympy).

    The zeros of V_m -> T_l (Eq. 2) are those of (K_hd + D_hd s) p1(s) (the velocity
    compensation does not move them); the root at -K_hd/D_hd is removed. An independent check of
    the symbolic rows of ``python -m haa_sym.verify``.

    Example
    -------
    >>> np.round(p1_roots(load_params().with_values(K_L2=0.0)).real, 3)    # doctest: +SKIP
    array([-7.53619948e+04, -2.55227e+02, -1.722e+00,  0.0])
    """
    from haa_sym.exact import to_float, transfer_polynomials
    from haa_sym.plant import OUTPUTS, continuous_plant
    cp = continuous_plant(params.plant)
    _, nums = transfer_polynomials(cp.A, cp.B[:, :1], cp.C)
    num = np.trim_zeros(to_float(nums[OUTPUTS.index("T_l")][0]), "f")
    roots = np.roots(num)
    spring_zero = -params.plant.K_hd / params.plant.D_hd
    roots = np.delete(roots, np.argmin(np.abs(roots - spring_zero)))
    roots = np.where(np.abs(roots) < 1e-9 * np.abs(roots).max(), 0.0, roots)
    return np.sort_complex(roots)


def torque_loop_margins(params: Params, *, options: LoopOptions | None = None,
                        beta: float | None = None, alpha: float | None = None):
    """Margins of the torque loop alone, opened at the PI output (Sec. 3.2 design targets:
    PM > 30 deg, GM > 12 dB at the leg-inertia and stiffness bounds). Returns
    :class:`haa_sym.margins.Margins`."""
    from haa_sym.margins import stability_margins
    _, _, beta, alpha = gain_points(0.0, 0.0, beta, alpha)
    loop = ClosedLoop(params, options)
    check_memory(sweep_bytes(1, 4 * loop.options.n_omega),
                 f"the torque loop on 4 x n_omega = {4 * loop.options.n_omega} frequencies")
    ctrl = params.controller
    w = np.logspace(np.log10(loop.options.omega_min), np.log10(np.pi / ctrl.Ts * (1 - 1e-9)),
                    4 * loop.options.n_omega)
    coef = loop.loop_coefficients(w, beta, alpha)
    return stability_margins(coef.evaluate("L_t", 0.0, 0.0), w)
