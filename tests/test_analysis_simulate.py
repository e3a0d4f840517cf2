"""The simulation with every limit off is the linear closed loop (issue 19's first check), against
the independently assembled closed loop of haa_sym.check.reference and scipy's dlsim."""
import numpy as np
import pytest
import scipy.signal

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import EXPERIMENTS, simulate, simulate_batch
from haa_sym.check.reference import closed_loop_matrices
from haa_sym.errors import ParameterError
from haa_sym.loop import LoopOptions
from haa_sym.model.limits import Limits

FILTERS = {"average": {"N_av": 4}, "lowpass1": {"velocity_filter": "lowpass1", "f_c": 40.0},
           "butterworth2": {"velocity_filter": "butterworth2", "f_c": 40.0}}


def _loop(leg="extended", filt="average", delay=0, Ts=1e-3):
    p = load_params().configuration(leg).with_values(Ts=Ts, **FILTERS[filt])
    return ClosedLoop(p, LoopOptions(delay=delay), basis=False)


@pytest.mark.parametrize("Ts", [5e-5, 1e-3, 4e-3])
@pytest.mark.parametrize("delay", [0, 1])
@pytest.mark.parametrize("filt", sorted(FILTERS))
@pytest.mark.parametrize("leg", ["extended", "retracted"])
def test_limits_off_is_the_linear_closed_loop(leg, filt, delay, Ts):
    loop = _loop(leg, filt, delay, Ts)
    P, D, A = 150.0, 3.0, 0.7
    n = 400
    s = simulate(loop, P, D, limits=Limits(), experiment="disturbance-step", amplitude=A,
                 duration=(n - 1) * Ts)
    assert len(s.time) == n
    Acl, Bcl, Ccl, Dcl = closed_loop_matrices(loop, P, D)
    u = np.zeros((n, 2))
    u[:, 0] = A
    _, y, _ = scipy.signal.dlsim((Acl, Bcl, Ccl, Dcl, Ts), u)
    for name, row in (("torque", 0), ("theta", 1), ("velocity", 2)):
        ref = y[:, row]
        assert np.abs(getattr(s, name) - ref).max() <= 1e-9 * np.abs(ref).max(), name
    assert s.saturation_time == 0 and not s.saturated.any()
    assert s.meta["integrator"] == "zoh" and s.meta["limits"] == {}


def test_impedance_step_is_a_torque_step_of_P_times_A():
    # T_ref = T_ff - P (theta - theta_ref): a set point A acts as a feed-forward P A
    loop = _loop()
    # (D_gain = 0: the reference is then T_ff - P theta, read off the angle)
    a = simulate(loop, 300.0, 0.0, limits=Limits(), experiment="impedance-step", amplitude=0.05, duration=0.3)
    b = simulate(loop, 300.0, 0.0, limits=Limits(), experiment="torque-step", amplitude=15.0, duration=0.3)
    assert np.abs(a.theta - b.theta).max() <= 1e-12 * np.abs(b.theta).max()
    assert np.abs(a.torque_ref - 15.0 + 300.0 * a.theta).max() <= 1e-9 * 15.0   # Eq. (8), theta_ref = A


def test_saturation_bounds_the_voltage_and_is_timed():
    loop = _loop()
    s = simulate(loop, 300.0, 4.0, limits=Limits(V_max=6.0), experiment="impedance-step", amplitude=0.2,
                 duration=0.4)
    free = simulate(loop, 300.0, 4.0, limits=Limits(), experiment="impedance-step", amplitude=0.2, duration=0.4)
    assert np.abs(free.voltage).max() > 6.0
    assert np.abs(s.voltage).max() <= 6.0
    assert s.saturated.sum() > 0
    assert s.saturation_time == pytest.approx(s.saturated.sum() * 1e-3)
    assert np.all(np.abs(s.voltage[s.saturated]) == 6.0)


def test_quantisation_puts_the_signals_on_their_grids():
    loop = _loop()
    lim = Limits(encoder_counts=2048, torque_resolution=0.05)
    s = simulate(loop, 300.0, 4.0, limits=lim, experiment="disturbance-step", amplitude=2.0, duration=0.3)
    q = 2 * np.pi / 2048
    assert np.abs(s.theta / q - np.round(s.theta / q)).max() < 1e-6
    assert np.abs(s.torque / 0.05 - np.round(s.torque / 0.05)).max() < 1e-6
    assert len(np.unique(np.round(s.theta / q))) > 3


def test_deflection_starts_at_the_amplitude_and_noise_is_seeded():
    loop = _loop()
    lim = Limits(torque_noise=0.01)
    a = simulate(loop, 300.0, 4.0, limits=lim, experiment="deflection", amplitude=0.05, duration=0.1, seed=3)
    b = simulate(loop, 300.0, 4.0, limits=lim, experiment="deflection", amplitude=0.05, duration=0.1, seed=3)
    c = simulate(loop, 300.0, 4.0, limits=lim, experiment="deflection", amplitude=0.05, duration=0.1, seed=4)
    assert np.array_equal(a.torque, b.torque) and not np.array_equal(a.torque, c.torque)
    assert a.meta["seed"] == 3


