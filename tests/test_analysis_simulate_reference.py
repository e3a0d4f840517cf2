"""The simulation against an independent one written here (issue 19's second check): the HyQ
plant of Eq. (1)-(2) by hand, integrated by scipy's solve_ivp (Radau) from sample instant to
sample instant with the voltage held, and the controller of Sec. 3 by hand (averaging velocity
filter, backward-Euler PI, velocity compensation, impedance law, no delay) with the limits; and
the drive (haa_sym.model.drive) by hand: the command clipped, then delayed (a list of past
commands, the held one switching at t_k + f inside the interval), then lagged (one more ODE
state u' = (V_delayed - u) / tau)."""
import math

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate
from haa_sym.loop.plant import continuous_plant
from haa_sym.model.limits import Limits

RTOL_IVP = 1e-11


class HandPlant:
    """Eq. (1)-(2) of Focchi et al. (2016): states [I_m, theta_m, dtheta_m, theta_L1, dtheta_L1,
    theta_L2, dtheta_L2]; the torque sensor reads the harmonic drive's T_hd (spring and damper)."""

    def __init__(self, p):
        self.p = p
        A = np.zeros((7, 7))
        L, R, kt, kw, Jm, Bm, N = p.L, p.R, p.k_t, p.k_w, p.J_m, p.B_m, p.N
        Khd, Dhd, Kp, Dp = p.K_hd, p.D_hd, p.K_p, p.D_p
        J1, B1, J2, B2, K2 = p.J_L1, p.B_L1, p.J_L2, p.B_L2, p.K_L2
        A[0, 0], A[0, 2] = -R / L, -kw / L
        A[1, 2] = A[3, 4] = A[5, 6] = 1.0
        # T_hd = Khd (theta_m/N - theta_1) + Dhd (dtheta_m/N - dtheta_1)
        hd = np.array([0, Khd / N, Dhd / N, -Khd, -Dhd, 0, 0])
        pp = np.array([0, 0, 0, Kp, Dp, -Kp, -Dp])
        A[2] = (np.eye(7)[0] * kt - np.eye(7)[2] * Bm - hd / N) / Jm
        A[4] = (hd - np.eye(7)[4] * B1 - pp) / J1
        A[6] = (pp - np.eye(7)[6] * B2 - np.eye(7)[5] * K2) / J2
        self.A, self.hd = A, hd
        self.bV = np.eye(7)[0] / L
        self.bd = np.eye(7)[6] / J2
        self.vel = {"m": 2, "L1": 4, "L2": 6}
        self.J = {"m": Jm, "L1": J1, "L2": J2}

    def f(self, x, V, Td, friction, vs, tau=0.0):
        if tau:                             # the drive's lag: x[7] is what the motor receives
            dx = np.append(self.A @ x[:7] + self.bV * x[7] + self.bd * Td, (V - x[7]) / tau)
        else:
            dx = self.A @ x + self.bV * V + self.bd * Td
        for b, Fc in friction.items():
            i = self.vel[b]
            dx[i] -= Fc * math.tanh(x[i] / vs) / self.J[b]
        return dx

    def jac(self, x, friction, vs):
        Jm = self.A.copy()
        for b, Fc in friction.items():
            i = self.vel[b]
            Jm[i, i] -= Fc / (vs * self.J[b] * math.cosh(x[i] / vs) ** 2)
        return Jm


def vc0(p):
    """Eq. (6) at alpha = 1: the voltage that cancels the back-EMF and the rotor's viscous
    friction at the link speed, N (k_w + R B_m / k_t) (V s/rad)."""
    return p.N * (p.k_w + p.R * p.B_m / p.k_t)


def _jitter_draws(seed, n):
    """The jitter's N(0, 1) draws: the seed's first spawned stream (docs/simulate.md, "The
    sampled-data model"; the noise's is default_rng(seed))."""
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0]).standard_normal(n)


