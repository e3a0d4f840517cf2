"""The torque loop alone (Sec. 3.2-3.3, Fig. 7): unit torque step responses and bandwidth.

The impedance loop is open: the torque reference T_lref is the input, the measured torque the
output, with the PI of Eq. (7) and the velocity compensation of Eq. (6) closed.

Example
-------
>>> from haa_sym import ClosedLoop, load_params
>>> from haa_sym.analysis.torque import step_response
>>> s = step_response(ClosedLoop(load_params()), duration=0.3)  # doctest: +SKIP
>>> s.rise_time, s.settling_time, s.overshoot_pct                # doctest: +SKIP
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from haa_sym.analysis.margins import Margins, margins
from haa_sym.errors import ParameterError
from haa_sym.io.budget import check_memory, sweep_bytes
from haa_sym.loop.exact import to_float, transfer_polynomials
from haa_sym.loop.plant import continuous_plant
from haa_sym.loop.statespace import INPUT_NAMES, OUTPUT_NAMES, closed_loop_batch
from haa_sym.model.params import Params, gain_array
from haa_sym.loop import loop_first

__all__ = ["StepResponse", "step_response", "step_info", "dc_gain", "describe_step",
           "torque_bandwidth", "STEP_CONVENTION", "ImpedanceStep", "impedance_step"]


# python-control ``step_info`` / MATLAB ``stepinfo`` defaults
SETTLING_THRESHOLD = 0.02
RISE_LIMITS = (0.1, 0.9)
STEP_CONVENTION = ("rise 10-90 % of the final value, settling within 2 % of it, overshoot in % of "
                   "it (python-control step_info / MATLAB stepinfo); final value = DC gain T/T_lref")


def step_info(t, y, final_value: float | None = None, *,
              settling_threshold: float = SETTLING_THRESHOLD,
              rise_limits: tuple[float, float] = RISE_LIMITS) -> dict:
    """Step-response characteristics of sampled data, python-control ``step_info`` convention.

    Parameters
    ----------
    t : (n,) array
        Sample times, s.
    y : (n,) array
        Response to a step applied at ``t[0]``.
    final_value : float, optional
        Steady-state value the metrics are relative to; default ``y[-1]`` (``step_info``'s
        default for data, which calls any response "settled" at its last sample).
    settling_threshold : float
        Settled: |y / final_value - 1| < this from some sample to the end of the data.
    rise_limits : (float, float)
        Rise time from the first sample at ``rise_limits[0]`` to the first at ``rise_limits[1]``
        of the final value.

    Returns
    -------
    dict
        The keys of ``control.step_info``: ``RiseTime``, ``SettlingTime``, ``PeakTime`` (s),
        ``Overshoot``, ``Undershoot`` (% of the final value), ``SettlingMin``, ``SettlingMax``,
        ``Peak``, ``SteadyStateValue`` (units of ``y``). The numbers equal ``step_info``'s
        whenever the data settle, with two differences where they do not: ``RiseTime`` is NaN
        when ``y`` never reaches the upper rise limit (``step_info`` raises IndexError), and
        ``Overshoot`` is NaN when ``y`` has not settled by ``t[-1]`` (a later peak may be higher;
        ``step_info`` reports the peak seen so far). ``SettlingTime`` is NaN when not settled.

    Example
    -------
    >>> t = np.arange(6.0)
    >>> info = step_info(t, np.array([0, 0.5, 1.2, 0.99, 1.0, 1.0]), 1.0)
    >>> info["RiseTime"], info["SettlingTime"], round(info["Overshoot"], 6)
    (1.0, 3.0, 20.0)
    >>> step_info(t, t / 10, 1.0)["RiseTime"]       # never reaches 90 % of the final value
    nan
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    yf = float(y[-1] if final_value is None else final_value)
    nan = float("nan")
    info = {"RiseTime": nan, "SettlingTime": nan, "SettlingMin": nan, "SettlingMax": nan,
            "Overshoot": nan, "Undershoot": nan, "Peak": nan, "PeakTime": nan, "SteadyStateValue": yf}
    if not np.isfinite(yf) or yf == 0:
        return info
    sgn = np.sign(yf)
    lo = np.flatnonzero(sgn * (y - rise_limits[0] * yf) >= 0)
    hi = np.flatnonzero(sgn * (y - rise_limits[1] * yf) >= 0)
    outside = np.flatnonzero(np.abs(y / yf - 1) >= settling_threshold)
    settled = 0 if outside.size == 0 else outside[-1] + 1
    if hi.size:
        info.update(RiseTime=t[hi[0]] - t[lo[0]], SettlingMin=min(y[hi[0]:].min(), yf),
                    SettlingMax=max(y[hi[0]:].max(), yf))
    if settled < t.size:
        info["SettlingTime"] = t[settled]
        info["Overshoot"] = max(0.0, 100.0 * (np.abs((sgn * y).max()) - abs(yf)) / abs(yf))
    y_us = y[(sgn * y).argmin()]
    info["Undershoot"] = -100.0 * y_us / yf if sgn * y_us < 0 else 0.0
    k = np.abs(y).argmax()
    info.update(Peak=np.abs(y[k]), PeakTime=t[k])
    return {key: float(v) for key, v in info.items()}


