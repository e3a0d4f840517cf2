"""haa_sym.fit.diagnostics (issue 23): the Ljung-Box test and its chi-square tail, the sandwich
(HAC) covariance against the long-run variance of an AR(1) mean, the near-null keys, NRMSE/VAF."""
import numpy as np
import scipy.stats

from haa_sym.fit.diagnostics import (_chi2_sf_even, andrews_bandwidth, fit_quality, hac_covariance,
                                     near_null_keys, whiteness)

from identify_coloured import ar1


def test_chi2_tail_closed_form_against_scipy():
    for dof in (2, 10, 20):
        for x in (0.1, 5.0, 19.3, 31.4, 80.0, 400.0):
            assert np.isclose(_chi2_sf_even(x, dof), scipy.stats.chi2.sf(x, dof), rtol=1e-10, atol=1e-300), (x, dof)


def test_whiteness_false_alarm_rate_and_ar1_power():
    rng = np.random.default_rng(0)
    flagged = sum(not whiteness(rng.standard_normal(2000))["white"] for _ in range(400))
    # the 5 % level: 20 of 400 expected, binomial sd 4.4
    assert 8 <= flagged <= 34, flagged
    w = whiteness(ar1(rng, (5000,), 0.9))
    assert not w["white"] and abs(w["lag1"] - 0.9) < 0.02 and w["p_value"] < 1e-12 and w["lags"] == 20


def test_sandwich_of_a_mean_is_the_long_run_variance():
    """The mean of AR(1) data (J = ones): var = sigma^2 (1 + rho) / (1 - rho) / N, 19x Gauss-Newton's
    sigma^2 / N at rho = 0.9; over 60 series the sandwich's mean is within 10 % of it."""
    rng = np.random.default_rng(1)
    n, rho = 20000, 0.9
    ratios = []
    for _ in range(60):
        e = ar1(rng, (n, 1), rho)
        r = e - e.mean()
        cov, bw = hac_covariance(np.array([[float(n)]]), [r])
        ratios.append(cov[0, 0] / ((1 + rho) / (1 - rho) / n))
    # the Bartlett kernel's bias at Andrews' bandwidth (about 150 lags here) is a few per cent low
    assert 0.85 < np.mean(ratios) < 1.02, np.mean(ratios)
    assert 100 < bw[0] < 250, bw


def test_andrews_bandwidth_grows_with_correlation():
    rng = np.random.default_rng(2)
    b = [andrews_bandwidth(ar1(rng, (10000, 2), rho)) for rho in (0.0, 0.5, 0.9)]
    assert b[0] < 3 and b[0] < b[1] < b[2], b


def test_near_null_keys_name_the_degenerate_group():
    # log-parameters a, b, c; the outputs see a - b only (and c on its own)
    J = np.array([[1.0, -1.0, 0.0], [2.0, -2.0, 0.0], [0.0, 0.0, 1.0], [1e-6, 0.0, 0.0]])
    H = J.T @ J
    d = np.sqrt(np.diag(H))
    assert sorted(near_null_keys(H / np.outer(d, d), d, ("a", "b", "c"))) == ["a", "b"]


def test_nrmse_and_vaf_definitions():
    y = np.sin(np.linspace(0, 20, 1000))
    q = fit_quality(y, np.full_like(y, y.mean()))
    assert np.isclose(q["nrmse"], 1) and np.isclose(q["vaf_percent"], 0) and q["samples"] == 1000
    q = fit_quality(y, y + 0.1)             # an offset: VAF ignores it, NRMSE does not
    assert np.isclose(q["vaf_percent"], 100) and np.isclose(q["nrmse"], 0.1 / np.std(y))
    q = fit_quality(y, 0.5 * y)
    assert np.isclose(q["vaf_percent"], 75) and np.isclose(q["nrmse"], 0.5, rtol=1e-3)
