"""The [limits] section of an actuator file (issue 19, part 1): read in SI with units checked,
absent means off, and every bad entry is one line naming file, section, key and what is allowed,
exit 2 from the command line with nothing written."""
import pytest

from haa_sym.errors import ParameterError
from haa_sym.model.limits import DEFAULT_FRICTION_VELOCITY, Limits, parse_limits
from haa_sym.model.params import load_params
from haa_sym.model.resources import data_dir

BASE = (data_dir("model") / "hyq_haa.toml").read_text()


def _file(tmp_path, limits: str):
    p = tmp_path.parent / f"{tmp_path.name}-lim.toml"
    p.write_text(BASE + "\n[limits]\n" + limits + "\n")
    return p


def test_bundled_file_has_no_limits():
    assert load_params().limits == Limits()
    assert Limits().active == {}


def test_limits_are_read_in_si(tmp_path):
    p = _file(tmp_path, "\n".join([
        'V_max = { value = 24000, unit = "mV", source = "-", description = "supply" }',
        'I_max = { value = 5, unit = "A", source = "D", description = "drive limit" }',
        'Fc_m = { value = 20, unit = "mNm", source = "I", description = "rotor friction" }',
        'Fc_L2 = { value = 0.8, unit = "Nm", source = "I", description = "leg friction" }',
        'encoder_counts = { value = 4096, unit = "-", source = "D", description = "counts per revolution" }',
        'torque_resolution = 0.05',
        'torque_noise = { value = 10, unit = "mNm", source = "-", description = "rms" }',
        'jitter = { value = 20, unit = "us", source = "-", description = "rms" }',
        'friction_velocity = { value = 6, unit = "deg/s", source = "-", description = "v_s" }',
        'friction_model = "tanh"']))
    lim = load_params(p).limits
    assert lim.V_max == pytest.approx(24.0) and lim.I_max == 5.0
    assert lim.friction == pytest.approx({"m": 0.02, "L2": 0.8})
    assert lim.encoder_counts == 4096 and isinstance(lim.encoder_counts, int)
    assert lim.torque_resolution == 0.05 and lim.torque_noise == pytest.approx(0.01)
    assert lim.jitter == pytest.approx(2e-5)
    assert lim.friction_velocity == pytest.approx(6 * 3.141592653589793 / 180)
    assert lim.friction_model == "tanh"


def test_friction_velocity_default():
    assert parse_limits({"Fc_m": 0.01}, ("L1", "L2")).friction_velocity == DEFAULT_FRICTION_VELOCITY


BAD = [
    ("V_max = 0", "V_max = 0 is out of range; allowed: a number > 0 (V)"),
    ("V_max = -24", "V_max = -24 is out of range"),
    ('V_max = "24 V"', "V_max = '24 V' is not a number"),
    ("V_max = inf", "V_max = inf is not finite"),
    ('V_max = { value = 24, unit = "A" }', "V_max: unit = 'A' is not a unit of voltage (V)"),
    ('I_max = { value = 5, unit = "V" }', "I_max: unit = 'V' is not a unit of current (A)"),
    ("I_max = nan", "I_max = nan is not finite"),
    ("Fc_m = -0.1", "Fc_m = -0.1 is out of range; allowed: a number >= 0 (Nm)"),
    ('Fc_L1 = { value = 0.1, unit = "Nm/rad" }', "Fc_L1: unit = 'Nm/rad' has angle^-1"),
    ("Fc_L3 = 0.1", "unknown key(s) ['Fc_L3']; allowed: ['V_max', 'I_max', 'Fc_m', 'Fc_L1', 'Fc_L2'"),
    ("encoder_counts = 10.5", "encoder_counts = 10.5 is out of range; allowed: an integer >= 1"),
    ("encoder_counts = 0", "encoder_counts = 0 is out of range"),
    ("torque_resolution = -1", "torque_resolution = -1 is out of range; allowed: a number >= 0 (Nm"),
    ("torque_noise = -0.1", "torque_noise = -0.1 is out of range"),
    ('jitter = { value = 1, unit = "Hz" }', "jitter: unit = 'Hz' is the reciprocal of a time (s)"),
    ("jitter = -1e-6", "jitter = -1e-06 is out of range"),
    ("friction_velocity = 0", "friction_velocity = 0 is out of range; allowed: a number > 0 (rad/s)"),
    ('friction_velocity = { value = 1, unit = "Nm" }', "friction_velocity: unit = 'Nm'"),
    ('friction_model = "stick-slip"', "friction_model = 'stick-slip' is not implemented; allowed: ['tanh']"),
    ('friction_model = "coulomb"', "friction_model = 'coulomb'; allowed: ['tanh']"),
    ('V_max = { value = 24, colour = "red" }', "V_max: unknown field(s) ['colour']"),
    ('V_max = { value = 24, source = "Z" }', "V_max: source = 'Z'"),
    ('V_max = { unit = "V" }', "V_max: missing field 'value'"),
]


@pytest.mark.parametrize("entry, message", BAD)
def test_every_bad_entry_is_one_line(tmp_path, entry, message):
    p = _file(tmp_path, entry)
    with pytest.raises(ParameterError) as e:
        load_params(p)
    text = str(e.value)
    assert "\n" not in text and text.startswith(f"{p} [limits]: ") and message in text, text


def test_limits_not_a_table(tmp_path):
    p = tmp_path.parent / f"{tmp_path.name}-lim.toml"
    p.write_text(BASE.replace("[about]", "limits = 3\n\n[about]", 1))
    with pytest.raises(ParameterError, match=r"\[limits\] = 3; allowed: a table"):
        load_params(p)


@pytest.mark.parametrize("entry, message", [BAD[0], BAD[9], BAD[18]])
def test_bad_entries_exit_2_from_the_command_line(tmp_path, assert_refused, entry, message):
    p = _file(tmp_path, entry)
    assert_refused(["simulate", "--params", str(p), "--P-gain", "100", "--D-gain", "1", "--experiment",
                    "deflection", "--duration", "0.1", "--out", str(tmp_path / "sim.csv")], message)
