"""Independent reference of the exact passivity test: the fast-rate lifting (issue 24).

The continuous port torque is restricted to functions held constant over M sub-steps of each
sample, h = Ts / M; the port velocity is averaged over each sub-step, so that <f, v> =
h sum_i f_i vbar_i exactly for such f. Over one sample the plant, the port torque's M values and
the controller's held voltage form a discrete system with M inputs and M outputs (the lifted
system); its M x M transfer matrix T_M(z) at z = exp(j w Ts) is the restriction of the
sampled-data operator to those functions. Its Hermitian part against that of the plant alone
(the controller off, G_M) gives

    mu_M(w) = min eig(T_M + T_M^*, G_M + G_M^*),

the smallest Rayleigh quotient Re<f, T f> / Re<f, G f> over the piecewise-constant f: it is at
least the exact mu(w) of :mod:`haa_sym.analysis.sampled_port` (a minimum over a subspace), does
not increase when M doubles (the subspaces are nested) and tends to mu(w) as M grows (they are
dense in L2). Nothing is shared with the exact method but the continuous plant's matrices
(the generated plant function) and the controller's realisation
(:func:`haa_sym.loop.statespace.controller_batch`, itself checked against
:mod:`haa_sym.check.reference`): no aliasing sums, no series, no closed forms; matrix exponentials
(scipy.linalg.expm) and a generalised Hermitian eigenvalue problem (scipy.linalg.eigh).
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

from haa_sym.analysis.sweep import blas_limits
from haa_sym.loop.plant import continuous_plant, current_commanded, with_lag
from haa_sym.loop.statespace import controller_batch

__all__ = ["lifted_mu", "sampled_data_mu", "loop_plant"]


def loop_plant(loop):
    """(A, b_u, b_f, c_v, C_y) of ``loop``'s continuous plant (drive lag included), C_y the rows of
    the controller's inputs (theta_encoder, the torque signal)."""
    params = loop.params
    # a current-commanded structure's plant: the current imposed, the command its column
    cont = with_lag(current_commanded(continuous_plant(params.plant, loop.backend), loop.structure.command == "current"),
                    params.drive.tau_drive)
    names = cont.output_names
    C_y = cont.C[[names.index("theta_encoder"), names.index(loop.torque_output)]]
    return cont.A, cont.B[:, :1], cont.B[:, 2:3], cont.C[[names.index(loop.options.structure.port)]], C_y


def _substep(A, b_u, b_f, h):
    """E = e^{Ah}, Gamma = int_0^h e^{At} dt [b_u b_f], Psi = int_0^h e^{At} dt,
    Theta = int_0^h int_0^t e^{As} ds dt [b_u b_f], from one exponential of a block matrix."""
    n = A.shape[0]
    Bm = np.concatenate([b_u, b_f], axis=1)
    M = np.zeros((n + 2, n + 2))
    M[:n, :n], M[:n, n:] = A, Bm
    big = np.zeros((2 * (n + 2), 2 * (n + 2)))
    big[:n + 2, :n + 2] = M
    big[:n + 2, n + 2:] = np.eye(n + 2)
    F = scipy.linalg.expm(big * h)
    eM, iM = F[:n + 2, :n + 2], F[:n + 2, n + 2:]
    return eM[:n, :n], eM[:n, n:], iM[:n, :n], iM[:n, n:]


