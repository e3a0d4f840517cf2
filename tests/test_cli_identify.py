"""haa-sym identify: the command end to end (FITTED.toml round trip, fit.json schema) and every
bad input refused with one line, exit 2 and nothing written."""
import json
import tomllib

import numpy as np
import pytest

from haa_sym.cli import main
from haa_sym.errors import ParameterError
from haa_sym.fit.fitted_file import fitted_text
from haa_sym.model.params import actuator_path, load_params, parse_params

from identify_synthetic import HD_TRUTH, experiment, two_mass, write_csv

KEYS = ("J_link", "B_link", "K_hd", "D_hd")
START = ("--set", "J_link=0.42", "--set", "B_link=1.7", "--set", "K_hd=3.6e4", "--set", "D_hd=50")


@pytest.fixture(scope="module")
def hd_log(tmp_path_factory):
    """A 6 s voltage log of the harmonic drive (its slowest oscillatory mode, 381 rad/s, is short)."""
    d = tmp_path_factory.mktemp("logs")
    params = load_params(actuator_path("harmonic_drive"))
    t, u, y, _ = experiment(two_mass, params.plant.as_dict(), seed=7, duration=6.0)
    return write_csv(d / "hd.csv", t, {"voltage": u, "torque": y[:, 0], "theta": y[:, 1]}), (t, u, y)


def _argv(log, out, *extra):
    return ["identify", "--params", "harmonic_drive", "--log", str(log), "--input", "voltage", "--output",
            "torque,theta", "--fit", ",".join(KEYS), "--out", str(out), *START, "-q", *extra]


def test_fitted_file_round_trip_and_report(tmp_path, hd_log, capsys):
    log, _ = hd_log
    out, rep = tmp_path / "fitted.toml", tmp_path / "fit.json"
    assert main(_argv(log, out, "--report", str(rep))) == 0
    printed = capsys.readouterr().out
    assert "hd.csv: 6000 samples, mean period 0.001 s" in printed and "uniform" in printed
    report = json.loads(rep.read_text())
    assert set(report) == {"parameters", "rms_error", "samples", "sampling", "meta", "ci95_method", "converged",
                           "residuals", "validation"}
    assert report["samples"] == 6000 and report["meta"]["logs"]["hd.csv"]["sha256"]
    text = out.read_text()
    original = actuator_path("harmonic_drive").read_text()
    # the text is the input's: every comment line kept
    assert [ln for ln in original.splitlines() if ln.startswith("#")] == \
        [ln for ln in text.splitlines() if ln.startswith("#")]
    fitted = parse_params(tomllib.loads(text), str(out))
    data = tomllib.loads(text)
    ref = [k for k in data["about"]["references"] if k.startswith("identify_")]
    assert len(ref) == 1 and "hd.csv" in data["about"]["references"][ref[0]]
    sections = {"J_link": ("bodies", "link", "J"), "B_link": ("bodies", "link", "B"), "K_hd": ("couplings", "hd", "K"),
                "D_hd": ("couplings", "hd", "D")}
    for k in KEYS:
        entry = data[sections[k][0]][sections[k][1]][sections[k][2]]
        p = report["parameters"][k]
        # exactly the report's numbers (regions --uncertainty compares the file's value with fit.json's)
        assert getattr(fitted.plant, k) == p["value"]
        assert entry["source"] == ref[0] and entry["ci95"] == p["ci95"]
        assert p["ci95"][0] <= HD_TRUTH[k] <= p["ci95"][1] and abs(p["value"] / HD_TRUTH[k] - 1) < 0.03
    # the keys not fitted are untouched
    base = load_params(actuator_path("harmonic_drive"))
    for k in base.plant.keys:
        if k not in KEYS:
            assert getattr(fitted.plant, k) == getattr(base.plant, k)


def test_ci95_entry_is_validated(tmp_path):
    text = actuator_path("harmonic_drive").read_text().replace(
        'K = { value = 3.1e4, unit = "Nm/rad",', 'K = { value = 3.1e4, ci95 = [3.2e4, 3.3e4], unit = "Nm/rad",')
    with pytest.raises(ParameterError, match=r"K: ci95 = \[32000.0, 33000.0\] does not contain value"):
        parse_params(tomllib.loads(text), "x.toml")
    with pytest.raises(ParameterError, match="ci95 = \\['a', 1\\]; allowed: two finite numbers"):
        parse_params(tomllib.loads(text.replace("ci95 = [3.2e4, 3.3e4]", "ci95 = ['a', 1]")), "x.toml")


