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
from haa_sym.model.drive import DRIVE_KEYS

__all__ = ["PlantModel", "Sampled", "plant_derivatives", "sample", "simulate", "output_rows", "stamp_grid"]


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


def open_loop_model(plant, keys, inputs: tuple[str, ...], outputs: tuple[str, ...], drive=None) -> PlantModel:
    """The open-loop plant for ``inputs`` (``voltage`` or ``current``, optionally ``T_dist``)
    and ``outputs`` (log names), with derivatives along ``keys``; behind the drive's lag
    (``drive.tau_drive`` > 0, :func:`with_drive_lag`) when ``drive`` is given. The drive's keys
    (``tau_drive``, ``delay_drive``) may be among ``keys``: the delay does not enter these
    matrices (its derivative is the simulation's, :func:`simulate_stamps`)."""
    model = _open_loop(plant, tuple(k for k in keys if k not in DRIVE_KEYS), inputs, outputs)
    model = _expand_keys(model, [k not in DRIVE_KEYS for k in keys])
    tau = 0.0 if drive is None else drive.tau_drive
    if tau > 0:
        model = with_drive_lag(model, tau, keys.index("tau_drive") if "tau_drive" in keys else None)
    return model


def _expand_keys(model: PlantModel, plant_key: list) -> PlantModel:
    """``model`` with zero derivatives inserted for the keys that are not plant keys (the drive's)."""
    if all(plant_key):
        return model
    idx = np.cumsum(plant_key) - 1

    def grow(d):
        out = np.zeros((len(plant_key),) + d.shape[1:])
        for j, (is_plant, i) in enumerate(zip(plant_key, idx)):
            if is_plant:
                out[j] = d[i]
        return out
    return PlantModel(model.A, model.B, model.C, model.D, *(grow(d) for d in (model.dA, model.dB, model.dC, model.dD)))


def with_drive_lag(model: PlantModel, tau: float, key: int | None = None) -> PlantModel:
    """``model`` behind the drive's first-order lag 1 / (tau s + 1) on its command input (the first
    column: V_m, or the current with ``--input current``): one more state, the command as the
    motor receives it, u_lag' = (u - u_lag) / tau, which drives the plant through the command's
    old column (and reaches the outputs through its old feedthrough). The same augmentation as
    :func:`haa_sym.loop.plant.with_lag`, with derivatives; ``key`` is the index of ``tau_drive``
    among the fitted keys (d/dtau of -1/tau and 1/tau: 1/tau^2 and -1/tau^2)."""
    n, m = model.B.shape
    ny, p = model.C.shape[0], model.dA.shape[0]
    A = np.zeros((n + 1, n + 1))
    A[:n, :n], A[:n, n], A[n, n] = model.A, model.B[:, 0], -1.0 / tau
    B = np.zeros((n + 1, m))
    B[:n, 1:], B[n, 0] = model.B[:, 1:], 1.0 / tau
    C = np.hstack([model.C, model.D[:, :1]])
    D = model.D.copy()
    D[:, 0] = 0.0
    dA, dB = np.zeros((p, n + 1, n + 1)), np.zeros((p, n + 1, m))
    dA[:, :n, :n], dA[:, :n, n] = model.dA, model.dB[:, :, 0]
    dB[:, :n, 1:] = model.dB[:, :, 1:]
    dC = np.concatenate([model.dC, model.dD[:, :, :1]], axis=2)
    dD = model.dD.copy()
    dD[:, :, 0] = 0.0
    if key is not None:
        dA[key, n, n], dB[key, n, 0] = 1.0 / tau ** 2, -1.0 / tau ** 2
    return PlantModel(A, B, C, D, dA, dB, dC, dD)


def _open_loop(plant, keys, inputs: tuple[str, ...], outputs: tuple[str, ...]) -> PlantModel:
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