def sampled_data_mu(A, b_u, b_f, c_v, C_y, ctrl, Ts: float, omega, M: int, delay_steps: int = 0) -> np.ndarray:
    """mu_M(w) at ``omega`` (rad/s) for the plant (A, b_u, b_f, c_v, C_y) under the discrete
    controller ``ctrl`` = (Ac, Bc, Cc, Dc) from y (n_y) to the held command (u = Cc xi + Dc y).

    ``delay_steps`` j (0 <= j <= M): the drive's dead time j Ts / M, built here as the hold itself
    does it: over sample k the first j sub-steps still get u[k-1] (a state of the lifted loop),
    the others u[k]."""
    Ac, Bc, Cc, Dc = (np.atleast_2d(np.asarray(m, float)) for m in ctrl)
    if not 0 <= int(delay_steps) <= M:
        raise ValueError(f"delay_steps = {delay_steps!r}; allowed: an integer from 0 to M = {M}")
    j = int(delay_steps)
    n, m = A.shape[0], Ac.shape[0]
    h = Ts / M
    E, G, Psi, Th = _substep(A, b_u, b_f, h)
    Gu, Gf = G[:, :1], G[:, 1:]
    # x_i = E^i x_0 + S_pre_i u[k-1] + S_post_i u[k] + sum_{l<i} E^(i-1-l) Gf f_l
    Ep = [np.eye(n)]
    for _ in range(M):
        Ep.append(E @ Ep[-1])
    S_pre, S_post = [np.zeros((n, 1))], [np.zeros((n, 1))]
    for i in range(M):
        S_pre.append(E @ S_pre[-1] + (Gu if i < j else 0.0))
        S_post.append(E @ S_post[-1] + (Gu if i >= j else 0.0))
    Fx = np.zeros((M + 1, n, M))                           # x_i's dependence on f
    for i in range(1, M + 1):
        Fx[i] = E @ Fx[i - 1]
        Fx[i][:, i - 1] += Gf[:, 0]
    # average velocity over sub-step i: (c_v Psi x_i + c_v Th_u V_i + c_v Th_f f_i) / h
    cP = c_v @ Psi
    cTu = (c_v @ Th[:, :1])[0, 0]
    Cx = np.concatenate([cP @ Ep[i] for i in range(M)]) / h                # (M, n)
    C_pre = np.array([[(cP @ S_pre[i])[0, 0] + (cTu if i < j else 0.0)] for i in range(M)]) / h
    C_post = np.array([[(cP @ S_post[i])[0, 0] + (cTu if i >= j else 0.0)] for i in range(M)]) / h
    Df = np.stack([(cP @ Fx[i])[0] for i in range(M)]) / h + np.eye(M) * (c_v @ Th[:, 1:])[0, 0] / h
    # the closed loop over one sample: state [x, xi, u[k-1]], u[k] = Cc xi + Dc C_y x
    KV = np.concatenate([Dc @ C_y, Cc, np.zeros((1, 1))], axis=1)         # u[k] as a row over the state
    N = n + m + 1
    Acl = np.zeros((N, N))
    Acl[:n, :n] = Ep[M]
    Acl[:n, n + m:] = S_pre[M]
    Acl[:n] += S_post[M] @ KV
    Acl[n:n + m, :n] = Bc @ C_y
    Acl[n:n + m, n:n + m] = Ac
    Acl[n + m:] = KV
    Bcl = np.concatenate([Fx[M], np.zeros((m + 1, M))])
    Ccl = np.concatenate([Cx, np.zeros((M, m)), C_pre], axis=1) + C_post @ KV
    z = np.exp(1j * np.asarray(omega, float).ravel() * Ts)
    out = np.empty(z.size)
    # one BLAS thread: the M x M problems are small, and threads fighting over a loaded 2-core
    # machine made M = 128 take 0.02-3.7 s
    with blas_limits(1):
        for k, zk in enumerate(z):
            T = Df + Ccl @ np.linalg.solve(zk * np.eye(N) - Acl, Bcl)
            G0 = Df + Cx @ np.linalg.solve(zk * np.eye(n) - Ep[M], Fx[M])
            out[k] = scipy.linalg.eigh(T + T.conj().T, G0 + G0.conj().T, eigvals_only=True)[0]
    return out


def lifted_mu(loop, P_gain: float, D_gain: float, omega, M: int, beta=None, alpha=None) -> np.ndarray:
    """mu_M(w) of ``loop`` at one gain point (see the module docstring); the drive's dead time
    must be a whole number (0 to M) of the sub-steps Ts / M."""
    Ac, Bc, Cc, Dc = (x[0] for x in controller_batch(loop, P_gain, D_gain, beta, alpha))
    ctrl = (Ac, Bc[:, :2], Cc[:1], Dc[:1, :2])
    Ts = loop.params.controller.Ts
    steps = loop.params.drive.delay_drive * M / Ts
    if abs(steps - round(steps)) > 1e-9 * max(steps, 1.0):
        raise ValueError(f"delay_drive = {loop.params.drive.delay_drive!r} s is not a whole number of the "
                         f"sub-steps Ts / M = {Ts / M!r} s")
    return sampled_data_mu(*loop_plant(loop), ctrl, Ts, omega, M, delay_steps=int(round(steps)))
