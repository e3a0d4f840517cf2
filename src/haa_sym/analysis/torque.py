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

from haa_sym.analysis.margins import Margins, loop_polynomials, margins
from haa_sym.errors import ParameterError
from haa_sym.io.budget import check_memory, sweep_bytes
from haa_sym.loop.exact import to_float, transfer_polynomials
from haa_sym.loop.plant import continuous_plant
from haa_sym.loop.statespace import INPUT_NAMES, OUTPUT_NAMES, closed_loop_batch
from haa_sym.model.params import Params, gain_array
from haa_sym.loop import loop_first

__all__ = ["StepResponse", "step_response", "step_info", "dc_gain", "describe_step",
           "torque_bandwidth", "BANDWIDTH_DEFINITIONS", "LoadMode", "load_mode", "step_figures",
           "STEP_CONVENTION", "ImpedanceStep", "impedance_step", "torque_loop_margins",
           "LOW_BAND_DECADES"]


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
    loop.require("torque_loop", "step_response")
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
    loop.require("torque_loop", "dc_gain")
    _, _, beta, alpha = loop.gain_points(0.0, 0.0, beta, alpha)
    coef = loop.loop_coefficients(np.array([1e-6]), beta, alpha)
    return float(coef.H_T[0].real)


#: How far below the options' ``omega_min`` (decades) the torque loop's crossovers and a slow
#: loop's tracking bandwidth are sought.
LOW_BAND_DECADES = 6

#: The torque bandwidth's definitions (:func:`torque_bandwidth`), by name.
BANDWIDTH_DEFINITIONS = {
    "magnitude": "the paper's (Sec. 3.3): the lowest frequency where |H_T| falls 3 dB below its value at "
                 "omega_min",
    "tracking": "the engineer's: the lowest frequency where the tracking error |1 - H_T| reaches -3 dB "
                "(1/sqrt 2)",
}


@loop_first
def torque_bandwidth(loop, *, beta: float | None = None, alpha: float | None = None,
                     definition: str = "magnitude") -> float:
    """The torque loop's bandwidth, rad/s, by one of :data:`BANDWIDTH_DEFINITIONS`.

    ``"magnitude"`` (default; the paper's, Sec. 3.3, used by the reproduction and the
    schedule): the lowest frequency where |T/T_lref| falls 3 dB below its low-frequency value
    (at ``omega_min``). On a drive whose load has an anti-resonance or a lightly damped mode
    this is where |H_T| dips or has risen and fallen back, not where the loop stops tracking:
    the bundled SEA's 1.78 rad/s lies above a +5.5 dB peak at 1.07 rad/s.

    ``"tracking"`` (``haa-sym tune``'s default): the lowest frequency where the tracking error
    E = 1 - H_T (the error's response to the reference) first reaches |E| = 1/sqrt 2 (-3 dB):
    below it the loop removes at least 29 % of a sinusoidal reference's error, whatever the
    magnitude of H_T does. A resonance peak or a notch of H_T both raise |E|, so neither can
    push the figure past them. It is the "error (sensitivity) bandwidth" of loop-shaping texts
    (e.g. Skogestad and Postlethwaite, Multivariable Feedback Control, Sec. 2.4.5: omega_B,
    where |S| first crosses 1/sqrt 2 from below; E = S for a unit-feedback loop, and the loop
    here has a filtered measurement, so E is computed from H_T directly).

    The paper defines the torque bandwidth with the leg free to move in the air (Sec. 3.3);
    build the loop with K_L2 = 0 for that. Both are interpolated linearly in log-log between
    the options' grid samples. NaN if the threshold is not reached below Nyquist; a tracking
    bandwidth below ``omega_min`` (a slow loop) is sought :data:`LOW_BAND_DECADES` decades
    further down, NaN if |E| is above the threshold there too.

    Example
    -------
    >>> torque_bandwidth(ClosedLoop(load_params().with_values(K_L2=0.0)))   # doctest: +SKIP
    30.36...
    """
    loop.require("torque_loop", "torque_bandwidth")
    if definition not in BANDWIDTH_DEFINITIONS:
        raise ParameterError(f"definition = {definition!r}; allowed: {list(BANDWIDTH_DEFINITIONS)}")
    _, _, beta, alpha = loop.gain_points(0.0, 0.0, beta, alpha)
    check_memory(sweep_bytes(1, loop.options.numerics.n_omega), f"the torque loop on n_omega = {loop.options.numerics.n_omega} frequencies")
    coef = loop.loop_coefficients(None, beta, alpha)
    omega = coef.omega
    if definition == "magnitude":
        mag = np.abs(coef.H_T)
        # falls 3 dB below the low-frequency value: ln(mag/ref) reaches -ln 2 / 2
        level = np.log(mag / mag[0]) + 0.5 * np.log(2)
        k = np.flatnonzero(level < 0)
    else:
        def tracking_level(H):
            with np.errstate(divide="ignore"):
                return -(np.log(np.abs(1.0 - H)) + 0.5 * np.log(2))   # <= 0 where |E| >= 1/sqrt 2
        level = tracking_level(coef.H_T)
        k = np.flatnonzero(level <= 0)
        if k.size and k[0] == 0:
            # a slow loop tracks badly already at omega_min: its bandwidth lies below the band,
            # sought over LOW_BAND_DECADES decades below it (as its crossovers)
            omega = omega[0] * np.logspace(-LOW_BAND_DECADES, 0, 20 * LOW_BAND_DECADES + 1)
            level = tracking_level(loop.loop_coefficients(omega, beta, alpha, cached=False).H_T)
            k = np.flatnonzero(level <= 0)
    if k.size == 0 or k[0] == 0:
        return float("nan")
    k = k[0]
    lw = np.log(omega)
    t = level[k - 1] / (level[k - 1] - level[k])
    return float(np.exp(lw[k - 1] + t * (lw[k] - lw[k - 1])))


