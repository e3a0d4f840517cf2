"""Synthetic identification experiments from an INDEPENDENT simulation (shared by the identify tests
and benchmarks/bench_identify.py): the two-mass harmonic drive's and the SEA's equations written out
by hand here (not the generated plant function), sampled with scipy's ``cont2discrete`` (ZOH) and
simulated with ``scipy.signal.dlsim``; band-limited Gaussian input up to a quarter of Nyquist and
Gaussian sensor noise of 1 % of each output's standard deviation."""
from __future__ import annotations

import numpy as np
import scipy.signal

HD_TRUTH = {"J_link": 0.3497, "B_link": 2.1, "K_hd": 3.1e4, "D_hd": 63.6}
SEA_TRUTH = {"J_link": 0.0867, "B_link": 0.1, "K_bar": 2300.0, "D_bar": 0.5}


def _motor(p):
    return p["L"], p["R"], p["k_t"], p["k_w"], p["J_m"], p["B_m"], p["N"]


def two_mass(p, current=False):
    """Harmonic drive: states [I, th_m, w_m, th_l, w_l]; inputs [V, T_dist]; outputs [T_hd (spring +
    damper), th_l, w_l, I]. ``current``: the current is imposed (states [th_m, w_m, th_l, w_l],
    inputs [I, T_dist])."""
    L, R, kt, kw, Jm, Bm, N = _motor(p)
    K, D, J, B, Kl = p["K_hd"], p["D_hd"], p["J_link"], p["B_link"], p["K_link"]
    # T_hd = K (th_m/N - th_l) + D (w_m/N - w_l); the rotor feels -T_hd / N
    A = np.array([[-R / L, 0, -kw / L, 0, 0],
                  [0, 0, 1, 0, 0],
                  [kt / Jm, -K / N ** 2 / Jm, -(Bm + D / N ** 2) / Jm, K / N / Jm, D / N / Jm],
                  [0, 0, 0, 0, 1],
                  [0, K / N / J, D / N / J, -(K + Kl) / J, -(D + B) / J]])
    Bm_ = np.array([[1 / L, 0], [0, 0], [0, 0], [0, 0], [0, 1 / J]])
    C = np.array([[0, K / N, D / N, -K, -D], [0, 0, 0, 1, 0], [0, 0, 0, 0, 1], [1, 0, 0, 0, 0]])
    if current:
        return A[1:, 1:], np.column_stack([A[1:, 0], Bm_[1:, 1]]), C[:3, 1:], np.zeros((3, 2))
    return A, Bm_, C, np.zeros((4, 2))


def sea(p, current=False):
    """SEA: states [I, th_m, w_m, th_g, w_g, th_l, w_l]; outputs [K_bar (th_g - th_l), th_l, w_l, I]."""
    L, R, kt, kw, Jm, Bm, N = _motor(p)
    Kh, Dh, Jg, Bg = p["K_hd"], p["D_hd"], p["J_g"], p["B_g"]
    Kb, Db, J, B, Kl = p["K_bar"], p["D_bar"], p["J_link"], p["B_link"], p["K_link"]
    A = np.zeros((7, 7))
    A[0, 0], A[0, 2] = -R / L, -kw / L
    A[1, 2] = 1
    A[2, 0] = kt / Jm
    A[2, 1:5] = [-Kh / N ** 2 / Jm, -(Bm + Dh / N ** 2) / Jm, Kh / N / Jm, Dh / N / Jm]
    A[3, 4] = 1
    A[4, 1:7] = [Kh / N / Jg, Dh / N / Jg, -(Kh + Kb) / Jg, -(Dh + Db + Bg) / Jg, Kb / Jg, Db / Jg]
    A[5, 6] = 1
    A[6, 3:7] = [Kb / J, Db / J, -(Kb + Kl) / J, -(Db + B) / J]
    Bm_ = np.zeros((7, 2))
    Bm_[0, 0], Bm_[6, 1] = 1 / L, 1 / J
    C = np.zeros((4, 7))
    C[0, 3], C[0, 5] = Kb, -Kb
    C[1, 5], C[2, 6], C[3, 0] = 1, 1, 1
    if current:
        return A[1:, 1:], np.column_stack([A[1:, 0], Bm_[1:, 1]]), C[:3, 1:], np.zeros((3, 2))
    return A, Bm_, C, np.zeros((4, 2))


OUTPUT_ROWS = {"torque": 0, "theta": 1, "velocity": 2, "current": 3}


def experiment(model, p, *, seed=0, duration=25.0, Ts=1e-3, amplitude=None, outputs=("torque", "theta"),
               current=False, noise=0.01):
    """(t, u, y_noisy, y_clean) of one experiment: ``model`` is :func:`two_mass` or :func:`sea`."""
    A, B, C, D = model(p, current)
    rng = np.random.default_rng(seed)
    n = int(round(duration / Ts))
    b, a = scipy.signal.butter(4, 0.25)                 # a quarter of Nyquist
    u = scipy.signal.lfilter(b, a, rng.standard_normal(n + 200))[200:]
    u *= (amplitude or (2.0 if not current else 5.0)) / np.std(u)
    Phi, Gam, *_ = scipy.signal.cont2discrete((A, B, C, D), Ts, "zoh")
    rows = [OUTPUT_ROWS[o] for o in outputs]
    U = np.column_stack([u, np.zeros(n)])
    _, y, _ = scipy.signal.dlsim((Phi, Gam, C[rows], D[rows], Ts), U)
    y_noisy = y + noise * np.std(y, axis=0) * rng.standard_normal(y.shape)
    return np.arange(n) * Ts, u, y_noisy, y


def write_csv(path, t, columns: dict):
    names = ["time"] + list(columns)
    data = np.column_stack([t] + [columns[k] for k in columns])
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt="%.12g")
    return path
