"""The actuator plant (Eq. 1-2 for HyQ, any chain of haa_sym.model.actuator): continuous state space
(generated from the sympy model of its topology) and its zero-order-hold discretisation at Ts.

Signals are named per plant (``state_names``, ``input_names``, ``output_names``, from the
topology): states ``[I_m, theta_m, dtheta_m, theta_X, dtheta_X ...]``, inputs
``[V_m, T_fr, T_dist]``, outputs ``[T_sensor, T_sensor_spring, theta_encoder, dtheta_X ...]``
where ``T_sensor`` is the torque sensor's coupling torque (Eq. 2, T_l for HyQ),
``T_sensor_spring`` its spring term alone and ``theta_encoder`` the encoder angle (theta_L1).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from haa_sym.errors import ParameterError
from haa_sym.model.params import Plant, load_params
from haa_sym.compiled.plant_code import plant_function

__all__ = ["ContinuousPlant", "DiscretePlant", "continuous_plant", "discretize", "with_lag", "current_commanded",
           "delay_split",
           "drive_states", "LAG_STATE", "DELAY_STATE"]

#: The names of the drive's states (haa_sym.model.drive): the lag's output (the command as the
#: motor receives it) and the delay line's held commands u[k-1], u[k-2], ...
LAG_STATE = "u_lag"
DELAY_STATE = "u_delay_{}"
# a fractional part of the delay below this fraction of Ts is a whole number of samples
# (rounding of delay_drive / Ts, e.g. 0.003 / 0.001 = 2.9999999999999996)
_WHOLE = 1e-9


def _index(names: tuple[str, ...], wanted, kind: str) -> list[int]:
    missing = [w for w in wanted if w not in names]
    if missing:
        raise ParameterError(f"{kind} {missing} not in this plant; allowed: {list(names)}")
    return [names.index(w) for w in wanted]


@dataclass(frozen=True)
class ContinuousPlant:
    """``dx/dt = A x + B u``, ``y = C x`` of Eq. (1)-(2); ``VC0`` is Eq. (6) at alpha = 1 (V s/rad).

    ``plant`` is the parameter set it was evaluated from (to name the key when sampling overflows).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    VC0: float
    plant: Plant | None = field(default=None, repr=False, compare=False)
    state_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()


@dataclass(frozen=True)
class DiscretePlant:
    """ZOH-sampled plant ``x[k+1] = Phi x[k] + Gamma u[k]``, ``y[k] = C x[k]`` at ``Ts`` seconds."""

    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    Ts: float
    VC0: float
    state_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()

    def frequency_response(self, omega: np.ndarray, outputs=None, inputs=None) -> np.ndarray:
        """``C (e^{j w Ts} I - Phi)^-1 Gamma`` for rows ``outputs``, columns ``inputs`` (names;
        default all of :attr:`output_names` and :attr:`input_names`).

        Returns a complex array of shape ``(len(outputs), len(inputs), len(omega))``; omega in rad/s.
        """
        omega = np.asarray(omega, dtype=float)
        rows = _index(self.output_names, self.output_names if outputs is None else outputs, "output(s)")
        cols = _index(self.input_names, self.input_names if inputs is None else inputs, "input(s)")
        z = np.exp(1j * omega * self.Ts)
        M = z[:, None, None] * np.eye(self.Phi.shape[0]) - self.Phi
        X = np.linalg.solve(M, np.broadcast_to(self.Gamma[:, cols], (len(z),) + self.Gamma[:, cols].shape))
        return np.einsum("oi,wij->ojw", self.C[rows], X)


def continuous_plant(plant: Plant, backend: str = "auto") -> ContinuousPlant:
    """Evaluate the plant function of ``plant.topology`` (Eq. 1-2, Eq. 6) for ``plant``: the
    generated one of a built-in actuator, else compiled on first use (:mod:`haa_sym.compiled.plant_code`).

    Raises :class:`ParameterError` naming the key when the matrices overflow (e.g. K_hd = 1e300).
    """
    cont = _evaluate(plant, backend)
    if not _finite(cont.A, cont.B, cont.C, cont.VC0):
        raise _overflow(plant, None, backend)
    return cont


#: The state a current command imposes (the motor's electrical state of every topology).
CURRENT_STATE = "I_m"