#: A feature of |H_T| counts as the load's mode when it departs this far from the
#: low-frequency value (dB) ...
LOAD_MODE_DB = 3.0
#: ... at a frequency below this multiple of the bandwidth (an octave above it: the loop's
#: response there is still shaped by it).
LOAD_MODE_FACTOR = 2.0


@dataclass(frozen=True)
class LoadMode:
    """A resonance peak or anti-resonance notch of |H_T| near the torque bandwidth
    (:func:`load_mode`): ``kind`` "peak" or "notch", ``omega`` (rad/s), ``depth_db`` (|H_T|
    there relative to its low-frequency value, dB; > 0 a peak, < 0 a notch)."""

    kind: str
    omega: float
    depth_db: float

    def describe(self) -> str:
        what = "resonance peak" if self.kind == "peak" else "anti-resonance notch"
        return f"|H_T| {what} {self.depth_db:+.1f} dB at {self.omega:.3g} rad/s"


@loop_first
def load_mode(loop, bandwidth: float, *, beta: float | None = None, alpha: float | None = None):
    """The load mode that dominates the torque response, or None.

    The lowest local extremum of |H_T| on the options' grid that departs more than
    :data:`LOAD_MODE_DB` (3 dB) from the low-frequency value, a resonance peak (above) or an
    anti-resonance notch (below), when it lies below :data:`LOAD_MODE_FACTOR` (2) times
    ``bandwidth`` (rad/s, e.g. :func:`torque_bandwidth`): the figure the bandwidth gives is then
    the load mode's, not the loop's (a step rings at it). None also when ``bandwidth`` is NaN.
    """
    loop.require("torque_loop", "load_mode")
    if not np.isfinite(bandwidth):
        return None
    _, _, beta, alpha = loop.gain_points(0.0, 0.0, beta, alpha)
    coef = loop.loop_coefficients(None, beta, alpha)
    db = 20 * np.log10(np.abs(coef.H_T) / abs(coef.H_T[0]))
    w = coef.omega
    inner = np.arange(1, w.size - 1)
    peak = (db[inner] > db[inner - 1]) & (db[inner] >= db[inner + 1]) & (db[inner] > LOAD_MODE_DB)
    notch = (db[inner] < db[inner - 1]) & (db[inner] <= db[inner + 1]) & (db[inner] < -LOAD_MODE_DB)
    hits = inner[peak | notch]
    if not hits.size or w[hits[0]] >= LOAD_MODE_FACTOR * bandwidth:
        return None
    i = hits[0]
    return LoadMode("peak" if db[i] > 0 else "notch", float(w[i]), float(db[i]))


#: Settling band of the torque-loop figures (+-5 % of the final value).
SETTLING_BAND = 0.05


