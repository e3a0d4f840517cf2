"""haa_sym.fit.model.simulate_stamps (issue 23, logs as measured): the exact per-interval ZOH
with the drive's lag and a fractional delay switching inside the intervals, a gap restarting the
recursion, and estimated initial states, against an independent simulation (one matrix
exponential per sub-interval, tests/stamps_reference.py) and its derivatives against central
differences."""
import numpy as np
import pytest

from haa_sym.errors import ParameterError
from haa_sym.fit.model import PlantModel, modal_check, simulate_stamps, with_drive_lag
from stamps_reference import jittered_log, reference_stamps

KEYS = ("k", "c", "tau_drive", "delay_drive")


def _model(th):
    """A mass on a spring-damper behind a lag; outputs the spring-damper torque and the angle."""
    k, c, tau = th[:3]
    A = np.array([[0.0, 1.0], [-k, -c]])
    dA = np.zeros((4, 2, 2))
    dA[0, 1, 0], dA[1, 1, 1] = -1.0, -1.0
    dC = np.zeros((4, 2, 2))
    dC[0, 0, 0], dC[1, 0, 1] = 1.0, 1.0
    m = PlantModel(A, np.array([[0.0], [1.0]]), np.array([[k, c], [1.0, 0.0]]), np.zeros((2, 1)), dA,
                   np.zeros((4, 2, 1)), dC, np.zeros((4, 2, 1)))
    return with_drive_lag(m, tau, 2)


def _reference(th, t, u, starts, x0s):
    return reference_stamps(_model(th), th[3], t, u, starts, x0s)


@pytest.fixture(scope="module")
def log():
    return jittered_log(0)


def test_exact_against_an_independent_simulation_with_lag_delay_and_gap(log):
    t, u = log
    th = np.array([400.0, 3.0, 0.02, 0.0047])         # the delay 1-9 intervals: switches inside them
    y, _, _ = simulate_stamps(_model(th), t, u, delay=th[3], starts=(0, 150), estimate=(False, False),
                              sensitivities=False)
    ref = _reference(th, t, u, (0, 150), (np.zeros(3), np.zeros(3)))
    assert np.max(np.abs(y - ref)) <= 1e-12 * np.max(np.abs(ref))


def test_sensitivities_against_central_differences(log):
    t, u = log
    th = np.array([400.0, 3.0, 0.02, 0.0047])
    _, dy, _ = simulate_stamps(_model(th), t, u, delay=th[3], delay_key=3, starts=(0, 150), estimate=(False, False))
    for j, key in enumerate(KEYS):
        h = 1e-6 * th[j]
        side = []
        for sgn in (1, -1):
            tj = th.copy()
            tj[j] += sgn * h
            side.append(simulate_stamps(_model(tj), t, u, delay=tj[3], starts=(0, 150), estimate=(False, False),
                                        sensitivities=False)[0])
        fd = (side[0] - side[1]) / (2 * h)
        assert np.max(np.abs(dy[j] - fd)) <= 1e-6 * np.max(np.abs(fd)), key


def test_a_segment_after_a_gap_restarts_from_its_estimated_state(log):
    t, u = log
    th = np.array([400.0, 3.0, 0.02, 0.0047])
    x0 = np.array([0.01, -0.2, 0.3])
    ref = _reference(th, t, u, (0, 150), (np.zeros(3), x0))
    y, _, rank = simulate_stamps(_model(th), t, u, delay=th[3], starts=(0, 150), estimate=(False, True), y=ref,
                                 sensitivities=False)
    assert rank == 3
    assert np.max(np.abs(y - ref)) <= 1e-9 * np.max(np.abs(ref))
    # from rest instead, the second segment misses its initial motion
    y0, _, _ = simulate_stamps(_model(th), t, u, delay=th[3], starts=(0, 150), estimate=(False, False),
                               sensitivities=False)
    assert np.max(np.abs(y0[150:] - ref[150:])) > 1e-2 * np.max(np.abs(ref))


def test_a_nearly_defective_model_is_refused_in_one_line_an_integrator_is_not():
    modal_check(np.array([[0.0, 1.0], [0.0, -1.0]]), "--log 'x.csv'")       # a free rotor: exact now
    with pytest.raises(ParameterError, match=r"coinciding modes .*condition number .* > 1e\+08"):
        modal_check(np.array([[-1.0, 1.0], [0.0, -1.0]]), "--log 'x.csv'")  # a Jordan block