def _bad_log(tmp_path, hd_log, case):
    _, (t, u, y) = hd_log
    cols = {"voltage": u.copy(), "torque": y[:, 0].copy(), "theta": y[:, 1].copy()}
    t = t.copy()
    if case == "nan":
        cols["theta"][100] = np.nan
    elif case == "missing":
        del cols["theta"]
    elif case == "constant":
        cols["voltage"][:] = 1.0
    elif case == "jitter":
        t = t + 3e-4 * np.random.default_rng(0).uniform(-1, 1, t.size)
        t.sort()
    elif case == "short":
        t, cols = t[:40], {k: v[:40] for k, v in cols.items()}
    return write_csv(tmp_path.parent / f"{tmp_path.name}-{case}.csv", t, cols)


@pytest.mark.parametrize("case,extra,match", [
    ("nan", (), "row(s) with NaN"),
    ("missing", (), "missing column(s) ['theta']"),
    ("constant", (), "input voltage is constant"),
    (None, ("--window", "100:200"), "--window 100:200 s holds 0 samples"),
    (None, ("--gap", "0"), "--gap 0.0; allowed: a threshold > 0"),
    (None, ("--fit", "delay_drive"), "has no [drive] delay_drive; allowed: add [drive] delay_drive = <start> (s)"),
    (None, ("--set", "tau_drive=-0.01"), "tau_drive = -0.01 is out of range"),
    ("short", (), "periods of the model's slowest mode"),
    (None, ("--fit", "K_nope"), "--fit K_nope: not a plant parameter"),
    (None, ("--fit", "B_m,B_m"), "given twice"),
    (None, ("--input", "velocity"), "--input velocity"),
    (None, ("--output", "torque,speed"), "--output torque,speed"),
    (None, ("--set", "K_link=0", "--fit", "K_link"), "--fit K_link: initial value 0"),
    (None, ("--configuration", "heavy", "--fit", "J_link"), "configuration heavy sets it"),
    (None, ("--configuration", "a", "--configuration", "b", "--configuration", "c"), "--configuration given 3 times"),
    (None, ("--out", "fitted.txt"), "--out 'fitted.txt': unsupported file type"),
    (None, ("--report", "fit.csv"), "--report 'fit.csv': unsupported file type"),
    (None, ("--option", "delay=1"), "--option delay=1: the loop options apply to the closed torque loop"),
])
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, hd_log, assert_refused, case, extra, match):
    log = _bad_log(tmp_path, hd_log, case) if case else hd_log[0]
    argv = _argv(log, "fitted.toml", "--report", "fit.json", "--plot", "fit.png")
    # later flags win: replace the ones the case gives
    for i in range(0, len(extra), 2):
        flag = extra[i]
        if flag in ("--fit", "--input", "--output", "--out", "--report") and flag in argv:
            j = argv.index(flag)
            argv[j + 1] = extra[i + 1]
        else:
            argv += [flag, extra[i + 1]]
    assert_refused(argv, match)


def test_current_commanded_sea_with_port_torque_and_velocity(tmp_path):
    """--input current,T_dist, --output torque,velocity: the drive's current and a port torque
    (the hand-written SEA, tests/identify_synthetic.py), fitted from 10 s."""
    import scipy.signal
    from identify_synthetic import SEA_TRUTH, sea
    params = load_params(actuator_path("sea"))
    A, B, C, D = sea(params.plant.as_dict(), True)
    rng = np.random.default_rng(5)
    n = 10000
    b, a = scipy.signal.butter(4, 0.25)
    U = np.column_stack([scipy.signal.lfilter(b, a, rng.standard_normal(n)) for _ in range(2)])
    U *= np.array([5.0, 20.0]) / np.std(U, axis=0)
    Phi, Gam, *_ = scipy.signal.cont2discrete((A, B, C, D), 1e-3, "zoh")
    _, y, _ = scipy.signal.dlsim((Phi, Gam, C[[0, 2]], D[[0, 2]], 1e-3), U)
    y = y + 0.01 * np.std(y, axis=0) * rng.standard_normal(y.shape)
    log = write_csv(tmp_path / "sea.csv", 1e-3 * np.arange(n),
                    {"current": U[:, 0], "T_dist": U[:, 1], "torque": y[:, 0], "velocity": y[:, 1]})
    rep = tmp_path / "fit.json"
    assert main(["identify", "--params", "sea", "--log", str(log), "--input", "current,T_dist", "--output",
                 "torque,velocity", "--fit", ",".join(SEA_TRUTH), "--set", "J_link=0.1", "--set", "K_bar=2000",
                 "--out", str(tmp_path / "f.toml"), "--report", str(rep), "-q"]) == 0
    for k, p in json.loads(rep.read_text())["parameters"].items():
        assert abs(p["value"] / SEA_TRUTH[k] - 1) < 0.03 and p["ci95"][0] <= SEA_TRUTH[k] <= p["ci95"][1], (k, p)


