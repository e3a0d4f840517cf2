"""haa_sym.model.params: every bad-input case of a parameter file gives one clear error naming
file, key, value, allowed; Plant, Controller and Params validate themselves.

These use the legacy flat-[plant] HyQ file (tests/data/hyq_haa_legacy.toml, read as the HyQ
topology); the actuator format's own cases are in test_model_actuator.py."""
import dataclasses
import math
import re

import pytest

from haa_sym.errors import ParameterError
from haa_sym.model.params import CONTROLLER_KEYS, Controller, Params, load_params

from conftest import ROOT

GOOD = (ROOT / "tests" / "data" / "hyq_haa_legacy.toml").read_text()


def write(tmp_path, text):
    p = tmp_path / "act.toml"
    p.write_text(text)
    return p


def test_bundled_file_matches_table1(params):
    assert params.plant.J_m == 5.72e-5 and params.plant.N == 100
    assert params.configuration("extended").plant.J_L2 == 0.439
    assert params.configuration("retracted").plant.K_L2 == 7.17
    c = params.controller
    assert (c.Ts, c.N_av, c.alpha, c.beta) == (1e-3, 4, 0.94, 1.0)
    assert math.isclose(c.P_t, 0.382) and math.isclose(c.I_t, 18.0)
    assert params.plant.topology.parameter_keys == tuple(params.plant.as_dict())


@pytest.mark.parametrize("old,new,pieces", [
    ("J_m  = { value = 5.72e-5", "J_m  = { value = -5.72e-5", ["[plant]", "J_m", "-5.72e-05", "> 0"]),
    ("J_L1 = { value = 1e-4", "J_L1 = { value = 0.0", ["J_L1", "0.0", "> 0"]),
    ("Ts    = { value = 1e-3", "Ts    = { value = 0.0", ["[controller]", "Ts", "0.0", "a sampling time from 1e-06 to 1 s"]),
    ("Ts    = { value = 1e-3", "Ts    = { value = -1e-3", ["Ts", "-0.001", "a sampling time from 1e-06 to 1 s"]),
    ("N_av  = { value = 4,", "N_av  = { value = 0,", ["N_av", "0", "integer >= 1"]),
    ("N_av  = { value = 4,", "N_av  = { value = 2.5,", ["N_av", "2.5", "not an integer"]),
    ("alpha = { value = 0.94", "alpha = { value = nan", ["alpha", "nan", "not finite"]),
    ("K_hd = { value = 8.077e3", "K_hd = { value = inf", ["K_hd", "inf", "not finite"]),
    ("R    = { value = 3.32", 'R    = { value = "3.32"', ["R", "'3.32'", "not a number"]),
    ("B_L2 = { value = 0.756", "B_L2 = { value = -0.1", ["B_L2", "-0.1", ">= 0"]),
])
def test_bad_values(tmp_path, old, new, pieces):
    assert old in GOOD
    with pytest.raises(ParameterError) as exc:
        load_params(write(tmp_path, GOOD.replace(old, new, 1)))
    msg = str(exc.value)
    assert "act.toml" in msg
    for piece in pieces:
        assert piece in msg, (piece, msg)


def test_unknown_key(tmp_path):
    text = GOOD.replace("[controller]", "J_x = { value = 1.0, unit = \"-\" }\n\n[controller]", 1)
    with pytest.raises(ParameterError, match=r"act.toml \[plant\]: unknown key\(s\) \['J_x'\]; allowed"):
        load_params(write(tmp_path, text))


def test_missing_key(tmp_path):
    lines = [ln for ln in GOOD.splitlines() if not ln.startswith("D_p ")]
    with pytest.raises(ParameterError, match=r"missing key\(s\) \['D_p'\]"):
        load_params(write(tmp_path, "\n".join(lines)))


def test_unknown_configuration_key(tmp_path):
    text = GOOD.replace("[configurations.retracted]\nJ_L2 = 0.129", "[configurations.retracted]\nJ_L3 = 0.129")
    with pytest.raises(ParameterError, match=r"configurations.retracted\]: unknown key\(s\) \['J_L3'\]"):
        load_params(write(tmp_path, text))


