"""The [drive] section (haa_sym.model.drive): parsed, unit-converted, validated, carried by Params."""
import pytest

from haa_sym.errors import ParameterError
from haa_sym.model.drive import Drive, parse_drive
from haa_sym.model.params import apply_sets, load_params, parse_params, set_keys

import tomllib
from haa_sym.model.resources import data_dir


def _sea_with(drive_text: str):
    text = (data_dir("model") / "sea.toml").read_text() + "\n[drive]\n" + drive_text
    return parse_params(tomllib.loads(text), "sea+drive.toml")


def test_units_and_declared():
    p = _sea_with('tau_drive = { value = 34, unit = "ms", description = "lag" }\ndelay_drive = 0.004\n')
    assert p.drive.tau_drive == pytest.approx(0.034)
    assert p.drive.delay_drive == 0.004
    assert p.drive.declared == ("delay_drive", "tau_drive")
    assert p.to_dict()["drive"] == {"tau_drive": pytest.approx(0.034), "delay_drive": 0.004}


def test_absent_section_is_no_drive():
    p = load_params()
    assert p.drive == Drive() and not p.drive.active and p.drive.declared == ()


@pytest.mark.parametrize("text, fragment", [
    ("tau_drive = -0.01\n", "tau_drive = -0.01 is out of range; allowed: a number in [0, 10]"),
    ("delay_drive = 2.0\n", "delay_drive = 2.0 is out of range; allowed: a number in [0, 1]"),
    ("delay_drive = nan\n", "is not finite"),
    ('tau_drive = "fast"\n', "is not a number"),
    ("lag = 0.01\n", "unknown key(s) ['lag']; allowed: ['tau_drive', 'delay_drive']"),
])
def test_bad_entries_name_file_section_key(text, fragment):
    with pytest.raises(ParameterError) as exc:
        _sea_with(text)
    msg = str(exc.value)
    assert msg.startswith("sea+drive.toml [drive]: ") and fragment in msg and "\n" not in msg


def test_drive_takes_part_in_equality_and_set():
    p = load_params()
    q = apply_sets(p, {"delay_drive": 0.0005})
    assert q != p and q.drive.delay_drive == 0.0005 and q.drive.declared == ("delay_drive",)
    assert apply_sets(q, {"delay_drive": 0.0}) == p
    with pytest.raises(ParameterError, match=r"^--set tau_drive=-1: tau_drive = -1 is out of range"):
        apply_sets(p, {"tau_drive": -1})
    assert [r[0] for r in set_keys(p)][-2:] == ["tau_drive", "delay_drive"]


def test_parse_drive_rejects_non_table():
    with pytest.raises(ParameterError, match=r"\[drive\] = 3; allowed: a table"):
        parse_drive(3, "f.toml")