def hand_simulation(params, P, D, lim: Limits, n, *, T_ff=0.0, T_dist=0.0, jitter_eps=None, tau=0.0,
                    delay=0.0):
    """Sample by sample: read, control, saturate, hold, integrate to the next instant. ``tau``,
    ``delay``: the drive's lag and dead time (s); the clipped command V_k acts from t_k + delay
    (with jitter: whole intervals, then the fraction of the interval it lands in)."""
    c, p = params.controller, params.plant
    plant = HandPlant(p)
    Ts, Nav = c.Ts, c.N_av
    P_t, I_t = c.beta * c.P_t0, c.beta * c.I_t0
    VC = c.alpha * vc0(p)
    x = np.zeros(8 if tau else 7)
    whole = int(math.floor(delay / Ts + 1e-9))
    frac = delay / Ts - whole              # of an interval
    frac = 0.0 if frac < 1e-9 else frac
    sent = []                              # the clipped commands V_0 ... V_k
    hist = [0.0] * Nav                     # theta_(k-1) ... theta_(k-N_av), at rest before t = 0
    integ = 0.0
    q_th = 2 * math.pi / lim.encoder_counts if lim.encoder_counts else 0.0
    q_T = lim.torque_resolution or 0.0
    quant = (lambda v, q: math.floor(v / q + 0.5) * q if q else v)
    R, kw = p.R, p.k_w
    fr = dict(lim.friction)
    times = np.arange(n) * Ts if jitter_eps is None else np.arange(n) * Ts + jitter_eps[:n]
    out = {k: np.empty(n) for k in ("theta", "velocity", "torque", "voltage", "current")}
    for k in range(n):
        th = quant(x[3], q_th)
        T = quant(plant.hd @ x[:7], q_T)
        v = (th - hist[-1]) / (Nav * Ts)
        hist = [th] + hist[:-1]
        T_ref = (T_ff[k] if np.ndim(T_ff) else T_ff) - P * th - D * v
        e = T_ref - T
        integ += Ts * e
        V = P_t * e + I_t * integ + VC * v
        emf = kw * x[2]
        # the current window first, then the supply (which wins where the window lies outside it)
        if lim.I_max:
            V = min(max(V, -R * lim.I_max + emf), R * lim.I_max + emf)
        if lim.V_max:
            V = min(max(V, -lim.V_max), lim.V_max)
        out["theta"][k], out["velocity"][k], out["torque"][k] = th, x[6], T
        out["voltage"][k], out["current"][k] = V, x[0]
        sent.append(V)
        t1 = (k + 1) * Ts + (0.0 if jitter_eps is None else jitter_eps[k + 1])
        old = sent[k - whole - 1] if k - whole - 1 >= 0 else 0.0
        new = sent[k - whole] if k - whole >= 0 else 0.0
        t_switch = times[k] + frac * (t1 - times[k])
        for Vh, (ta, tb) in ((old, (times[k], t_switch)), (new, (t_switch, t1))):
            if tb > ta:
                sol = scipy.integrate.solve_ivp(
                    lambda t, y: plant.f(y, Vh, T_dist, fr, lim.friction_velocity, tau),
                    (ta, tb), x, method="DOP853", rtol=RTOL_IVP, atol=1e-14)
                x = sol.y[:, -1]
    return times, out


def test_hand_plant_is_the_plant_the_simulation_uses():
    p = load_params().plant
    assert np.allclose(HandPlant(p).A, continuous_plant(p).A, rtol=1e-12, atol=0)
    assert continuous_plant(p).VC0 == pytest.approx(vc0(p), rel=1e-12)


def _compare(sim, ref, rtol, names=("theta", "velocity", "torque", "voltage", "current")):
    for name in names:
        a, b = getattr(sim, name), ref[name]
        assert np.abs(a - b).max() <= rtol * np.abs(b).max(), (name, np.abs(a - b).max() / np.abs(b).max())


def test_voltage_and_current_limits_agree_with_solve_ivp():
    params = load_params()
    lim = Limits(V_max=8.0, I_max=1.5)
    n = 100
    sim = simulate(ClosedLoop(params, basis=False), 300.0, 4.0, limits=lim, experiment="torque-step",
                   amplitude=40.0, duration=(n - 1) * params.controller.Ts)
    t, ref = hand_simulation(params, 300.0, 4.0, lim, n, T_ff=40.0)
    assert sim.saturated.sum() > 10
    _compare(sim, ref, 1e-8)


@pytest.mark.slow
def test_quantisation_agrees_with_solve_ivp():
    params = load_params()
    lim = Limits(encoder_counts=4096, torque_resolution=0.02)
    n = 150
    sim = simulate(ClosedLoop(params, basis=False), 300.0, 4.0, limits=lim, experiment="disturbance-step",
                   amplitude=3.0, duration=(n - 1) * params.controller.Ts)
    t, ref = hand_simulation(params, 300.0, 4.0, lim, n, T_dist=3.0)
    _compare(sim, ref, 1e-8)


@pytest.mark.parametrize("friction", [{"m": 0.02}, pytest.param({"L2": 1.0}, marks=pytest.mark.slow)])
def test_coulomb_friction_agrees_with_solve_ivp(friction):
    params = load_params()
    lim = Limits(friction=friction, friction_velocity=0.05)
    n = 100
    sim = simulate(ClosedLoop(params, basis=False), 300.0, 4.0, limits=lim, experiment="torque-step",
                   amplitude=2.0, duration=(n - 1) * params.controller.Ts, rtol=1e-7)
    t, ref = hand_simulation(params, 300.0, 4.0, lim, n, T_ff=2.0)
    assert sim.meta["n_sub_max"] > 1
    # the friction changes the run by far more than the tolerance
    free = simulate(ClosedLoop(params, basis=False), 300.0, 4.0, limits=Limits(), experiment="torque-step",
                    amplitude=2.0, duration=(n - 1) * params.controller.Ts)
    assert np.abs(free.velocity - ref["velocity"]).max() > 1e-3 * np.abs(ref["velocity"]).max()
    _compare(sim, ref, 1e-6)


