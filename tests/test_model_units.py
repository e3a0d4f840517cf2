"""Units are read (issue 16.1): every entry's ``unit`` is checked against its key's dimension and
converted to SI (haa_sym.model.units); a wrong dimension, a missing or extra angle, a reciprocal
and an unknown unit are one error naming the file, the key, the unit and what is allowed."""
import math
import subprocess
import sys
import tomllib

import numpy as np
import pytest

from haa_sym import ClosedLoop, ParameterError, region_map
from haa_sym.cli import main
from haa_sym.model.actuator import HYQ
from haa_sym.model.params import builtin_actuators, load_params
from haa_sym.model.units import CONTROLLER_UNITS, KINDS, _parse, to_si

from conftest import ROOT

HYQ_FILE = ROOT / "model" / "hyq_haa.toml"


def _toml(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"


def _dump(data: dict) -> str:
    """A minimal TOML writer for the parameter files' shape (tables of tables of entries)."""
    out = []

    def table(name, tab):
        # a dict with a "value" is an entry (an inline table); any other dict is a sub-table
        scalars = {k: v for k, v in tab.items() if not (isinstance(v, dict) and "value" not in v)}
        nested = {k: v for k, v in tab.items() if k not in scalars}
        out.append(f"[{name}]")
        out.extend(f"{k} = {_toml(v)}" for k, v in scalars.items())
        for k, v in nested.items():
            table(f"{name}.{k}", v)
    for name, tab in data.items():
        table(name, tab)
    return "\n".join(out) + "\n"


def _hyq_data() -> dict:
    with open(HYQ_FILE, "rb") as fh:
        return tomllib.load(fh)


def _write(tmp_path, data, name="x.toml"):
    path = tmp_path / name
    path.write_text(_dump(data))
    return path


def _other_units(data: dict) -> dict:
    """The HyQ file with entries in g cm^2, mNm/A, Nm/deg, ms, mH, mV/rpm, mNm s/rad, kHz-free."""
    def put(sec, key, value, unit):
        sec[key] = {**sec[key], "value": value, "unit": unit}
    m, b1, b2 = data["motor"], data["bodies"]["L1"], data["bodies"]["L2"]
    hd, p, c = data["couplings"]["hd"], data["couplings"]["p"], data["controller"]
    put(m, "J_m", 5.72e-5 * 1e7, "g cm^2")
    put(m, "k_t", 190.0, "mNm/A")
    put(m, "k_w", 0.19 * 1e3 * 2 * math.pi / 60, "mV/rpm")      # V s/rad -> mV per rev/min
    put(m, "L", 2.02, "mH")
    put(m, "R", 3320.0, "mOhm")
    put(m, "B_m", 1.5, "mNm s/rad")
    put(b1, "J", 1.0, "kg cm^2")
    put(b2, "K", 11.2 * math.pi / 180, "Nm/deg")
    put(hd, "K", 8.077e3 * math.pi / 180, "Nm/deg")
    put(p, "K", 1.923, "kNm/rad")
    put(p, "D", 7.56 * math.pi / 180, "Nm s/deg")
    put(c, "Ts", 1.0, "ms")
    data["configurations"]["retracted"]["J_L2"] = {"value": 0.129e7, "unit": "g cm^2"}
    return data


def _close(a, b):
    return abs(a - b) <= 1e-12 * abs(b)


def test_same_actuator_in_other_units_gives_the_same_params_and_map(tmp_path):
    si = load_params(_write(tmp_path, _hyq_data(), "si.toml"))
    other = load_params(_write(tmp_path, _other_units(_hyq_data()), "other.toml"))
    assert si.plant == load_params(HYQ_FILE).plant                     # the dump is faithful
    a, b = other.plant.as_dict(), si.plant.as_dict()
    assert a.keys() == b.keys()
    # the converted values differ in their last bits only (g cm^2 -> kg m^2 is a factor 1e-7)
    assert a != b
    assert all(_close(a[k], b[k]) for k in b), {k: (a[k], b[k]) for k in b if not _close(a[k], b[k])}
    assert _close(other.controller.Ts, si.controller.Ts) and other.controller.N_av == 4
    assert _close(other.configuration("retracted").plant.J_L2, 0.129)
    P, D = np.geomspace(1, 20000, 40), np.linspace(1, 50, 25)
    m_si = region_map(ClosedLoop(si), P, D, method="grid")
    m_other = region_map(ClosedLoop(other), P, D, method="grid")
    for name in ("stable", "low_pm", "passive"):
        assert np.array_equal(getattr(m_si, name), getattr(m_other, name)), name
    assert m_si.stable.any() and not m_si.stable.all()                  # a map that could differ


def test_bundled_files_read_without_pint_and_unchanged():
    """The SI spellings are read without pint (it costs 0.75 s a process) and keep every value."""
    code = ("import sys; from haa_sym.model.params import builtin_actuators, load_params\n"
            "[load_params(f) for f in builtin_actuators()]\n"
            "print('pint' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    for f in builtin_actuators():
        with open(f, "rb") as fh:
            data = tomllib.load(fh)
        p = load_params(f)
        for sec in ("motor",):
            for k, e in data[sec].items():
                if k == "convention":          # a name, not an entry (docs/model.md, "Motor constants")
                    assert p.motor_convention == e
                    continue
                assert getattr(p.plant, k) == e["value"]


@pytest.mark.parametrize("si", sorted(KINDS))
def test_every_si_spelling_is_what_pint_reads_as_factor_one(si):
    kind = KINDS[si]
    ref = _parse("-" if si in ("-", "samples") else si)
    for spelling in kind.spellings:
        got = _parse(spelling if spelling.strip() not in ("", "1") else "-")
        assert not isinstance(got, str), (spelling, got)
        assert got[1:] == ref[1:] and got[0] == ref[0], (spelling, got, ref)
    for example in kind.examples:                        # the examples a message offers convert
        got = _parse(example)
        assert got[1:] == ref[1:] and got[0] != ref[0], (example, got, ref)


def test_every_key_has_a_kind():
    assert set(HYQ.units.values()) | set(CONTROLLER_UNITS.values()) <= set(KINDS)
    for f in builtin_actuators():
        assert set(load_params(f).plant.topology.units.values()) <= set(KINDS)


@pytest.mark.parametrize("value,unit,si,expected", [
    (5720.0, "g cm^2", "kg m^2", 5.72e-4),
    (1.0, "Nm/deg", "Nm/rad", 180 / math.pi),
    (1.0, "mV/rpm", "V s/rad", 1e-3 * 60 / (2 * math.pi)),
    (1.0, "V/(rad/s)", "V s/rad", 1.0),
    (250.0, "us", "s", 2.5e-4),
    (0.1, "kHz", "Hz", 100.0),
    (2.0, "kNm/rad", "Nm/rad", 2000.0),
    (3.0, "mNm s/rad", "Nm s/rad", 3e-3),
    (5.0, "mV/Nm", "V/Nm", 5e-3),
])
def test_conversions(value, unit, si, expected):
    assert _close(to_si(value, unit, si, "f.toml [s]", "k"), expected)


def test_si_value_is_kept_exactly():
    """An integer in its SI unit stays an integer (N_av, a huge N_av's own message), a float
    is not multiplied by 1."""
    assert to_si(4, "samples", "samples", "f", "N_av") == 4 and isinstance(to_si(4, "-", "samples", "f", "N_av"), int)
    assert to_si(10**30, "samples", "samples", "f", "N_av") == 10**30


@pytest.mark.parametrize("section,key,unit,msg", [
    ("bodies.L2", "J", "Nm", r"\[bodies.L2\]: J: unit = 'Nm' is not a unit of inertia \(kg m\^2\); allowed: "
                             r"a unit of inertia, e.g. kg m\^2 \(SI\), g cm\^2"),
    ("motor", "L", "furlong/fortnight", r"\[motor\]: L: unit = 'furlong/fortnight' is not a unit of inductance"),
    ("motor", "R", "Ohms_typo", r"\[motor\]: R: unit = 'Ohms_typo' is not a unit pint can read \(UndefinedUnitError"
                                r".*\); allowed: a unit of resistance, e.g. Ohm \(SI\), mOhm"),
    ("couplings.hd", "K", "Nm", r"\[couplings.hd\]: K: unit = 'Nm' has no angle, but K is a rotational stiffness in "
                                r"Nm/rad \(angle\^-1\); allowed: a unit of rotational stiffness, e.g. Nm/rad \(SI\), "
                                r"Nm/deg"),
    ("motor", "k_w", "rpm/V", r"\[motor\]: k_w: unit = 'rpm/V' is the reciprocal of a back-EMF constant \(V s/rad\); "
                              r"allowed: .*give 1/value; for a speed constant K_v in rpm/V, k_w = 60/\(2 pi K_v\)"),
    ("motor", "k_w", "Nms/rad", r"\[motor\]: k_w: unit = 'Nms/rad' is not a unit of back-EMF constant"),
    ("motor", "N", "rad", r"\[motor\]: N: unit = 'rad' has angle\^1, but N is a dimensionless number"),
    ("controller", "Ts", "Hz", r"\[controller\]: Ts: unit = 'Hz' is the reciprocal of a time \(s\)"),
    ("controller", "Ts", "kg m^", r"\[controller\]: Ts: unit = 'kg m\^' is not a unit pint can read"),
    ("controller", "N_av", "s", r"\[controller\]: N_av: unit = 's' is not a unit of number of samples"),
])
def test_wrong_units_are_refused(tmp_path, section, key, unit, msg):
    data = _hyq_data()
    tab = data
    for part in section.split("."):
        tab = tab[part]
    tab[key] = {**tab[key], "unit": unit}
    path = _write(tmp_path, data)
    with pytest.raises(ParameterError, match=msg) as exc:
        load_params(path)
    text = str(exc.value)
    assert text.startswith(f"{path} [{section}]: {key}: unit = {unit!r}") and "\n" not in text


def test_f_c_in_rad_per_s_is_refused(tmp_path):
    data = _hyq_data()
    data["controller"]["velocity_filter"] = "lowpass1"
    data["controller"]["f_c"] = {"value": 100.0, "unit": "rad/s"}
    with pytest.raises(ParameterError, match=r"f_c: unit = 'rad/s' has angle\^1, but f_c is a frequency in cycles "
                                             r"per second in Hz \(no angle\).*rad/s is 2 pi Hz"):
        load_params(_write(tmp_path, data))
    data["controller"]["f_c"] = {"value": 0.1, "unit": "kHz"}
    assert load_params(_write(tmp_path, data)).controller.f_c == 100.0
    data["controller"]["velocity_filter"] = {"value": "lowpass1", "unit": "Hz"}
    with pytest.raises(ParameterError, match=r"velocity_filter: unit = 'Hz', but velocity_filter is a name"):
        load_params(_write(tmp_path, data))


def test_configuration_units(tmp_path):
    data = _hyq_data()
    data["configurations"]["retracted"]["K_L2"] = {"value": 7.17, "unit": "Nm"}
    with pytest.raises(ParameterError, match=r"\[configurations.retracted\]: K_L2: unit = 'Nm' has no angle"):
        load_params(_write(tmp_path, data))


def test_cli_exit_2_one_line(tmp_path, capsys):
    data = _hyq_data()
    data["bodies"]["L2"]["J"] = {**data["bodies"]["L2"]["J"], "unit": "Nm"}
    path = _write(tmp_path, data, "bad.toml")
    out = tmp_path / "m.npz"
    rc = main(["regions", "--params", str(path), "--P-gain", "1,10", "--D-gain", "1,2", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and not out.exists()
    assert err == (f"haa-sym: error: {path} [bodies.L2]: J: unit = 'Nm' is not a unit of inertia (kg m^2); "
                   "allowed: a unit of inertia, e.g. kg m^2 (SI), g cm^2, kg cm^2, kg mm^2\n")


def test_set_help_says_si(capsys):
    with pytest.raises(SystemExit):
        main(["regions", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "the value in SI units whatever unit the file gives (kg m^2, Nm/rad" in help_text
