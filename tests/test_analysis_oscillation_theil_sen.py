"""The limit-cycle detector's Theil-Sen slope (numpy, so that no command imports scipy.stats)
against scipy.stats.theilslopes, the independent implementation it replaced."""
import numpy as np
import pytest
from scipy.stats import theilslopes

from haa_sym.analysis.oscillation import theil_sen_slope


@pytest.mark.parametrize("n", [2, 3, 4, 5, 8, 31, 200])
def test_equals_scipy_theilslopes(n):
    rng = np.random.default_rng(n)
    for y in (rng.standard_normal(n).cumsum(),                     # a random walk
              np.round(rng.standard_normal(n), 1),                  # many tied slopes
              -0.03 * np.arange(n) + 0.01 * rng.standard_normal(n)):  # a decaying log-amplitude
        assert theil_sen_slope(y) == pytest.approx(theilslopes(y, np.arange(n))[0], rel=1e-12, abs=1e-15)


def test_robust_to_an_outlying_cycle():
    y = 0.5 * np.arange(12.0)
    y[7] += 100.0                      # one cycle far off: least squares would follow it
    assert theil_sen_slope(y) == pytest.approx(0.5, rel=1e-12)
    assert np.polyfit(np.arange(12.0), y, 1)[0] > 0.6
