"""The fit's first-order recursion through LAPACK's triangular band solve (fit/model.py,
``_first_order``) against scipy.signal.lfilter, which it replaced (so that identify does not
import scipy.signal), and against the recursion written out in Python."""
import numpy as np
import pytest
import scipy.signal

from haa_sym.fit.model import _first_order


@pytest.mark.parametrize("a", [0.999 * np.exp(0.01j), 0.2 - 0.5j, 1.0, -0.7, 1.0005 * np.exp(0.3j)])
def test_equals_lfilter(a):
    rng = np.random.default_rng(0)
    d = rng.standard_normal((3, 2, 3000)) + 1j * rng.standard_normal((3, 2, 3000))
    ref = scipy.signal.lfilter([0.0, 1.0], [1.0, -a], d, axis=-1)
    got = _first_order(a, d)
    assert got.shape == d.shape
    assert np.max(np.abs(got - ref)) <= 1e-13 * np.max(np.abs(ref))


def test_one_column_and_the_recursion():
    rng = np.random.default_rng(1)
    a, d = 0.9 + 0.3j, rng.standard_normal(50)
    xi = np.zeros(50, complex)
    for k in range(49):
        xi[k + 1] = a * xi[k] + d[k]
    got = _first_order(a, d)
    assert got[0] == 0
    assert np.max(np.abs(got - xi)) <= 1e-14 * np.max(np.abs(xi))
