"""Describing functions of a current-commanded structure (impedance_current; docs/describing.md):
the current command's saturation I_max, whose linear part is the impedance loop opened at the
torque reference (T_ref / (k_t N) is the command), friction through the current-commanded
plant, the limits without a describing function refused in one line, and the confirming
simulation of the current command."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.describing import confirm_cycles, limit_cycles, limit_nonlinearities, linear_part
from haa_sym.errors import ParameterError
from haa_sym.model.limits import Limits


@pytest.mark.parametrize("name, P, D", [("qdd_leg", 300.0, 0.0), ("haptic_wall", 20.0, 0.001)])
def test_the_current_saturations_linear_part_is_the_impedance_loop(name, P, D):
    loop = ClosedLoop(load_params(name))
    w = np.geomspace(1.0, np.pi / loop.params.controller.Ts * 0.999, 200)
    G = linear_part(loop, P, D, "I_max", w)
    L = loop.frequency_response(w, P, D).L_imp
    assert np.abs(G - L).max() <= 1e-9 * np.abs(L).max()


def test_qdd_leg_current_limit_cycle_is_predicted_and_confirmed():
    loop = ClosedLoop(load_params("qdd_leg"))           # linearly unstable: spectral radius 1.0065
    r = limit_cycles(loop, 300.0, 0.0, nonlinearity={"I_max": 5.0})
    (k,) = np.flatnonzero(r.stable)
    assert r.unit == "A" and 7.0 < r.frequency_hz[k] < 7.7
    (c,) = [c for c in confirm_cycles(loop, 300.0, 0.0, r) if c is not None]
    # the held current command's fundamental against N(A) A, and the frequency
    assert c["verdict"] == "limit cycle" and c["agrees"], c
    assert c["amplitude_error"] < 0.02 and c["frequency_error"] < c["tolerance"]


@pytest.mark.parametrize("key, match", [("V_max", "the supply of a current command"),
                                        ("T_res", "reads no torque")])
def test_limits_without_a_describing_function_are_refused(key, match):
    loop = ClosedLoop(load_params("haptic_wall"))
    with pytest.raises(ParameterError, match=f"{key}: structure = 'impedance_current' commands a current.*{match}"):
        limit_cycles(loop, 2.0, 0.0, nonlinearity={key: 1.0})
    with pytest.raises(ParameterError, match="I_max: structure = 'paper' commands a voltage"):
        limit_cycles(ClosedLoop(load_params()), 2.0, 0.0, nonlinearity={"I_max": 1.0})


def test_the_files_limits_a_current_command_predicts():
    lim = Limits(V_max=24.0, I_max=3.0, torque_resolution=0.01, friction={"m": 0.1})
    assert limit_nonlinearities(lim, "current") == [{"I_max": 3.0}, {"Fc_m": 0.1}]
    assert limit_nonlinearities(lim) == [{"V_max": 24.0}, {"T_res": 0.01}, {"Fc_m": 0.1}]


def test_friction_linear_part_uses_the_current_commanded_plant():
    # at omega -> 0 the loop holds the rotor by the wall's stiffness: velocity per torque -> j w / K_eff,
    # and with the voltage-driven plant the same gains give another response (the check fails if
    # the friction's plant were the voltage-driven one: it has a state the loop's plant lacks)
    loop = ClosedLoop(load_params("haptic_wall"))
    G = linear_part(loop, 3.0, 0.0, "Fc_m", np.array([0.01]))
    assert abs(G[0] - 1j * 0.01 / 3.0) <= 1e-3 * abs(G[0])