@dataclass(frozen=True)
class StepResponse:
    """Samples ``t`` (s) and measured torque ``T`` (Nm) after a unit step of T_lref at t = 0;
    ``final_value`` is the steady state the loop tends to (its DC gain; 1 with the PI's integral
    action). The metrics follow :func:`step_info` relative to ``final_value``: NaN when the
    response does not reach 90 % of it / does not settle within 2 % of it inside the window."""

    t: np.ndarray
    T: np.ndarray
    final_value: float = 1.0

    @property
    def info(self) -> dict:
        """:func:`step_info` of the samples relative to ``final_value``."""
        return step_info(self.t, self.T, self.final_value)

    @property
    def rise_time(self) -> float:
        """10 % to 90 % of the final value, s (NaN if 90 % is not reached in the window)."""
        return float(self.info["RiseTime"])

    @property
    def settling_time(self) -> float:
        """Entry into +-2 % of the final value for good, s (NaN if not settled in the window)."""
        return float(self.info["SettlingTime"])

    @property
    def overshoot_pct(self) -> float:
        """Peak above the final value, % of it (0 if none; NaN if not settled in the window)."""
        return float(self.info["Overshoot"])


def describe_step(s: StepResponse) -> str:
    """One line of step metrics for people, saying "not reached" / "not settled" where
    :func:`step_info` gives NaN, and the window they refer to. An unsettled response that has
    already passed its final value has an overshoot of at least its peak so far (a later peak may
    be higher): said as a lower bound; "undefined" only when it has not passed the final value."""
    info, end = s.info, f"{s.t[-1]:g} s"

    def ms(x, never):
        return f"{x * 1e3:.1f} ms" if np.isfinite(x) else never
    yf = s.final_value
    above = 100.0 * (np.max(np.sign(yf) * s.T) - abs(yf)) / abs(yf) if np.isfinite(yf) and yf != 0 else np.nan
    if np.isfinite(info["Overshoot"]):
        overshoot = f"{info['Overshoot']:.1f} %"
    elif above > 0:
        overshoot = f"at least {above:.1f} % (the peak within {end}; not settled)"
    else:
        overshoot = f"undefined (below the final value until {end}; not settled)"
    return (f"final value (DC gain) {s.final_value:.4f}; rise time (10-90 %) "
            f"{ms(info['RiseTime'], 'not reached within ' + end)}, settling time (2 %) "
            f"{ms(info['SettlingTime'], 'not settled within ' + end)}, overshoot {overshoot}"
            f"; T at {end} = {s.T[-1]:.4f}")


@loop_first
def step_response(loop, *, duration: float = 0.3, beta: float | None = None,
                  alpha: float | None = None) -> StepResponse:
    """Unit step of the torque reference with the impedance loop open (Fig. 7).

    Parameters
    ----------
    loop : ClosedLoop
        Plant, controller and options; K_L2 = 0 is the gravity-compensated free leg.
    duration : float
        Simulated time, s.
    beta, alpha : float, optional
        Torque-gain scale (Eq. 7) and velocity compensation (Eq. 6).

    Returns
    -------
    StepResponse
    """
    t = _step_times(loop, duration)
    _, _, beta, alpha = loop.gain_points(0.0, 0.0, beta, alpha)
    ss = [m[0] for m in closed_loop_batch(loop, 0.0, 0.0, beta, alpha, cut="T_ref")]
    # cut at T_ref, the loop's input "r" is the torque reference
    T = _unit_step(*ss, output="T_meas", input="r", n=t.size)
    return StepResponse(t, T, dc_gain(loop, beta=beta, alpha=alpha))