@pytest.mark.slow
def test_jitter_agrees_with_exact_transitions_over_the_jittered_intervals():
    params = load_params()
    Ts, sigma, n = params.controller.Ts, 5e-6, 120
    lim = Limits(jitter=sigma)
    sim = simulate(ClosedLoop(params, basis=False), 300.0, 4.0, limits=lim, experiment="disturbance-step",
                   amplitude=2.0, duration=(n - 1) * Ts, seed=7)
    eps = np.zeros(n + 1)
    eps[1:] = np.clip(sigma * _jitter_draws(7, n), -3 * sigma, 3 * sigma)
    assert np.allclose(sim.time, np.arange(n) * Ts + eps[:n], rtol=0, atol=1e-18)
    t, ref = hand_simulation(params, 300.0, 4.0, lim, n, T_dist=2.0, jitter_eps=eps)
    _compare(sim, ref, 1e-8)


@pytest.mark.slow
def test_chirp_agrees_with_solve_ivp():
    params = load_params()
    Ts, n, f1 = params.controller.Ts, 200, 40.0
    sim = simulate(ClosedLoop(params, basis=False), 300.0, 4.0, limits=Limits(V_max=10.0), experiment="chirp",
                   amplitude=8.0, duration=(n - 1) * Ts, chirp_f1=f1)
    t = np.arange(n) * Ts
    T_ff = 8.0 * np.sin(2 * np.pi * (0.1 * t + (f1 - 0.1) * t ** 2 / (2 * t[-1])))
    _, ref = hand_simulation(params, 300.0, 4.0, Limits(V_max=10.0), n, T_ff=T_ff)
    assert np.abs(sim.torque_ref + 300.0 * sim.theta).max() > 1.0
    _compare(sim, ref, 1e-8)


def _cycle(t, y):
    """Amplitude (half peak-to-peak) and period of the last half of y, from its up-crossings."""
    h = len(y) // 2
    t, y = t[h:], y[h:] - y[h:].mean()
    i = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
    tc = t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])
    return (y.max() - y.min()) / 2, (tc[-1] - tc[0]) / (len(tc) - 1)


@pytest.mark.slow
def test_saturation_limit_cycle_amplitude_and_period_agree():
    # linearly unstable at beta = 3 (spectral radius 1.013), bounded by the 24 V supply
    params = load_params().with_values(beta=3.0)
    loop = ClosedLoop(params)
    assert not loop.stability(20000.0, 10.0).stable
    lim = Limits(V_max=24.0)
    n = 1500
    sim = simulate(loop, 20000.0, 10.0, limits=lim, experiment="disturbance-step", amplitude=1.0,
                   duration=(n - 1) * params.controller.Ts)
    t, ref = hand_simulation(params, 20000.0, 10.0, lim, n, T_dist=1.0)
    a_ref, T_ref = _cycle(t, ref["torque"])
    assert a_ref > 1.0
    assert sim.limit_cycle
    assert sim.cycle_amplitude == pytest.approx(a_ref, rel=0.02)
    assert 1 / sim.cycle_frequency == pytest.approx(T_ref, rel=0.02)
    _compare(sim, ref, 1e-6)


@pytest.mark.parametrize("delay_samples", [0.4, 2.37])
def test_drive_lag_and_delay_with_friction_and_supply_agree_with_solve_ivp(delay_samples):
    # the drive's lag (4 ms) and dead time (fractional: the substeps must end at the switch)
    # with rotor friction (the ETDRK4 pieces) and the supply clip (before the delay)
    Ts = load_params().controller.Ts
    params = load_params().with_values(tau_drive=0.004, delay_drive=delay_samples * Ts)
    lim = Limits(V_max=2.0, friction={"m": 0.02}, friction_velocity=0.05)
    n = 70
    sim = simulate(ClosedLoop(params, basis=False), 300.0, 4.0, limits=lim, experiment="torque-step",
                   amplitude=2.0, duration=(n - 1) * Ts, rtol=1e-7)
    t, ref = hand_simulation(params, 300.0, 4.0, lim, n, T_ff=2.0, tau=0.004, delay=delay_samples * Ts)
    assert sim.saturated.sum() > 20 and sim.meta["n_sub_max"] > 1
    _compare(sim, ref, 1e-6)


def test_drive_delay_with_jitter_switches_at_its_fraction_of_the_interval():
    # with jitter the fractional switch sits at the same fraction of each jittered interval
    # (docs/simulate.md, "The drive")
    Ts, sigma, n = load_params().controller.Ts, 5e-6, 80
    params = load_params().with_values(tau_drive=0.002, delay_drive=1.4 * Ts)
    lim = Limits(jitter=sigma)
    sim = simulate(ClosedLoop(params, basis=False), 300.0, 4.0, limits=lim, experiment="disturbance-step",
                   amplitude=2.0, duration=(n - 1) * Ts, seed=7)
    eps = np.zeros(n + 1)
    eps[1:] = np.clip(sigma * _jitter_draws(7, n), -3 * sigma, 3 * sigma)
    t, ref = hand_simulation(params, 300.0, 4.0, lim, n, T_dist=2.0, jitter_eps=eps, tau=0.002,
                             delay=1.4 * Ts)
    _compare(sim, ref, 1e-8)
