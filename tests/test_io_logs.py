"""haa_sym.io.logs: the sampling of a log is found and stated, the log kept as measured (split at
gaps, cut to a window), and every unusable log is one ParameterError naming the log and the field."""
import numpy as np
import pytest

from haa_sym.errors import ParameterError
from haa_sym.io.logs import read_log


def _write(path, t, cols, header=None):
    names = header or ["time"] + list(cols)
    rows = np.column_stack([t] + list(cols.values()))
    path.write_text(",".join(names) + "\n" + "\n".join(",".join(repr(float(x)) for x in r) for r in rows) + "\n")
    return path


def _signals(n, seed=0):
    rng = np.random.default_rng(seed)
    return {"voltage": rng.standard_normal(n), "torque": rng.standard_normal(n)}


def test_uniform_log_is_read_as_is(tmp_path):
    t = 1e-3 * np.arange(500)
    cols = _signals(500)
    log = read_log(_write(tmp_path / "a.csv", t, cols), ("voltage",), ("torque",))
    assert log.Ts == pytest.approx(1e-3, rel=1e-12)
    assert log.uniform and log.sampling["jitter"] < 1e-6 and log.starts == (0,)
    np.testing.assert_array_equal(log.signals["torque"], cols["torque"])
    assert log.samples == 500 and len(log.sha256) == 64


def test_jittered_log_is_kept_as_measured_and_split_at_gaps(tmp_path):
    """No resampling: the stamps and values are the file's; an interval above the gap threshold
    (default 10 median periods, or --gap) starts a new segment; a window keeps START <= t < STOP."""
    rng = np.random.default_rng(1)
    n = 400
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n))
    t[200:] += 0.05                                             # a 50 ms pause of the logger
    t[300:] += 0.005                                            # 5 ms: a gap only for --gap 0.004
    cols = {"voltage": rng.standard_normal(n), "torque": rng.standard_normal(n)}
    path = _write(tmp_path / "j.csv", t, cols)
    log = read_log(path, ("voltage",), ("torque",))
    assert not log.uniform and log.starts == (0, 200) and log.sampling["segments"] == 2
    np.testing.assert_array_equal(log.t, t)
    np.testing.assert_array_equal(log.signals["voltage"], cols["voltage"])
    assert read_log(path, ("voltage",), ("torque",), gap=0.004).starts == (0, 200, 300)
    w = read_log(path, ("voltage",), ("torque",), window=(t[100], t[250]))
    assert w.samples == 150 and w.t[0] == t[100] and not w.from_start and w.starts == (0, 100)
    for bad, match in (({"gap": 0.0}, "--gap 0.0; allowed: a threshold > 0"),
                       ({"window": (10.0, 20.0)}, "--window 10:20 s holds 0 samples")):
        with pytest.raises(ParameterError, match=match):
            read_log(path, ("voltage",), ("torque",), **bad)


def test_large_angle_log_is_refused_for_its_amplitude(tmp_path):
    """A swing-up to +-pi is refused for what makes it unfit for a linear model, before its length."""
    t = 1e-3 * np.arange(300)
    cols = {"current": np.sin(30 * t), "theta": 3.1 * np.sin(10 * t)}
    path = _write(tmp_path / "swing.csv", t, cols)
    with pytest.raises(ParameterError, match=r"theta spans 3\.1 rad .*allowed: at most 1\.5708 rad.*--max-angle"):
        read_log(path, ("current",), ("theta",))
    assert read_log(path, ("current",), ("theta",), max_angle=7.0).samples == 300


@pytest.mark.parametrize("case,match", [
    ("nan", "row(s) with NaN"), ("missing", "missing column(s) ['theta']"),
    ("constant", "input voltage is constant"), ("time", "time is not increasing at data row"),
    ("unknown", "unknown column(s) ['speed']"), ("empty", "empty file")])
def test_each_unusable_log_is_one_clear_error(tmp_path, case, match):
    n = 300
    t = 1e-3 * np.arange(n)
    cols = {**_signals(n), "theta": np.zeros(n)}
    header = None
    if case == "nan":
        cols["torque"][17] = np.nan
    elif case == "missing":
        del cols["theta"]
    elif case == "constant":
        cols["voltage"][:] = 3.0
    elif case == "time":
        t[40] = t[39]
    elif case == "unknown":
        header = ["time", "voltage", "torque", "speed"]
    path = tmp_path / "bad.csv"
    if case == "empty":
        path.write_text("")
    else:
        _write(path, t, cols, header)
    with pytest.raises(ParameterError) as exc:
        read_log(path, ("voltage",), ("torque", "theta"))
    msg = str(exc.value)
    assert match in msg and "\n" not in msg and "bad.csv" in msg and "allowed" in msg
