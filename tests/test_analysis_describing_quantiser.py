"""The quantiser's harmonic balance finds every amplitude with N(A) = -1/G (review of issue 19).

N of a rounding quantiser is continuous and rises like sqrt(A - t) just above each threshold t;
the root on that steep rise (N' > 0, a stable cycle by Loeb) was lost when the samples of each
interval started a thirty-second of a step above the threshold. Here N is computed independently
(the first harmonic of the quantiser's output by quadrature) on a fine amplitude grid, and the
prediction must hold every crossing of -1/G, alternately stable and unstable.
"""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.describing import limit_cycles, nonlinearity_output
from haa_sym.analysis.sweep import blas_limits


def _N_by_quadrature(q: float, A: np.ndarray) -> np.ndarray:
    th = np.linspace(0.0, 2 * np.pi, 20_001)
    b1 = [np.trapezoid(nonlinearity_output("quantiser", q, a[:, None] * np.sin(th)) * np.sin(th), th, axis=1)
          for a in np.array_split(A, max(1, A.size // 100))]
    return np.concatenate(b1) / (np.pi * A)


def test_every_quantiser_crossing_is_found_and_stability_alternates():
    # the doc's case (docs/describing.md): HyQ, alpha 1.2, beta 3, P_gain 5000, T_res 0.1 Nm
    q = 0.1
    loop = ClosedLoop(load_params().with_values(alpha=1.2, beta=3.0))
    with blas_limits(1):
        r = limit_cycles(loop, 5000.0, 0.0, nonlinearity={"T_res": q}, amplitude_max=8.0)
    assert r.omega.size >= 2 and np.allclose(r.omega, r.omega[0])      # one phase crossover
    target = -1.0 / r.G_crossing[0]
    A = np.linspace(0.5 * q + 1e-9, 8.0 * q, 1501)
    f = _N_by_quadrature(q, A) - target
    brackets = np.flatnonzero(np.sign(f[1:]) != np.sign(f[:-1]))
    # every bracket of the independent N holds one predicted amplitude (within a grid step: the
    # quadrature's N is good to about 1e-4) and the prediction solves N(A) = -1/G there
    assert r.amplitude.size == brackets.size
    step = A[1] - A[0]
    for i, a in zip(brackets, np.sort(r.amplitude)):
        assert A[i] - step <= a <= A[i + 1] + step
    np.testing.assert_allclose(_N_by_quadrature(q, np.sort(r.amplitude)), target, rtol=1e-3)
    # N rises then falls across each crossing in turn: Loeb's verdict alternates
    s = r.stable[np.argsort(r.amplitude)]
    assert np.all(s[1:] != s[:-1])
    # rising crossings (N' > 0 by the independent N) are the stable ones
    rising = f[brackets + 1] > f[brackets]
    np.testing.assert_array_equal(s, rising)

