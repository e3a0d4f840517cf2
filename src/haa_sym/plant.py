"""The actuator plant of Eq. (1)-(2): continuous state space (generated from the sympy model)
and its zero-order-hold discretisation at Ts.

State ``[I_m, theta_m, dtheta_m, theta_L1, dtheta_L1, theta_L2, dtheta_L2]``, inputs
``[V_m, T_fr, T_dist]``, outputs ``[T_l, T_l_spring, theta_L1, dtheta_L1, dtheta_L2]`` where
``T_l`` is Eq. (2) and ``T_l_spring`` its K_hd term alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from haa_sym.compiled import evaluators
from haa_sym.params import ParameterError, Plant

STATES = ("I_m", "theta_m", "dtheta_m", "theta_L1", "dtheta_L1", "theta_L2", "dtheta_L2")
INPUTS = ("V_m", "T_fr", "T_dist")
OUTPUTS = ("T_l", "T_l_spring", "theta_L1", "dtheta_L1", "dtheta_L2")

__all__ = ["STATES", "INPUTS", "OUTPUTS", "ContinuousPlant", "DiscretePlant", "continuous_plant",
           "discretize"]


@dataclass(frozen=True)
class ContinuousPlant:
    """``dx/dt = A x + B u``, ``y = C x`` of Eq. (1)-(2); ``VC0`` is Eq. (6) at alpha = 1 (V s/rad)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    VC0: float


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
    """Evaluate the generated ``haa_plant`` function (Eq. 1-2, Eq. 6) for ``plant``."""
    A, B, C, VC0 = evaluators(backend)["haa_plant"](np.array(plant.as_tuple(), dtype=float))
    return ContinuousPlant(np.array(A), np.array(B), np.array(C), float(VC0))


def discretize(cont: ContinuousPlant, Ts: float) -> DiscretePlant:
    """Zero-order hold at ``Ts`` (s): expm of the augmented matrix [[A, B], [0, 0]] Ts."""
    if not (isinstance(Ts, (int, float)) and np.isfinite(Ts) and Ts > 0):
        raise ParameterError(f"Ts = {Ts!r}; allowed: a finite number > 0 (seconds)")
    n, m = cont.B.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = cont.A
    aug[:n, n:] = cont.B
    E = scipy.linalg.expm(aug * Ts)
    Phi, Gamma, C = E[:n, :n].copy(), E[:n, n:].copy(), cont.C.copy()
    for arr in (Phi, Gamma, C):          # shared by every ClosedLoop of this plant (memoised)
        arr.setflags(write=False)
    return DiscretePlant(Phi, Gamma, C, float(Ts), cont.VC0)
