"""The grid reductions of haa_sym.analysis.sweep on loops with known answers."""
import numpy as np
import pytest

from haa_sym.analysis.sweep import gain_rows, monomial_rows, phase_excess, product_form


def test_product_form_is_the_product():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(5, 3)) + 1j * rng.normal(size=(5, 3))
    b = rng.normal(size=(5, 3)) + 1j * rng.normal(size=(5, 3))
    X = gain_rows(rng.uniform(0, 100, 7), rng.uniform(0, 10, 7))
    direct = (X @ a.T) * np.conj(X @ b.T)
    np.testing.assert_allclose(monomial_rows(X) @ product_form(a, b), direct, rtol=1e-12)


def test_phase_excess_of_known_impedances():
    """Z = P/s + D (spring-damper, phase in [-90, 0]) is inside; Z = P/s - D is not."""
    w = np.logspace(-2, 3, 2000)
    s = 1j * w
    num = np.stack([np.zeros_like(s), 1 / s, np.ones_like(s)], axis=1)   # P/s + D
    den = np.stack([np.ones_like(s), 0 * s, 0 * s], axis=1)
    ex, _ = phase_excess(gain_rows([10.0], [2.0]), num, den, w, Ts=1.0, colgate="none")
    assert ex[0] <= 0
    num_bad = np.stack([np.zeros_like(s), 1 / s, -np.ones_like(s)], axis=1)
    ex, ww = phase_excess(gain_rows([10.0], [2.0]), num_bad, den, w, Ts=1.0, colgate="none")
    # phase of 10/(jw) - 2 tends to -180 deg at high frequency: excess -> 90 deg
    assert ex[0] == pytest.approx(np.degrees(np.arctan2(2, 10 / w[-1])), abs=1e-9)
    assert ww[0] == w[-1]
