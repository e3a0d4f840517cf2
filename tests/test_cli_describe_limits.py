"""haa-sym describe reads the file's [limits] when no --limit is given, and takes the [limits] name
torque_resolution for the describing function's T_res (one name per concept)."""
import json

from haa_sym.cli import main
from haa_sym.model.params import actuator_path


def _with_limits(tmp_path, section: str):
    path = tmp_path / "hyq_limits.toml"
    path.write_text(actuator_path("hyq_haa").read_text() + "\n[limits]\n" + section)
    return path


def test_the_files_limits_are_predicted_without_limit_flags(tmp_path):
    f = _with_limits(tmp_path, 'V_max = { value = 24, unit = "V", source = "-", description = "supply" }\n')
    out_file, flag = tmp_path / "file.json", tmp_path / "flag.json"
    assert main(["describe", "--params", str(f), "--P-gain", "3000", "--D-gain", "1", "--out", str(out_file)]) == 0
    assert main(["describe", "--P-gain", "3000", "--D-gain", "1", "--limit", "V_max=24", "--out", str(flag)]) == 0
    a, b = (_cycles(p) for p in (out_file, flag))
    assert a == b and len(a) == 1 and a[0]["limit_cycles"]


def test_torque_resolution_is_t_res(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    args = ["describe", "--P-gain", "3000", "--D-gain", "1"]
    assert main(args + ["--limit", "torque_resolution=0.1", "--out", str(a)]) == 0
    assert main(args + ["--limit", "T_res=0.1", "--out", str(b)]) == 0
    assert _cycles(a) == _cycles(b)


def _cycles(path):
    """The predictions of a describe JSON without their meta (which names the parameter file)."""
    return [{k: v for k, v in p.items() if k != "meta"} for p in json.loads(path.read_text())["predictions"]]


def test_no_limit_anywhere_is_one_line(capsys):
    assert main(["describe", "--P-gain", "3000", "--D-gain", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "[limits]" in err[0] and "--limit" in err[0]


def test_subnormal_quantum_is_one_line(capsys):
    """T_res = 1e-310 (subnormal) left the root finding no digits: xtol 0, a ValueError traceback."""
    assert main(["describe", "--P-gain", "1000", "--D-gain", "10", "--set", "beta=3", "--limit", "T_res=1e-310"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["haa-sym: error: --limit: T_res = 1e-310; allowed: a number from 1e-100 to 1e+100 (Nm)"]
