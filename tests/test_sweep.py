"""The grid reductions of haa_sym.analysis.sweep on loops with known answers."""
import numpy as np
import pytest

from haa_sym.analysis.margins import stability_margins
from haa_sym.analysis.sweep import gain_rows, monomial_rows, phase_excess, phase_margins, product_form


def test_product_form_is_the_product():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(5, 3)) + 1j * rng.normal(size=(5, 3))
    b = rng.normal(size=(5, 3)) + 1j * rng.normal(size=(5, 3))
    X = gain_rows(rng.uniform(0, 100, 7), rng.uniform(0, 10, 7))
    direct = (X @ a.T) * np.conj(X @ b.T)
    np.testing.assert_allclose(monomial_rows(X) @ product_form(a, b), direct, rtol=1e-12)


def test_phase_margins_match_margins_module():
    """L = (P + D s) e^{-s T}/(s (1 + s/100)) written gain-affinely: c = (0, G, s G)."""
    w = np.logspace(-1, 4, 3000)
    s = 1j * w
    G = np.exp(-s * 1e-3) / (s * (1 + s / 100))
    L = np.stack([0 * G, G, s * G], axis=1)
    P = np.array([5.0, 50.0, 200.0, 0.01])
    D = np.array([0.1, 0.5, 0.0, 0.0])
    for rule in ("min_abs", "worst"):
        pm, wc = phase_margins(gain_rows(P, D), L, w, rule)
        for i in range(P.size):
            m = stability_margins(P[i] * G + D[i] * s * G, w)
            if m.phase_margins_deg.size == 0:
                assert np.isnan(pm[i])
                continue
            pick = np.argmin(np.abs(m.phase_margins_deg)) if rule == "min_abs" else np.argmin(m.phase_margins_deg)
            assert pm[i] == pytest.approx(m.phase_margins_deg[pick], abs=1e-6)
            assert wc[i] == pytest.approx(m.gain_crossovers[pick], rel=1e-6)
    # |L| < 1 on the whole grid: no crossover, NaN
    assert np.all(np.abs(0.001 * G) < 1)
    assert np.isnan(phase_margins(gain_rows([0.001], [0.0]), L, w)[0][0])


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
