"""Describing-function predictions (haa_sym.analysis.describing) against independent computations:
the closed forms against the harmonics of the nonlinearity itself, the linear part against the
reference's loop transfer (haa_sym.check.reference), and the predicted limit cycle against a
simulation of the sampled loop written here (the continuous plant sampled by scipy, the
controller of Eq. 6-8 by hand, the saturation at the sample instants).

Tolerance of the prediction (docs/describing.md, "How good is the prediction"): the harmonic
balance drops the harmonics; the harmonic content returning to the nonlinearity's input relative
to the fundamental, ``distortion`` = sum_k |G(k w)| |b_k| / (|G(w)| |b_1|) over the odd k >= 3, is
the size of the neglected terms, so the amplitude and frequency of the simulated cycle must agree
with the prediction within it.
"""
import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from haa_sym import ClosedLoop, LoopOptions, load_params
from haa_sym.analysis.describing import (describing_function, df_harmonics, limit_cycles, linear_part,
                                         nonlinearity_output)
from haa_sym.analysis.oscillation import limit_cycle
from haa_sym.analysis.sweep import blas_limits
from haa_sym.check import reference
from haa_sym.errors import ParameterError
from haa_sym.loop.plant import continuous_plant

PARAMS = load_params()


@pytest.fixture(autouse=True)
def _one_blas_thread():
    # the simulations multiply small matrices thousands of times: threaded BLAS on a loaded
    # 2-core machine made them 20x slower (measured)
    with blas_limits(1):
        yield


@pytest.mark.parametrize("kind,value,A", [("saturation", 24.0, 30.0), ("saturation", 24.0, 200.0),
                                          ("relay", 0.05, 0.3), ("quantiser", 0.1, 0.08),
                                          ("quantiser", 0.1, 0.37), ("quantiser", 0.1, 2.04)])
def test_closed_forms_are_the_first_harmonic(kind, value, A):
    # the first harmonic of n(A sin t) by quadrature of the nonlinearity itself (not the FFT of
    # df_harmonics): b1 = (1/pi) int n(A sin t) sin t dt
    th = np.linspace(0, 2 * np.pi, 2_000_001)
    b1 = np.trapezoid(nonlinearity_output(kind, value, A * np.sin(th)) * np.sin(th), th) / np.pi
    N, dN = describing_function(kind, value, np.array([A, A * (1 + 1e-6), A * (1 - 1e-6)]))
    assert N[0] * A == pytest.approx(b1, rel=1e-5)
    assert df_harmonics(kind, value, A)[0] == pytest.approx(b1, rel=1e-4)
    b3 = np.trapezoid(nonlinearity_output(kind, value, A * np.sin(th)) * np.sin(3 * th), th) / np.pi
    assert df_harmonics(kind, value, A)[1] == pytest.approx(abs(b3), rel=1e-3, abs=1e-6 * abs(b1))
    assert dN[0] == pytest.approx((N[1] - N[2]) / (2e-6 * A), rel=1e-5)


def test_saturation_is_linear_below_the_limit():
    N, dN = describing_function("saturation", 24.0, np.array([1.0, 24.0]))
    assert np.all(N == 1) and np.all(dN == 0)


@pytest.mark.parametrize("delay", [0, 1])
@pytest.mark.parametrize("P,D", [(0.0, 0.0), (3000.0, 1.0), (200.0, 10.0)])
def test_voltage_linear_part_is_the_reference_loop_without_compensation(delay, P, D):
    # with alpha = 0 the saturated voltage is the PI output, where the reference cuts L_t
    loop = ClosedLoop(PARAMS.with_values(alpha=0.0, beta=1.7), LoopOptions(delay=delay))
    w = np.geomspace(0.5, 3000, 200)
    G = linear_part(loop, P, D, "V_max", w)
    ref = reference.frequency_response(loop, w, P, D, which=("L_t",))["L_t"]
    np.testing.assert_allclose(G, ref, rtol=1e-8, atol=1e-12 * np.abs(ref).max())


