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

__all__ = ["ContinuousPlant", "DiscretePlant", "continuous_plant", "discretize"]


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
    return DiscretePlant(Phi, Gamma, C, float(Ts), cont.VC0, cont.state_names, cont.input_names,
                         cont.output_names)


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