def current_commanded(cont: ContinuousPlant, current: bool = True) -> ContinuousPlant:
    """The plant with its motor current imposed: the state I_m removed and its column of A
    (k_t/J_m and, through nothing else, the mechanics' dependence on the current) made the
    command input (the first, still named ``V_m``: the command, here in A). Exact for an ideal
    current loop, as ``fit`` does with ``--input current``; the [drive] lag and delay then act
    on this command (:func:`with_lag`, :func:`discretize`). Output rows lose I_m's column (the
    estimate k_t N I_m of a current sensor is then no signal: a current-commanded structure
    reads no torque). ``current=False`` returns ``cont`` itself."""
    if not current:
        return cont
    i = cont.state_names.index(CURRENT_STATE)
    keep = [j for j in range(cont.A.shape[0]) if j != i]
    B = cont.B[keep].copy()
    B[:, 0] = cont.A[keep, i]
    return ContinuousPlant(cont.A[np.ix_(keep, keep)].copy(), B, cont.C[:, keep].copy(), cont.VC0, cont.plant,
                           tuple(cont.state_names[j] for j in keep), cont.input_names, cont.output_names)


def with_lag(cont: ContinuousPlant, tau_drive: float) -> ContinuousPlant:
    """The plant behind the drive's first-order lag 1 / (tau_drive s + 1) on its command input
    (the first, ``V_m``): one more state, :data:`LAG_STATE`, u_lag' = (u - u_lag) / tau_drive,
    which drives the plant through the command's old column. The torques (T_fr, T_dist) still
    act directly. ``tau_drive = 0`` returns ``cont`` itself (no lag: the paper's model)."""
    if not tau_drive > 0:
        return cont
    n, m = cont.B.shape
    A = np.zeros((n + 1, n + 1))
    A[:n, :n], A[:n, n], A[n, n] = cont.A, cont.B[:, 0], -1.0 / tau_drive
    B = np.zeros((n + 1, m))
    B[:n, 1:], B[n, 0] = cont.B[:, 1:], 1.0 / tau_drive
    C = np.hstack([cont.C, np.zeros((cont.C.shape[0], 1))])
    return ContinuousPlant(A, B, C, cont.VC0, cont.plant, cont.state_names + (LAG_STATE,), cont.input_names,
                           cont.output_names)


def delay_split(delay_drive: float, Ts: float) -> tuple[int, float]:
    """``delay_drive = whole Ts + frac`` with ``whole`` an integer >= 0 and 0 <= frac < Ts (s);
    a remainder within 1e-9 Ts of a whole sample counts as that whole sample."""
    q = delay_drive / Ts
    whole = int(np.floor(q + _WHOLE))
    frac = (q - whole) * Ts
    return whole, (0.0 if frac < _WHOLE * Ts else float(frac))


def drive_states(drive, Ts: float) -> int:
    """States the drive adds to the sampled plant at ``Ts``: 1 for a lag, and the delay line's
    ``whole`` (+1 with a fractional part) held commands (:func:`delay_split`)."""
    whole, frac = delay_split(drive.delay_drive, Ts)
    return int(drive.tau_drive > 0) + whole + int(frac > 0)


def discretize(cont: ContinuousPlant, Ts: float, delay_drive: float = 0.0) -> DiscretePlant:
    """Zero-order hold at ``Ts`` (s): expm of the augmented matrix [[A, B], [0, 0]] Ts; with the
    drive's dead time ``delay_drive`` (s) on the command input (the first column), exactly.

    The delay d = l Ts + f (0 <= f < Ts, :func:`delay_split`) is the modified z-transform's
    augmentation (Astrom and Wittenmark, Computer-Controlled Systems, Sec. 2.3): over one period
    the held command is u[k-l-1] for the first f seconds and u[k-l] for the rest, so
    x[k+1] = Phi x[k] + Gamma_0 u[k-l] + Gamma_1 u[k-l-1] with
    Gamma_0 = int_0^{Ts-f} e^{A s} ds b and Gamma_1 = e^{A (Ts-f)} int_0^f e^{A s} ds b, and the
    past commands are states (:data:`DELAY_STATE`, u[k-1] first). Exact for any d, not only whole
    samples; the new states sit at z = 0.
    """
    if not (isinstance(Ts, (int, float)) and np.isfinite(Ts) and Ts > 0):
        raise ParameterError(f"Ts = {Ts!r}; allowed: a finite number > 0 (seconds)")
    Phi, Gamma = _zoh(cont.A, cont.B, Ts)
    if not _finite(Phi, Gamma):
        raise _overflow(cont.plant, Ts)
    C = cont.C.copy()
    states = cont.state_names
    whole, frac = delay_split(delay_drive, Ts)
    if whole or frac:
        Phi, Gamma, C, states = _delayed(cont, Ts, Phi, Gamma, C, whole, frac)
    for arr in (Phi, Gamma, C):          # shared by every ClosedLoop of this plant (memoised)
        arr.setflags(write=False)
    return DiscretePlant(Phi, Gamma, C, float(Ts), cont.VC0, states, cont.input_names,
                         cont.output_names)


