"""haa_sym.cli: one clear error (exit 2, field, value, what is allowed; no traceback, no file) for
every user-caused condition (issue 7.5), and one rule set for gains on every command (issue 7.6;
the API's side is in test_loop_closed_loop.py)."""
import tracemalloc

import pytest



def run(tmp_path, assert_refused, *argv, match="", printed=False):
    """``haa-sym argv`` with an --out in tmp_path for the commands that write: refused (exit 2,
    one line, no traceback, tmp_path left empty; conftest.assert_refused); returns (2, stderr)."""
    argv = list(argv)
    if argv[0] in ("regions", "passivity", "step"):
        argv += ["--out", str(tmp_path / ("x.npz" if argv[0] == "regions" else "x.csv"))]
    err = assert_refused(argv, match, printed=printed)
    assert list(tmp_path.iterdir()) == []
    assert err.count("haa-sym: error:") == 1
    return 2, err


def test_binary_params_file(tmp_path, assert_refused):
    garbage = tmp_path.parent / f"{tmp_path.name}-garbage.toml"
    garbage.write_bytes(bytes(range(256)) * 4)
    rc, err = run(tmp_path, assert_refused, "regions", "--params", str(garbage))
    assert rc == 2
    assert f"{garbage}: not a text file (byte 0x80 at offset 128 is not UTF-8); allowed: a TOML" in err


@pytest.mark.parametrize("setting,key", [("K_hd=1e300", "K_hd = 1e+300"), ("J_m=1e-300", "J_m = 1e-300"),
                                         ("K_hd=1e308", "K_hd = 1e+308")])
def test_overflowing_plant_names_the_key(tmp_path, assert_refused, setting, key):
    rc, err = run(tmp_path, assert_refused, "step", "--set", setting)
    assert rc == 2
    assert err.startswith(f"haa-sym: error: {key}: the plant matrices of Eq. (1)-(2)")
    assert "overflow to non-finite values; allowed: " in err


@pytest.mark.parametrize("value", ["1e300", "1e-300", "2", "5e-7"])
def test_sampling_time_outside_the_checked_range(tmp_path, assert_refused, value):
    """Ts = 1e-300 gave "stable: True, spectral radius 1" (the poles within rounding of z = 1)
    and Ts = 1e300 an overflow: Ts is refused outside 1 us .. 1 s (the decisions are checked
    against eigenvalues from 10 us to 8 ms)."""
    rc, err = run(tmp_path, assert_refused, "stability", "--P-gain", "2000", "--D-gain", "10", "--set", f"Ts={value}")
    assert rc == 2
    line = err.strip()
    assert line.startswith("haa-sym: error: --set Ts=") and len(line.splitlines()) == 1
    assert line.endswith("is out of range; allowed: a sampling time from 1e-06 to 1 s")


@pytest.mark.parametrize("argv,size", [
    (["regions", "--P-gain", "log:1:100:1000000", "--D-gain", "lin:1:50:1000000"], "TiB"),
    (["regions", "--P-gain", "1", "--D-gain", "1", "--option", "n_omega=100000000000"], "TiB"),
    (["passivity", "--P-gain", "log:1:100:1000", "--D-gain", "lin:1:50:1000",
      "--option", "n_omega=10000000"], "GiB"),
    (["margins", "--option", "n_omega=100000000000"], "TiB"),
    (["step", "--duration", "1e12"], "PiB"),
    (["regions", "--P-gain", "log:1:2:10000000000000"], "TiB"),
])
def test_work_beyond_the_memory_budget_is_refused_before_allocating(tmp_path, assert_refused, monkeypatch, argv, size):
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", "4G")
    tracemalloc.start()
    try:
        rc, err = run(tmp_path, assert_refused, *argv, printed=argv[0] == "margins")  # its first line is out
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert rc == 2
    assert "would need about " in err and f" {size} of memory; allowed: at most 4 GiB" in err
    assert "HAA_SYM_MEMORY_BUDGET" in err
    assert peak < 64 * 2**20                    # refused up front, not after a large allocation


@pytest.mark.parametrize("spec,why", [
    ("log:100:1:10", "START = 100 is above STOP = 1 (reversed range)"),
    ("lin:5:1:10", "START = 5 is above STOP = 1 (reversed range)"),
    ("log:0:1:10", "START = 0: a log grid needs START > 0"),
    ("log:-1:1:10", "START = -1 is negative"),
    ("lin:1:5:0", "N = '0' is not an integer >= 1"),
    ("lin:1:x:3", "STOP = 'x' is not a number"),
    ("1,inf", "inf is not finite"),
])
def test_grid_says_what_is_wrong_once(tmp_path, assert_refused, spec, why):
    rc, err = run(tmp_path, assert_refused, "regions", "--P-gain", spec)
    assert rc == 2
    assert err.startswith(f"haa-sym: error: --P-gain = '{spec}': {why}; allowed: 'log:START:STOP:N'")
    assert err.count("allowed") == 1 and "not a number" not in err.replace("'x' is not a number", "")


@pytest.mark.parametrize("setting,msg", [
    ("N_av=0", "--set N_av=0: N_av = 0 is out of range; allowed: an integer >= 1"),
    ("N_av=2.5", "--set N_av=2.5: N_av = 2.5 is not an integer; allowed: an integer >= 1"),
    ("beta=0", "--set beta=0: beta = 0 is out of range; allowed: a finite number > 0"),
    ("J_L2=abc", "--set J_L2=abc: 'abc' is not a number; allowed: a finite number"),
])
def test_set_errors_name_the_key(tmp_path, assert_refused, setting, msg):
    rc, err = run(tmp_path, assert_refused, "regions", "--set", setting)
    assert rc == 2 and err == f"haa-sym: error: {msg}\n"


# --- one set of rules for gains (7.6) ------------------------------------------------------------
@pytest.mark.parametrize("argv,msg", [
    (["stability", "--P-gain", "-200", "--D-gain", "10"], "--P-gain = -200.0 is out of range; allowed: a finite number >= 0 (Nm/rad)"),
    (["stability", "--P-gain", "200", "--D-gain", "nan"], "--D-gain = nan is not finite"),
    (["margins", "--P-gain", "200", "--D-gain", "-1"], "--D-gain = -1.0 is out of range; allowed: a finite number >= 0 (Nms/rad)"),
    (["regions", "--P-gain=-5,1"], "--P-gain = '-5,1': -5 is negative"),
    (["passivity", "--P-gain", "1,-5", "--D-gain", "1,1"], "--P-gain = '1,-5': -5 is negative"),
])
def test_negative_gains_are_refused_by_every_command(tmp_path, assert_refused, argv, msg):
    rc, err = run(tmp_path, assert_refused, *argv)
    assert rc == 2 and msg in err