def test_negative_configuration_value(tmp_path):
    text = GOOD.replace("[configurations.retracted]\nJ_L2 = 0.129", "[configurations.retracted]\nJ_L2 = -0.129")
    with pytest.raises(ParameterError, match=r"J_L2 = -0.129 is out of range; allowed: a finite number > 0"):
        load_params(write(tmp_path, text))


def test_bad_source_letter(tmp_path):
    text = GOOD.replace('source = "D", description = "Rotor', 'source = "X", description = "Rotor', 1)
    with pytest.raises(ParameterError, match=r"J_m: source = 'X'"):
        load_params(write(tmp_path, text))


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(ParameterError, match="no such parameter file"):
        load_params(tmp_path / "nope.toml")
    with pytest.raises(ParameterError, match="not valid TOML"):
        load_params(write(tmp_path, "[plant\n"))


def test_overrides_are_validated(params):
    assert params.with_values(N_av=10).controller.N_av == 10
    with pytest.raises(ParameterError, match=r"unknown parameter key\(s\) \['Nav'\]"):
        params.with_values(Nav=10)
    with pytest.raises(ParameterError, match=r"N_av = 0 is out of range"):
        params.with_values(N_av=0)
    with pytest.raises(ParameterError, match=r"J_L2 = nan is not finite"):
        params.with_values(J_L2=float("nan"))
    with pytest.raises(ParameterError, match="unknown configuration 'sitting'"):
        params.configuration("sitting")


def test_controller_keys_and_the_velocity_filter_default(params):
    assert CONTROLLER_KEYS == ("Ts", "N_av", "alpha", "beta", "P_t0", "I_t0", "velocity_filter", "f_c", "structure")
    # the paper's filter and structure are the stated defaults; a file need not name them
    assert params.controller.velocity_filter == "average" and params.controller.f_c is None
    assert params.controller.structure == "paper"
    lp = params.with_values(velocity_filter="lowpass1", f_c=40.0)
    assert lp.controller.velocity_filter == "lowpass1" and lp.controller.f_c == 40.0


@pytest.mark.parametrize("changes, message", [
    ({"velocity_filter": "median"}, "velocity_filter = 'median'; allowed: one of ['average', 'lowpass1', 'butterworth2']"),
    ({"velocity_filter": "lowpass1"}, "f_c is missing; allowed: a cut-off frequency in Hz, 0 < f_c < 500"),
    ({"velocity_filter": "butterworth2", "f_c": 500.0}, "f_c = 500.0 is at or above Nyquist 1/(2 Ts) = 500 Hz; allowed: 0 < f_c < 500"),
    ({"velocity_filter": "lowpass1", "f_c": -3.0}, "f_c = -3.0 is out of range; allowed: a finite number > 0"),
])
def test_velocity_filter_errors_name_the_key(params, changes, message):
    with pytest.raises(ParameterError, match=re.escape(message)):
        params.with_values(**changes)


def test_missing_N_av_for_the_average_is_one_clear_error(tmp_path):
    text = GOOD.replace("N_av  = { value = 4,", "#N_av = { value = 4,")
    f = tmp_path / "p.toml"
    f.write_text(text)
    with pytest.raises(ParameterError, match=r"\[controller\]: N_av is missing; allowed: an integer >= 1, "
                                             "required by velocity_filter = 'average'"):
        load_params(f)


def test_params_file_integer_beyond_float(tmp_path):
    text = (ROOT / "model" / "hyq_haa.toml").read_text().replace("K = { value = 8.077e3", "K = { value = 1" + "0" * 400, 1)
    (tmp_path / "big.toml").write_text(text)
    with pytest.raises(ParameterError, match=r"big.toml \[couplings.hd\]: K = 10{400} is not finite"):
        load_params(tmp_path / "big.toml")


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
