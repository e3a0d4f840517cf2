"""The torque loop's figures as an engineer reads them (issue 26, item 7): a gain crossover
below the analysed band is found (not "no crossover"), the tracking bandwidth |1 - H_T| = -3 dB
and the load mode of the bundled SEA by an independent frequency response, and step figures
that an initial spike cannot fake."""
import numpy as np
import pytest
import scipy.optimize

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.torque import (StepResponse, load_mode, step_figures, torque_bandwidth,
                                     torque_loop_margins)
from haa_sym.check.reference_margins import reference_crossovers
from haa_sym.errors import ParameterError


def test_a_crossover_below_the_analysed_band_is_found_and_equals_the_reference():
    """HyQ with the PI `tune --pm 179` used to write (PM "n/a"): the torque loop crosses
    |L_t| = 1 at 0.0999 rad/s, below omega_min = 0.1 rad/s; the margins find it, equal to the
    independent reference searched from 1e-3 rad/s."""
    params = load_params().with_values(P_t0=0.123732, I_t0=0.0123732)
    for p in [params] + [params.configuration(c) for c in params.configurations]:
        m = torque_loop_margins(ClosedLoop(p))
        (ref,) = reference_crossovers(ClosedLoop(p, basis=False), 0.0, 0.0, cut="PI", omega_min=1e-3)
        assert ref.omega_c.size >= 1 and ref.omega_c.min() < 0.1
        assert np.isfinite(m.distance_deg)
        assert m.gain_crossovers == pytest.approx(ref.omega_c, rel=1e-9)
        assert m.distance_deg == pytest.approx(ref.distance_deg, abs=1e-6)


def test_a_crossover_below_the_extension_is_refused_in_one_line():
    params = load_params().with_values(P_t0=0.0, I_t0=1e-12)
    with pytest.raises(ParameterError, match="still rising below it"):
        torque_loop_margins(ClosedLoop(params))


def _sea():
    p = load_params("sea")
    loop = ClosedLoop(p)
    sys = loop.to_statespace(0.0, 0.0, cut="T_ref")
    H = sys[sys.output_labels.index("T_meas"), sys.input_labels.index("r")]
    return loop, H


def test_tracking_bandwidth_and_load_mode_of_the_sea_by_python_control():
    """SEA (bundled, nominal): |1 - H_T| reaches 1/sqrt 2 at the tracking bandwidth (brentq on
    python-control's response of the explicit closed loop), below the +5.5 dB peak of |H_T| at
    1.07 rad/s, which is reported as the load mode; the paper's magnitude definition lands above
    that peak (1.78 rad/s), the number the issue found misleading."""
    loop, H = _sea()

    def resp(w):
        return complex(np.squeeze(H(np.exp(1j * w * H.dt))))
    w = np.geomspace(0.1, 20.0, 4000)
    Hw = np.squeeze(H(np.exp(1j * w * H.dt)))
    e = np.abs(1 - Hw)
    k = int(np.flatnonzero(e >= 2 ** -0.5)[0])
    ref_bw = scipy.optimize.brentq(lambda x: abs(1 - resp(x)) - 2 ** -0.5, w[k - 1], w[k], xtol=1e-12)
    bw = torque_bandwidth(loop, definition="tracking")
    assert bw == pytest.approx(ref_bw, rel=2e-3)
    mag = np.abs(Hw) / abs(Hw[0])
    i = int(np.argmax(mag[w < 3]))
    mode = load_mode(loop, bw)
    assert mode is not None and mode.kind == "peak"
    assert mode.omega == pytest.approx(w[i], rel=0.02)
    assert mode.depth_db == pytest.approx(20 * np.log10(mag[i]), abs=0.05) and mode.depth_db > 3
    assert bw < mode.omega < torque_bandwidth(loop, definition="magnitude")
    # a loop without such a feature near its bandwidth reports none: the harmonic drive (its
    # gearbox notch lies at 284 rad/s, 20 times its tracking bandwidth)
    hd = ClosedLoop(load_params("harmonic_drive"))
    assert load_mode(hd, torque_bandwidth(hd, definition="tracking")) is None


def test_step_figures_are_not_faked_by_a_spike():
    """A spike to 0.95 at 0.013 s, then a rise ringing +-15 % that decays: t90 is where the
    response stays above 90 %, rise time ends there, settling is the last exit from +-5 %."""
    t = np.arange(0, 10, 0.001)
    y = 1 - np.exp(-t / 0.3) + 0.3 * np.sin(2 * np.pi * t) * np.exp(-t / 2.5) * (t > 1)
    y[13] = 0.95                                          # the spike
    f = step_figures(StepResponse(t, y, 1.0))
    last_below = t[np.flatnonzero(y < 0.9)[-1]]
    last_out = t[np.flatnonzero(np.abs(y - 1) >= 0.05)[-1]]
    assert f["t90_s"] == pytest.approx(last_below + 0.001) and f["t90_s"] > 1
    assert f["settling_time_s"] == pytest.approx(last_out + 0.001) and f["settling_time_s"] > 4
    assert f["rise_time_s"] == pytest.approx(f["t90_s"] - t[np.flatnonzero(y[:int(f["t90_s"] / 0.001)] < 0.1)[-1]])
    # a response still ringing outside the band at the window's end has no t90 / settling time
    g = step_figures(StepResponse(t[:2751], y[:2751], 1.0))
    assert abs(y[2750] - 1) > 0.05 and np.isnan(g["settling_time_s"])
