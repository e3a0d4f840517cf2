"""The nonlinear simulation of a current-commanded structure (``impedance_current``; issue 24,
docs/simulate.md, "A current command"): the plant without the electrical state, the held command
a current. With every limit off it is the explicit closed loop of ClosedLoop (whose plant is
``current_commanded``) for the QDD leg and the haptic wall, with and without a drive; a point the
linear map calls unstable grows; the current limit and the supply clip the current command. The
independent check with friction and the current limit is in
tests/test_analysis_simulate_reference.py."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate, simulate_batch
from haa_sym.loop.statespace import closed_loop_batch
from haa_sym.model.limits import Limits

# gain points near the edge of each map: spectral radii 0.9856 (QDD leg), 0.9917 (haptic wall)
POINTS = {"qdd_leg": (60.0, 0.6), "haptic_wall": (8.0, 0.004)}


def _params(name, tau=0.0, delay_samples=0.0):
    p = load_params(name)
    return p.with_values(tau_drive=tau, delay_drive=delay_samples * p.controller.Ts)


def _linear(loop, P, D, A, n):
    """theta_encoder and port velocity of the explicit closed loop under a constant T_dist A."""
    Acl, Bcl, Ccl, Dcl = (m[0] for m in closed_loop_batch(loop, P, D))
    x, u, y = np.zeros(Acl.shape[0]), np.array([A, 0.0]), np.empty((n, 2))
    for k in range(n):
        y[k] = (Ccl @ x + Dcl @ u)[1:3]
        x = Acl @ x + Bcl @ u
    return y


def _rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@pytest.mark.parametrize("tau, delay_samples", [(0.0, 0.0), (0.002, 0.0), (0.0, 2.0), (0.0, 0.4), (0.002, 2.37)])
@pytest.mark.parametrize("name", sorted(POINTS))
def test_limits_off_is_the_linear_closed_loop(name, tau, delay_samples):
    p = _params(name, tau, delay_samples)
    loop = ClosedLoop(p, basis=False)
    (P, D), A, n = POINTS[name], 0.7, 500
    s = simulate(loop, P, D, limits=Limits(), experiment="disturbance-step", amplitude=A,
                 duration=(n - 1) * p.controller.Ts)
    y = _linear(loop, P, D, A, n)
    assert _rel(s.theta, y[:, 0]) <= 1e-9 and _rel(s.velocity, y[:, 1]) <= 1e-9
    assert s.meta["drive"]["command"] == "current"
    # the torque signal is k_t N I, I the current the motor carried up to t_k: without a lag the
    # command of the interval before, delayed by the drive's whole samples (and by one more
    # piece when fractional: the last piece holds the newer command), from the impedance law
    # on the linear loop's encoder angle (N_av of the file)
    k_t, N, Nav, Ts = p.plant.k_t, p.plant.N, p.controller.N_av, p.controller.Ts
    th = np.concatenate([np.zeros(Nav), y[:, 0]])
    T_ref = -(P * th[Nav:] + D * (th[Nav:] - th[:-Nav]) / (Nav * Ts))
    assert _rel(s.torque_ref, T_ref) <= 1e-9
    lag = 1 + int(delay_samples)
    if tau == 0:
        expect = np.concatenate([np.zeros(lag), T_ref[:-lag]])
        assert _rel(s.torque, expect) <= 1e-9
        assert _rel(s.current, expect / (k_t * N)) <= 1e-9
    else:                                   # the lag's state: the current moves within the sample
        assert _rel(s.torque, k_t * N * s.current) <= 1e-12
    # the drive changes the response by far more than that
    if tau or delay_samples:
        free = _linear(ClosedLoop(_params(name), basis=False), P, D, A, n)
        assert _rel(free[:, 0], y[:, 0]) > 1e-3


@pytest.mark.parametrize("name", sorted(POINTS))
@pytest.mark.parametrize("limits, kind", [(Limits(friction={"m": 1e-12}), "etd"), (Limits(jitter=1e-13), "jitter")])
def test_every_plant_step_holds_the_current(name, limits, kind):
    # friction and jitter too small to matter: the ETDRK4 substeps and the jittered steps must
    # reproduce the linear loop, which they do only if the held current is the command
    p = _params(name, 0.0, 0.4)
    loop = ClosedLoop(p, basis=False)
    (P, D), A, n = POINTS[name], 0.7, 300
    s = simulate(loop, P, D, limits=limits, experiment="disturbance-step", amplitude=A,
                 duration=(n - 1) * p.controller.Ts, rtol=1e-8)
    assert s.meta["integrator"].startswith({"etd": "etdrk4", "jitter": "jitter"}[kind])
    y = _linear(loop, P, D, A, n)
    assert _rel(s.theta, y[:, 0]) <= 1e-9 and _rel(s.velocity, y[:, 1]) <= 1e-9
    assert np.array_equal(s.current[1:], s.voltage[:-1])     # the newer command holds the last piece


@pytest.mark.parametrize("name, P, D", [("qdd_leg", 300.0, 0.0), ("haptic_wall", 20.0, 0.0)])
def test_a_point_the_map_calls_unstable_grows(name, P, D):
    # spectral radii 1.0065 (QDD leg) and 1.0340 (haptic wall)
    loop = ClosedLoop(load_params(name))
    r = loop.stability(P, D, radius=True)
    assert not bool(r.stable)
    s = simulate(loop, P, D, limits=Limits(), experiment="disturbance-step", amplitude=1.0, duration=1.0)
    q = len(s.torque) // 4
    assert s.verdict in ("growing", "diverged")
    if s.verdict == "growing":
        assert np.ptp(s.torque[-q:]) > 2 * np.ptp(s.torque[q:2 * q])


def test_the_current_limit_clips_the_current_command():
    p = load_params("haptic_wall")
    loop = ClosedLoop(p)
    s = simulate(loop, 3.0, 0.0, limits=Limits(I_max=5.0), experiment="deflection", amplitude=0.2, duration=0.2)
    free = simulate(loop, 3.0, 0.0, limits=Limits(), experiment="deflection", amplitude=0.2, duration=0.2)
    # K theta / k_t = 3 x 0.2 / 0.0302 = 19.9 A asked at first: clipped to 5 A
    assert np.abs(free.voltage).max() > 19 and np.abs(s.voltage).max() == pytest.approx(5.0, abs=1e-12)
    assert s.saturated.any() and np.abs(s.current).max() <= 5.0 + 1e-12
    assert np.array_equal(s.saturated, np.abs(s.voltage) >= 5.0 - 1e-12)


def test_the_supply_bounds_the_current_by_the_back_emf():
    # a current command under a supply V_max: the current the bridge sustains at the rotor's
    # speed, (+-V_max - k_w dtheta_m) / R (docs/simulate.md); the haptic wall spun by a large
    # deflection of a soft wall, 1 V: |I| <= (1 + k_w |w|) / R
    p = load_params("haptic_wall")
    loop = ClosedLoop(p)
    V, R, k_w = 1.0, p.plant.R, p.plant.k_w
    s = simulate(loop, 3.0, 0.001, limits=Limits(V_max=V), experiment="deflection", amplitude=1.0, duration=0.3)
    assert s.saturated.any()
    # the velocity column is the rotor's (port = rotor): the command at t_k within the window
    lo, hi = (-V - k_w * s.velocity) / R, (V - k_w * s.velocity) / R
    assert np.all(s.voltage >= lo - 1e-9) and np.all(s.voltage <= hi + 1e-9)
    on = s.saturated
    assert np.allclose(np.minimum(np.abs(s.voltage[on] - lo[on]), np.abs(s.voltage[on] - hi[on])), 0, atol=1e-9)


def test_batch_runs_a_current_command():
    loop = ClosedLoop(load_params("haptic_wall"))
    b = simulate_batch(loop, [2.0, 40.0], [0.0, 0.0], limits=Limits(I_max=2.0), experiment="deflection",
                       amplitude=0.1, duration=1.0)
    assert b.status[0] == "converging" and b.status[1] in ("limit cycle", "saturating", "growing")