# --- logs as measured: exact ZOH on each log's own intervals ---------------------------------
#
# Between two stamps every input is constant (the ZOH of the log: u[k] over [t_k, t_k+1), the
# delayed command switching at t_j + delay_drive inside an interval), so the exact solution over a
# sub-interval of length h is x+ = e^{A h} x + int_0^h e^{A s} ds B u. In A's eigenbasis
# (A = V diag(lam) V^-1) each mode is a first-order recursion z+ = e^{lam h} z + e_h[lam, 0] beta u
# with a coefficient per interval, which LAPACK's band solver runs as it does for a uniform log
# (ztbtrs takes a subdiagonal per column); e_h[.] are the divided differences of lam -> e^{lam h}
# (e_h[lam, 0] = (e^{lam h} - 1) / lam = h at lam = 0).
#
# The derivatives are taken in A's eigenbasis only (Daleckii-Krein), with F = V^-1 dA V and
# H = V^-1 dB: d e^{A h} = V (F o E1) V^-1 with E1_ab = e_h[lam_a, lam_b], and
# d int_0^h e^{A s} ds B = V ((F o E2) beta + diag(e_h[lam, 0]) H) with E2_ab = e_h[lam_a, lam_b, 0]
# (int_0^h e_s[a, b] ds = e_h[a, b, 0]: the second divided difference on a, b and the input's 0).
# Why A's basis and not that of X = [[A, B], [0, 0]] (Van Loan's block, whose Daleckii-Krein form
# needs only first differences): X is defective as soon as A has a mode at s = 0 (a free link, a
# free rotor driven in current: the input's zero eigenvalue meets the integrator's), while A itself
# stays diagonalisable; the second differences carry the confluent limits (a = b, a = 0, a = b = 0)
# exactly, so an integrator costs nothing. What remains refused is a nearly defective A (close
# modes whose eigenvectors nearly coincide): the modal coordinates lose cond(V) digits.

#: Largest condition number of A's eigenvector matrix the per-interval simulation accepts: a
#: nearly defective A loses that many digits in the modal coordinates.
EIGENVECTOR_CONDITION = 1e8

#: Below this |lam h| both nodes of a second divided difference are summed by their Taylor series
#: (:func:`_divided2`); the terms fall as (k + 1) 0.1^k / (k + 2)!, 10 of them reach 1e-18.
_TAYLOR_RADIUS = 0.1
_TAYLOR_TERMS = 10


