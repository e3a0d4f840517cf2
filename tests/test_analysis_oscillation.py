"""limit_cycle on synthetic traces with known answers (haa_sym.analysis.oscillation)."""
import numpy as np
import pytest

from haa_sym.analysis.oscillation import limit_cycle
from haa_sym.errors import ParameterError

T_S = 1e-3                               # 1 kHz, the HyQ loop's rate
t = np.arange(0, 10, T_S)
rng = np.random.default_rng(19)


def test_sustained_sinusoid_with_noise():
    y = 0.3 + 2.0 * np.sin(2 * np.pi * 3.7 * t + 0.4) + rng.normal(0, 0.1, t.size)
    r = limit_cycle(t, y)
    assert r.kind == "sustained"
    assert r.frequency_hz == pytest.approx(3.7, rel=2e-3)
    assert r.fundamental == pytest.approx(2.0, rel=0.01)       # least squares over ~18 cycles
    assert r.offset == pytest.approx(0.3, abs=0.02)
    assert r.noise == pytest.approx(0.1, rel=0.15)
    # half peak-to-peak sees the noise's extremes: above the sinusoid's, within a few sigma
    assert 2.0 < r.amplitude < 2.0 + 4 * 0.1


def test_decaying_sinusoid():
    sigma = 0.15                                                 # 1/s
    y = np.exp(-sigma * t) * np.sin(2 * np.pi * 2.0 * t)
    r = limit_cycle(t, y)
    assert r.kind == "decaying"
    assert r.frequency_hz == pytest.approx(2.0, rel=1e-3)
    assert r.growth_per_cycle == pytest.approx(np.expm1(-sigma / 2.0), rel=0.02)


def test_growing_sinusoid():
    y = np.exp(0.1 * t) * np.sin(2 * np.pi * 5.0 * t)
    r = limit_cycle(t, y)
    assert r.kind == "growing"
    assert r.growth_per_cycle == pytest.approx(np.expm1(0.1 / 5.0), rel=0.02)


def test_relay_square_wave_quantised():
    # a relay oscillation: a square-ish wave (tanh-rounded edges) read through a quantiser
    f, a, q = 1.3, 0.8, 0.05
    y = q * np.round(a * np.tanh(8 * np.sin(2 * np.pi * f * t)) / q)
    r = limit_cycle(t, y, resolution=q)
    assert r.kind == "sustained"
    assert r.frequency_hz == pytest.approx(f, rel=2e-3)
    assert r.amplitude == pytest.approx(q * np.round(a * np.tanh(8) / q), abs=1e-12)
    # the square wave's fundamental is 4/pi times its height (rounded edges: a little less)
    assert 0.95 * 4 / np.pi * a < r.fundamental < 4 / np.pi * a


def test_converging_step_is_none():
    # a damped step response settling to 1, then noise and quantisation of the sensor
    y = 1 - np.exp(-3 * t) * np.cos(2 * np.pi * 1.5 * t)
    y = 0.01 * np.round((y + rng.normal(0, 0.002, t.size)) / 0.01)
    r = limit_cycle(t, y, resolution=0.01)
    assert r.kind == "none"
    assert r.offset == pytest.approx(1.0, abs=0.01)


def test_sensor_toggling_one_step_is_not_a_cycle_but_two_steps_are():
    y1 = 0.01 * (np.sin(2 * np.pi * 4 * t) > 0)                   # one quantum: below the band
    assert limit_cycle(t, y1, resolution=0.01).kind == "none"
    y2 = 0.01 * np.round(2.4 * np.sin(2 * np.pi * 4 * t))          # +-2 quanta
    r = limit_cycle(t, y2, resolution=0.01)
    assert r.kind == "sustained" and r.frequency_hz == pytest.approx(4, rel=2e-3)


@pytest.mark.parametrize("kwargs", [dict(settle=1.0), dict(min_cycles=1)])
def test_bad_arguments(kwargs):
    with pytest.raises(ParameterError):
        limit_cycle(t, np.sin(t), **kwargs)


def test_nonuniform_times_refused():
    with pytest.raises(ParameterError, match="uniformly"):
        limit_cycle(t ** 2, np.sin(t))
