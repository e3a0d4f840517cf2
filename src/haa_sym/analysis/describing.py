"""Describing-function estimates of limit cycles in the loop (docs/describing.md).

One memoryless nonlinearity at a time is cut out of the sampled closed loop; the rest of the
loop is linear, ``G``, written so that the loop closes as ``u = -G n(u)``: the signal ``u`` the
nonlinearity sees goes round the loop and comes back with negative sign. A sinusoid
``u = A sin(omega t)`` through the nonlinearity gives a fundamental ``N(A) A sin(omega t)``
(the describing function ``N``, real for the odd single-valued nonlinearities here); a limit
cycle is predicted where the harmonic balance ``1 + N(A) G(j omega) = 0`` holds. As ``N`` is
real and positive, that is ``arg G = -180 deg`` (a phase crossover, located by root finding of
``sin(arg G)`` from the sign changes on the loop's frequency grid) and ``N(A) = -1 / G`` there
(solved for ``A`` in closed form or by root finding).

The nonlinearities (their parameters plain data, ``{"V_max": 24.0}``; the names of issue 19's
``[limits]`` section):

``V_max`` (V)        saturation of the voltage command ``V_k`` (PI output + velocity
                     compensation) before the delay and the zero-order hold; ``u = V_k`` (V),
                     discrete: ``G = K_T G_TV + K_theta G_thV`` at ``z = exp(j omega Ts)``.
``I_max`` (A)        a current-commanded structure (``impedance_current``): saturation of the
                     current command ``I_k`` (T_ref / (k_t N)) before the delay and the hold,
                     ``u = I_k`` (A), the same ``G`` with the current-commanded plant's column.
``T_res`` (Nm)       a rounding quantiser of step ``T_res`` on the torque the loop reads; ``u`` the
                     torque (Nm), discrete: ``G = K_T G_TV / (1 + K_theta G_thV)``.
``Fc_m``, ``Fc_<body>`` (Nm)  Coulomb friction ``-Fc sign(v)`` on the rotor or on a body; ``u`` its
                     velocity ``v`` (rad/s), a continuous signal: ``G`` is the fundamental
                     harmonic response of the sampled-data loop from a torque on that body to its
                     velocity (the continuous plant, the sampled controller, the hold).

``K_T`` and ``K_theta`` are the controller's two branches (every element of the loop: the PI of
Eq. 7, the impedance law Eq. 8 with its velocity estimate, velocity compensation Eq. 6 and the
delay): the applied voltage is ``V = -(K_T T + K_theta theta)``. The Loeb criterion decides
whether a predicted cycle is stable (attracting in amplitude).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from haa_sym.analysis.oscillation import limit_cycle
from haa_sym.analysis.simulate import simulate
from haa_sym.analysis.sweep import BLAS_THREADS, blas_limits
from haa_sym.errors import ParameterError
from haa_sym.loop import ClosedLoop, loop_first
from haa_sym.loop.plant import continuous_plant, current_commanded, with_lag
from haa_sym.model.limits import Limits
from haa_sym.model.params import gain_array

__all__ = ["LimitCycles", "NONLINEARITIES", "describing_function", "df_harmonics", "limit_cycles", "limit_nonlinearities",
           "linear_part", "nonlinearity_output", "compare_cycle", "confirm_cycles", "CONFIRM_TOL_FLOOR",
           "DISTORTION_STRONG", "SUBHARMONIC_TOL", "CONFIRM_CYCLES", "CONFIRM_MIN_DURATION", "CONFIRM_MAX_DURATION",
           "CONFIRM_EXPERIMENT"]

# key (or prefix) -> (what the nonlinearity sees, the unit of that signal, the unit of the parameter)
NONLINEARITIES = {
    "V_max": ("voltage command V_k (PI output + velocity compensation, before the hold)", "V", "V"),
    "I_max": ("current command I_k (T_ref / (k_t N), before the hold)", "A", "A"),
    "T_res": ("torque the loop reads (the torque sensor)", "Nm", "Nm"),
    "Fc_m": ("rotor velocity dtheta_m", "rad/s", "Nm"),
    "Fc_<body>": ("velocity dtheta_<body> of the body", "rad/s", "Nm"),
}
KINDS = {"V_max": "saturation", "I_max": "saturation", "T_res": "quantiser", "Fc": "relay"}
# Which saturation is the command's own, by the structure's command (haa_sym.model.structures):
# the other limit is a window that moves with the rotor's speed (the current limit of a voltage
# command, the supply of a current command; docs/simulate.md), which no describing function here
# covers; a current command's loop reads no torque, so a torque quantiser is outside its loop
COMMAND_SATURATION = {"voltage": "V_max", "current": "I_max"}
NO_DF = {"voltage": {"I_max": "the current limit of a voltage command is a window that moves with the speed"},
         "current": {"V_max": "the supply of a current command is a window of currents that moves with the speed",
                     "T_res": "a current-commanded structure reads no torque: the quantiser is outside its loop"}}


@dataclass(frozen=True)
class LimitCycles:
    """Predicted limit cycles of one nonlinearity at one gain point.

    Attributes
    ----------
    nonlinearity : str
        The key (``V_max``, ``T_res``, ``Fc_m``, ``Fc_<body>``); ``value`` its parameter, in
        ``value_unit`` (V or Nm).
    signal, unit : str
        What the nonlinearity sees and its unit (the unit of ``amplitude``).
    amplitude : ndarray
        Amplitude ``A`` of the sinusoid at the nonlinearity's input, one per predicted cycle.
    omega, frequency_hz : ndarray
        Its frequency, rad/s and Hz.
    stable : ndarray of bool
        Loeb criterion: the cycle attracts perturbations of its amplitude (``loeb > 0``).
    loeb : ndarray
        ``N'(A) N(A) (Re G Im G' - Re G' Im G)`` at the cycle (G' = dG/domega); > 0 stable.
    G_crossing : ndarray
        ``Re G`` at the phase crossover (``-1/N(A)``; dimensionless).
    distortion : ndarray
        Filtering check: ``sum_k |G(k omega)| |b_k(A)| / (|G(omega)| |b_1(A)|)`` over the odd
        harmonics k = 3 .. ``k_max`` (b_k: the harmonics of the nonlinearity's output), the
        harmonic content that returns to the nonlinearity's input relative to the fundamental,
        added in magnitude; the prediction is trustworthy when it is small (docs/describing.md).
    omega_curve, G_curve : ndarray
        The loop's ``G`` on the frequency grid (rad/s; complex), for the Nyquist-type figure.
    amplitude_curve, minus_inv_N : ndarray
        ``-1/N(A)`` on a grid of amplitudes (real: the negative real axis).
    meta : dict
        ``loop.provenance()`` with the gain point, the nonlinearity and the options.
    """

    nonlinearity: str
    value: float
    value_unit: str
    signal: str
    unit: str
    amplitude: np.ndarray
    omega: np.ndarray
    frequency_hz: np.ndarray
    stable: np.ndarray
    loeb: np.ndarray
    G_crossing: np.ndarray
    distortion: np.ndarray
    omega_curve: np.ndarray = field(repr=False)
    G_curve: np.ndarray = field(repr=False)
    amplitude_curve: np.ndarray = field(repr=False)
    minus_inv_N: np.ndarray = field(repr=False)
    meta: dict = field(repr=False, default_factory=dict)

    def to_dict(self) -> dict:
        """The cycles as plain JSON data (the curves left out)."""
        cycles = [{"amplitude": float(a), "unit": self.unit, "omega_rad_s": float(w), "frequency_hz": float(f),
                   "stable": bool(s), "loeb": float(lb), "G_crossing": float(g), "distortion": float(d)}
                  for a, w, f, s, lb, g, d in zip(self.amplitude, self.omega, self.frequency_hz, self.stable,
                                                  self.loeb, self.G_crossing, self.distortion)]
        return {"nonlinearity": self.nonlinearity, "value": self.value, "value_unit": self.value_unit,
                "signal": self.signal,
                "unit": self.unit, "limit_cycles": cycles, "meta": self.meta}


# --- the describing functions ---------------------------------------------------------------------
def _kind(key: str) -> str:
    return KINDS["Fc"] if key.startswith("Fc_") else KINDS[key]


def nonlinearity_output(kind: str, value: float, u: np.ndarray) -> np.ndarray:
    """The nonlinearity itself, ``n(u)``: saturation at +-value, rounding to multiples of value,
    or the relay ``value sign(u)`` (Coulomb friction's magnitude; the loop applies it with minus)."""
    u = np.asarray(u, float)
    if kind == "saturation":
        return np.clip(u, -value, value)
    if kind == "quantiser":
        return value * np.round(u / value)
    return value * np.sign(u)


def describing_function(kind: str, value: float, A) -> tuple[np.ndarray, np.ndarray]:
    """``(N(A), dN/dA)`` of a nonlinearity for the input amplitude(s) ``A`` (the signal's unit).

    saturation (limit ``value``): 1 for A <= value, else (2/pi)(asin a + a sqrt(1 - a^2)), a = value/A;
    relay (``value`` sign(u)): 4 value / (pi A);
    quantiser (rounding, step q = ``value``): (4 q / (pi A)) sum_i sqrt(1 - ((2i - 1) q / (2 A))^2)
    over the thresholds (2i - 1) q / 2 below A (0 below the first).
    """
    A = np.asarray(A, float)
    if kind == "saturation":
        a = np.minimum(value / A, 1.0)
        r = np.sqrt(np.maximum(1 - a * a, 0.0))
        return (2 / np.pi) * (np.arcsin(a) + a * r), -(4 / np.pi) * (a / A) * r
    if kind == "relay":
        N = 4 * value / (np.pi * A)
        return N, -N / A
    q = value
    n = np.floor(A / q + 0.5).astype(int)                # thresholds (2i - 1) q / 2 <= A
    i = np.arange(1, max(int(n.max(initial=0)), 1) + 1)
    c = (2 * i - 1) * q / 2 / A[..., None]
    on = i <= n[..., None]
    r = np.sqrt(np.where(on, np.maximum(1 - c * c, 1e-300), 1.0))
    N = 4 * q / (np.pi * A) * np.where(on, r, 0.0).sum(-1)
    dN = -N / A + 4 * q / (np.pi * A ** 2) * np.where(on, c * c / r, 0.0).sum(-1)
    return N, dN


def df_harmonics(kind: str, value: float, A: float, k_max: int = 39, n: int = 65536) -> np.ndarray:
    """Amplitudes ``|b_k|`` of the odd harmonics k = 1, 3, ..., ``k_max`` of ``n(A sin t)`` (FFT over
    one period of ``n`` points, midpoints: about 1e-4 relative where the nonlinearity jumps)."""
    t = 2 * np.pi * (np.arange(n) + 0.5) / n
    c = np.fft.rfft(nonlinearity_output(kind, value, A * np.sin(t))) * 2 / n
    return np.abs(c[1:k_max + 1:2])


# --- the linear part ------------------------------------------------------------------------------
def _controller(loop: ClosedLoop, P: float, D: float, omega: np.ndarray):
    """``(K_T, K_theta)``: the applied voltage V = -(K_T T + K_theta theta) at z = exp(j omega Ts)."""
    ctrl, el = loop.params.controller, loop.elements
    Ts = ctrl.Ts
    E = {k: el[k].frequency_response(omega, Ts) for k in ("F_d", "F_vc", "I_z", "z_delay")}
    # the structure's gains (haa_sym.model.structures): P_r on the reference, P_m on the torque
    P_r, P_m = ctrl.beta * loop.const[0], ctrl.beta * loop.P_m0
    I_t, VC = ctrl.beta * loop.const[1], ctrl.alpha * loop.const[2]
    K_T = E["z_delay"] * (P_m + I_t * E["I_z"])
    K_th = E["z_delay"] * ((P_r + I_t * E["I_z"]) * (P + D * E["F_d"]) - VC * E["F_vc"])
    return K_T, K_th


def _friction_input(loop: ClosedLoop, key: str):
    """(continuous plant, input column of a torque on the body, velocity row) for ``Fc_<body>``:
    the plant behind the drive's lag (its states first, as in ``loop.plant``; the drive's delay
    is applied by :func:`linear_part`)."""
    cont = with_lag(current_commanded(continuous_plant(loop.params.plant, loop.backend),
                                      loop.structure.command == "current"), loop.params.drive.tau_drive)
    body = key[3:]
    names = cont.state_names
    if f"dtheta_{body}" not in names:
        bodies = [n[7:] for n in names if n.startswith("dtheta_")]
        raise ParameterError(f"{key}: no body {body!r} in this actuator; allowed: "
                             + ", ".join(f"Fc_{b}" for b in bodies) + " (Nm)")
    row = np.zeros(len(names))
    row[names.index(f"dtheta_{body}")] = 1.0
    if body == "m":
        col = cont.B[:, cont.input_names.index("T_fr")]
    else:
        col = np.zeros(len(names))
        J = getattr(loop.params.plant, f"J_{body}", None)
        if J is None:
            raise ParameterError(f"{key}: the body {body!r} has no inertia J_{body} in this model; allowed: "
                                 "friction on a body of the chain (docs/describing.md)")
        col[names.index(f"dtheta_{body}")] = 1.0 / J
    return cont, col, row


def linear_part(loop: ClosedLoop, P_gain: float, D_gain: float, key: str, omega) -> np.ndarray:
    """``G(omega)`` (complex, dimensionless in the nonlinearity's signal) seen by nonlinearity
    ``key`` at one gain point: the loop closes as u = -G n(u) (module docstring)."""
    omega = np.asarray(omega, float)
    kind = _kind(key)
    K_T, K_th = _controller(loop, P_gain, D_gain, omega)
    if kind != "relay":
        G = loop.plant.frequency_response(omega, outputs=(loop.torque_output, "theta_encoder"), inputs=("V_m",))
        G_TV, G_thV = G[0, 0], G[1, 0]
        if kind == "saturation":
            return K_T * G_TV + K_th * G_thV
        return K_T * G_TV / (1 + K_th * G_thV)
    # the sampled-data loop's fundamental response to a torque f e^{j omega t} on the body: the
    # samples of the measurements are G_mf f + G_mV,d V (exactly, at z = exp(j omega Ts)), the
    # controller closes V = -K y, and the hold's fundamental (1 - e^{-j omega Ts})/(j omega Ts)
    # carries V back into continuous time (the images at omega + k 2 pi/Ts are left out); the
    # drive's dead time delays that held voltage by e^{-j omega delay_drive} (its lag is a state
    # of cont, its delay line the last states of loop.plant, which the continuous plant lacks)
    cont, col, row = _friction_input(loop, key)
    Ts = loop.params.controller.Ts
    n = cont.A.shape[0]
    C_m = loop.plant.C[[loop.plant_output(loop.torque_output), loop.plant_output("theta_encoder")], :n]
    M = 1j * omega[:, None, None] * np.eye(n) - cont.A
    rhs = np.broadcast_to(np.stack([col, cont.B[:, cont.input_names.index("V_m")]], axis=1), (omega.size, n, 2))
    X = np.linalg.solve(M, rhs)                                   # (w, n, 2): columns f, V
    G_vf, G_vV = X[:, :, 0] @ row, X[:, :, 1] @ row
    G_mf = np.einsum("on,wn->ow", C_m, X[:, :, 0])
    Gd = loop.plant.frequency_response(omega, outputs=(loop.torque_output, "theta_encoder"), inputs=("V_m",))
    V = -(K_T * G_mf[0] + K_th * G_mf[1]) / (1 + K_T * Gd[0, 0] + K_th * Gd[1, 0])
    x = omega * Ts
    hold = np.where(x > 0, -np.expm1(-1j * x) / np.where(x > 0, 1j * x, 1.0), 1.0)
    hold = hold * np.exp(-1j * omega * loop.params.drive.delay_drive)
    # the friction torque is -n(v): G = (velocity per unit torque on the body)
    return G_vf + G_vV * hold * V


# --- the harmonic balance -------------------------------------------------------------------------
def _check(nonlinearity) -> tuple[str, float]:
    if not isinstance(nonlinearity, dict) or len(nonlinearity) != 1:
        raise ParameterError(f"nonlinearity = {nonlinearity!r}; allowed: one entry, e.g. {{'V_max': 24.0}} "
                             f"(keys {list(NONLINEARITIES)})")
    (key, value), = nonlinearity.items()
    if key not in NONLINEARITIES and not (isinstance(key, str) and key.startswith("Fc_") and len(key) > 3):
        raise ParameterError(f"nonlinearity {key!r}; allowed: {', '.join(NONLINEARITIES)}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    unit = NONLINEARITIES.get(key, NONLINEARITIES["Fc_<body>"])[2]
    if not (math.isfinite(v) and VALUE_RANGE[0] <= v <= VALUE_RANGE[1]):
        raise ParameterError(f"{key} = {value!r}; allowed: a number from {VALUE_RANGE[0]:g} to {VALUE_RANGE[1]:g} "
                             f"({unit})")
    return key, v


# The nonlinearity's parameter, in its unit: the amplitudes searched are multiples of it (up to
# amplitude_max) and the root finding's tolerances relative to it, so a value near the ends of
# the floating-point range (T_res = 1e-310, subnormal) left them no digits (xtol 0: a traceback)
VALUE_RANGE = (1e-100, 1e100)


def _amplitudes(kind: str, value: float, N_target: float, A_max: float) -> list[float]:
    """Every amplitude A with N(A) = N_target (> 0)."""
    # scipy.optimize takes about 0.25 s to import (docs/startup.md): only the commands that locate a root pay it
    from scipy.optimize import brentq
    if kind == "relay":
        return [4 * value / (np.pi * N_target)]
    if kind == "saturation":
        if N_target >= 1:
            return []                         # N <= 1: only a loop with |G| > 1 at the crossover
        # N as a function of a = value/A in (0, 1) is increasing: one root
        a = brentq(lambda a: (2 / np.pi) * (np.arcsin(a) + a * math.sqrt(1 - a * a)) - N_target,
                   0.0, 1.0, xtol=1e-15, rtol=1e-14)
        return [value / a] if a > 0 else []
    # quantiser: N is continuous but rises like sqrt(A - t) just above each threshold t, then falls
    # smoothly to the next; the samples start at the threshold itself and crowd there (quadratic
    # in the offset, so the sqrt rise is sampled evenly), else the root on the steep rise (where
    # N' > 0) falls between two intervals' samples and is lost
    out = []
    q = value
    edges = (np.arange(1, int(A_max / q) + 2) - 0.5) * q
    for lo, hi in zip(edges[:-1], edges[1:]):
        s = lo + (hi - lo) * np.linspace(0.0, 1.0, 33) ** 2
        s[-1] = hi * (1 - 1e-12)
        f = describing_function(kind, q, s)[0] - N_target
        for i in np.flatnonzero(np.sign(f[1:]) != np.sign(f[:-1])):
            out.append(brentq(lambda A: float(describing_function(kind, q, np.array(A))[0]) - N_target,
                              s[i], s[i + 1], xtol=1e-14 * hi))
    return out


@loop_first
def limit_cycles(loop: ClosedLoop, P_gain: float, D_gain: float, *, nonlinearity: dict,
                 n_omega: int = 4000, amplitude_max: float = 200.0, k_max: int = 39) -> LimitCycles:
    """Describing-function prediction of the limit cycles of one nonlinearity at one gain point.

    Parameters
    ----------
    loop : ClosedLoop
        The sampled loop (its ``beta``, ``alpha`` and options).
    P_gain, D_gain : float
        Impedance stiffness (Nm/rad) and damping (Nms/rad), Eq. (8); 0 and 0 is the torque loop
        alone (the impedance loop open, T_ref = 0).
    nonlinearity : dict
        One entry: ``{"V_max": V}`` (V), ``{"T_res": q}`` (Nm), ``{"Fc_m": F}`` or
        ``{"Fc_<body>": F}`` (Nm).
    n_omega : int
        Points of the loop's log frequency grid (``omega_min`` to Nyquist pi/Ts) whose sign
        changes of ``sin(arg G)`` bracket the phase crossovers (each then refined by brentq).
        Default 4000.
    amplitude_max : float
        Quantiser only: amplitudes searched up to ``amplitude_max`` steps. Default 200.
    k_max : int
        The highest odd harmonic in ``distortion``. Default 39.

    Returns
    -------
    LimitCycles
        Every (A, omega) of the harmonic balance, the crossings in increasing frequency.
    """
    key, value = _check(nonlinearity)
    command = loop.structure.command
    if key in NO_DF[command]:
        ok = ", ".join(k for k in NONLINEARITIES if k not in NO_DF[command])
        raise ParameterError(f"{key}: structure = {loop.structure.name!r} commands a {command}, and "
                             f"{NO_DF[command][key]}; allowed: {ok}")
    # many small stacked solves: threaded BLAS only contends for the cores (as in the sweeps)
    with blas_limits(BLAS_THREADS):
        return _limit_cycles(loop, P_gain, D_gain, key, value, n_omega, amplitude_max, k_max)


def _limit_cycles(loop, P_gain, D_gain, key, value, n_omega, amplitude_max, k_max) -> LimitCycles:
    from scipy.optimize import brentq
    kind = _kind(key)
    P, D = (gain_array(n, v, n).ravel() for n, v in (("P_gain", P_gain), ("D_gain", D_gain)))
    if P.size != 1 or D.size != 1:
        raise ParameterError(f"P_gain has {P.size} and D_gain {D.size} values; allowed: one gain point "
                             "(one value each)")
    P, D = float(P[0]), float(D[0])
    if not (isinstance(n_omega, int) and n_omega >= 10):
        raise ParameterError(f"n_omega = {n_omega!r}; allowed: an integer >= 10")
    if not (isinstance(k_max, int) and k_max >= 3 and k_max % 2):
        raise ParameterError(f"k_max = {k_max!r}; allowed: an odd integer >= 3")
    Ts = loop.params.controller.Ts
    w_nyq = math.pi / Ts
    grid = np.append(loop.options.numerics.omega(Ts, n_omega), w_nyq)

    def G(w):
        return linear_part(loop, P, D, key, np.atleast_1d(np.asarray(w, float)))

    Gg = G(grid)
    s = np.sin(np.angle(Gg))
    found = []
    for i in np.flatnonzero((np.sign(s[1:]) != np.sign(s[:-1])) & np.isfinite(s[1:]) & np.isfinite(s[:-1])):
        if s[i + 1] == 0 and i + 1 == grid.size - 1:
            w = grid[-1]                               # real at Nyquist (the discrete loops)
        else:
            w = brentq(lambda x: float(np.sin(np.angle(G(x)[0]))), grid[i], grid[i + 1], xtol=1e-13 * grid[i + 1])
        g = G(w)[0]
        if g.real < 0 and abs(g.imag) <= 1e-6 * abs(g):
            found.append((w, g.real))
    # a sampled loop is real at Nyquist (up to rounding): a negative G there is a crossover
    if kind != "relay" and abs(Gg[-1].imag) <= 1e-9 * abs(Gg[-1]) and Gg[-1].real < 0 \
            and not any(abs(w - w_nyq) <= 1e-9 * w_nyq for w, _ in found):
        found.append((w_nyq, Gg[-1].real))
    rows = []
    for w, g in found:
        h = 1e-6 * w
        dG = (G(min(w + h, w_nyq))[0] - G(w - h)[0]) / (min(w + h, w_nyq) - (w - h))
        for A in _amplitudes(kind, value, -1.0 / g, amplitude_max * value):
            N, dN = (float(v) for v in describing_function(kind, value, np.array(A)))
            # Loeb: N' N (Re G Im G' - Re G' Im G), with Im G = 0 at the crossing
            loeb = dN * N * g * dG.imag
            b = df_harmonics(kind, value, A, k_max)
            Gk = np.abs(G(w * np.arange(3, k_max + 1, 2)))
            rows.append((A, w, loeb, g, float((Gk * b[1:]).sum() / (abs(g) * b[0])) if b[0] > 0 else np.inf))
    rows.sort(key=lambda r: (r[1], r[0]))
    cols = [np.array(c, float) for c in zip(*rows)] if rows else [np.empty(0)] * 5
    A, w, loeb, g, dist = cols
    # the locus -1/N(A) drawn: from the saturation's limit (-1) or below the quantiser's first
    # threshold (-inf); the relay's -1/N = -pi A/(4 F) tends to 0, so it starts three decades
    # down; and always past every predicted amplitude, else a cycle is drawn where no locus is
    lo = {"saturation": 0.0, "quantiser": -0.3, "relay": -3.0}[kind]
    hi = 3.0
    if A.size:
        lo, hi = min(lo, math.log10(A.min() / value) - 0.3), max(hi, math.log10(A.max() / value) + 0.3)
    amp_curve = value * np.logspace(lo, hi, 400)
    N_curve = describing_function(kind, value, amp_curve)[0]
    with np.errstate(divide="ignore"):
        minus_inv_N = np.where(N_curve > 0, -1.0 / N_curve, -np.inf)
    meta = loop.provenance(analysis="limit_cycles", P_gain=P, D_gain=D, nonlinearity={key: value},
                           describing_function=kind, n_omega=n_omega, k_max=k_max)
    info = NONLINEARITIES.get(key, NONLINEARITIES["Fc_<body>"])
    signal = info[0].replace("<body>", key[3:]) if key.startswith("Fc_") and key != "Fc_m" else info[0]
    return LimitCycles(key, value, info[2], signal, info[1], A, w, w / (2 * np.pi), loeb > 0, loeb, g, dist,
                       grid, Gg, amp_curve, minus_inv_N, meta)


def limit_nonlinearities(limits, command: str = "voltage") -> list[dict]:
    """The entries of a :class:`haa_sym.model.limits.Limits` a describing function predicts, each
    as a ``nonlinearity`` of :func:`limit_cycles`: the command's saturation (``V_max`` of a
    voltage command, ``I_max`` of a current command: ``command``, the structure's), the torque
    quantum of a loop that reads the torque (``torque_resolution`` as ``T_res``) and every
    Coulomb friction ``Fc_m``, ``Fc_<body>`` (the windows that move with the speed, encoder
    quantisation, noise and jitter have no describing function here: :data:`NO_DF`)."""
    out = []
    if command == "voltage" and limits.V_max:
        out.append({"V_max": float(limits.V_max)})
    if command == "current" and limits.I_max:
        out.append({"I_max": float(limits.I_max)})
    if command == "voltage" and limits.torque_resolution:
        out.append({"T_res": float(limits.torque_resolution)})
    out += [{f"Fc_{b}": float(v)} for b, v in limits.friction.items() if v > 0]
    return out


# --- is a prediction borne out? (issue 26, item 6) -------------------------------------------------

#: A predicted cycle agrees with a simulated one when the amplitude's and the frequency's relative
#: errors are both within max(its distortion, CONFIRM_TOL_FLOOR): the distortion is the first
#: neglected term of the harmonic balance (docs/describing.md, "How good is the prediction"),
#: the floor what the sampled cycle's locking to whole samples adds (0.4 % in the 24 V case)
CONFIRM_TOL_FLOOR = 0.02
#: Above this distortion the harmonics are strong: the DF is not to be trusted without a
#: simulation (the harmonic drive at 2 V: 0.166 predicted 3.27 Hz, the loop cycles at 1.31 Hz)
DISTORTION_STRONG = 0.1
#: A simulated frequency within this relative distance of f_pred / k (k = 2, 3, ...) is a
#: sub-harmonic cycle, which a describing function of the fundamental cannot predict
SUBHARMONIC_TOL = 0.05
#: The confirming simulation: CONFIRM_CYCLES periods of the predicted frequency, at least
#: CONFIRM_MIN_DURATION and at most CONFIRM_MAX_DURATION seconds, from CONFIRM_EXPERIMENT
CONFIRM_CYCLES = 60
CONFIRM_MIN_DURATION = 2.0
CONFIRM_MAX_DURATION = 30.0
CONFIRM_EXPERIMENT = "deflection"


def _signal_column(key: str, port: str):
    """(CSV column of ``haa-sym simulate`` carrying the nonlinearity's signal, "input" or
    "output"), or (None, None): the supply's command is not a column, its held output is; the
    rotor's velocity is not a column."""
    if key in ("V_max", "I_max"):               # the held command's column (a current's for I_max)
        return "voltage", "output"
    if key == "T_res":
        return "torque", "input"
    if key == f"Fc_{port}":
        return "velocity", "input"
    return None, None


def compare_cycle(r: LimitCycles, k: int, columns: dict, Ts: float, *, port: str, n_limits: int = 1) -> dict:
    """The predicted cycle ``k`` of ``r`` against a simulated run (``columns``: the CSV's columns
    of :func:`haa_sym.analysis.simulate.simulate`, on the nominal instants k ``Ts``).

    The compared signal: the held voltage's fundamental against N(A) A for ``V_max``, the torque
    signal's amplitude against A for ``T_res`` (``resolution`` its quantum), the port body's
    velocity for its friction; for the rotor's friction the torque signal's frequency only. The
    trace classifier runs without the torque quantum as hysteresis here: a quantiser's predicted
    cycle of A near half a step is a one-step toggle of the torque read.

    Parameters
    ----------
    port : str
        The port body's name (its velocity is the CSV's ``velocity``).
    n_limits : int
        How many limits acted in the run: more than one, and the prediction (one nonlinearity
        alone) is not the run's loop.

    Returns
    -------
    dict
        ``signal``, ``predicted_amplitude``, ``predicted_frequency_hz``, ``simulated_kind``,
        ``simulated_amplitude``, ``simulated_frequency_hz``, ``amplitude_error``,
        ``frequency_error`` (relative; None when not comparable), ``tolerance``, ``agrees``
        (bool) and ``untrusted`` (the reasons, plain sentences; empty when it can be trusted).
    """
    col, side = _signal_column(r.nonlinearity, port)
    A, f, d = float(r.amplitude[k]), float(r.frequency_hz[k]), float(r.distortion[k])
    pred_amp = float(describing_function("saturation", r.value, A)[0]) * A if side == "output" else A
    shown = "current command" if r.nonlinearity == "I_max" else col
    out = {"signal": shown or "torque (frequency only)", "predicted_amplitude": pred_amp, "predicted_frequency_hz": f,
           "simulated_kind": None, "simulated_amplitude": None, "simulated_frequency_hz": None,
           "amplitude_error": None, "frequency_error": None, "tolerance": max(d, CONFIRM_TOL_FLOOR),
           "agrees": False, "untrusted": []}
    why = out["untrusted"]
    if n_limits > 1:
        why.append(f"{n_limits} limits act at once (the prediction cuts out one)")
    strong = f"strong harmonics (distortion {d:.3g} > {DISTORTION_STRONG:g})" if d > DISTORTION_STRONG else None
    y = columns.get(col or "torque")
    if y is None or len(y) < 8 or not np.all(np.isfinite(y)):
        why.append("the simulation has no usable trace (it diverged or is too short)")
        return out
    o = limit_cycle(np.arange(len(y)) * Ts, y)
    out["simulated_kind"] = o.kind
    if o.kind != "sustained":
        why += [strong] if strong else []
        why.append(f"the simulation shows no sustained periodic oscillation ({o.kind})")
        return out
    sim_amp = o.fundamental if side == "output" else o.amplitude
    out.update(simulated_frequency_hz=o.frequency_hz, frequency_error=abs(o.frequency_hz - f) / f)
    if col is not None:
        out.update(simulated_amplitude=sim_amp, amplitude_error=abs(sim_amp - pred_amp) / pred_amp)
    tol = out["tolerance"]
    out["agrees"] = bool(out["frequency_error"] <= tol and (col is None or out["amplitude_error"] <= tol))
    ratio = f / o.frequency_hz
    if round(ratio) >= 2 and abs(ratio / round(ratio) - 1) <= SUBHARMONIC_TOL:
        why.append(f"a sub-harmonic cycle (simulated at 1/{round(ratio)} of the predicted frequency)")
    if not out["agrees"] and strong:
        why.append(strong)
    if not out["agrees"]:
        why.append("the simulation disagrees (error beyond the tolerance "
                   f"{tol:.3g}: amplitude {_pct(out['amplitude_error'])}, frequency {_pct(out['frequency_error'])})")
    return out


def _pct(x) -> str:
    return "n/a" if x is None else f"{100 * x:.3g} %"


def confirm_cycles(loop, P_gain: float, D_gain: float, r: LimitCycles, *, seed: int = 0) -> list[dict]:
    """Confirm every stable predicted cycle of ``r`` by a short simulation of the loop with that
    one nonlinearity (:func:`haa_sym.analysis.simulate.simulate`, experiment
    :data:`CONFIRM_EXPERIMENT` at its default amplitude, :data:`CONFIRM_CYCLES` predicted periods
    within [:data:`CONFIRM_MIN_DURATION`, :data:`CONFIRM_MAX_DURATION`] s) and compare
    (:func:`compare_cycle`). One list entry per predicted cycle (None for an unstable one: no
    simulation settles on it). A run from one initial state confirms only the cycle it reaches."""
    key = r.nonlinearity
    if key == "V_max":
        lim = Limits(V_max=r.value)
    elif key == "I_max":
        lim = Limits(I_max=r.value)
    elif key == "T_res":
        lim = Limits(torque_resolution=r.value)
    else:
        lim = Limits(friction={key[3:]: r.value})
    out = []
    for k in range(r.amplitude.size):
        if not r.stable[k]:
            out.append(None)
            continue
        dur = min(max(CONFIRM_CYCLES / float(r.frequency_hz[k]), CONFIRM_MIN_DURATION), CONFIRM_MAX_DURATION)
        s = simulate(loop, P_gain, D_gain, limits=lim, experiment=CONFIRM_EXPERIMENT, duration=dur, seed=seed)
        c = compare_cycle(r, k, s.columns(), loop.params.controller.Ts, port=loop.params.plant.topology.port)
        c.update(duration_s=dur, experiment=CONFIRM_EXPERIMENT, verdict=s.verdict)
        out.append(c)
    return out
