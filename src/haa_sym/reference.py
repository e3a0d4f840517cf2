"""Independent reference: the closed loop as an explicit discrete state space (numpy only).

This is the textbook construction, sample by sample, used by the tests and the benchmarks to
check the generated evaluators (which work on the characteristic polynomial and on loop
algebra instead). It shares only the ZOH-discretised plant with them.

Closed-loop state ``[x (7), theta[k-1..k-N_av], integrator[k-1], V[k-1] (if delay)]``,
inputs ``[T_dist, r]`` where ``r`` is injected at the cut point, outputs
``[T_meas, theta_L1, port velocity, y]`` where ``y`` is what returns to the cut point with
negative sign (so the loop transfer r -> y is the ``L`` of 1/(1+L)).
"""
from __future__ import annotations

import numpy as np

from haa_sym.loop import ClosedLoop

__all__ = ["closed_loop_matrices", "closed_loop_eigenvalues", "spectral_radius", "frequency_response"]


def closed_loop_matrices(loop: ClosedLoop, P_gain: float, D_gain: float, beta: float | None = None,
                         alpha: float | None = None, cut: str | None = None):
    """``(A, B, C, D)`` of the sampled closed loop; ``cut`` in {None, "T_ref", "PI"}."""
    A, B, C, D = _closed_loop_batch(loop, np.atleast_1d(np.asarray(P_gain, float)),
                                    np.atleast_1d(np.asarray(D_gain, float)), beta, alpha, cut)
    return A[0], B[0], C[0], D[0]


def _closed_loop_batch(loop: ClosedLoop, P_gain: np.ndarray, D_gain: np.ndarray, beta=None, alpha=None,
                       cut: str | None = None):
    """The construction of :func:`closed_loop_matrices` for k gain points at once (shape (k,))."""
    ctrl, opt, pl = loop.params.controller, loop.options, loop.plant
    beta = ctrl.beta if beta is None else beta
    alpha = ctrl.alpha if alpha is None else alpha
    P_t, I_t, VC = beta * ctrl.P_t0, beta * ctrl.I_t0, alpha * pl.VC0
    N, Ts, d = ctrl.N_av, ctrl.Ts, opt.delay
    nx = pl.Phi.shape[0]
    n = nx + N + 1 + d
    i_h, i_int, i_u = nx, nx + N, nx + N + 1
    nin = 2  # T_dist, r
    k = P_gain.shape[0]
    Pg, Dg = P_gain[:, None], D_gain[:, None]
    # every signal at sample k is a row over [state (n), inputs (2)]
    def zero():
        return np.zeros(n + nin)
    def row_from_C(name):
        r = zero()
        r[:nx] = pl.C[pl.output_names.index(name)]
        return r
    th = row_from_C("theta_encoder")
    T = row_from_C(loop.torque_output)
    r_in = zero(); r_in[n + 1] = 1
    def average(k):                                       # (theta[k] - theta[k-k]) / (k Ts)
        th_k = zero(); th_k[i_h + k - 1] = 1
        return (th - th_k) / (k * Ts)
    N_vc, N_d = loop.filter_lengths
    v = average(N)                                        # the encoder average (port option)
    v_vc, v_d = average(N_vc), average(N_d)
    imp = Pg * th + Dg * v_d                              # Eq. (8) with theta_ref = 0: T_ref = -imp
    T_ref = np.broadcast_to(r_in, imp.shape) if cut == "T_ref" else -imp
    e = T_ref - T
    i_prev = zero(); i_prev[i_int] = 1
    i_k = i_prev + Ts * e                                 # backward Euler, Eq. (7)
    u_pi = P_t * e + I_t * i_k
    V_k = (np.broadcast_to(r_in, imp.shape) if cut == "PI" else u_pi) + VC * v_vc   # Eq. (6)
    if d:
        V_applied = np.broadcast_to(i_u == np.arange(n + nin), imp.shape).astype(float)
    else:
        V_applied = V_k
    rows = np.zeros((k, n, n + nin))
    rows[:, :nx, :nx] = pl.Phi
    rows[:, :nx] += pl.Gamma[None, :, 0, None] * V_applied[:, None, :]
    rows[:, :nx, n] += pl.Gamma[:, 2]                     # T_dist
    rows[:, i_h] = th
    for j in range(1, N):
        rows[:, i_h + j, i_h + j - 1] = 1
    rows[:, i_int] = i_k
    if d:
        rows[:, i_u] = V_k
    port = v if opt.port == "encoder_average" else row_from_C(opt.port)
    y = {None: np.zeros_like(imp), "T_ref": imp, "PI": -u_pi}[cut]
    out = np.concatenate([np.broadcast_to(r, imp.shape)[:, None] for r in (T, th, port)] + [y[:, None]], axis=1)
    return rows[:, :, :n], rows[:, :, n:], out[:, :, :n], out[:, :, n:]


