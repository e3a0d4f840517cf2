"""identify end to end on a jittered log of a model with an integrator (issue 23): the harmonic drive
with its link free (K_link = 0: a mode at s = 0), voltage-driven, stamps jittered by up to 10 % of
the period. The log comes from an INDEPENDENT simulation: the drive's equations written by hand in
tests/identify_synthetic.py (``two_mass``), one scipy matrix exponential per interval, the voltage
held over each true interval. Before the per-interval sensitivities were taken in A's eigenbasis,
this log was refused ("a mode at s = 0")."""
import json

import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from haa_sym.analysis.sweep import blas_limits
from haa_sym.cli import main
from haa_sym.model.params import load_params
from identify_synthetic import HD_TRUTH, two_mass, write_csv

TS = 1e-3


def _jittered_log(path, *, seed, duration, jitter):
    """(t, u, y) with intervals TS (1 + jitter U(-1, 1)); the voltage band-passed (2-125 Hz: the
    free link's angle then stays within a few degrees instead of drifting), 1 % sensor noise."""
    plant = load_params("harmonic_drive").plant
    p = {k: getattr(plant, k) for k in plant.topology.parameter_keys} | HD_TRUTH | {"K_link": 0.0}
    A, B, C, _ = two_mass(p)
    assert np.min(np.abs(np.linalg.eigvals(A))) < 1e-9 * np.max(np.abs(np.linalg.eigvals(A)))   # the integrator
    rng = np.random.default_rng(seed)
    n = int(round(duration / TS))
    t = np.concatenate([[0.0], np.cumsum(TS * (1 + jitter * rng.uniform(-1, 1, n - 1)))])
    b, a = scipy.signal.butter(2, [2 * 2 * TS, 0.25], btype="band")
    u = scipy.signal.lfilter(b, a, rng.standard_normal(n + 500))[500:]
    u *= 2.0 / np.std(u)
    k = A.shape[0]
    M = np.zeros((k + 1, k + 1))
    M[:k, :k], M[:k, k] = A, B[:, 0]
    x, ys = np.zeros(k), []
    with blas_limits(1):
        for i in range(n):
            ys.append(C[:2] @ x)                              # torque (spring + damper), link angle
            if i + 1 < n:
                E = scipy.linalg.expm(M * (t[i + 1] - t[i]))
                x = E[:k, :k] @ x + E[:k, k] * u[i]
    y = np.array(ys)
    y += 0.01 * np.std(y, axis=0) * rng.standard_normal(y.shape)
    write_csv(path, t, {"voltage": u, "torque": y[:, 0], "theta": y[:, 1]})
    return t, u, y


@pytest.mark.slow
def test_jittered_free_link_log_is_fitted_on_its_own_stamps(tmp_path, capsys):
    log = tmp_path / "hd_free_jittered.csv"
    _jittered_log(log, seed=4, duration=8.0, jitter=0.1)
    report = tmp_path / "fit.json"
    assert main(["identify", "--params", "harmonic_drive", "--log", str(log), "--input", "voltage",
                 "--output", "torque,theta", "--fit", "J_link,B_link,K_hd,D_hd", "--set", "K_link=0",
                 "--set", "J_link=0.42", "--set", "B_link=2.6", "--set", "K_hd=2.5e4", "--set", "D_hd=50",
                 "--out", str(tmp_path / "fitted.toml"), "--report", str(report)]) == 0
    assert "simulated on its own intervals" in capsys.readouterr().out
    fit = json.loads(report.read_text())["parameters"]
    for key, truth in HD_TRUTH.items():
        v, (lo, hi) = fit[key]["value"], fit[key]["ci95"]
        assert abs(v / truth - 1) < 0.01, (key, v, truth)
        assert lo <= truth <= hi, (key, lo, truth, hi)
