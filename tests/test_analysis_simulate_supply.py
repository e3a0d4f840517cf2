"""The supply bounds the held voltage whatever the current window does (review of issue 19).

The current limit is a voltage window around the back-EMF e, [e - R I_max, e + R I_max]; the
supply clips to +-V_max. Merged into one clip, a window entirely below -V_max (a fast rotor
driven backwards) gave V = e + R I_max < -V_max: -36 V from a 2 V supply on HyQ, and the runs
of +A and -A were not mirror images. With neither quantiser nor noise the loop is odd, so the
run of -A must be exactly the negated run of +A."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate
from haa_sym.model.limits import Limits


@pytest.mark.parametrize("name", ["hyq_haa", "harmonic_drive"])
def test_voltage_never_exceeds_the_supply_and_the_loop_stays_odd(name):
    loop = ClosedLoop(load_params(name))
    lim = Limits(V_max=2.0, I_max=0.2)
    up, down = (simulate(loop, 100.0, 2.0, limits=lim, experiment="deflection", amplitude=a, duration=0.1)
                for a in (0.1, -0.1))
    for s in (up, down):
        assert np.abs(s.voltage).max() <= 2.0
        assert s.saturated.any()
    for col in ("voltage", "current", "torque", "theta"):
        a, b = getattr(up, col), getattr(down, col)
        assert np.allclose(a, -b, rtol=1e-12, atol=1e-12 * np.abs(a).max()), col