def _delayed(cont: ContinuousPlant, Ts: float, Phi, Gamma, C, whole: int, frac: float):
    """The sampled plant with the command delayed by ``whole`` Ts + ``frac`` (see discretize)."""
    n, m = Gamma.shape
    b = cont.B[:, :1]
    if frac:
        Phi_late, G_late = _zoh(cont.A, b, Ts - frac)       # e^{A (Ts-f)}, int_0^{Ts-f}
        _, G_early = _zoh(cont.A, b, frac)
        g0, g1 = G_late[:, 0], Phi_late @ G_early[:, 0]
    else:
        g0, g1 = Gamma[:, 0], None
    L = whole + int(bool(frac))
    N = n + L
    P = np.zeros((N, N))
    G = np.zeros((N, m))
    P[:n, :n] = Phi
    G[:n, 1:] = Gamma[:, 1:]
    G[n, 0] = 1.0                                           # u_delay_1[k+1] = u[k]
    for i in range(1, L):                                   # u_delay_{i+1}[k+1] = u_delay_i[k]
        P[n + i, n + i - 1] = 1.0
    if whole == 0:
        G[:n, 0] = g0
    else:
        P[:n, n + whole - 1] = g0                           # u[k - whole]
    if frac:
        P[:n, n + whole] = g1                               # u[k - whole - 1]
    Cd = np.hstack([C, np.zeros((C.shape[0], L))])
    names = cont.state_names + tuple(DELAY_STATE.format(i + 1) for i in range(L))
    return P, G, Cd, names


def _evaluate(plant: Plant, backend: str = "auto") -> ContinuousPlant:
    top = plant.topology
    f = plant_function(top, backend)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        A, B, C, VC0 = f(np.array(plant.as_tuple(), dtype=float))
    return ContinuousPlant(np.array(A), np.array(B), np.array(C), float(VC0), plant,
                           top.state_names, top.input_names, top.output_names)


def _zoh(A: np.ndarray, B: np.ndarray, Ts: float):
    n, m = B.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = A
    aug[:n, n:] = B
    with np.errstate(over="ignore", invalid="ignore"):
        E = scipy.linalg.expm(aug * Ts)
    return E[:n, :n].copy(), E[:n, n:].copy()


def _finite(*arrays) -> bool:
    return all(np.all(np.isfinite(a)) for a in arrays)


def _sampled_finite(plant: Plant, Ts: float | None, backend: str = "auto") -> bool:
    cont = _evaluate(plant, backend)
    return _finite(cont.A, cont.B, cont.C, cont.VC0) and (Ts is None or _finite(*_zoh(cont.A, cont.B, Ts)))


def _overflow(plant: Plant | None, Ts: float | None, backend: str = "auto") -> ParameterError:
    """The error for a plant whose matrices are not finite, naming the key(s) responsible.

    A key is named when setting it alone to 1 (SI) makes the matrices finite; Ts likewise.
    """
    what = "the plant matrices of Eq. (1)-(2)" + ("" if Ts is None else f" sampled at Ts = {Ts!r} s")
    keys = [] if plant is None else \
        [k for k in plant.keys if _sampled_finite(plant.replace(**{k: 1.0}), Ts, backend)]
    if not keys and plant is not None and Ts is not None and _sampled_finite(plant, 1e-3, backend):
        return ParameterError(f"Ts = {Ts!r}: {what} overflow to non-finite values; allowed: a sampling "
                              "time for which they stay finite (the bundled file has Ts = 0.001)")
    if not keys:
        return ParameterError(f"{what} overflow to non-finite values; allowed: physically sized parameters")
    try:
        ref = load_params().plant
        hint = " (the bundled HyQ file has " + ", ".join(f"{k} = {getattr(ref, k):g}" for k in keys) + ")" \
            if all(k in ref.keys for k in keys) else ""
    except ParameterError:
        hint = ""
    given = ", ".join(f"{k} = {getattr(plant, k)!r}" for k in keys)
    return ParameterError(f"{given}: {what} overflow to non-finite values; allowed: a physically "
                          f"sized value{hint}")