def step_figures(s: StepResponse, settling_band: float = SETTLING_BAND) -> dict:
    """The torque step's figures as an engineer reads them, where a spike cannot fake them.

    ``t90_s``: the time from which the response stays at or above 90 % of the final value
    (the last time it is below, plus one sample; NaN if it is below at the window's end);
    ``rise_time_s``: from the last time the response is below 10 % before that to ``t90_s``
    (a 10-90 % rise that an initial spike cannot shorten); ``settling_time_s``: the last time
    the response leaves the +-``settling_band`` band around the final value, plus one sample
    (:func:`step_info`'s rule with a 5 % band; NaN if not settled in the window).
    Times in s from the step.
    """
    t, y, yf = s.t, s.T, s.final_value
    nan = float("nan")
    out = {"t90_s": nan, "rise_time_s": nan,
           "settling_time_s": float(step_info(t, y, yf, settling_threshold=settling_band)["SettlingTime"])}
    if not np.isfinite(yf) or yf == 0:
        return out
    r = np.sign(yf) * y / abs(yf)
    below90 = np.flatnonzero(r < 0.9)
    k90 = 0 if below90.size == 0 else below90[-1] + 1
    if k90 >= t.size:
        return out
    below10 = np.flatnonzero(r[:k90] < 0.1)
    k10 = 0 if below10.size == 0 else below10[-1]
    out.update(t90_s=float(t[k90]), rise_time_s=float(t[k90] - t[k10]))
    return out


@loop_first
def torque_bandwidth_map(loop, beta, alpha):
    """Torque bandwidth (rad/s, :func:`torque_bandwidth`) and stability of the torque loop alone
    (impedance loop open) on the grid ``beta`` x ``alpha``: arrays of shape (n_beta, n_alpha).

    The trade the paper's Sec. 3 describes: higher torque gains (beta, Eq. 7) and more velocity
    compensation (alpha, Eq. 6) widen the bandwidth until the loop goes unstable. The bandwidth is
    NaN where the torque loop is unstable. For the paper's definition (leg free in the air) build
    the loop with the port body's ground stiffness 0 (K_L2 = 0).
    """
    loop.require("torque_loop", "torque_bandwidth_map")
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
    The plant's alone: the drive (``[drive]``) adds a pole (its lag) and a dead time, no zero.

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
    exactly (:func:`haa_sym.analysis.margins.margins`).

    A crossover below the options' band is still a crossover: a PI with a small integral gain
    crosses |L_t| = 1 below ``omega_min``. |L_t| is sampled at 20 points a decade over
    :data:`LOW_BAND_DECADES` decades below ``omega_min``; where it crosses 1 there, the band is
    extended down to the lowest such sample (same density) and the crossovers and phase
    crossovers are located exactly on it.

    Raises
    ------
    ParameterError
        |L_t| is below 1 and still rising at the bottom of that extension: a crossover may lie
        further down, where the torque loop does nothing useful.
    """
    loop.require("torque_loop", "torque_loop_margins")
    _, _, beta, alpha = loop.gain_points(0.0, 0.0, beta, alpha)
    base = loop.options.omega(loop.params.controller.Ts)
    x = np.array([[1.0, 0.0, 0.0]])
    poly = loop_polynomials(loop, beta, alpha, "L_t", base)
    n_ext = 20 * LOW_BAND_DECADES
    low = base[0] * np.logspace(-LOW_BAND_DECADES, 0, n_ext + 1)
    mag = np.abs(poly.gain(np.repeat(x, low.size, axis=0), low))
    above = mag >= 1
    change = np.flatnonzero(above[:-1] != above[1:])
    omega = None
    if change.size:
        lo = low[change[0]]
        per_decade = (base.size - 1) / np.log10(base[-1] / base[0])
        m = max(2, int(np.ceil(per_decade * np.log10(base[0] / lo))) + 1)
        omega = np.concatenate([np.geomspace(lo, base[0], m)[:-1], base])
    elif not above[0] and mag[0] > mag[1]:
        raise ParameterError(
            f"the torque loop at beta = {beta:g}, alpha = {alpha:g}: |L_t| = {mag[0]:.3g} at {low[0]:.3g} rad/s, "
            f"{LOW_BAND_DECADES} decades below omega_min = {base[0]:g} rad/s, and still rising below it, so its gain "
            "crossover is lower still; allowed: a torque PI whose loop gain reaches 1 above that frequency")
    return margins(loop, 0.0, 0.0, beta, alpha, which="L_t", omega=omega)


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
