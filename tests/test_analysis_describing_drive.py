"""The friction describing function's linear part with the drive ([drive]: lag and dead time;
docs/simulate.md, "The drive"): the fundamental response of the sampled-data loop written here
(the plant behind the lag by hand, the held command switching at t_k + f inside the sample)
against haa_sym.analysis.describing.linear_part. Without the drive in that linear part the
command's path misses e^{-j omega d} and the lag, and the two disagree by percents."""
import numpy as np
import pytest
import scipy.linalg

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.describing import linear_part
from haa_sym.loop.plant import continuous_plant

M = 16                                   # sub-sample grid; the delay's fraction lies on it


def _fundamental_response(params, P, D, body, omega_samples, tau, whole, frac_steps, n_periods=40):
    """Velocity of ``body`` per unit torque cos(omega t) on it: the motor plant by hand behind a
    lag state u' = (V_held - u) / tau, the command V_k held from t_k + (whole + frac_steps / M) Ts,
    the controller of Eq. 6-8 by hand; projected on exp(-j omega t) after the transient."""
    pl, c = params.plant, params.controller
    cont = continuous_plant(pl)
    Ts, Nav, n = c.Ts, c.N_av, cont.A.shape[0]
    w = 2 * np.pi / (omega_samples * Ts)
    i_v = cont.state_names.index(f"dtheta_{body}")
    col = cont.B[:, 1] if body == "m" else np.eye(n)[i_v] / getattr(pl, f"J_{body}")
    N = n + 4                                  # [x, u_lag, cos, sin, V held]
    A = np.zeros((N, N))
    A[:n, :n], A[:n, n], A[:n, n + 1] = cont.A, cont.B[:, 0], col
    A[n, n], A[n, n + 3] = -1.0 / tau, 1.0 / tau
    A[n + 1, n + 2], A[n + 2, n + 1] = -w, w
    E = scipy.linalg.expm(A * Ts / M)
    C = cont.C[[cont.output_names.index("T_sensor"), cont.output_names.index("theta_encoder")]]
    P_t, I_t = c.beta * c.P_t0, c.beta * c.I_t0
    VC = c.alpha * pl.N / pl.k_t * (pl.R * pl.B_m + pl.k_t * pl.k_w)
    K = 2 * n_periods * omega_samples
    z = np.zeros(N)
    z[n + 1] = 1.0
    theta = np.zeros(K + Nav)
    sent, integral, v = [], 0.0, np.empty((K, M))
    for k in range(K):
        T, theta[k + Nav] = C @ z[:n]
        vel = (theta[k + Nav] - theta[k]) / (Nav * Ts)
        e = -(P * theta[k + Nav] + D * vel) - T
        integral += Ts * e
        sent.append(P_t * e + I_t * integral + VC * vel)
        old = sent[k - whole - 1] if k - whole - 1 >= 0 else 0.0
        new = sent[k - whole] if k - whole >= 0 else 0.0
        for j in range(M):
            z[n + 3] = old if j < frac_steps else new
            v[k, j] = z[i_v]
            z = E @ z
    t = (np.arange(K * M)) * Ts / M
    keep = t >= t[K // 2 * M]
    return w, 2 * np.mean(v.ravel()[keep] * np.exp(-1j * w * t[keep]))


@pytest.mark.parametrize("body, P, D, omega_samples", [("m", 200.0, 10.0, 40), ("L2", 200.0, 10.0, 25)])
def test_friction_linear_part_carries_the_drive(body, P, D, omega_samples):
    base = load_params()
    Ts, tau, whole, frac_steps = base.controller.Ts, 0.002, 2, 4          # 2.25 samples of dead time
    params = base.with_values(tau_drive=tau, delay_drive=(whole + frac_steps / M) * Ts)
    w, sim = _fundamental_response(params, P, D, body, omega_samples, tau, whole, frac_steps)
    G = linear_part(ClosedLoop(params), P, D, f"Fc_{body}", np.array([w]))[0]
    # as tests/test_analysis_describing.py: the images of the held command alias onto omega on
    # the M-point grid, attenuated far below 1e-4 by the plant (and the lag)
    assert abs(sim - G) <= 1e-4 * abs(G), abs(sim - G) / abs(G)
    G0 = linear_part(ClosedLoop(base), P, D, f"Fc_{body}", np.array([w]))[0]
    assert abs(G0 - G) > 1e-2 * abs(G)