def test_batch_summarises_each_point_like_single_runs():
    loop = _loop()
    lim = Limits(V_max=24.0)
    b = simulate_batch(loop, [200.0, 400.0], 5.0, limits=lim, experiment="disturbance-step", duration=0.2)
    for i, P in enumerate((200.0, 400.0)):
        s = simulate(loop, P, 5.0, limits=lim, experiment="disturbance-step", duration=0.2)
        assert b.saturation_time[i] == s.saturation_time
        assert b.final_theta[i] == pytest.approx(s.theta[-20:].mean(), rel=1e-12)
        assert b.status[i] == s.verdict
    # basis=False: the linear decision is unknown, and a 24 V supply that never acts cannot tell
    assert list(b.status) == ["undecided", "undecided"]
    known = simulate_batch(ClosedLoop(load_params()), [200.0, 400.0], 5.0, limits=lim, duration=0.2)
    assert list(known.status) == ["converging", "converging"]


def test_batch_tells_growth_from_a_limit_cycle():
    # beta = 3, P_gain = 20000, D_gain = 10 is linearly unstable (spectral radius 1.013 per
    # sample): without limits the swing grows by 1.013^150 per quarter of 0.6 s; a 24 V supply
    # bounds it to a limit cycle
    loop = ClosedLoop(load_params().with_values(beta=3.0), basis=False)
    free = simulate_batch(loop, 20000.0, 10.0, limits=Limits(), duration=0.6)
    sat = simulate_batch(loop, 20000.0, 10.0, limits=Limits(V_max=24.0), duration=1.5)
    assert free.growth[0] == pytest.approx(1.01258529 ** 150, rel=0.1)
    assert list(sat.status) == ["limit cycle"] and sat.growth[0] == pytest.approx(1.0, abs=0.05)


@pytest.mark.parametrize("kw, field", [
    ({"experiment": "ramp"}, "experiment"), ({"duration": 0.0}, "duration"),
    ({"duration": float("nan")}, "duration"), ({"amplitude": float("inf")}, "amplitude"),
    ({"seed": -1}, "seed"), ({"rtol": 0.0}, "rtol")])
def test_bad_arguments_are_one_line_parameter_errors(kw, field):
    args = {"experiment": "disturbance-step", "duration": 0.1, **kw}
    with pytest.raises(ParameterError) as e:
        simulate(_loop(), 100.0, 1.0, **args)
    assert str(e.value).startswith(field) and "\n" not in str(e.value)
    assert set(EXPERIMENTS) >= {"disturbance-step", "torque-step", "impedance-step", "deflection", "chirp"}


def test_friction_with_jitter_is_refused():
    with pytest.raises(ParameterError, match="jitter"):
        simulate(_loop(), 100.0, 1.0, limits=Limits(friction={"m": 0.01}, jitter=1e-6), duration=0.01)


@pytest.mark.parametrize("lim", [Limits(V_max=6.0, encoder_counts=4096), Limits(friction={"L2": 0.5}),
                                 Limits(jitter=2e-6)])
def test_casadi_vm_runs_the_same_loop(lim):
    # without a C compiler the serialised functions run in CasADi's VM, the drivers' loops in Python
    p = load_params()
    a = simulate(ClosedLoop(p, basis=False, backend="vm"), 300.0, 4.0, limits=lim, experiment="torque-step",
                 amplitude=20.0, duration=0.02)
    b = simulate(ClosedLoop(p, basis=False), 300.0, 4.0, limits=lim, experiment="torque-step",
                 amplitude=20.0, duration=0.02)
    assert a.meta["backend"] == "vm" and b.meta["backend"] == "compiled"
    for name in ("theta", "torque", "voltage", "current"):
        ref = getattr(b, name)
        assert np.abs(getattr(a, name) - ref).max() <= 1e-12 * np.abs(ref).max(), name


@pytest.mark.parametrize("name", ["sea", "harmonic_drive", "qdd_leg"])
def test_limits_off_is_the_linear_closed_loop_for_every_bundled_actuator(name):
    # other chains, a current-based torque estimate (qdd_leg) and a motor-side encoder
    p = load_params(name)
    # the QDD leg's own structure commands the current (no simulation): the paper's reads the estimate
    loop = ClosedLoop(p if p.controller.structure == "paper" else p.with_values(structure="paper"), basis=False)
    n, Ts = 300, loop.params.controller.Ts
    s = simulate(loop, 20.0, 0.5, limits=Limits(), experiment="disturbance-step", amplitude=0.3,
                 duration=(n - 1) * Ts)
    _, y, _ = scipy.signal.dlsim((*closed_loop_matrices(loop, 20.0, 0.5), Ts), np.c_[np.full(n, 0.3), np.zeros(n)])
    for name_, row in (("torque", 0), ("theta", 1), ("velocity", 2)):
        assert np.abs(getattr(s, name_) - y[:, row]).max() <= 1e-9 * np.abs(y[:, row]).max(), name_