def test_torque_quantiser_linear_part_torque_loop_alone():
    # P = D = 0 and alpha = 0: the only path from the read torque back to the torque is the PI
    loop = ClosedLoop(PARAMS.with_values(alpha=0.0))
    w = np.geomspace(0.5, 3000, 100)
    ref = reference.frequency_response(loop, w, 0.0, 0.0, which=("L_t",))["L_t"]
    np.testing.assert_allclose(linear_part(loop, 0.0, 0.0, "T_res", w), ref, rtol=1e-8)


def test_harmonic_balance_holds_at_the_prediction():
    # a high torque gain with a computation delay: the torque loop alone is unstable
    loop = ClosedLoop(PARAMS.with_values(alpha=0.0, beta=50.0), LoopOptions(delay=1))
    r = limit_cycles(loop, 0.0, 0.0, nonlinearity={"V_max": 24.0})
    assert r.amplitude.size >= 1
    ref = reference.frequency_response(loop, r.omega, 0.0, 0.0, which=("L_t",))["L_t"]
    N = describing_function("saturation", 24.0, r.amplitude)[0]
    np.testing.assert_allclose(1 + N * ref, 0, atol=1e-8)


def _sampled_loop(params, P, D, V_max, n, delay=0, x0_key="theta_L2", x0=0.01):
    """The sampled loop with the voltage saturated at the sample instants, written out here:
    the continuous plant sampled by scipy's ZOH, the average of N_av differences, the impedance
    law (Eq. 8), the backward-Euler PI (Eq. 7), velocity compensation (Eq. 6) and ``delay``
    samples between the command and the applied voltage.
    Returns the voltage command V_k (before the saturation) per sample."""
    pl, c = params.plant, params.controller
    cont = continuous_plant(pl)
    Ts, Nav = c.Ts, c.N_av
    C = cont.C[[cont.output_names.index("T_sensor"), cont.output_names.index("theta_encoder")]]
    Ad, Bd, *_ = scipy.signal.cont2discrete((cont.A, cont.B[:, [0]], C, np.zeros((2, 1))), Ts, "zoh")
    P_t, I_t = c.beta * c.P_t0, c.beta * c.I_t0
    VC = c.alpha * pl.N / pl.k_t * (pl.R * pl.B_m + pl.k_t * pl.k_w)
    x = np.zeros(Ad.shape[0])
    x[cont.state_names.index(x0_key)] = x0
    theta = np.zeros(n + Nav)              # theta before t = 0: at rest at 0
    integral, u = 0.0, np.zeros(n + delay)
    for k in range(n):
        T, theta[k + Nav] = C @ x
        v = (theta[k + Nav] - theta[k]) / (Nav * Ts)
        e = -(P * theta[k + Nav] + D * v) - T
        integral += Ts * e
        u[k + delay] = P_t * e + I_t * integral + VC * v
        x = Ad @ x + Bd[:, 0] * np.clip(u[k], -V_max, V_max)
    return np.arange(n) * Ts, u[delay:]


@pytest.mark.parametrize("beta,delay,P,D", [(1.0, 0, 3000.0, 1.0), (1.0, 0, 20000.0, 0.0), (50.0, 1, 0.0, 0.0)])
def test_saturation_limit_cycle_against_the_sampled_loop(beta, delay, P, D):
    # linearly unstable points (the impedance loop's stiffness; a high torque gain with a delay)
    V_max, params = 24.0, PARAMS.with_values(beta=beta)
    r = limit_cycles(ClosedLoop(params, LoopOptions(delay=delay)), P, D, nonlinearity={"V_max": V_max})
    assert r.amplitude.size == 1 and bool(r.stable[0])          # one stable cycle (Loeb)
    t, u = _sampled_loop(params, P, D, V_max, 6000, delay)
    osc = limit_cycle(t, u)
    assert osc.kind == "sustained"
    eps = float(r.distortion[0])
    print(f"beta={beta} delay={delay} P={P} D={D}: DF {r.amplitude[0]:.4g} V at {r.omega[0]:.5g} rad/s, simulated {osc.fundamental:.4g} V at "
          f"{osc.omega:.5g} rad/s (distortion {eps:.3g})")
    assert abs(osc.fundamental / r.amplitude[0] - 1) <= eps
    assert abs(osc.omega / r.omega[0] - 1) <= eps


