"""The model an identification fits: the sampled plant of an actuator as a function of chosen
parameters, with exact derivatives, and its fast simulation with output sensitivities.

* The continuous matrices A(p), B(p), C(p) are the actuator's plant function
  (:func:`haa_sym.compiled.plant_code.plant_function`'s serialised CasADi form, which carries
  automatic differentiation; a compiled ``external`` does not), and CasADi gives dA/dp, dB/dp,
  dC/dp exactly.
* The zero-order hold and its derivative come from one matrix exponential per parameter (Van
  Loan 1978): with X = [[A, B], [0, 0]] and dX its derivative,
  expm([[X, dX], [0, X]] Ts) = [[e^{X Ts}, d e^{X Ts}], [0, e^{X Ts}]], whose blocks are
  [Phi, Gamma] and [dPhi, dGamma], exact to rounding.
* The simulation x[k+1] = Phi x[k] + Gamma u[k], y = C x + D u (x[0] = 0: the log starts at
  rest) and the state sensitivities s_j[k+1] = Phi s_j[k] + dPhi_j x[k] + dGamma_j u[k] run in
  the complex Schur basis Phi = Q T Q^H: T is triangular, so each coordinate is a first-order
  recursion driven by the ones below it, which LAPACK's triangular band solver runs in Fortran
  (:func:`_first_order`); the basis is unitary, so a nearly defective Phi (modes crowding near
  z = 1) costs no accuracy.

Inputs (``--input``): ``voltage`` drives the open-loop plant through V_m; ``current`` removes the
electrical state: a drive's current loop imposes I_m, so the mechanical states are driven by
the current through A's I_m column (the back-EMF and L, R drop out of the model); ``T_dist`` adds
the port torque. ``torque_ref`` is the file's torque loop closed around the plant
(:mod:`haa_sym.fit.closed`).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.linalg

from haa_sym.compiled.generated import evaluators
from haa_sym.compiled.plant_code import compile_actuator
from haa_sym.errors import ParameterError
from haa_sym.model.actuator import Actuator

__all__ = ["PlantModel", "Sampled", "plant_derivatives", "sample", "simulate", "output_rows"]


@functools.lru_cache(maxsize=None)
def _ad_function(topology: Actuator) -> ca.Function:
    """The plant function with its Jacobians: ``p -> (A, B, C, dA/dp, dB/dp, dC/dp)`` (vec'ed)."""
    ev = evaluators("vm")
    entry = ev.code.manifest["topologies"].get(topology.fingerprint)
    if entry is not None:
        f = ca.Function.deserialize((ev.code.dir / f"{entry['function']}.casadi").read_text())
    else:
        f = compile_actuator(topology, "vm", quiet=True).function()
    p = ca.MX.sym("p", len(topology.parameter_keys))
    A, B, C, VC0 = f(p)
    jac = [ca.jacobian(ca.vec(M), p) for M in (A, B, C, VC0)]
    return ca.Function("plant_ad", [p], [A, B, C, VC0] + jac)


def plant_derivatives(plant, keys: tuple[str, ...], vc0: bool = False):
    """``A, B, C`` of ``plant`` and their derivatives with respect to ``keys``: arrays
    ``dA (len(keys), n, n)``, ``dB (len(keys), n, 3)``, ``dC (len(keys), ny, n)``; with ``vc0``
    also Eq. (6)'s VC0 (V s/rad) and its derivative (len(keys),)."""
    top = plant.topology
    f = _ad_function(top)
    out = f(np.array(plant.as_tuple(), dtype=float))
    A, B, C = (np.array(m) for m in out[:3])
    VC0 = float(out[3])
    cols = [top.parameter_keys.index(k) for k in keys]

    def unvec(J, shape):
        J = np.array(J)[:, cols]
        # CasADi's vec stacks columns (column-major)
        return np.stack([J[:, i].reshape(shape[1], shape[0]).T for i in range(len(cols))]) if cols else \
            np.zeros((0,) + shape)
    derivs = (unvec(out[4], A.shape), unvec(out[5], B.shape), unvec(out[6], C.shape))
    if vc0:
        return (A, B, C) + derivs + (VC0, np.array(out[7]).ravel()[cols])
    return (A, B, C) + derivs


def output_rows(topology, outputs: tuple[str, ...]) -> list[tuple[str, int]]:
    """Where each log output comes from: ("y", row of the plant's C) or ("x", state index)."""
    rows = []
    torque = "T_sensor" if topology.torque_damping or topology.sensor == "current" else "T_sensor_spring"
    for o in outputs:
        if o == "torque":
            rows.append(("y", topology.output_names.index(torque)))
        elif o == "theta":
            rows.append(("y", topology.output_names.index("theta_encoder")))
        elif o == "velocity":
            rows.append(("y", topology.output_names.index(f"dtheta_{topology.port}")))
        elif o == "current":
            rows.append(("x", topology.state_names.index("I_m")))
        else:
            raise ParameterError(f"--output {o}: unknown; allowed: torque, theta, current, velocity")
    return rows


@dataclass(frozen=True)
class PlantModel:
    """The continuous model of one experiment: ``dx/dt = A x + B u``, ``y = C x + D u`` with the
    log's inputs as ``u`` and its outputs as ``y``, and the derivatives ``dA ... dD`` with respect
    to the fitted keys (first axis)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dA: np.ndarray
    dB: np.ndarray
    dC: np.ndarray
    dD: np.ndarray

    def slowest_period(self) -> float:
        """2 pi / (smallest nonzero |eigenvalue| of A), s: the slowest mode's period (or time
        constant times 2 pi); inf when every mode is an integrator."""
        lam = np.abs(np.linalg.eigvals(self.A))
        lam = lam[lam > 1e-9 * max(1.0, lam.max())]
        return float(2 * np.pi / lam.min()) if lam.size else float("inf")


def open_loop_model(plant, keys, inputs: tuple[str, ...], outputs: tuple[str, ...]) -> PlantModel:
    """The open-loop plant for ``inputs`` (``voltage`` or ``current``, optionally ``T_dist``)
    and ``outputs`` (log names), with derivatives along ``keys``."""
    top = plant.topology
    A, B, C, dA, dB, dC = plant_derivatives(plant, keys)
    p = len(keys)
    rows = output_rows(top, outputs)
    n = A.shape[0]

    def out_rows(Cm):
        R = np.zeros(Cm.shape[:-2] + (len(rows), n))
        for i, (kind, j) in enumerate(rows):
            if kind == "y":
                R[..., i, :] = Cm[..., j, :]
            elif Cm.ndim == 2:              # the current is a state: a unit row, no derivative
                R[i, j] = 1.0
        return R
    Cy, dCy = out_rows(C), out_rows(dC)
    col = {"voltage": 0, "T_dist": 2}
    if inputs[0] == "current":
        keep = [i for i in range(n) if top.state_names[i] != "I_m"]
        i_m = top.state_names.index("I_m")
        if "current" in outputs:
            raise ParameterError("--output current with --input current: the current is the input; allowed: "
                                 "torque, theta, velocity")
        Bu = np.column_stack([A[keep, i_m]] + [B[keep, col[k]] for k in inputs[1:]])
        dBu = np.stack([np.column_stack([dA[j][keep, i_m]] + [dB[j][keep, col[k]] for k in inputs[1:]])
                        for j in range(p)]) if p else np.zeros((0,) + Bu.shape)
        Dy = np.column_stack([Cy[:, i_m]] + [np.zeros(len(rows)) for _ in inputs[1:]])
        dDy = np.stack([np.column_stack([dCy[j][:, i_m]] + [np.zeros(len(rows)) for _ in inputs[1:]])
                        for j in range(p)]) if p else np.zeros((0,) + Dy.shape)
        return PlantModel(A[np.ix_(keep, keep)], Bu, Cy[:, keep], Dy, dA[:, keep][:, :, keep], dBu,
                          dCy[:, :, keep], dDy)
    cols = [col[k] for k in inputs]
    m = len(cols)
    return PlantModel(A, B[:, cols], Cy, np.zeros((len(rows), m)), dA, dB[:, :, cols], dCy,
                      np.zeros((p, len(rows), m)))


@dataclass(frozen=True)
class Sampled:
    """The ZOH-sampled model at ``Ts``: ``Phi, Gamma, C, D`` and their derivatives."""

    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dPhi: np.ndarray
    dGamma: np.ndarray
    dC: np.ndarray
    dD: np.ndarray
    Ts: float


def sample(model: PlantModel, Ts: float) -> Sampled:
    """Exact ZOH of ``model`` at ``Ts`` (s) and its exact derivative (Van Loan's block exponential)."""
    n, m = model.B.shape
    k = n + m
    X = np.zeros((k, k))
    X[:n, :n], X[:n, n:] = model.A, model.B
    with np.errstate(over="ignore", invalid="ignore"):
        E = scipy.linalg.expm(X * Ts) if np.all(np.isfinite(X * Ts)) else np.full((k, k), np.nan)
    if not np.all(np.isfinite(E)):
        # time stamps far from seconds (1e97 s a sample): the exponential overflows; LAPACK
        # would refuse the next step with a LinAlgError traceback
        raise ParameterError(f"--log: mean sampling period {Ts:.6g} s: the plant sampled at it overflows (the "
                             f"modes decay in about {_slowest(model.A):.3g} s); allowed: a log whose time column "
                             "is in seconds")
    p = model.dA.shape[0]
    dPhi, dGamma = np.zeros((p, n, n)), np.zeros((p, n, m))
    for j in range(p):
        M = np.zeros((2 * k, 2 * k))
        M[:k, :k] = M[k:, k:] = X
        M[:n, k:k + n], M[:n, k + n:] = model.dA[j], model.dB[j]
        F = scipy.linalg.expm(M * Ts)
        dPhi[j], dGamma[j] = F[:n, k:k + n], F[:n, k + n:]
    return Sampled(E[:n, :n], E[:n, n:], model.C, model.D, dPhi, dGamma, model.dC, model.dD, Ts)


def _slowest(A: np.ndarray) -> float:
    """The slowest stable mode's time constant of ``A``, s (inf for none)."""
    re = -np.linalg.eigvals(A).real
    re = re[re > 0]
    return float(1 / re.min()) if re.size else math.inf


def _first_order(a: complex, d: np.ndarray) -> np.ndarray:
    """xi[k+1] = a xi[k] + d[k], xi[0] = 0, along the last axis of ``d`` (..., N), for every
    leading index at once.

    The recursion is the lower bidiagonal system xi[k] - a xi[k-1] = d[k-1] (1 on the diagonal,
    -a below it), and LAPACK's triangular band solve (``ztbtrs``) is forward substitution: the
    recursion itself, in Fortran, with the same arithmetic as ``scipy.signal.lfilter([0, 1],
    [1, -a], d)``, without importing scipy.signal (about 0.7 s, most of ``haa-sym identify``'s
    start before; docs/startup.md).
    """
    N = d.shape[-1]
    rhs = d.reshape(-1, N)
    b = np.empty((N, rhs.shape[0]), complex, order="F")   # column-major: LAPACK solves in place
    b[0] = 0.0
    b[1:] = rhs[:, :-1].T
    band = np.empty((2, N), complex)
    band[0], band[1] = 1.0, -a
    x, info = scipy.linalg.lapack.ztbtrs(band, b, uplo="L", overwrite_b=1)
    # info > 0 would be a zero on the diagonal, which is 1 here
    assert info == 0, info
    return x.T.reshape(d.shape)


def _triangular_run(T: np.ndarray, drive: np.ndarray) -> np.ndarray:
    """xi[k+1] = T xi[k] + drive[k], xi[0] = 0, T upper triangular (n, n); ``drive`` (n, ..., N)."""
    n = T.shape[0]
    xi = np.zeros(drive.shape, dtype=complex)
    for i in range(n - 1, -1, -1):
        d = drive[i] + np.tensordot(T[i, i + 1:], xi[i + 1:], axes=(0, 0)) if i + 1 < n else drive[i]
        xi[i] = _first_order(T[i, i], d)
    return xi


def simulate(s: Sampled, u: np.ndarray, sensitivities: bool = True):
    """Outputs ``y (N, ny)`` for inputs ``u (N, m)`` from rest and, when ``sensitivities``, their
    derivatives ``dy (p, N, ny)`` with respect to the fitted keys."""
    T, Q = scipy.linalg.schur(s.Phi, output="complex")
    uT = np.ascontiguousarray(u.T)                            # (m, N)
    xi = _triangular_run(T, Q.conj().T @ (s.Gamma @ uT))
    x = (Q @ xi).real                                         # (n, N)
    y = (s.C @ x + s.D @ uT).T
    if not sensitivities:
        return y, None
    drive = Q.conj().T @ (s.dPhi @ x + s.dGamma @ uT)                      # (p, n, N), BLAS
    sx = (Q @ _triangular_run(T, drive.transpose(1, 0, 2)).transpose(1, 0, 2)).real
    dy = s.C @ sx + s.dC @ x + s.dD @ uT                                    # (p, ny, N)
    return y, dy.transpose(0, 2, 1)
