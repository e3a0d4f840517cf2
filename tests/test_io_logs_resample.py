"""haa_sym.io.logs.read_log, review of issue 17: a jittered log resampled onto its mean period
gives each grid interval the input sample that covers it (the one in effect at the interval's
middle). It took the one in effect at the interval's start, which is the previous sample whenever
a stamp lands a hair after its grid point: half the inputs shifted by a whole sample, and a fit
of a log with 1e-5 jitter (simulated exactly at its stamps) drove B_link to 1e-9."""
import numpy as np

from haa_sym.io.logs import read_log

from identify_synthetic import write_csv


def test_small_jitter_keeps_every_input_sample_on_its_own_interval(tmp_path):
    n, Ts = 2000, 1e-3
    rng = np.random.default_rng(0)
    t = Ts * (np.arange(n) + rng.uniform(-1e-4, 1e-4, n))        # stamps within 0.01 % of the grid
    t[0] = 0.0
    u = np.arange(n, dtype=float)                                # every sample distinct (exact in the CSV)
    y = np.sin(2 * np.pi * 5 * t)
    log = read_log(write_csv(tmp_path / "j.csv", t, {"voltage": u, "torque": y}), ("voltage",), ("torque",),
                   max_jitter=1e-3)
    assert log.sampling["resampled"]
    # the interval [g_k, g_k+1) is covered by sample k from t_k (within 1e-7 s of g_k) to t_k+1
    assert np.array_equal(log.signals["voltage"], u)
    grid = np.arange(n) * log.Ts
    assert np.allclose(log.signals["torque"], np.interp(grid, t, y), rtol=0, atol=1e-9)
