"""What a fit's residuals say about its own uncertainty, and how well a fitted model predicts
(``haa-sym identify``; docs/identify.md, "Residuals", "Intervals", "Validation").

numpy only (the CLI's start-up imports this module; docs/startup.md).

- :func:`whiteness`: the Ljung-Box portmanteau test of one residual series.
- :func:`hac_covariance`: the sandwich covariance of a least-squares estimate whose residuals are
  correlated in time (Newey-West, Bartlett kernel, Andrews' AR(1) plug-in bandwidth).
- :func:`near_null_keys`: the keys that make up the direction the normal matrix barely sees.
- :func:`fit_quality`: NRMSE and VAF of a prediction.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["whiteness", "hac_covariance", "andrews_bandwidth", "near_null_keys", "fit_quality",
           "WHITENESS_LAGS", "WHITENESS_LEVEL", "MAX_SCORE_RHO"]

# Ljung-Box over the first 20 lags: an even number, so the chi-square tail has its closed form
# (below) and no scipy.stats at run time; 20 lags reach 20 samples, beyond the correlation time
# of the 1 kHz logs' sensor filters and of an AR(1) with lag-1 correlation up to about 0.85
WHITENESS_LAGS = 20
# "white" when the Ljung-Box p-value is at least this (the test's usual 5 % level)
WHITENESS_LEVEL = 0.05
# the lag-1 correlation of a score series is clipped here before Andrews' plug-in: 1 / (1 - rho)
# diverges as rho -> 1 and a bandwidth beyond ~ N^(1/3) x 70 only adds estimation noise
MAX_SCORE_RHO = 0.97


def _autocorrelation(e: np.ndarray, lags: int) -> np.ndarray:
    """rho_1 .. rho_lags of ``e`` (mean removed; the biased estimator, normalised by rho_0)."""
    e = np.asarray(e, float) - np.mean(e)
    n = len(e)
    c0 = float(e @ e)
    if not c0 > 0:
        return np.zeros(lags)
    return np.array([float(e[k:] @ e[:n - k]) / c0 for k in range(1, lags + 1)])


def _chi2_sf_even(x: float, dof: int) -> float:
    """P(chi^2_dof > x) for an even ``dof``: exp(-x/2) sum_{i < dof/2} (x/2)^i / i! (the Poisson
    tail identity), summed in logarithms so that large x gives 0, not inf * 0."""
    if x <= 0:
        return 1.0
    h = x / 2
    logs = [i * math.log(h) - math.lgamma(i + 1) - h for i in range(dof // 2)]
    top = max(logs)
    return float(min(1.0, math.exp(top) * sum(math.exp(v - top) for v in logs)))


def whiteness(e: np.ndarray, lags: int = WHITENESS_LAGS, level: float = WHITENESS_LEVEL) -> dict:
    """Ljung-Box test of one residual series.

    Q = N (N + 2) sum_{k=1}^{m} rho_k^2 / (N - k), chi-square with m degrees of freedom under
    white residuals (Ljung & Box 1978; the fitted parameters' few degrees of freedom are not
    subtracted: they are spread over many outputs and samples). ``lags`` is rounded down to an
    even number and to at most N / 4.

    Returns
    -------
    dict
        ``lag1`` (the lag-1 autocorrelation), ``lags`` (m), ``statistic`` (Q), ``p_value`` and
        ``white`` (p >= ``level``).
    """
    n = len(e)
    m = int(min(lags, n // 4)) // 2 * 2
    if m < 2:
        return {"lag1": float("nan"), "lags": 0, "statistic": float("nan"), "p_value": float("nan"), "white": False}
    rho = _autocorrelation(e, m)
    q = float(n * (n + 2) * np.sum(rho ** 2 / (n - np.arange(1, m + 1))))
    p = _chi2_sf_even(q, m)
    return {"lag1": float(rho[0]), "lags": m, "statistic": q, "p_value": p, "white": bool(p >= level)}


def andrews_bandwidth(v, max_rho: float = MAX_SCORE_RHO) -> float:
    """Andrews' (1991) AR(1) plug-in bandwidth of the Bartlett kernel for the series ``v`` (N, p),
    or for a list of its segments (a log split at gaps: the lag pairs are taken inside each
    segment only, N is their total length).

    Each column's lag-1 correlation rho_a (clipped to +-``max_rho``) gives
    alpha(1) = sum_a 4 rho_a^2 / ((1 - rho_a)^6 (1 + rho_a)^2) / sum_a 1 / (1 - rho_a)^4
    (his weights 1 / sigma_a^4, which make it independent of each column's scale) and
    S = 1.1447 (alpha(1) N)^(1/3).
    """
    segs = [np.asarray(x, float) for x in (v if isinstance(v, (list, tuple)) else [v])]
    n = sum(x.shape[0] for x in segs)
    mean = sum(x.sum(axis=0) for x in segs) / max(n, 1)
    segs = [x - mean for x in segs]
    den = sum(np.einsum("ij,ij->j", x[:-1], x[:-1]) for x in segs)
    num = sum(np.einsum("ij,ij->j", x[1:], x[:-1]) for x in segs)
    rho = np.clip(num / np.maximum(den, 1e-300), -max_rho, max_rho)
    alpha = np.sum(4 * rho ** 2 / ((1 - rho) ** 6 * (1 + rho) ** 2)) / np.sum(1 / (1 - rho) ** 4)
    return float(1.1447 * (alpha * n) ** (1 / 3))


def hac_covariance(H: np.ndarray, scores: list[np.ndarray], max_rho: float = MAX_SCORE_RHO):
    """The sandwich (heteroskedasticity and autocorrelation consistent) covariance of a
    least-squares estimate: H^-1 S H^-1.

    Parameters
    ----------
    H : (p, p) array
        J^T J of the weighted residuals r (the Gauss-Newton normal matrix).
    scores : list of (N_i, p) arrays, or of lists of them
        Per log, the score series v_t = sum over outputs of J_{t,o}^T r_{t,o} (its sum is the
        gradient / 2), whole or as the list of its segments (split at gaps). The logs are
        independent experiments: S = sum over logs of their long-run covariances; the outputs of
        one log share v_t, so their correlation with each other at every lag is kept. A log's
        segments share its bandwidth, and the lagged products are taken inside each segment only
        (a gap of 30-300 ms is not one sample period: samples across it are not neighbours).
    max_rho : float
        See :func:`andrews_bandwidth`.

    Returns
    -------
    cov : (p, p) array
        The covariance (of the parameters J differentiates by: log-parameters here).
    bandwidths : list of float
        Per log, the Bartlett bandwidth S (lags l < S get the weight 1 - l / S; Newey & West 1987).

    Notes
    -----
    With white residuals S -> s^2 H and the sandwich reduces to Gauss-Newton's s^2 H^-1. H is
    inverted in its scaled coordinates (divided by its diagonal), as the Gauss-Newton covariance
    is, so a barely seen key gets a wide interval and not a dropped direction.
    """
    p = H.shape[0]
    S = np.zeros((p, p))
    bandwidths = []
    for v in scores:
        segs = [np.asarray(x, float) for x in (v if isinstance(v, (list, tuple)) else [v])]
        n = sum(x.shape[0] for x in segs)
        bw = min(andrews_bandwidth(segs, max_rho), n / 4)
        bandwidths.append(bw)
        for x in segs:
            Si = x.T @ x
            for lag in range(1, min(int(math.ceil(bw)), x.shape[0])):
                w = 1 - lag / bw
                # one key: a dot product (BLAS's gemm on a 1 x N x 1 product took 0.4-8 ms a lag
                # with its threads on a loaded machine, 1000x the dot's 7 us)
                G = np.array([[x[lag:, 0] @ x[:-lag, 0]]]) if p == 1 else x[lag:].T @ x[:-lag]
                Si += w * (G + G.T)
            S += Si
    d = np.sqrt(np.maximum(np.diag(H), 1e-300))
    Hinv = np.linalg.pinv(H / np.outer(d, d)) / np.outer(d, d)
    cov = Hinv @ S @ Hinv
    return (cov + cov.T) / 2, bandwidths


def near_null_keys(Hs: np.ndarray, scale: np.ndarray, keys, share: float = 0.1) -> list[str]:
    """The keys of the normal matrix's near-null direction, largest component first.

    The direction is the eigenvector of the smallest eigenvalue of the scaled normal matrix
    ``Hs`` = H / (d d^T), taken back to the fitted coordinates (log-parameters: divided by
    ``scale`` = d, the square roots of H's diagonal) and normalised; the keys whose squared
    component is at least ``share`` (the squares sum to 1) form it. In log-parameters an exact
    degeneracy reads directly: (1, 1, 1, 1) / 2 for four keys the outputs see only through their
    ratios (an inertia, a damping, a stiffness scaled together)."""
    w, V = np.linalg.eigh((Hs + Hs.T) / 2)
    v = V[:, int(np.argmin(w))] / np.asarray(scale, float)
    v = v / np.linalg.norm(v)
    order = np.argsort(-np.abs(v))
    return [keys[i] for i in order if v[i] ** 2 >= share]


def fit_quality(y: np.ndarray, yhat: np.ndarray) -> dict:
    """NRMSE = rms(y - yhat) / rms(y - mean(y)) and VAF = 100 (1 - var(y - yhat) / var(y)) (%)
    of one output, and the samples compared.

    NRMSE is 0 for a perfect prediction and 1 for predicting the mean; VAF (variance accounted
    for) ignores a constant offset of the error, NRMSE does not."""
    y, yhat = np.asarray(y, float), np.asarray(yhat, float)
    e = y - yhat
    spread = float(np.sqrt(np.mean((y - y.mean()) ** 2))) if y.size else 0.0
    var = float(np.var(y)) if y.size else 0.0
    nrmse = float(np.sqrt(np.mean(e ** 2))) / spread if spread > 0 else float("nan")
    vaf = 100 * (1 - float(np.var(e)) / var) if var > 0 else float("nan")
    return {"nrmse": nrmse, "vaf_percent": vaf, "samples": int(y.size)}
