"""Synthetic logs with COLOURED sensor noise from an independent simulation (issue 23, the check of
honest intervals): the hand-written equations of tests/identify_synthetic.py, driven by the same kind
of band-limited Gaussian input, sampled by composing fine zero-order-hold sub-steps (scipy ``expm`` of
each sub-step, not the code under test and not the modified z-transform of ``loop/plant.py``), with
an optional first-order drive lag (an extra continuous state between the command and the model's
first input) and an optional dead time that need not be a whole number of samples (a whole number
of sub-steps). The sensor noise is AR(1): e_k = rho e_(k-1) + sqrt(1 - rho^2) w_k, stationary from
its first sample, scaled to ``noise`` times each output's standard deviation.

Once the drive keys (tau_drive, delay_drive of the [drive] section) are fittable, a test passes
``tau_drive`` / ``delay_drive`` here and fits them by name; the generator does not change.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.signal

from identify_synthetic import OUTPUT_ROWS


def _with_drive_lag(A, B, C, D, tau):
    """Augment the continuous model with q' = (c - q) / tau, q driving the first input: the
    command c becomes the first input, the others are unchanged."""
    n, m = B.shape
    Aa = np.zeros((n + 1, n + 1))
    Aa[:n, :n], Aa[:n, n], Aa[n, n] = A, B[:, 0], -1 / tau
    Ba = np.zeros((n + 1, m))
    Ba[:n, 1:], Ba[n, 0] = B[:, 1:], 1 / tau
    Ca = np.column_stack([C, D[:, 0]])
    Da = np.column_stack([np.zeros(len(C)), D[:, 1:]])
    return Aa, Ba, Ca, Da


def sampled(A, B, Ts, delay=0.0, substeps=40):
    """(Phi, G_old, G_new): x[k+1] = Phi x[k] + G_old u[k-d-1] + G_new u[k-d], d = floor(delay / Ts),
    for the input held over each sample interval and delayed by ``delay`` (a whole number of
    sub-steps Ts / substeps). Built by composing the exact ZOH of each sub-step."""
    h = Ts / substeps
    j = delay / h
    if abs(j - round(j)) > 1e-9:
        raise ValueError(f"delay {delay} is not a whole number of sub-steps {h}")
    frac = int(round(j)) % substeps             # sub-steps of each interval still under the old input
    n, m = B.shape
    E = scipy.linalg.expm(np.block([[A, B], [np.zeros((m, n + m))]]) * h)
    Ph, Gh = E[:n, :n], E[:n, n:]
    Phi, G_old, G_new = np.eye(n), np.zeros((n, m)), np.zeros((n, m))
    for s in range(substeps):
        Phi, G_old, G_new = Ph @ Phi, Ph @ G_old, Ph @ G_new
        if s < frac:
            G_old = G_old + Gh
        else:
            G_new = G_new + Gh
    return Phi, G_old, G_new


def ar1(rng, shape, rho):
    """Stationary AR(1) noise of unit variance along axis 0."""
    w = rng.standard_normal(shape)
    # e_0 = w_0 (unit variance, the stationary start), then e_k = rho e_(k-1) + sqrt(1 - rho^2) w_k:
    # lfilter's state before e_1 is rho e_0
    e = scipy.signal.lfilter([np.sqrt(1 - rho ** 2)], [1, -rho], w[1:], axis=0,
                             zi=rho * w[:1])[0]
    return np.concatenate([w[:1], e], axis=0)


def coloured_experiment(model, p, *, seed=0, duration=25.0, Ts=1e-3, rho=0.9, noise=0.01,
                        outputs=("torque", "theta"), current=False, tau_drive=0.0, delay_drive=0.0,
                        amplitude=None, substeps=40, noise_seeds=None):
    """(t, u, y_noisy, y_clean) of one experiment (``model``: identify_synthetic.two_mass or sea);
    with ``noise_seeds``, y_noisy is a list: one noise realisation per seed on the same run (the
    coverage of an interval is a statement over noise realisations for a given input)."""
    A, B, C, D = model(p, current)
    if tau_drive > 0:
        A, B, C, D = _with_drive_lag(A, B, C, D, tau_drive)
    rng = np.random.default_rng(seed)
    n = int(round(duration / Ts))
    b, a = scipy.signal.butter(4, 0.25)                 # a quarter of Nyquist
    u = scipy.signal.lfilter(b, a, rng.standard_normal(n + 200))[200:]
    u *= (amplitude or (2.0 if not current else 5.0)) / np.std(u)
    U = np.column_stack([u, np.zeros(n)])
    d = int(np.floor(delay_drive / Ts + 1e-12))
    Phi, G_old, G_new = sampled(A, B, Ts, delay_drive - d * Ts, substeps)
    # the delayed input sequence: the command of step k acts from t_k + delay on
    Ud = np.vstack([np.zeros((d + 1, U.shape[1])), U])[:n + 1]
    rows = [OUTPUT_ROWS[o] for o in outputs]
    # D carries the input in effect at t_k: u[k - d - 1] while a fraction of the interval is still
    # to come, u[k - d] with a whole-sample delay
    frac = delay_drive - d * Ts > 1e-12
    Dd = np.hstack([D[rows], np.zeros_like(D[rows])]) if frac else np.hstack([np.zeros_like(D[rows]), D[rows]])
    _, y, _ = scipy.signal.dlsim((Phi, np.hstack([G_old, G_new]), C[rows], Dd, Ts),
                                 np.hstack([Ud[:n], Ud[1:n + 1]]))
    if noise_seeds is not None:
        return (np.arange(n) * Ts, u, [y + noise * np.std(y, axis=0) * ar1(np.random.default_rng(s), y.shape, rho)
                                       for s in noise_seeds], y)
    y_noisy = y + noise * np.std(y, axis=0) * ar1(rng, y.shape, rho)
    return np.arange(n) * Ts, u, y_noisy, y


def friction_experiment(model, p, *, Fc, v_s, seed=0, duration=6.0, Ts=1e-3, rho=0.9, noise=0.01,
                        outputs=("torque", "theta"), tau_drive=0.0, delay_drive=0.0, amplitude=None,
                        substeps=20, noise_seeds=(0,), from_zero=False):
    """(t, u, [y_noisy per noise seed], y_clean) of a current-driven experiment with Coulomb friction
    T = -Fc tanh(w_m / v_s) on the rotor (``model``'s current-driven states; the rotor's velocity is
    the second, its inertia ``p["J_m"]``), a first-order drive lag and a dead time (a whole number
    of sub-steps Ts / ``substeps``). Integrated here, independently of haa_sym.fit.friction: the
    linear part exactly over each sub-step (scipy ``expm`` of [A, [B_c, W]]), the friction torque
    held over the sub-step at its value at the sub-step's start (explicit: stable while
    Fc h / (v_s J_m) < 2, checked), the command c(t - delay) held over the sub-step, 0 before the
    log. ``from_zero``: the first command sample is 0 as well (the command before a log is not in
    it: identify holds the first sample back to before the start, this generator 0; with the first
    sample 0 the two agree, else the first delay's worth of command differs and offsets theta)."""
    A, B, C, D = model(p, True)
    n0 = A.shape[0]
    W = np.zeros(n0)
    W[1] = 1.0 / p["J_m"]
    if tau_drive > 0:
        A, B, C, D = _with_drive_lag(A, B, C, D, tau_drive)
        W = np.append(W, 0.0)
    h = Ts / substeps
    if not Fc * h / (v_s * p["J_m"]) < 2:
        raise ValueError("explicit friction sub-step unstable: more substeps")
    j = delay_drive / h
    if abs(j - round(j)) > 1e-9:
        raise ValueError(f"delay {delay_drive} is not a whole number of sub-steps {h}")
    lagj = int(round(j))
    rng = np.random.default_rng(seed)
    N = int(round(duration / Ts))
    b, a = scipy.signal.butter(4, 0.25)
    u = scipy.signal.lfilter(b, a, rng.standard_normal(N + 200))[200:]
    u *= (amplitude or 5.0) / np.std(u)
    if from_zero:
        u[0] = 0.0
    n = A.shape[0]
    BW = np.column_stack([B[:, 0], W])
    E = scipy.linalg.expm(np.block([[A, BW], [np.zeros((2, n + 2))]]) * h)
    Ph, Gc, Gw = E[:n, :n], E[:n, n], E[:n, n + 1]
    rows = [OUTPUT_ROWS[o] for o in outputs]
    x, y = np.zeros(n), np.empty((N, len(rows)))
    for k in range(N):
        y[k] = C[rows] @ x            # D's command column is zero for these outputs
        for s in range(substeps):
            i = k * substeps + s - lagj                           # the sub-step whose command acts now
            c = u[i // substeps] if i >= 0 else 0.0
            x = Ph @ x + Gc * c + Gw * (-Fc * np.tanh(x[1] / v_s))
    noisy = [y + noise * np.std(y, axis=0) * ar1(np.random.default_rng(s), y.shape, rho) for s in noise_seeds]
    return np.arange(N) * Ts, u, noisy, y
