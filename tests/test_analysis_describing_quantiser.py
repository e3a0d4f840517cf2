"""The quantiser's harmonic balance finds every amplitude with N(A) = -1/G (review of issue 19).

N of a rounding quantiser is continuous and rises like sqrt(A - t) just above each threshold t;
the root on that steep rise (N' > 0, a stable cycle by Loeb) was lost when the samples of each
interval started a thirty-second of a step above the threshold. Here N is computed independently
(the first harmonic of the quantiser's output by quadrature) on a fine amplitude grid, and the
prediction must hold every crossing of -1/G, alternately stable and unstable.
"""
import numpy as np
import scipy.signal

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.describing import limit_cycles, nonlinearity_output
from haa_sym.analysis.oscillation import limit_cycle
from haa_sym.analysis.sweep import blas_limits
from haa_sym.loop.plant import continuous_plant


def _N_by_quadrature(q: float, A: np.ndarray) -> np.ndarray:
    th = np.linspace(0.0, 2 * np.pi, 20_001)
    b1 = [np.trapezoid(nonlinearity_output("quantiser", q, a[:, None] * np.sin(th)) * np.sin(th), th, axis=1)
          for a in np.array_split(A, max(1, A.size // 100))]
    return np.concatenate(b1) / (np.pi * A)


def test_every_quantiser_crossing_is_found_and_stability_alternates():
    # the doc's case (docs/describing.md): HyQ, alpha 1.2, beta 3, P_gain 5000, T_res 0.1 Nm
    q = 0.1
    loop = ClosedLoop(load_params().with_values(alpha=1.2, beta=3.0))
    with blas_limits(1):
        r = limit_cycles(loop, 5000.0, 0.0, nonlinearity={"T_res": q}, amplitude_max=8.0)
    assert r.omega.size >= 2 and np.allclose(r.omega, r.omega[0])      # one phase crossover
    target = -1.0 / r.G_crossing[0]
    A = np.linspace(0.5 * q + 1e-9, 8.0 * q, 1501)
    f = _N_by_quadrature(q, A) - target
    brackets = np.flatnonzero(np.sign(f[1:]) != np.sign(f[:-1]))
    # every bracket of the independent N holds one predicted amplitude (within a grid step: the
    # quadrature's N is good to about 1e-4) and the prediction solves N(A) = -1/G there
    assert r.amplitude.size == brackets.size
    step = A[1] - A[0]
    for i, a in zip(brackets, np.sort(r.amplitude)):
        assert A[i] - step <= a <= A[i + 1] + step
    np.testing.assert_allclose(_N_by_quadrature(q, np.sort(r.amplitude)), target, rtol=1e-3)
    # N rises then falls across each crossing in turn: Loeb's verdict alternates
    s = r.stable[np.argsort(r.amplitude)]
    assert np.all(s[1:] != s[:-1])
    # rising crossings (N' > 0 by the independent N) are the stable ones
    rising = f[brackets + 1] > f[brackets]
    np.testing.assert_array_equal(s, rising)



def _quantised_loop_torque(params, P, D, q, x0, n):
    """The sampled loop with the PI reading the torque rounded to multiples of ``q``, written out
    here: the continuous plant sampled by scipy's ZOH, the average of N_av differences, the
    impedance law (Eq. 8), the backward-Euler PI (Eq. 7), velocity compensation (Eq. 6), no delay;
    the leg released from theta_L2 = x0. Returns the (unquantised) measured torque per sample."""
    pl, c = params.plant, params.controller
    cont = continuous_plant(pl)
    Ts, Nav = c.Ts, c.N_av
    C = cont.C[[cont.output_names.index("T_sensor"), cont.output_names.index("theta_encoder")]]
    Ad, Bd, *_ = scipy.signal.cont2discrete((cont.A, cont.B[:, [0]], C, np.zeros((2, 1))), Ts, "zoh")
    P_t, I_t = c.beta * c.P_t0, c.beta * c.I_t0
    VC = c.alpha * pl.N / pl.k_t * (pl.R * pl.B_m + pl.k_t * pl.k_w)
    x = np.zeros(Ad.shape[0])
    x[cont.state_names.index("theta_L2")] = x0
    theta, integral, T_out = np.zeros(n + Nav), 0.0, np.empty(n)
    for k in range(n):
        T_out[k], theta[k + Nav] = C @ x
        v = (theta[k + Nav] - theta[k]) / (Nav * Ts)
        e = -(P * theta[k + Nav] + D * v) - q * np.round(T_out[k] / q)
        integral += Ts * e
        x = Ad @ x + Bd[:, 0] * (P_t * e + I_t * integral + VC * v)
    return np.arange(n) * Ts, T_out


def test_a_cycle_on_the_rising_branch_is_what_a_simulation_settles_on():
    # released from 1 mrad the quantised loop settles on a torque cycle of about 0.35 Nm: the
    # stable cycle on N's rise just above the threshold 0.35 (the one the search used to lose)
    q, P = 0.1, 5000.0
    params = load_params().with_values(alpha=1.2, beta=3.0)
    with blas_limits(1):
        r = limit_cycles(ClosedLoop(params), P, 0.0, nonlinearity={"T_res": q}, amplitude_max=8.0)
        t, T = _quantised_loop_torque(params, P, 0.0, q, 1e-3, 8000)
    osc = limit_cycle(t, T)
    assert osc.kind == "sustained"
    i = np.argmin(np.abs(r.amplitude - osc.fundamental))
    assert bool(r.stable[i])
    assert abs(osc.fundamental / r.amplitude[i] - 1) <= r.distortion[i]
    assert abs(osc.omega / r.omega[i] - 1) <= r.distortion[i]