def _step_times(loop, duration: float) -> np.ndarray:
    """The sample instants (s) of a step response of ``duration`` seconds, checked."""
    if not np.isfinite(duration) or duration <= 0:
        raise ParameterError(f"duration = {duration!r}; allowed: a finite time > 0 (s)")
    Ts = loop.params.controller.Ts
    n = int(round(duration / Ts)) + 1
    check_memory(16 * n, f"duration = {duration!r} s: a step response of {float(n):.4g} samples")
    return np.arange(n) * Ts


def _unit_step(A, B, C, D, *, output: str, input: str, n: int) -> np.ndarray:
    """``n`` samples of the closed loop's ``output`` after a unit step on ``input`` from rest
    (names of :data:`haa_sym.loop.statespace.OUTPUT_NAMES` and ``INPUT_NAMES``)."""
    i, j = OUTPUT_NAMES.index(output), INPUT_NAMES.index(input)
    x = np.zeros(A.shape[0])
    y = np.empty(n)
    for k in range(n):
        y[k] = C[i] @ x + D[i, j]
        x = A @ x + B[:, j]
    return y


@loop_first
def dc_gain(loop, *, beta: float | None = None, alpha: float | None = None) -> float:
    """Steady-state gain T_l / T_lref of the torque loop (impedance loop open), Nm/Nm.

    Evaluated on the generated frequency response at 1e-6 rad/s rather than as
    C (I - A)^-1 B + D: with the leg free (K_L2 = 0) the closed loop keeps a pole at z = 1 that
    the torque output does not see, and the matrix form is then singular (python-control's
    ``dcgain`` returns 1.22 for a loop whose step tends to 1).
    """
    _, _, beta, alpha = loop.gain_points(0.0, 0.0, beta, alpha)
    coef = loop.loop_coefficients(np.array([1e-6]), beta, alpha)
    return float(coef.H_T[0].real)


@loop_first
def torque_bandwidth(loop, *, beta: float | None = None, alpha: float | None = None) -> float:
    """Lowest frequency (rad/s) where |T/T_lref| falls 3 dB below its low-frequency value.

    The paper defines the torque bandwidth with the leg free to move in the air (Sec. 3.3);
    build the loop with K_L2 = 0 for that. NaN if |H_T| never drops 3 dB below Nyquist.

    Example
    -------
    >>> torque_bandwidth(ClosedLoop(load_params().with_values(K_L2=0.0)))   # doctest: +SKIP
    30.36...
    """
    _, _, beta, alpha = loop.gain_points(0.0, 0.0, beta, alpha)
    check_memory(sweep_bytes(1, loop.options.numerics.n_omega), f"the torque loop on n_omega = {loop.options.numerics.n_omega} frequencies")
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


@loop_first
def torque_bandwidth_map(loop, beta, alpha):
    """Torque bandwidth (rad/s, :func:`torque_bandwidth`) and stability of the torque loop alone
    (impedance loop open) on the grid ``beta`` x ``alpha``: arrays of shape (n_beta, n_alpha).

    The trade the paper's Sec. 3 describes: higher torque gains (beta, Eq. 7) and more velocity
    compensation (alpha, Eq. 6) widen the bandwidth until the loop goes unstable. The bandwidth is
    NaN where the torque loop is unstable. For the paper's definition (leg free in the air) build
    the loop with the port body's ground stiffness 0 (K_L2 = 0).
    """
    B = gain_array("beta", beta).ravel()
    A = gain_array("alpha", alpha).ravel()
    BB, AA = np.meshgrid(B, A, indexing="ij")
    # the free position mode of a free leg is not seen by the torque: stability without it
    res = loop.stability(np.zeros(BB.shape), np.zeros(BB.shape), BB, AA)
    stable = res.stable | res.marginal
    bw = np.full(BB.shape, np.nan)
    for i, j in zip(*np.nonzero(stable)):
        bw[i, j] = torque_bandwidth(loop, beta=B[i], alpha=A[j])
    return bw, stable


