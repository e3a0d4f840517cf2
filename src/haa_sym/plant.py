"""The actuator plant of Eq. (1)-(2): continuous state space (generated from the sympy model)
and its zero-order-hold discretisation at Ts.

State ``[I_m, theta_m, dtheta_m, theta_L1, dtheta_L1, theta_L2, dtheta_L2]``, inputs
``[V_m, T_fr, T_dist]``, outputs ``[T_sensor, T_sensor_spring, theta_encoder, dtheta_L1, dtheta_L2]``
where ``T_sensor`` is the torque sensor of Eq. (2) (T_l), ``T_sensor_spring`` its K_hd term alone
and ``theta_encoder`` the encoder angle (theta_L1).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg

from haa_sym.compiled import evaluators
from haa_sym.params import PLANT_KEYS, ParameterError, Plant

STATES = ("I_m", "theta_m", "dtheta_m", "theta_L1", "dtheta_L1", "theta_L2", "dtheta_L2")
INPUTS = ("V_m", "T_fr", "T_dist")
OUTPUTS = ("T_sensor", "T_sensor_spring", "theta_encoder", "dtheta_L1", "dtheta_L2")

__all__ = ["STATES", "INPUTS", "OUTPUTS", "ContinuousPlant", "DiscretePlant", "continuous_plant",
           "discretize"]


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


@dataclass(frozen=True)
class DiscretePlant:
    """ZOH-sampled plant ``x[k+1] = Phi x[k] + Gamma u[k]``, ``y[k] = C x[k]`` at ``Ts`` seconds."""

    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    Ts: float
    VC0: float

    def frequency_response(self, omega: np.ndarray, outputs=OUTPUTS, inputs=INPUTS) -> np.ndarray:
        """``C (e^{j w Ts} I - Phi)^-1 Gamma`` for rows ``outputs``, columns ``inputs``.

        Returns a complex array of shape ``(len(outputs), len(inputs), len(omega))``; omega in rad/s.
        """
        omega = np.asarray(omega, dtype=float)
        rows = [OUTPUTS.index(o) for o in outputs]
        cols = [INPUTS.index(i) for i in inputs]
        z = np.exp(1j * omega * self.Ts)
        M = z[:, None, None] * np.eye(self.Phi.shape[0]) - self.Phi
        X = np.linalg.solve(M, np.broadcast_to(self.Gamma[:, cols], (len(z),) + self.Gamma[:, cols].shape))
        return np.einsum("oi,wij->ojw", self.C[rows], X)


def continuous_plant(plant: Plant, backend: str = "auto") -> ContinuousPlant:
    """Evaluate the generated ``haa_plant`` function (Eq. 1-2, Eq. 6) for ``plant``.

    Raises :class:`ParameterError` naming the key when the matrices overflow (e.g. K_hd = 1e300).
    """
    cont = _evaluate(plant, backend)
    if not _finite(cont.A, cont.B, cont.C, cont.VC0):
        raise _overflow(plant, None, backend)
    return cont


def discretize(cont: ContinuousPlant, Ts: float) -> DiscretePlant:
    """Zero-order hold at ``Ts`` (s): expm of the augmented matrix [[A, B], [0, 0]] Ts."""
    if not (isinstance(Ts, (int, float)) and np.isfinite(Ts) and Ts > 0):
        raise ParameterError(f"Ts = {Ts!r}; allowed: a finite number > 0 (seconds)")
    Phi, Gamma = _zoh(cont.A, cont.B, Ts)
    if not _finite(Phi, Gamma):
        raise _overflow(cont.plant, Ts)
    C = cont.C.copy()
    for arr in (Phi, Gamma, C):          # shared by every ClosedLoop of this plant (memoised)
        arr.setflags(write=False)
    return DiscretePlant(Phi, Gamma, C, float(Ts), cont.VC0)


def _evaluate(plant: Plant, backend: str = "auto") -> ContinuousPlant:
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        A, B, C, VC0 = evaluators(backend)["haa_plant"](np.array(plant.as_tuple(), dtype=float))
    return ContinuousPlant(np.array(A), np.array(B), np.array(C), float(VC0), plant)


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
        [k for k in PLANT_KEYS if _sampled_finite(replace(plant, **{k: 1.0}), Ts, backend)]
    if not keys and plant is not None and Ts is not None and _sampled_finite(plant, 1e-3, backend):
        return ParameterError(f"Ts = {Ts!r}: {what} overflow to non-finite values; allowed: a sampling "
                              "time for which they stay finite (the bundled file has Ts = 0.001)")
    if not keys:
        return ParameterError(f"{what} overflow to non-finite values; allowed: physically sized parameters")
    try:
        from haa_sym.params import load_params
        ref = load_params().plant
        hint = " (the bundled HyQ file has " + ", ".join(f"{k} = {getattr(ref, k):g}" for k in keys) + ")"
    except ParameterError:
        hint = ""
    given = ", ".join(f"{k} = {getattr(plant, k)!r}" for k in keys)
    return ParameterError(f"{given}: {what} overflow to non-finite values; allowed: a physically "
                          f"sized value{hint}")
