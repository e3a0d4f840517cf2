"""When Levenberg-Marquardt stops (haa_sym.fit.identify._levenberg_marquardt): at a minimum where
no step lowers the cost, it stops at the first rejected step whose actual and predicted changes are
both within the tolerance (MINPACK's ftol test) instead of simulating every rung of lam up to
1e12, and it does not simulate a step it has just rejected again. Each evaluation stands for a
whole simulation of the logs (0.5 s on the stiffness ramp of docs/identify.md)."""
import numpy as np

from haa_sym.fit.identify import SAME_STEP, FitOptions, _levenberg_marquardt

A = np.array([[2.0, 0.3], [0.1, 1.5], [0.7, 0.2], [0.4, 1.1]])
B = np.array([1.0, -0.5, 0.3, 0.8])
THETA = np.linalg.lstsq(A, B, rcond=None)[0]


def _counted(jacobian_error=0.0):
    """A linear least-squares problem with a residual at its minimum, and a counter of evaluations;
    ``jacobian_error`` perturbs the Jacobian (as the friction path's variable projection does)."""
    calls = []
    E = jacobian_error * np.array([[0.3, -1.0], [0.5, 0.2], [-0.4, 0.6], [1.0, 0.1]])

    def evaluate(theta, sens=True):
        calls.append(theta.copy())
        return A @ theta - B, A + E
    return evaluate, calls


def test_at_the_minimum_it_stops_at_the_first_rejected_step():
    """Started at the minimum: the step (rounding only) changes nothing, and one evaluation of it
    decides; the ladder to lam = 1e12 took 16."""
    evaluate, calls = _counted()
    theta, it, converged = _levenberg_marquardt(evaluate, THETA.copy(), FitOptions(), ("a", "b"))
    assert converged and it == 1
    assert len(calls) == 2                                    # the start and one trial
    assert np.allclose(theta, THETA, rtol=1e-12, atol=0)


def test_an_inexact_jacobian_stops_where_no_rung_of_lam_gains_the_tolerance():
    """With a Jacobian 1 % off (as the friction path's variable projection is), the fit stalls a
    little off the least-squares minimum (no step along the inexact gradient lowers the cost): it
    stops there, converged, without simulating the rungs of lam that could not gain more than the
    tolerance (checked here on every rung from 1e-12 to 1e12)."""
    evaluate, calls = _counted(1e-2)
    opt = FitOptions()
    theta, it, converged = _levenberg_marquardt(evaluate, THETA + np.array([0.8, -0.6]), opt, ("a", "b"))
    assert converged
    r, J = evaluate(theta)
    cost = float(r @ r)
    H, g = J.T @ J, J.T @ r
    for lam in 10.0 ** np.arange(-12, 13):
        step = np.linalg.solve(H + lam * np.diag(np.diag(H)), -g)
        assert float(np.sum((A @ (theta + step) - B) ** 2)) >= cost - opt.tolerance * cost, lam
    # measured: 12 evaluations (the same theta); with every rung up to lam = 1e12, 14
    assert len(calls) - 1 <= 12


def test_a_step_equal_to_one_just_rejected_is_not_evaluated_again():
    """A cost that rejects every step: the trials' steps differ from each other by more than
    SAME_STEP (lam far below the scaled H's spectrum gives the Gauss-Newton step each time)."""
    calls = []

    def evaluate(theta, sens=True):
        calls.append(theta.copy())
        r = A @ theta - B
        return r + (0.0 if len(calls) == 1 else 10.0), A      # every trial worse than the start
    _levenberg_marquardt(evaluate, THETA + 0.5, FitOptions(), ("a", "b"))
    steps = [c - calls[0] for c in calls[1:]]
    for s0, s1 in zip(steps[:-1], steps[1:]):
        assert np.linalg.norm(s1 - s0) > SAME_STEP * np.linalg.norm(s0)
