"""The drive's lag and dead time in the nonlinear simulation (issue 23; docs/simulate.md, "The
drive"): with every limit off the simulation is the explicit closed loop of ClosedLoop, whose
sampled plant carries the drive (the lag as a state, the fractional delay by the modified
z-transform's augmentation), for two actuators and whole and fractional delays; through each
plant step (exact ZOH, jitter, ETDRK4) the command switches at t_k + f. The independent check with
friction, the supply and jitter is in tests/test_analysis_simulate_reference.py."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate
from haa_sym.loop.statespace import closed_loop_batch
from haa_sym.model.limits import Limits

ACTUATORS = {"hyq": None, "harmonic_drive": "harmonic_drive"}


def _params(actuator, tau, delay_samples):
    p = load_params(ACTUATORS[actuator]) if ACTUATORS[actuator] else load_params()
    return p.with_values(tau_drive=tau, delay_drive=delay_samples * p.controller.Ts)


def _linear(loop, P, D, A, n):
    """T_meas, theta_encoder, port_velocity of the explicit closed loop under a constant T_dist A."""
    Acl, Bcl, Ccl, Dcl = (m[0] for m in closed_loop_batch(loop, P, D))
    x, u, y = np.zeros(Acl.shape[0]), np.array([A, 0.0]), np.empty((n, 3))
    for k in range(n):
        y[k] = (Ccl @ x + Dcl @ u)[:3]
        x = Acl @ x + Bcl @ u
    return y


def _assert_linear(s, y, rtol):
    for name, row in (("torque", 0), ("theta", 1), ("velocity", 2)):
        ref = y[:, row]
        err = np.abs(getattr(s, name) - ref).max() / np.abs(ref).max()
        assert err <= rtol, (name, err)


# gain points near the edge (spectral radii 0.997-1.0001: HyQ with 2 ms and 2.37 samples just unstable)
POINTS = {"hyq": (150.0, 3.0), "harmonic_drive": (40.0, 3.0)}


@pytest.mark.parametrize("tau, delay_samples", [(0.002, 0.0), (0.0, 2.0), (0.0, 0.4), (0.002, 0.4),
                                                (0.002, 2.37)])
@pytest.mark.parametrize("actuator", sorted(ACTUATORS))
def test_limits_off_with_a_drive_is_the_linear_closed_loop(actuator, tau, delay_samples):
    loop = ClosedLoop(_params(actuator, tau, delay_samples), basis=False)
    (P, D), A, n = POINTS[actuator], 0.7, 500
    s = simulate(loop, P, D, limits=Limits(), experiment="disturbance-step", amplitude=A,
                 duration=(n - 1) * loop.params.controller.Ts)
    y = _linear(loop, P, D, A, n)
    _assert_linear(s, y, 1e-9)
    # the drive changes the response by far more than that
    free = _linear(ClosedLoop(_params(actuator, 0.0, 0.0), basis=False), P, D, A, n)
    assert np.abs(free[:, 0] - y[:, 0]).max() > 1e-3 * np.abs(y[:, 0]).max()
    assert s.meta["drive"]["delay_whole_samples"] == int(delay_samples)


@pytest.mark.parametrize("limits, kind", [(Limits(friction={"m": 1e-12}), "etd"),
                                          (Limits(jitter=1e-13), "jitter")])
def test_every_plant_step_switches_the_command_at_the_fraction(limits, kind):
    # friction and jitter too small to matter: the ETDRK4 substeps and the jitter's pieces must
    # reproduce the linear loop with the drive, which they do only if each switches the held
    # command at t_k + f
    loop = ClosedLoop(_params("hyq", 0.002, 2.37), basis=False)
    (P, D), A, n = POINTS["hyq"], 0.7, 300
    s = simulate(loop, P, D, limits=limits, experiment="disturbance-step", amplitude=A,
                 duration=(n - 1) * loop.params.controller.Ts, rtol=1e-8)
    assert s.meta["integrator"].startswith({"etd": "etdrk4", "jitter": "jitter"}[kind])
    _assert_linear(s, _linear(loop, P, D, A, n), 1e-9)


@pytest.mark.parametrize("actuator, P, D", [("hyq", 5000.0, 6.95), ("harmonic_drive", 1615.0, 50.0)])
def test_a_point_unstable_because_of_the_drive_grows(actuator, P, D):
    # stable without the drive (spectral radius 0.9991 / 0.9981), unstable with a 4 ms lag and
    # 2.37 samples of dead time (1.0061 / 1.0045): the simulated torque swing grows
    swings = {}
    for tau, delay in ((0.0, 0.0), (0.004, 2.37)):
        loop = ClosedLoop(_params(actuator, tau, delay))
        assert bool(loop.stability(P, D).stable) == (tau == 0)
        s = simulate(loop, P, D, limits=Limits(), experiment="disturbance-step", amplitude=1.0, duration=1.0)
        q = len(s.torque) // 4             # the swing of the last quarter over the second's
        swings[tau] = np.ptp(s.torque[-q:]) / np.ptp(s.torque[q:2 * q])
        assert s.verdict == ("converging" if tau == 0 else "growing")
    assert swings[0.0] < 1.0 and swings[0.004] > 2.0, swings


@pytest.mark.parametrize("limits", [Limits(V_max=2.0), Limits(friction={"m": 0.02}, friction_velocity=0.05)])
def test_casadi_vm_runs_the_same_delay_line(limits):
    # the VM's loop in Python (no C compiler) is driver.c's: the same ring of commands and pieces
    p = _params("hyq", 0.002, 2.37)
    runs = [simulate(ClosedLoop(p, basis=False, backend=b), 300.0, 4.0, limits=limits, experiment="torque-step",
                     amplitude=3.0, duration=0.04) for b in ("vm", "compiled")]
    assert runs[0].meta["backend"] == "vm" and runs[1].meta["backend"] == "compiled"
    for name in ("theta", "torque", "voltage", "current"):
        a, b = getattr(runs[0], name), getattr(runs[1], name)
        assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max(), name