def test_no_cycle_where_the_loop_is_stable_and_saturation_only_lowers_the_gain():
    # the torque loop alone at the file's gains: |G| < 1 at every phase crossover
    r = limit_cycles(ClosedLoop(PARAMS), 0.0, 0.0, nonlinearity={"V_max": 24.0})
    assert r.amplitude.size == 0
    assert np.all(r.G_curve[np.abs(np.sin(np.angle(r.G_curve))) < 1e-3].real > -1)


@pytest.mark.parametrize("bad,match", [({"V_max": -1}, "V_max = -1"), ({"V_max": "x"}, "V_max = 'x'"),
                                       ({"I_max": 3}, "I_max"), ({"Fc_L7": 1.0}, "no body 'L7'"),
                                       ({"V_max": 24, "Fc_m": 1}, "one entry")])
def test_bad_nonlinearity_is_one_line(bad, match):
    with pytest.raises(ParameterError, match=match) as e:
        limit_cycles(ClosedLoop(PARAMS), 0.0, 0.0, nonlinearity=bad)
    assert "\n" not in str(e.value)


def test_one_gain_point_only():
    with pytest.raises(ParameterError, match="one gain point"):
        limit_cycles(ClosedLoop(PARAMS), [1.0, 2.0], 0.0, nonlinearity={"V_max": 24.0})