def test_fitted_entries_say_they_were_fitted_before_their_old_description(tmp_path):
    """A fitted entry's description starts with where the value now comes from and the initial
    value; the file's own description follows (it may state a rule the fit replaced)."""
    class Result:                           # what fitted_text reads of a FitResult
        keys, value, initial = ("K_hd",), np.array([30000.0]), np.array([31000.0])
        ci95 = np.array([[29900.0, 30100.0]])
        inputs, outputs = ("voltage",), ("torque",)
        meta = {"logs": {"run.csv": {"sha256": "0" * 64, "samples": 100}}, "converged": True,
                "intervals": {"method": "sandwich (HAC) covariance"}}
    path = actuator_path("harmonic_drive")
    text = fitted_text(path.read_text(), str(path), load_params(path), Result(), "2026-11-24")
    entry = tomllib.loads(text)
    old = tomllib.loads(path.read_text())
    new_d = _find(entry, "K")["description"]
    assert new_d.startswith("Fitted by haa-sym identify (identify_20261124), initial value 31000. Before: ")
    assert new_d.endswith(_find(old, "K")["description"])


def _find(data, key):
    """The [couplings.hd] entry ``key`` (K_hd) of a parsed harmonic_drive file."""
    return data["couplings"]["hd"][key]


def test_out_is_the_log(tmp_path, hd_log, capsys):
    """identify --log data.toml --out data.toml replaced the log with the fitted file (issue 26)."""
    log, _ = hd_log
    data = tmp_path / "data.toml"
    data.write_bytes(log.read_bytes())
    link = tmp_path / "link.toml"
    link.symlink_to(data)
    for out in (data, link):
        assert main(_argv(data, out)) == 2
        err = capsys.readouterr().err.strip()
        assert err == (f"haa-sym: error: --out {str(out)!r}: is one of this command's inputs"
                       + ("" if out == data else f" (the same file as {str(data)!r})")
                       + "; allowed: an output path that is not an input (write elsewhere, then move it)")
    assert data.read_bytes() == log.read_bytes()


def test_memory_gate_before_reading_and_before_fitting(tmp_path, hd_log, capsys, monkeypatch):
    """A 10 M-row log reached 9.9 GB and died (issue 26, item 10): the read and the fit are
    gated by what they allocate (io.budget: 6 B per file byte; fit_bytes per sample)."""
    from haa_sym.io.budget import LOG_BYTES_PER_FILE_BYTE, fit_bytes
    log, _ = hd_log
    size = log.stat().st_size
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", str(size * LOG_BYTES_PER_FILE_BYTE - 1))
    assert main(_argv(log, tmp_path / "f.toml")) == 2
    err = capsys.readouterr().err.strip()
    assert f"reading its {size} bytes would need about" in err and len(err.splitlines()) == 1
    need = fit_bytes(6000, 5, 2, len(KEYS))
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", str(need - 1))
    assert need - 1 > size * LOG_BYTES_PER_FILE_BYTE
    assert main(_argv(log, tmp_path / "f.toml")) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("haa-sym: error: fitting 4 key(s) to 6000 samples would need about")
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", str(need))
    assert main(_argv(log, tmp_path / "f.toml")) == 0
    assert (tmp_path / "f.toml").exists()


def test_time_column_far_from_seconds(tmp_path, hd_log, capsys):
    """Time stamps near 1e100 (a sample every 1e94 s) were a LinAlgError traceback (issue 26)."""
    log, _ = hd_log
    lines = log.read_text().splitlines()
    far = tmp_path / "far.csv"
    far.write_text("\n".join([lines[0]] + [",".join([repr(float(r.split(",")[0]) * 1e97)] + r.split(",")[1:])
                                           for r in lines[1:]]) + "\n")
    assert main(_argv(far, tmp_path / "f.toml")) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"haa-sym: error: --log {str(far)!r}: mean sampling period "
                                                         "1e+94 s; allowed: 1e-07 to 10 s (the time column in seconds)")


@pytest.mark.parametrize("how", ["same path", "other spelling", "symlink", "hard link", "copy"])
def test_repeated_log_refused(tmp_path, hd_log, assert_refused, how):
    """The same experiment given twice (issue 26, item 8): 40 copies of one log narrowed every ci95
    6.3x (sqrt 40) with no warning. Refused whether it is the same file (path, link, inode) or a copy."""
    import os
    import shutil
    log = hd_log[0]
    second = {"same path": lambda: log,
              "other spelling": lambda: log.parent / "." / log.name,
              "symlink": lambda: os.symlink(log, tmp_path / "link.csv") or tmp_path / "link.csv",
              "hard link": lambda: os.link(log, tmp_path / "hard.csv") or tmp_path / "hard.csv",
              "copy": lambda: shutil.copy(log, tmp_path / "copy.csv")}[how]()
    how_said = "identical content (sha256)" if how == "copy" else "the same file"
    assert_refused(_argv(log, "fitted.toml", "--log", str(second)),
                   (f"--log {second}: {how_said} as --log {log}", "allowed: each experiment once"))