def p1_roots(params: Params) -> np.ndarray:
    """Roots (1/s) of p1 of Eq. (3)-(4), computed numerically from the plant (no sympy).

    The zeros of V_m -> T_l (Eq. 2) are those of (K_hd + D_hd s) p1(s) (the velocity
    compensation does not move them); the root at -K_hd/D_hd is removed. An independent check of
    the symbolic rows of ``python -m haa_sym.check.verify``. For another topology: the zeros of
    V_m -> T_sensor without the sensor coupling's own zero -K/D (p1 is the paper's, HyQ's, name;
    with the torque from the current, ``[sensors] torque = "current"``, all zeros of V_m -> T_sensor).

    Example
    -------
    >>> np.round(p1_roots(load_params().with_values(K_L2=0.0)).real, 3)    # doctest: +SKIP
    array([-7.53619948e+04, -2.55227e+02, -1.722e+00,  0.0])
    """
    cp = continuous_plant(params.plant)
    _, nums = transfer_polynomials(cp.A, cp.B[:, :1], cp.C)
    num = np.trim_zeros(to_float(nums[cp.output_names.index("T_sensor")][0]), "f")
    roots = np.roots(num)
    sensor = params.plant.topology.sensor
    D = getattr(params.plant, f"D_{sensor}", 0.0)       # 0: the current estimate, no coupling
    if D > 0:                       # the sensor coupling's own zero (K + D s)
        spring_zero = -getattr(params.plant, f"K_{sensor}") / D
        roots = np.delete(roots, np.argmin(np.abs(roots - spring_zero)))
    roots = np.where(np.abs(roots) < 1e-9 * np.abs(roots).max(), 0.0, roots)
    return np.sort_complex(roots)


@loop_first
def torque_loop_margins(loop, *, beta: float | None = None, alpha: float | None = None) -> Margins:
    """Margins of the torque loop alone (impedance gains 0), opened at the PI output (Sec. 3.2
    design targets: PM > 30 deg, GM > 12 dB at the leg-inertia and stiffness bounds), located
    exactly (:func:`haa_sym.analysis.margins.margins`)."""
    return margins(loop, 0.0, 0.0, beta, alpha, which="L_t")


@dataclass(frozen=True)
class ImpedanceStep:
    """:func:`impedance_step`: samples ``t`` (s) and the encoder angle ``theta`` (rad) after a
    unit step of the external torque T_dist (1 Nm) on the port at t = 0, with the impedance loop
    closed; ``final_value`` (rad/Nm) is the closed loop's DC compliance, C (I - A)^-1 B + D, NaN
    when the loop is not asymptotically stable (no steady state)."""

    t: np.ndarray
    theta: np.ndarray
    final_value: float


@loop_first
def impedance_step(loop, P_gain: float = 0.0, D_gain: float = 0.0, *, duration: float = 0.3,
                   beta: float | None = None, alpha: float | None = None) -> ImpedanceStep:
    """The rendered impedance in the time domain: the encoder angle after a unit torque step
    on the port, impedance loop closed at one gain point (theta_ref = 0; an ideal spring
    P_gain would settle at 1 / P_gain rad per Nm, less where the port body has its own
    stiffness to ground).

    Parameters
    ----------
    loop : ClosedLoop
    P_gain, D_gain : float
        Impedance stiffness (Nm/rad) and damping (Nms/rad), Eq. (8); one point.
    duration : float
        Simulated time, s.
    beta, alpha : float, optional
        Torque-gain scale (Eq. 7) and velocity compensation (Eq. 6).

    Returns
    -------
    ImpedanceStep
    """
    t = _step_times(loop, duration)
    P, D, beta, alpha = loop.gain_points(P_gain, D_gain, beta, alpha)
    if P.size != 1:
        raise ParameterError(f"P_gain has {P.size} values; allowed: one gain point")
    A, B, C, Dm = (m[0] for m in closed_loop_batch(loop, P, D, beta, alpha))
    theta = _unit_step(A, B, C, Dm, output="theta_encoder", input="T_dist", n=t.size)
    i, j = OUTPUT_NAMES.index("theta_encoder"), INPUT_NAMES.index("T_dist")
    stable = bool(np.all(loop.stability(P, D, beta, alpha).stable))
    final = float(C[i] @ np.linalg.solve(np.eye(A.shape[0]) - A, B[:, j]) + Dm[i, j]) if stable else float("nan")
    return ImpedanceStep(t, theta, final)