def _fundamental_response(params, P, D, body, omega_samples, n_periods=40, M=16):
    """Velocity of ``body`` per unit torque cos(omega t) on it, at omega = 2 pi / (omega_samples Ts),
    from a simulation of the linear sampled-data loop written here: the continuous plant with an
    oscillator for the torque, exact (expm) between the sample instants with the voltage held,
    the controller of Eq. 6-8 by hand; the velocity read M times per sample and projected on
    exp(-j omega t) over whole periods after ``n_periods`` periods of transient."""
    pl, c = params.plant, params.controller
    cont = continuous_plant(pl)
    Ts, Nav, n = c.Ts, c.N_av, cont.A.shape[0]
    w = 2 * np.pi / (omega_samples * Ts)
    i_v = cont.state_names.index(f"dtheta_{body}")
    col = cont.B[:, 1] if body == "m" else np.eye(n)[i_v] / getattr(pl, f"J_{body}")
    A = np.zeros((n + 3, n + 3))                  # [x, cos, sin, V held]
    A[:n, :n], A[:n, n], A[:n, n + 2] = cont.A, col, cont.B[:, 0]
    A[n, n + 1], A[n + 1, n] = -w, w
    E = [scipy.linalg.expm(A * Ts * j / M) for j in range(M + 1)]
    C = cont.C[[cont.output_names.index("T_sensor"), cont.output_names.index("theta_encoder")]]
    P_t, I_t = c.beta * c.P_t0, c.beta * c.I_t0
    VC = c.alpha * pl.N / pl.k_t * (pl.R * pl.B_m + pl.k_t * pl.k_w)
    K = 2 * n_periods * omega_samples
    z = np.zeros(n + 3)
    z[n] = 1.0
    theta = np.zeros(K + Nav)
    integral, Z = 0.0, np.empty((K, n + 3))
    for k in range(K):
        T, theta[k + Nav] = C @ z[:n]
        v = (theta[k + Nav] - theta[k]) / (Nav * Ts)
        e = -(P * theta[k + Nav] + D * v) - T
        integral += Ts * e
        z[n + 2] = P_t * e + I_t * integral + VC * v
        Z[k] = z
        z = E[M] @ z
    tail = Z[K // 2:]
    v = np.stack([tail @ E[j][i_v] for j in range(M)], axis=1).ravel()     # M points per sample
    t = (np.arange(v.size) + K // 2 * M) * Ts / M
    return w, 2 * np.mean(v * np.exp(-1j * w * t))


@pytest.mark.parametrize("body,P,D,omega_samples", [("m", 200.0, 10.0, 40), ("m", 0.0, 0.0, 400),
                                                     ("L2", 200.0, 10.0, 25), ("L1", 1000.0, 30.0, 60)])
def test_friction_linear_part_is_the_fundamental_of_the_sampled_data_loop(body, P, D, omega_samples):
    w, sim = _fundamental_response(PARAMS, P, D, body, omega_samples)
    G = linear_part(ClosedLoop(PARAMS), P, D, f"Fc_{body}", np.array([w]))[0]
    # the simulation's only approximation: the images of the held voltage at omega + k M 2 pi/Ts
    # alias onto omega on the M-point grid; the plant attenuates them far below 1e-4
    print(f"Fc_{body} at P={P} D={D}, omega={w:.5g} rad/s: |sim - G|/|G| = {abs(sim - G) / abs(G):.2e}")
    assert abs(sim - G) <= 1e-4 * abs(G)


# --- Coulomb friction: a simulation with events ------------------------------------------------
class _FrictionLoop:
    """The sampled loop with Coulomb friction on one body, written here. Three modes of the body:
    slipping forwards or backwards (friction -s Fc) and stuck (the friction holds it at rest while
    the torque that needs stays within Fc). Each mode is linear with the held voltage, so the
    state flows exactly (expm) between events; an event (the velocity reaching zero, or the
    holding torque reaching Fc) is located by brentq on the exact flow, and decides the next mode.
    ``step(V)`` advances one sample with the held voltage V, recording the velocity M times."""

    def __init__(self, params, body, Fc, M=10, x0=1e-4):
        pl = params.plant
        cont = continuous_plant(pl)
        n = cont.A.shape[0]
        self.n, self.Fc, self.M, self.h = n, Fc, M, params.controller.Ts / M
        self.i_v = i_v = cont.state_names.index(f"dtheta_{body}")
        A, B = cont.A, cont.B[:, 0]
        col = cont.B[:, 1] if body == "m" else np.eye(n)[i_v] / getattr(pl, f"J_{body}")
        self.A, self.B, self.col = A, B, col
        self.g = -np.r_[A[i_v], B[i_v], 0.0] / col[i_v]        # holding torque: g . [x, V, 1]
        self.aug = {}
        for s in (-1, 0, 1):
            Z = np.zeros((n + 2, n + 2))
            if s:
                Z[:n, :n], Z[:n, n], Z[:n, n + 1] = A, B, -s * Fc * col
            else:
                Z[:n, :n + 1] = np.c_[A, B] + np.outer(col, self.g[:n + 1])
            self.aug[s] = Z
        self.sub = {s: scipy.linalg.expm(Z * self.h) for s, Z in self.aug.items()}
        self.z = np.zeros(n + 2)
        self.z[n + 1] = 1.0
        self.z[cont.state_names.index(f"theta_{body}")] = x0
        self.mode, self.events = 0, 0
        self.C = cont.C[[cont.output_names.index("T_sensor"), cont.output_names.index("theta_encoder")]]

    def _flow(self, z, tau):
        return scipy.linalg.expm(self.aug[self.mode] * tau) @ z

    def _passed(self, z):
        return -self.mode * z[self.i_v] > 0 if self.mode else abs(self.g @ z) > self.Fc

    def _next_mode(self, z):
        f = self.g @ z
        return 0 if (self.mode != 0 and abs(f) <= self.Fc) else int(-np.sign(f))

    def step(self, V):
        z, n, i_v = self.z, self.n, self.i_v
        z[n] = V
        if self.mode == 0 and abs(self.g @ z) > self.Fc:
            self.mode = int(-np.sign(self.g @ z))
        out = np.empty(self.M)
        for j in range(self.M):
            out[j] = z[i_v]
            left, zn = self.h, self.sub[self.mode] @ z
            while self._passed(zn):
                if self.mode:
                    s = self.mode
                    tau = brentq(lambda t: -s * self._flow(z, t)[i_v], 0.0, left, xtol=1e-16)
                else:
                    sgn = np.sign(self.g @ zn)
                    tau = brentq(lambda t: sgn * (self.g @ self._flow(z, t)) - self.Fc, 0.0, left, xtol=1e-16)
                z = self._flow(z, tau)
                left -= tau
                self.events += 1
                if self.mode:
                    z[i_v] = 0.0
                self.mode = self._next_mode(z)
                zn = self._flow(z, left)
            z = zn
            if self.mode == 0:
                z[i_v] = 0.0
        self.z = z
        return out


def _run_friction(params, P, D, body, Fc, duration, M=10):
    c, pl = params.controller, params.plant
    Ts, Nav = c.Ts, c.N_av
    P_t, I_t = c.beta * c.P_t0, c.beta * c.I_t0
    VC = c.alpha * pl.N / pl.k_t * (pl.R * pl.B_m + pl.k_t * pl.k_w)
    sim = _FrictionLoop(params, body, Fc, M)
    K = int(round(duration / Ts))
    theta, integral, v_out = np.zeros(K + Nav), 0.0, []
    for k in range(K):
        T, theta[k + Nav] = sim.C @ sim.z[:sim.n]
        v = (theta[k + Nav] - theta[k]) / (Nav * Ts)
        e = -(P * theta[k + Nav] + D * v) - T
        integral += Ts * e
        v_out.append(sim.step(P_t * e + I_t * integral + VC * v))
    return np.arange(K * M) * Ts / M, np.concatenate(v_out), sim


# the case: friction on the leg of HyQ with over-compensated back-EMF and a high torque gain; the
# loop is linearly stable (spectral radius 0.9997) and the leg stuck by friction is the stiff
# contact that destabilises it (Sec. 5), so friction sustains a cycle
FRICTION_CASE = dict(values=dict(alpha=1.2, beta=3.0), P=5000.0, D=0.0, body="L2", Fc=0.1)


def test_friction_limit_cycle_against_a_simulation_with_events():
    cs = FRICTION_CASE
    params = PARAMS.with_values(**cs["values"])
    loop = ClosedLoop(params)
    assert bool(loop.stability(cs["P"], cs["D"]).stable)
    r = limit_cycles(loop, cs["P"], cs["D"], nonlinearity={f"Fc_{cs['body']}": cs["Fc"]})
    assert r.amplitude.size == 1 and bool(r.stable[0])
    # the cycle attracts slowly (about 0.2 % a cycle near it): 12 s, the last 40 % analysed
    t, v, sim = _run_friction(params, cs["P"], cs["D"], cs["body"], cs["Fc"], 12.0, M=5)
    osc = limit_cycle(t, v, settle=0.6)
    assert osc.kind == "sustained" and abs(osc.growth_per_cycle) < 1e-3
    eps = float(r.distortion[0])
    print(f"Fc_{cs['body']} = {cs['Fc']} Nm: DF {r.amplitude[0]:.5g} rad/s at {r.omega[0]:.6g} rad/s, simulated "
          f"{osc.fundamental:.5g} rad/s at {osc.omega:.6g} rad/s (distortion {eps:.3g}, {sim.events} events)")
    assert abs(osc.fundamental / r.amplitude[0] - 1) <= eps
    assert abs(osc.omega / r.omega[0] - 1) <= eps


@pytest.mark.slow
def test_event_simulation_matches_solve_ivp():
    # the exact-flow friction simulation against scipy's solve_ivp (LSODA, events at the
    # velocity's zero crossings and at the holding torque reaching Fc, restarted at every sample
    # instant), over the first 0.2 s of the case above: they agree within the integrator's tolerance
    cs = FRICTION_CASE
    params = PARAMS.with_values(**cs["values"])
    c, pl = params.controller, params.plant
    Ts, Nav, Fc = c.Ts, c.N_av, cs["Fc"]
    P_t, I_t = c.beta * c.P_t0, c.beta * c.I_t0
    VC = c.alpha * pl.N / pl.k_t * (pl.R * pl.B_m + pl.k_t * pl.k_w)
    ref = _FrictionLoop(params, cs["body"], Fc, M=1)
    A, B, col, i_v, n = ref.A, ref.B, ref.col, ref.i_v, ref.n
    g = ref.g
    x, mode = ref.z[:n].copy(), 0
    K = 200
    theta, integral, v_ivp, v_exact = np.zeros(K + Nav), 0.0, np.empty(K), np.empty(K)
    for k in range(K):
        T, theta[k + Nav] = ref.C @ x
        v = (theta[k + Nav] - theta[k]) / (Nav * Ts)
        e = -(cs["P"] * theta[k + Nav] + cs["D"] * v) - T
        integral += Ts * e
        V = P_t * e + I_t * integral + VC * v
        v_ivp[k] = x[i_v]
        v_exact[k] = ref.step(V)[0]
        hold = lambda y: g @ np.r_[y, V, 1.0]                                   # noqa: E731
        if mode == 0 and abs(hold(x)) > Fc:
            mode = int(-np.sign(hold(x)))
        t0 = k * Ts
        while True:
            if mode:
                rhs = (lambda s: lambda t, y: A @ y + B * V - s * Fc * col)(mode)
                ev = (lambda s: lambda t, y: y[i_v])(mode)
                ev.direction = -mode
            else:
                rhs = lambda t, y: A @ y + B * V + col * hold(y)                 # noqa: E731
                ev = lambda t, y: abs(hold(y)) - Fc                              # noqa: E731
                ev.direction = 1
            ev.terminal = True
            sol = solve_ivp(rhs, (t0, (k + 1) * Ts), x, method="LSODA", rtol=1e-10, atol=1e-14, events=ev,
                            jac=lambda t, y: A if mode else A + np.outer(col, g[:n]))
            x = sol.y[:, -1].copy()
            if sol.status != 1:
                break
            t0 = sol.t_events[0][0]
            x = sol.y_events[0][0].copy()
            if mode:
                x[i_v] = 0.0
            f = hold(x)
            mode = 0 if (mode and abs(f) <= Fc) else int(-np.sign(f))
    scale = np.abs(v_exact).max()
    assert ref.events > 2                            # the trace passes through events
    np.testing.assert_allclose(v_ivp, v_exact, rtol=0, atol=1e-6 * scale)


@pytest.mark.slow
def test_sampled_saturation_loop_matches_solve_ivp():
    # the exactly ZOH-sampled loop above against scipy's solve_ivp (LSODA) restarted at every
    # sample instant with the held, saturated voltage: 300 samples of the first case, through the
    # saturation (the trace leaves +-V_max), within the integrator's tolerance
    params, P, D, V_max, n = PARAMS, 3000.0, 1.0, 24.0, 300
    t, u_exact = _sampled_loop(params, P, D, V_max, n, x0=0.05)
    pl, c = params.plant, params.controller
    cont = continuous_plant(pl)
    Ts, Nav = c.Ts, c.N_av
    C = cont.C[[cont.output_names.index("T_sensor"), cont.output_names.index("theta_encoder")]]
    P_t, I_t = c.beta * c.P_t0, c.beta * c.I_t0
    VC = c.alpha * pl.N / pl.k_t * (pl.R * pl.B_m + pl.k_t * pl.k_w)
    A, B = cont.A, cont.B[:, 0]
    x = np.zeros(A.shape[0])
    x[cont.state_names.index("theta_L2")] = 0.05
    theta, integral, u = np.zeros(n + Nav), 0.0, np.empty(n)
    for k in range(n):
        T, theta[k + Nav] = C @ x
        v = (theta[k + Nav] - theta[k]) / (Nav * Ts)
        e = -(P * theta[k + Nav] + D * v) - T
        integral += Ts * e
        u[k] = P_t * e + I_t * integral + VC * v
        V = np.clip(u[k], -V_max, V_max)
        x = solve_ivp(lambda _, y: A @ y + B * V, (k * Ts, (k + 1) * Ts), x, method="LSODA", rtol=1e-10,
                      atol=1e-14, jac=lambda _, y: A).y[:, -1]
    assert np.abs(u_exact).max() > 2 * V_max
    np.testing.assert_allclose(u, u_exact, rtol=0, atol=1e-6 * np.abs(u_exact).max())
