"""haa_sym.loop.plant: the numeric plant against python-control (ZOH) and Eq. (6)."""
import numpy as np
import pytest

from haa_sym.loop.plant import continuous_plant, discretize


def test_zoh_matches_python_control(params):
    control = pytest.importorskip("control")
    cont = continuous_plant(params.plant)
    for Ts in (0.5e-3, 1e-3, 8e-3):
        d = discretize(cont, Ts)
        ref = control.c2d(control.ss(cont.A, cont.B, cont.C, 0), Ts, "zoh")
        np.testing.assert_allclose(d.Phi, ref.A, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(d.Gamma, ref.B, rtol=1e-10, atol=1e-14)


def test_vc_gain_eq6(params):
    p = params.plant
    assert np.isclose(continuous_plant(p).VC0, p.N / p.k_t * (p.R * p.B_m + p.k_t * p.k_w), rtol=1e-15)