def _divided(la: np.ndarray, lb: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(e^{la h} - e^{lb h}) / (la - lb) (h e^{la h} when equal), broadcast; stable for close
    la, lb: h e^{(la+lb) h/2} sinh(x)/x with x = (la - lb) h / 2, the direct quotient when |x| is
    large (where the exponentials differ enough that nothing cancels). The exponentials are taken
    before broadcasting (per node and interval, not per pair) and the close form only where it is
    used: the pairs of modes over every interval are the simulation's largest arrays."""
    la, lb, h = (np.asarray(v) for v in (la, lb, h))
    x = 0.5 * (la - lb) * h
    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        small = np.abs(x) < 0.5
        out = (np.exp(la * h) - np.exp(lb * h)) / np.where(small, 1.0, la - lb)
        if small.any():
            xs = np.broadcast_to(x, small.shape)[small]
            hs = np.broadcast_to(h, small.shape)[small]
            ms = np.broadcast_to(0.5 * (la + lb) * h, small.shape)[small]
            sinhc = np.where(xs == 0, 1.0, np.sinh(xs) / np.where(xs == 0, 1.0, xs))
            out = np.array(np.broadcast_to(out, small.shape), dtype=np.result_type(out, sinhc, ms))
            out[small] = hs * np.exp(ms) * sinhc
    return out


def _divided2(la, lb, h, e_ab=None, e_a0=None, e_b0=None) -> np.ndarray:
    """e_h[la, lb, 0]: the second divided difference of lam -> e^{lam h} on la, lb and 0 (s^2),
    broadcast, with every confluent limit (h^2 / 2 at la = lb = 0).

    Where |la h| and |lb h| are both below :data:`_TAYLOR_RADIUS`, the series
    h^2 sum_k h_k(la h, lb h) / (k + 2)! with h_k = sum_{i <= k} x^i y^(k-i) (the complete
    symmetric polynomials of the nodes; nothing cancels there), on those entries only. Elsewhere
    the recurrence e[o, b, 0] = (e[o, b] - e[o, 0]) / b, divided by the node b of larger modulus
    (|b h| >= the radius, so the quotient amplifies rounding by at most 1 / radius = 10), its
    first differences from :func:`_divided` (stable for close or equal nodes) or given: ``e_ab``
    = e_h[la, lb], ``e_a0`` = e_h[la, 0], ``e_b0`` = e_h[lb, 0], broadcastable (the simulation has
    them already, and the pairs of modes over every interval are its largest arrays).
    """
    la, lb, h = (np.asarray(v) for v in (la, lb, h))
    x, y = la * h, lb * h
    swap = np.abs(x) < np.abs(y)
    big = np.where(swap, lb, la)
    far = np.abs(big * h) >= _TAYLOR_RADIUS
    e_ab = _divided(la, lb, h) if e_ab is None else e_ab
    e_o0 = np.where(swap, _divided(la, 0.0, h) if e_a0 is None else e_a0,
                    _divided(lb, 0.0, h) if e_b0 is None else e_b0)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        out = (e_ab - e_o0) / np.where(far, big, 1.0)
    near = ~far
    if near.any():
        hn = np.broadcast_to(h, near.shape)[near]
        xs, ys = np.broadcast_to(x, near.shape)[near], np.broadcast_to(y, near.shape)[near]
        hk, yk, total, fact = np.ones_like(xs), np.ones_like(xs), np.full_like(xs, 0.5), 2.0
        for k in range(1, _TAYLOR_TERMS):
            yk = yk * ys
            hk = xs * hk + yk
            fact *= k + 2
            total = total + hk / fact
        out = np.array(np.broadcast_to(out, near.shape), dtype=np.result_type(out, total))
        out[near] = hn * hn * total
    return out


def _recursion(a: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """xi[0] = rhs[0], xi[i+1] = a[i] xi[i] + rhs[i+1] along the last axis (a (N-1,), rhs
    (..., N)): the lower bidiagonal system with -a[i] in column i, solved by ``ztbtrs``."""
    N = rhs.shape[-1]
    b = np.asfortranarray(rhs.reshape(-1, N).T.astype(complex))
    band = np.zeros((2, N), complex)
    band[0], band[1, :-1] = 1.0, -a
    x, info = scipy.linalg.lapack.ztbtrs(band, b, uplo="L", overwrite_b=1)
    assert info == 0, info
    return x.T.reshape(rhs.shape)


def modal_check(A: np.ndarray, what: str = "the model") -> None:
    """Refuse (one line) a model the per-interval simulation cannot take: a nearly defective A
    (see the comment above :data:`EIGENVECTOR_CONDITION`); modes at s = 0 are exact."""
    cond = float(np.linalg.cond(np.linalg.eig(A)[1]))
    if not cond <= EIGENVECTOR_CONDITION:
        raise ParameterError(f"{what}: coinciding modes (A's eigenvector matrix has condition number {cond:.3g} > "
                             f"{EIGENVECTOR_CONDITION:.0e}: nearly defective), which the per-interval simulation of a "
                             "jittered, windowed, segmented or delayed log cannot take exactly; allowed: a uniform "
                             "log from rest without delay_drive, or parameters whose modes are distinct")


def stamp_grid(t: np.ndarray, u: np.ndarray, delay: float, starts, on_stamps: bool = False):
    """The simulation grid of a log's own stamps ``t`` (s, N) with its first (command) input column
    delayed by ``delay`` (s): the grid of both the linear path (:func:`simulate_stamps`) and the
    friction path (:func:`haa_sym.fit.friction.simulate_friction_stamps`).

    The grid points are the stamps and the delayed command's switches t_j + delay inside a
    segment's span (``starts``: first sample of each segment); a switch within 1e-9 median periods
    of a stamp is the stamp: left out, or with ``on_stamps`` kept as a point of its own at the
    stamp, after it (an interval of length 0 whose end moves with the delay: a scheme that
    differentiates its intervals' lengths needs it, the linear path's exact derivative does not).
    On each grid interval every input is constant: the stamp's inputs,
    the command as the motor gets it (held from before a segment's start into it).

    Returns
    -------
    grid : (G,) the points (s); ug : (G, m) the inputs held from each point; samp : (N,) the grid
    positions of the stamps; moves : (G,) bool, the points that are switches (they move with the
    delay: d point / d delay = 1).
    """
    N = t.size
    starts = np.asarray(starts, int)
    ends = np.append(starts[1:], N)                                   # exclusive
    tol = 1e-9 * float(np.median(np.diff(t))) if N > 1 else 0.0
    sw = t + delay
    seg_sw = np.searchsorted(t[starts], sw, side="right") - 1
    keep = (seg_sw >= 0) & (sw < t[np.maximum(ends[np.maximum(seg_sw, 0)] - 1, 0)] - tol)
    near = np.searchsorted(t, sw)
    on_stamp = (np.abs(t[np.clip(near, 0, N - 1)] - sw) <= tol) | (np.abs(t[np.clip(near - 1, 0, N - 1)] - sw) <= tol)
    if on_stamps:
        above, below = np.clip(near, 0, N - 1), np.clip(near - 1, 0, N - 1)
        hit = np.where(np.abs(t[above] - sw) <= tol, above, below)
        sw = np.where(on_stamp, t[hit], sw)[keep & (delay > 0)]
    else:
        sw = sw[keep & ~on_stamp & (delay > 0)]
    grid = np.concatenate([t, sw])
    order = np.argsort(grid, kind="stable")
    grid = grid[order]
    samp = np.flatnonzero(order < N)                                  # grid positions of the stamps, in order
    stamp_of = np.searchsorted(t, grid + tol, side="right") - 1       # the stamp whose input holds
    cmd_of = np.clip(np.searchsorted(t, grid - delay + tol, side="right") - 1, 0, N - 1)
    ug = u[stamp_of].copy()
    if on_stamps:
        # a stamp with a switch on it holds the old command over the interval of length 0 after it
        cmd_of[samp] = np.clip(np.searchsorted(t, grid[samp] - delay - tol, side="right") - 1, 0, N - 1)
    ug[:, 0] = u[cmd_of, 0]                                           # the command as the motor gets it
    return grid, ug, samp, order >= N


def simulate_stamps(model: PlantModel, t: np.ndarray, u: np.ndarray, *, delay: float = 0.0,
                    delay_key: int | None = None, starts=(0,), estimate=(False,), y=None, weights=None,
                    sensitivities: bool = True):
    """Outputs of ``model`` at the log's own stamps ``t`` (s, N), inputs ``u`` (N, m) held over
    [t_k, t_k+1), the first (command) column delayed by ``delay`` (s) and switching at
    t_j + delay inside the intervals: exact for any stamps and delay.

    Parameters
    ----------
    starts : sequence of int
        First sample of each segment (``starts[0]`` = 0): the recursion restarts there (a gap).
    estimate : sequence of bool
        Per segment: its initial state is estimated (weighted linear least squares against ``y``
        with ``weights`` per output, inside this call), else the segment starts at rest.
    delay_key : int, optional
        Index of ``delay_drive`` among the keys: its derivative is d x / d delay =
        -(A x_c + B_c c(t)) + e^{A (t - t_s)} B_c c(t_s) (x_c the state the delayed command c
        forces from the segment's start t_s: a shifted copy, so its derivative is minus its
        time derivative, plus the command held into the segment from before it).

    Returns
    -------
    y_model : (N, ny); dy : (p, N, ny) or None (at the estimated initial states, projected
    onto the complement of the initial states' directions: variable projection with Kaufman's
    Jacobian); rank : int, the number of initial-state values the data determined.
    """
    A, B = model.A, model.B
    n, m = B.shape
    N = t.size
    lam, V = np.linalg.eig(A)
    Vi = np.linalg.inv(V)
    beta = Vi @ B                                                     # (n, m)
    starts = np.asarray(starts, int)
    ends = np.append(starts[1:], N)                                   # exclusive
    grid, ug, samp, _ = stamp_grid(t, u, delay, starts)
    G = grid.size
    seg_start_grid = samp[starts]
    cut = np.zeros(G, bool)
    cut[seg_start_grid] = True
    h = np.diff(grid)                                                 # (G-1,)
    link = ~cut[1:]                                                   # interval i joins point i to i+1
    a = np.where(link[:, None], np.exp(np.outer(h, lam)), 0.0)        # (G-1, n)
    phi = _divided(lam[None, :], 0.0, h[:, None])                     # phi1(lam, h)
    bu = ug @ beta.T                                                  # (G, n)
    drive = np.zeros((G, n), complex)
    drive[1:] = np.where(link[:, None], phi * bu[:-1], 0.0)
    z = np.stack([_recursion(a[:, i], drive[:, i]) for i in range(n)], axis=1)   # forced, (G, n)
    one = np.zeros((G, n), complex)
    one[seg_start_grid] = 1.0
    Pi = np.stack([_recursion(a[:, i], one[:, i]) for i in range(n)], axis=1)    # free response per mode
    CV = model.C @ V
    seg_of = np.cumsum(cut) - 1                                       # segment of each grid point
    ys = (z[samp] @ CV.T).real + ug[samp] @ model.D.T                 # (N, ny)
    ny = ys.shape[1]
    w = np.ones(ny) if weights is None else np.asarray(weights, float)
    x0 = np.zeros((starts.size, n))
    bases, rank = {}, 0
    for g, (s, e) in enumerate(zip(starts, ends)):
        if not estimate[g]:
            continue
        Psi = np.einsum("oa,ka,as->kos", CV, Pi[samp[s:e]], Vi).real  # (len, ny, n)
        Pw = (Psi / w[None, :, None]).reshape(-1, n)
        U, sv, _ = np.linalg.svd(Pw, full_matrices=False)
        r = int(np.sum(sv > 1e-9 * max(sv.max(), 1e-300)))
        bases[g] = U[:, :r]
        rank += r
        res = ((y[s:e] - ys[s:e]) / w).ravel()
        x0[g] = np.linalg.lstsq(Pw, res, rcond=1e-9)[0]
    z = z + Pi * (x0 @ Vi.T)[seg_of]
    ys = (z[samp] @ CV.T).real + ug[samp] @ model.D.T
    if not sensitivities:
        return ys, None, rank
    p = model.dA.shape[0]
    F = Vi @ model.dA @ V                                             # (p, n, n)
    H = Vi @ model.dB                                                 # (p, n, m)
    la, lb, hh = lam[None, :, None], lam[None, None, :], h[:, None, None]
    # d x+ = (F o E1) z + (F o E2) beta u + diag(e_h[lam, 0]) H u (the comment above EIGENVECTOR_CONDITION)
    E1 = _divided(la, lb, hh)                                         # (G-1, n, n)
    W = E1 * z[:-1, None, :] + _divided2(la, lb, hh, E1, phi[:, :, None], phi[:, None, :]) * bu[:-1, None, :]
    r = np.einsum("iab,jab->jia", W, F) + phi[None] * np.einsum("jam,im->jia", H, ug[:-1])
    rhs = np.zeros((p, G, n), complex)
    rhs[:, 1:] = np.where(link[None, :, None], r, 0.0)
    sz = np.stack([_recursion(a[:, i], rhs[:, :, i]) for i in range(n)], axis=2)   # (p, G, n)
    if delay_key is not None:
        bc = np.outer(ug[:, 0], beta[:, 0])                           # B_c c(t) in modal coordinates
        dc = np.zeros((G, n), complex)
        dc[1:] = np.where(link[:, None], phi * bc[:-1], 0.0)
        zc = np.stack([_recursion(a[:, i], dc[:, i]) for i in range(n)], axis=1)
        sz[delay_key] = -(lam * zc + bc) + Pi * bc[seg_start_grid][seg_of]
    x = (z[samp] @ V.T).real                                          # (N, n)
    dy = (sz[:, samp] @ CV.T).real + np.einsum("joa,ka->jko", model.dC, x) + \
        np.einsum("jom,km->jko", model.dD, ug[samp])
    for g, U in bases.items():                                        # Kaufman: the initial state's directions out
        s, e = starts[g], ends[g]
        D = (dy[:, s:e] / w).reshape(p, -1)
        D -= (D @ U) @ U.T
        dy[:, s:e] = D.reshape(p, e - s, ny) * w
    return ys, dy, rank
