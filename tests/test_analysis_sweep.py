"""The grid reductions of haa_sym.analysis.sweep on loops with known answers; BLAS threads."""
import numpy as np
import pytest

from haa_sym import ClosedLoop
from haa_sym.analysis.regions import region_map
from haa_sym.analysis.sweep import blas_limits, gain_rows, monomial_rows, phase_excess, product_form


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


# --- BLAS threads ---------------------------------------------------------------------------------
def test_blas_limits_and_same_map(params):
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads():
        return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    # from two threads: an xdist worker starts with one (tests/conftest.py), where limiting to
    # one and restoring would change nothing and prove nothing
    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        assert before and min(before) == 2
        with blas_limits(1):
            assert blas_threads() and set(blas_threads()) == {1}
        assert blas_threads() == before
    P, D = np.logspace(0, 4.3, 20), np.linspace(1, 50, 10)
    one = region_map(ClosedLoop(params), P, D, radius=False, blas_threads=1)
    untouched = region_map(ClosedLoop(params), P, D, radius=False, blas_threads=None)
    for k in ("stable", "phase_margin_deg", "passive", "phase_excess_deg"):
        np.testing.assert_allclose(getattr(one, k), getattr(untouched, k), rtol=1e-12, err_msg=k)
