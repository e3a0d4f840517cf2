"""haa_sym.analysis.passivity: Table 2's wording, the passivity of Z(z) against the phase of Z from
the independent closed loop (haa_sym.check.reference), shapes, and the bands beyond 90 deg."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, LoopOptions, ParameterError
from haa_sym.analysis.passivity import bands_beyond, corrected_phase, passivity, status
from haa_sym.analysis.sweep import colgate_factor
from haa_sym.check import reference as ref


@pytest.fixture(scope="module")
def loop(params):
    return ClosedLoop(params)


def _reference_excess(loop, P, D):
    """Worst corrected phase of Z beyond +-90 deg on the options' grid, from the reference."""
    Ts = loop.params.controller.Ts
    w = loop.options.omega(Ts)
    Z = ref.frequency_response(loop, w, P, D, which=("Z",))["Z"]
    return float(np.abs(np.degrees(np.angle(Z * colgate_factor(w, Ts, "subtract")))).max() - 90)


def test_status_wording():
    assert status([False, True, True], [False, True, False]).tolist() == ["Unstable", "Yes", "No"]
    assert status(True, [True, False]).tolist() == ["Yes", "No"]                # broadcast


def test_the_torque_loop_alone_is_not_passive_the_impedance_loop_is(loop):
    """Sec. 5 / Table 2: (0, 0) is stable and not passive, (200, 10) passive (the module's example)."""
    r = passivity(loop, [0, 200], [0, 10])
    assert r.status.tolist() == ["No", "Yes"]
    assert r.phase_excess_deg[0] > LoopOptions().passivity_tol_deg >= r.phase_excess_deg[1]
    assert 0 < r.omega_worst[0] < np.pi / loop.params.controller.Ts


def test_excess_equals_the_reference_closed_loop(loop):
    P, D = np.array([0.0, 200.0, 1000.0, 5000.0, 20000.0]), np.array([0.0, 10.0, 9.0, 2.0, 50.0])
    r = passivity(loop, P, D)
    assert r.stable.any() and (~r.stable).any()          # both branches: NaN where unstable
    for i in range(P.size):
        if not r.stable[i]:
            assert np.isnan(r.phase_excess_deg[i]) and np.isnan(r.omega_worst[i]) and not r.passive[i]
            assert ref.spectral_radius(loop, P[i], D[i]) > 1
            continue
        assert r.phase_excess_deg[i] == pytest.approx(_reference_excess(loop, P[i], D[i]), abs=1e-6)
        assert r.passive[i] == (r.phase_excess_deg[i] <= loop.options.passivity_tol_deg)


def test_excess_is_the_worst_corrected_phase(loop):
    P, D = np.array([0.0, 300.0]), np.array([0.0, 12.0])
    w, ph = corrected_phase(loop, P, D)
    assert ph.shape == (2, w.size) and w.size == loop.options.n_omega
    r = passivity(loop, P, D)
    np.testing.assert_allclose(r.phase_excess_deg, np.abs(ph).max(axis=1) - 90, atol=1e-9)
    np.testing.assert_allclose(r.omega_worst, w[np.abs(ph).argmax(axis=1)], rtol=1e-12)


def test_shapes_broadcast(loop):
    r = passivity(loop, np.array([[10.0], [200.0]]), np.array([1.0, 5.0, 10.0]))
    assert r.stable.shape == r.passive.shape == r.phase_excess_deg.shape == r.omega_worst.shape == (2, 3)
    w, ph = corrected_phase(loop, [[0.0, 200.0]], [[0.0, 10.0]], omega=np.array([1.0, 10.0, 100.0]))
    assert ph.shape == (1, 2, 3) and w.tolist() == [1.0, 10.0, 100.0]


def test_the_loop_comes_first(params):
    with pytest.raises(ParameterError, match=r"passivity: the first argument is a Params; allowed: a haa_sym.ClosedLoop"):
        passivity(params, 0.0, 0.0)
    with pytest.raises(ParameterError, match=r"corrected_phase: the first argument is a Params"):
        corrected_phase(params)


def test_bands_beyond():
    w = np.array([1.0, 2.0, 4.0, 8.0, 16.0])
    assert bands_beyond(w, [80.0, 80, 80, 80, 80]) == []
    assert bands_beyond(w, [100.0, 100, 80, 80, 80])[0][0] == 1.0                 # open at the start
    assert bands_beyond(w, [80.0, 80, 80, 100, 100])[-1][1] == 16.0               # open at the end
    (lo, hi), = bands_beyond(w, [-80.0, -100, -100, -80, -80])                    # |phase|: both signs
    assert lo == pytest.approx(np.sqrt(2.0)) and hi == pytest.approx(np.sqrt(32.0))
    assert len(bands_beyond(w, [100.0, 80, 100, 80, 100])) == 3
    assert bands_beyond(w, [95.0, 95, 95, 95, 95], limit=100.0) == []
