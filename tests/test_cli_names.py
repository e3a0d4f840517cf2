"""Bundled actuators by name wherever a file is accepted (issue 16.6)."""
import pytest

from haa_sym import load_params
from haa_sym.cli import main
from haa_sym.errors import ParameterError
from haa_sym.model.params import ALIASES, actuator_path, builtin_actuators, bundled_actuators

NAMES = ["haptic_wall", "harmonic_drive", "hyq_haa", "qdd_leg", "sea"]


def test_the_bundled_names_are_the_bundled_files():
    assert sorted(bundled_actuators()) == NAMES
    assert sorted(bundled_actuators().values()) == builtin_actuators()


@pytest.mark.parametrize("name", NAMES + list(ALIASES))
def test_load_params_by_name_from_any_directory(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)                      # no model/ here
    p = load_params(name)
    stem = ALIASES.get(name, name)
    assert p.source == str(bundled_actuators()[stem])
    assert p == load_params(bundled_actuators()[stem])


def test_hyq_is_the_default():
    assert load_params("hyq") == load_params() == load_params("hyq_haa")
    assert load_params("sea") != load_params()


def test_an_existing_file_wins_over_a_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sea").write_text(bundled_actuators()["harmonic_drive"].read_text())
    assert actuator_path("sea") == tmp_path.joinpath("sea").relative_to(tmp_path)
    assert load_params("sea").plant.topology == load_params("harmonic_drive").plant.topology


@pytest.mark.parametrize("argv", [
    ["stability", "--params", "seaa", "--P-gain", "1", "--D-gain", "1"],
    ["regions", "--params", "seaa"],
    ["compile", "seaa"],
    ["verify", "--params", "seaa"],
])
def test_unknown_name_exits_2_listing_the_names(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "'seaa': no such parameter file, nor a bundled actuator" in err
    assert "harmonic_drive, hyq_haa, qdd_leg, sea, hyq (= hyq_haa)" in err


def test_unknown_name_in_the_api_names_the_value():
    with pytest.raises(ParameterError, match=r"'hyq.toml': no such parameter file, nor a bundled actuator; "
                                             r"allowed: a TOML file or a bundled name: haptic_wall, harmonic_drive"):
        load_params("hyq.toml")


def test_cli_params_by_name_equals_the_file(capsys):
    f = str(bundled_actuators()["sea"])
    outs = []
    for params in ("sea", f):
        assert main(["stability", "--params", params, "--P-gain", "100", "--D-gain", "5"]) == 0
        outs.append(capsys.readouterr().out)
    assert outs[0] == outs[1] and "spectral radius" in outs[0]


def test_compile_by_name(capsys):
    assert main(["compile", "harmonic_drive"]) == 0
    out = capsys.readouterr().out
    assert "harmonic_drive.toml: topology" in out and "is built in" in out


def test_actuators_lists_name_description_configurations_and_path(capsys):
    assert main(["actuators"]) == 0
    out = capsys.readouterr().out
    for name, path in bundled_actuators().items():
        p = load_params(path)
        start = 0 if out.startswith(name) else out.index(f"\n{name}") + 1
        block = out[start:]
        assert block.splitlines()[1].strip() == p.about["description"]
        assert f"  configurations: {', '.join(p.configurations)}" in block
        assert f"  file: {path}" in block
        assert path.is_file()
    assert "hyq_haa (alias hyq): HyQ HAA joint" in out


def test_names_resolve_through_the_package_data_not_the_working_tree(tmp_path, monkeypatch, capsys):
    # an installed package reads model/ from haa_sym/_model (haa_sym.model.resources.data_dir):
    # point data_dir at a copy and run from elsewhere; the names follow it
    import shutil

    from haa_sym.model import params as params_module
    copy = tmp_path / "_model"
    shutil.copytree(bundled_actuators()["sea"].parent, copy)
    monkeypatch.setattr(params_module, "data_dir", lambda name: copy)
    monkeypatch.chdir(tmp_path)
    assert bundled_actuators()["sea"] == copy / "sea.toml"
    assert load_params("hyq").source == str(copy / "hyq_haa.toml")
    assert main(["actuators"]) == 0
    assert f"  file: {copy / 'harmonic_drive.toml'}" in capsys.readouterr().out


@pytest.mark.parametrize("command", ["simulate", "identify", "export-mujoco"])
def test_params_help_names_every_bundled_actuator(command, capsys):
    """--help's --params text names each bundled actuator (the QDD leg and the haptic wall were
    left out of a hand-written list) and the alias with its file."""
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for name in NAMES:
        assert name in text.split("--params NAME|FILE", 1)[1].split("default: hyq_haa", 1)[0], (command, name)
    assert "hyq_haa or hyq" in text