def closed_loop_eigenvalues(loop: ClosedLoop, points, chunk_bytes: int = 64 << 20) -> np.ndarray:
    """Eigenvalues of the closed-loop state matrix at gain points, shape (k, order).

    ``points`` is (4, k): rows P_gain, D_gain, beta, alpha. One ``numpy.linalg.eigvals`` call
    per chunk of stacked matrices (``chunk_bytes`` of them at a time) and distinct (beta, alpha).
    """
    pts = np.asarray(points, dtype=float).reshape(4, -1)
    order = loop.degree
    out = np.empty((pts.shape[1], order), complex)
    pairs, inv = np.unique(pts[2:].T, axis=0, return_inverse=True)
    step = max(1, chunk_bytes // (8 * order * order))
    for j, (b, a) in enumerate(pairs):
        sel = np.flatnonzero(inv.ravel() == j)
        for c in range(0, sel.size, step):
            idx = sel[c:c + step]
            A = _closed_loop_batch(loop, pts[0, idx], pts[1, idx], b, a)[0]
            out[idx] = np.linalg.eigvals(A)
    return out


def spectral_radius(loop: ClosedLoop, P_gain, D_gain, beta=None, alpha=None) -> float:
    """max |eig| of the closed-loop state matrix (numpy.linalg.eigvals)."""
    A = closed_loop_matrices(loop, P_gain, D_gain, beta, alpha)[0]
    return float(np.abs(np.linalg.eigvals(A)).max())


def _tf(A, B, C, D, omega, Ts, out, inp):
    z = np.exp(1j * np.asarray(omega) * Ts)
    M = z[:, None, None] * np.eye(A.shape[0]) - A
    X = np.linalg.solve(M, np.broadcast_to(B[:, inp:inp + 1], (len(z), A.shape[0], 1)))[..., 0]
    return X @ C[out] + D[out, inp]


def frequency_response(loop: ClosedLoop, omega, P_gain, D_gain, beta=None, alpha=None) -> dict:
    """``L_t``, ``L_imp``, ``Z``, ``H_T`` of :meth:`ClosedLoop.frequency_response`, by state space."""
    Ts = loop.params.controller.Ts
    res = {}
    A, B, C, D = closed_loop_matrices(loop, P_gain, D_gain, beta, alpha, cut="PI")
    res["L_t"] = _tf(A, B, C, D, omega, Ts, 3, 1)
    A, B, C, D = closed_loop_matrices(loop, P_gain, D_gain, beta, alpha, cut="T_ref")
    res["L_imp"] = _tf(A, B, C, D, omega, Ts, 3, 1)
    res["H_T"] = _tf(A, B, C, D, omega, Ts, 0, 1)
    A, B, C, D = closed_loop_matrices(loop, P_gain, D_gain, beta, alpha)
    res["Z"] = 1 / _tf(A, B, C, D, omega, Ts, 2, 0)
    return res
