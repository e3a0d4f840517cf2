"""haa_sym.fit.model.simulate_stamps on a model with an integrator (issue 23): the bundled harmonic
drive with its link free (K_link = 0, the file's own remark: "a marginal position mode"), voltage-
and current-driven, on jittered stamps with a gap and a fractional delay of the command, against an
independent simulation (one scipy matrix exponential per sub-interval, tests/stamps_reference.py)
and its derivatives against central differences. Until the sensitivities were taken in A's
eigenbasis such a model was refused (X = [[A, B], [0, 0]] is defective when A has a zero mode)."""
import mpmath
import numpy as np
import pytest

from haa_sym.fit.model import _divided2, modal_check, open_loop_model, sample, simulate, simulate_stamps, with_drive_lag
from haa_sym.model.params import load_params
from stamps_reference import jittered_log, reference_stamps

PLANT_KEYS = ("J_link", "B_link", "K_hd", "D_hd")
KEYS = PLANT_KEYS + ("delay_drive",)
TRUTH = np.array([0.3497, 2.1, 3.1e4, 63.6, 0.0047])       # the delay 1.5-9 intervals: switches inside them
TAU = 0.004                                                 # the current loop's lag, s (current-driven only)
HD = load_params("harmonic_drive").with_values(K_link=0.0)


def _model(inp, th):
    m = open_loop_model(HD.with_values(**dict(zip(PLANT_KEYS, th[:4]))).plant, KEYS, (inp,), ("torque", "theta"))
    return with_drive_lag(m, TAU) if inp == "current" else m


def _reference(inp, th, t, u, starts, x0s):
    return reference_stamps(_model(inp, th), th[4], t, u, starts, x0s)


@pytest.fixture(scope="module")
def log():
    return jittered_log(3)


@pytest.mark.parametrize("inp", ["voltage", "current"])
def test_the_free_link_has_a_zero_mode_and_is_accepted(inp):
    A = _model(inp, TRUTH).A
    lam = np.abs(np.linalg.eigvals(A))
    assert lam.min() < 1e-9 * lam.max()                     # the integrator, whichever the input
    modal_check(A)                                          # no refusal


@pytest.mark.parametrize("inp", ["voltage", "current"])
def test_exact_against_an_independent_simulation(inp, log):
    t, u = log
    y, _, _ = simulate_stamps(_model(inp, TRUTH), t, u, delay=TRUTH[4], starts=(0, 150), estimate=(False, False),
                              sensitivities=False)
    n = _model(inp, TRUTH).A.shape[0]
    ref = _reference(inp, TRUTH, t, u, (0, 150), (np.zeros(n), np.zeros(n)))
    for o in range(2):                                      # torque and the drifting angle, each to 1e-10
        assert np.max(np.abs(y[:, o] - ref[:, o])) <= 1e-10 * np.max(np.abs(ref[:, o]))


@pytest.mark.parametrize("inp", ["voltage", "current"])
def test_sensitivities_against_central_differences(inp, log):
    t, u = log
    _, dy, _ = simulate_stamps(_model(inp, TRUTH), t, u, delay=TRUTH[4], delay_key=4, starts=(0, 150),
                               estimate=(False, False))
    for j, key in enumerate(KEYS):
        h = 1e-5 * TRUTH[j]                                 # 1e-6: rounding reaches 1e-6 of the slope
        side = []
        for sgn in (1, -1):
            th = TRUTH.copy()
            th[j] += sgn * h
            side.append(simulate_stamps(_model(inp, th), t, u, delay=th[4], starts=(0, 150),
                                        estimate=(False, False), sensitivities=False)[0])
        fd = (side[0] - side[1]) / (2 * h)
        for o in range(2):
            assert np.max(np.abs(dy[j][:, o] - fd[:, o])) <= 1e-6 * np.max(np.abs(fd[:, o])), (key, o)


@pytest.mark.parametrize("inp", ["voltage", "current"])
def test_sensitivities_agree_with_van_loans_on_uniform_stamps(inp):
    """On uniform stamps from rest the per-interval route and the uniform one (Van Loan's block
    exponential per key, a Schur-basis recursion) are two independent exact computations."""
    rng = np.random.default_rng(5)
    t, u = np.arange(400) * 1e-3, rng.standard_normal((400, 1))
    m = _model(inp, TRUTH)
    y, dy, _ = simulate_stamps(m, t, u)
    y_vl, dy_vl = simulate(sample(m, 1e-3), u)
    # d y / d log p, the fit's Jacobian: each key's error against the output's largest column
    # (theta hardly depends on K_hd, 1e-5 of the other keys: its own scale would ask for 1e-21)
    dy, dy_vl = dy[:4] * TRUTH[:4, None, None], dy_vl[:4] * TRUTH[:4, None, None]
    for o in range(2):
        assert np.max(np.abs(y[:, o] - y_vl[:, o])) <= 1e-10 * np.max(np.abs(y_vl[:, o]))
        scale = np.max(np.abs(dy_vl[:, :, o]))
        for j in range(4):
            assert np.max(np.abs(dy[j][:, o] - dy_vl[j][:, o])) <= 1e-10 * scale, (j, o)


@pytest.mark.parametrize("inp", ["voltage", "current"])
def test_a_segment_after_a_gap_restarts_from_its_estimated_state_with_an_angle_offset(inp, log):
    t, u = log
    n = _model(inp, TRUTH).A.shape[0]
    rng = np.random.default_rng(1)
    x0 = 1e-3 * rng.standard_normal(n)
    x0[3 if inp == "voltage" else 2] = 0.3                  # theta_link 0.3 rad off (current: I_m is not a state)
    ref = _reference(inp, TRUTH, t, u, (0, 150), (np.zeros(n), x0))
    y, _, _ = simulate_stamps(_model(inp, TRUTH), t, u, delay=TRUTH[4], starts=(0, 150), estimate=(False, True),
                              y=ref, sensitivities=False)
    for o in range(2):
        assert np.max(np.abs(y[150:, o] - ref[150:, o])) <= 1e-8 * np.max(np.abs(ref[150:, o]))


def test_second_divided_difference_against_mpmath():
    """e_h[a, b, 0] (the sensitivity's new coefficient) against 50-digit mpmath: Opitz's formula,
    the (0, 2) entry of expm(h [[a, 1, 0], [0, b, 1], [0, 0, 0]]), which holds for any
    confluence; nodes from 1e-6 to 300 in |lam h|, equal, conjugate, 1e-9 apart, at 0."""
    mpmath.mp.dps = 50
    rng = np.random.default_rng(0)
    h, worst = 1e-3, 0.0
    for s in (1e-6, 1e-3, 0.1, 0.4, 0.6, 1.0, 3.0, 30.0, 300.0):
        for _ in range(2):
            a, b = (complex(*rng.standard_normal(2)) * s for _ in range(2))
            for x, y in ((a, b), (a, a), (a, 0), (0, a), (a, 1e-15), (a, a + 1e-9 * s), (a, a.conjugate()), (0, 0)):
                ref = complex(mpmath.expm(mpmath.matrix([[x, h, 0], [0, y, h], [0, 0, 0]]))[0, 2])
                got = complex(_divided2(np.array(x / h), np.array(y / h), np.array(h)))
                err = abs(got - ref) / abs(ref)
                assert np.isfinite(err), (x, y)
                worst = max(worst, err)
    assert worst <= 1e-12, worst
