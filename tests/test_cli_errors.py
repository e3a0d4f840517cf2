"""One clear error (exit 2, field, value, what is allowed; no traceback, no file) for every
user-caused condition (issue 7.5), and one rule set for gains and parameters (issue 7.6)."""
import dataclasses
import tracemalloc

import numpy as np
import pytest

from haa_sym import ClosedLoop, ParameterError, passivity, region_map
from haa_sym.io.budget import check_memory, memory_budget
from haa_sym.cli import main
from haa_sym.analysis.contact import contact_stability

from haa_sym.model.params import Controller, Params, load_params
from haa_sym.analysis.torque import step_response, torque_bandwidth

from conftest import ROOT


def run(tmp_path, capsys, *argv):
    """main(argv) with an --out in tmp_path for the commands that write; returns (rc, stderr)."""
    argv = list(argv)
    if argv[0] in ("regions", "passivity", "step"):
        argv += ["--out", str(tmp_path / ("x.npz" if argv[0] == "regions" else "x.csv"))]
    rc = main(argv)
    err = capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
    assert err.count("haa-sym: error:") == 1 and "Traceback" not in err
    return rc, err


def test_binary_params_file(tmp_path, capsys):
    garbage = tmp_path.parent / f"{tmp_path.name}-garbage.toml"
    garbage.write_bytes(bytes(range(256)) * 4)
    rc, err = run(tmp_path, capsys, "regions", "--params", str(garbage))
    assert rc == 2
    assert f"{garbage}: not a text file (byte 0x80 at offset 128 is not UTF-8); allowed: a TOML" in err


def test_params_file_integer_beyond_float(tmp_path):
    text = (ROOT / "model" / "hyq_haa.toml").read_text().replace("K = { value = 8.077e3", "K = { value = 1" + "0" * 400, 1)
    (tmp_path / "big.toml").write_text(text)
    with pytest.raises(ParameterError, match=r"big.toml \[couplings.hd\]: K = 10{400} is not finite"):
        load_params(tmp_path / "big.toml")


@pytest.mark.parametrize("setting,key", [("K_hd=1e300", "K_hd = 1e+300"), ("J_m=1e-300", "J_m = 1e-300"),
                                         ("K_hd=1e308", "K_hd = 1e+308"), ("Ts=1e300", "Ts = 1e+300")])
def test_overflowing_plant_names_the_key(tmp_path, capsys, setting, key):
    rc, err = run(tmp_path, capsys, "step", "--set", setting)
    assert rc == 2
    assert err.startswith(f"haa-sym: error: {key}: the plant matrices of Eq. (1)-(2)")
    assert "overflow to non-finite values; allowed: " in err


@pytest.mark.parametrize("argv,size", [
    (["regions", "--P-gain", "log:1:100:1000000", "--D-gain", "lin:1:50:1000000"], "TiB"),
    (["regions", "--P-gain", "1", "--D-gain", "1", "--option", "n_omega=100000000000"], "TiB"),
    (["passivity", "--P-gain", "log:1:100:1000", "--D-gain", "lin:1:50:1000",
      "--option", "n_omega=10000000"], "GiB"),
    (["margins", "--option", "n_omega=100000000000"], "TiB"),
    (["step", "--duration", "1e12"], "PiB"),
    (["regions", "--P-gain", "log:1:2:10000000000000"], "TiB"),
])
def test_work_beyond_the_memory_budget_is_refused_before_allocating(tmp_path, capsys, monkeypatch, argv, size):
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", "4G")
    tracemalloc.start()
    try:
        rc, err = run(tmp_path, capsys, *argv)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert rc == 2
    assert "would need about " in err and f" {size} of memory; allowed: at most 4 GiB" in err
    assert "HAA_SYM_MEMORY_BUDGET" in err
    assert peak < 64 * 2**20                    # refused up front, not after a large allocation


def test_memory_budget_env(monkeypatch):
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", "512M")
    assert memory_budget() == 512 * 2**20
    with pytest.raises(ParameterError, match=r"would need about 1 GiB of memory; allowed: at most 512 MiB"):
        check_memory(2**30, "this")
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", "lots")
    with pytest.raises(ParameterError, match=r"HAA_SYM_MEMORY_BUDGET = 'lots'; allowed: a number of bytes"):
        memory_budget()


@pytest.mark.parametrize("spec,why", [
    ("log:100:1:10", "START = 100 is above STOP = 1 (reversed range)"),
    ("lin:5:1:10", "START = 5 is above STOP = 1 (reversed range)"),
    ("log:0:1:10", "START = 0: a log grid needs START > 0"),
    ("log:-1:1:10", "START = -1 is negative"),
    ("lin:1:5:0", "N = '0' is not an integer >= 1"),
    ("lin:1:x:3", "STOP = 'x' is not a number"),
    ("1,inf", "inf is not finite"),
])
def test_grid_says_what_is_wrong_once(tmp_path, capsys, spec, why):
    rc, err = run(tmp_path, capsys, "regions", "--P-gain", spec)
    assert rc == 2
    assert err.startswith(f"haa-sym: error: --P-gain = '{spec}': {why}; allowed: 'log:START:STOP:N'")
    assert err.count("allowed") == 1 and "not a number" not in err.replace("'x' is not a number", "")


@pytest.mark.parametrize("setting,msg", [
    ("N_av=0", "--set N_av=0: N_av = 0 is out of range; allowed: an integer >= 1"),
    ("N_av=2.5", "--set N_av=2.5: N_av = 2.5 is not an integer; allowed: an integer >= 1"),
    ("beta=0", "--set beta=0: beta = 0 is out of range; allowed: a finite number > 0"),
    ("J_L2=abc", "--set J_L2=abc: 'abc' is not a number; allowed: a finite number"),
])
def test_set_errors_name_the_key(tmp_path, capsys, setting, msg):
    rc, err = run(tmp_path, capsys, "regions", "--set", setting)
    assert rc == 2 and err == f"haa-sym: error: {msg}\n"


# --- one set of rules for gains (7.6) ------------------------------------------------------------
@pytest.mark.parametrize("argv,msg", [
    (["stability", "--P-gain", "-200", "--D-gain", "10"], "--P-gain = -200.0 is out of range; allowed: a finite number >= 0 (Nm/rad)"),
    (["stability", "--P-gain", "200", "--D-gain", "nan"], "--D-gain = nan is not finite"),
    (["margins", "--P-gain", "200", "--D-gain", "-1"], "--D-gain = -1.0 is out of range; allowed: a finite number >= 0 (Nms/rad)"),
    (["regions", "--P-gain=-5,1"], "--P-gain = '-5,1': -5 is negative"),
    (["passivity", "--P-gain", "1,-5", "--D-gain", "1,1"], "--P-gain = '1,-5': -5 is negative"),
])
def test_negative_gains_are_refused_by_every_command(tmp_path, capsys, argv, msg):
    rc, err = run(tmp_path, capsys, *argv)
    assert rc == 2 and msg in err


@pytest.fixture(scope="module")
def loop(params):
    return ClosedLoop(params)


@pytest.mark.parametrize("call,msg", [
    (lambda p, lp: lp.stability(-1.0, 0.0), r"P_gain = -1.0 is out of range"),
    (lambda p, lp: lp.stability([1.0, 2.0], [0.0, -3.0]), r"D_gain contains -3.0, which is out of range"),
    (lambda p, lp: lp.stability(1.0, 1.0, beta=0.0), r"beta = 0.0 is out of range; allowed: a finite number > 0"),
    (lambda p, lp: lp.loop_coefficients(beta=0.0), r"beta = 0.0 is out of range"),
    (lambda p, lp: lp.loop_coefficients(alpha=-0.5), r"alpha = -0.5 is out of range"),
    (lambda p, lp: lp.frequency_response([1.0], -1.0), r"P_gain = -1.0 is out of range"),
    (lambda p, lp: region_map(lp, [1.0], [1.0], beta=0.0), r"beta = 0.0 is out of range"),
    (lambda p, lp: passivity(lp, -1.0, 0.0), r"P_gain = -1.0 is out of range"),
    (lambda p, lp: step_response(lp, alpha=-1.0), r"alpha = -1.0 is out of range"),
    (lambda p, lp: torque_bandwidth(lp, beta=0.0), r"beta = 0.0 is out of range"),
    (lambda p, lp: contact_stability(ClosedLoop(p), [1.0], D_gain=-1.0), r"D_gain = -1.0 is out of range"),
])
def test_api_applies_the_same_gain_rule(params, loop, call, msg):
    with pytest.raises(ParameterError, match=msg):
        call(params, loop)


def test_dataclasses_validate_themselves(params):
    with pytest.raises(ParameterError, match=r"J_m = -1.0 is out of range; allowed: a finite number > 0"):
        params.plant.replace(J_m=-1.0)            # Plant validates itself (not a dataclass)
    with pytest.raises(ParameterError, match=r"beta = 0.0 is out of range"):
        dataclasses.replace(params.controller, beta=0.0)
    with pytest.raises(ParameterError, match=r"N_av = 2.5 is not an integer"):
        Controller(Ts=1e-3, N_av=2.5, alpha=0.9, beta=1.0, P_t0=0.4, I_t0=18.0)
    with pytest.raises(ParameterError, match=r"<memory> \[configurations.folded\]: J_L2 = -1 is out of range"):
        Params(params.plant, params.controller, {"folded": {"J_L2": -1}})
    with pytest.raises(ParameterError, match=r"plant = None; allowed: a haa_sym.Plant"):
        dataclasses.replace(params, plant=None)
    assert dataclasses.replace(params.controller, N_av=10.0).N_av == 10      # normalised to int
