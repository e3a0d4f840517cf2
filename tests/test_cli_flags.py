"""One meaning per flag (issue 16.10): --P-gain / --D-gain are grids everywhere, point commands
take the grid's points, every --help shows syntax, units and default, `haa-sym options` lists
--set keys and --option values, and reproduce checks its configurations before any work."""
import re
import time

import pytest

from haa_sym.cli import main
from haa_sym.cli.common import MAP_D_GAIN
from haa_sym.loop import LoopOptions
from haa_sym.model.params import CONTROLLER_KEYS, bundled_actuators, load_params

COMMANDS_WITH_GAINS = ["regions", "boundary", "schedule", "passivity", "stability", "margins", "contact"]


def helptext(capsys, *argv):
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0
    # argparse wraps lines; compare the words
    return " ".join(capsys.readouterr().out.split())


@pytest.mark.parametrize("cmd", COMMANDS_WITH_GAINS)
def test_every_help_shows_syntax_units_and_default(cmd, capsys):
    text = helptext(capsys, cmd)
    text = text[text.index("options:"):]                # past the usage line
    for flag, unit in (("--P-gain", "Nm/rad"), ("--D-gain", "Nms/rad")):
        m = re.search(re.escape(flag) + r" GRID (.*?)(?= --|$)", text)
        assert m, text
        h = m.group(1)
        assert unit in h and "log:START:STOP:N, lin:START:STOP:N, V1,V2,... or one value V" in h, h
        assert "default " in h or "required" in h, h


def test_top_level_help_has_an_example_per_command_and_the_grid_rule(capsys):
    text = helptext(capsys)
    sub = ["regions", "boundary", "schedule", "passivity", "stability", "margins", "contact", "step",
           "reproduce", "verify", "compile", "actuators", "options"]
    for cmd in sub:
        assert f"haa-sym {cmd} " in text, cmd
    assert "the i-th P_gain with the i-th D_gain" in text and "axes of a map" in text


def test_regions_and_boundary_share_the_default_d_gain(capsys):
    for cmd in ("regions", "boundary"):
        assert f"default {MAP_D_GAIN}" in helptext(capsys, cmd)
    assert MAP_D_GAIN == "lin:1:50:100"


def out_of(capsys, *argv):
    assert main(list(argv)) == 0
    return capsys.readouterr().out


def test_stability_takes_several_points_one_line_each(capsys):
    both = out_of(capsys, "stability", "--P-gain", "200,2000", "--D-gain", "10").splitlines()
    assert len(both) == 2
    for line, P in zip(both, ("200", "2000")):
        single = out_of(capsys, "stability", "--P-gain", P, "--D-gain", "10").strip()
        assert line == f"P_gain {P}  D_gain 10: {single}"
    # the decisions differ, so the pairing is visible
    assert "stable: True" in both[0] and "stable: False" in both[1]


def test_a_grid_spec_is_the_same_points_as_its_list(capsys):
    a = out_of(capsys, "stability", "--P-gain", "lin:100:300:3", "--D-gain", "5")
    b = out_of(capsys, "stability", "--P-gain", "100,200,300", "--D-gain", "5,5,5")
    assert a == b and len(a.splitlines()) == 3


def test_margins_of_several_points_are_the_single_blocks(capsys):
    both = out_of(capsys, "margins", "--P-gain", "0,200", "--D-gain", "0,10")
    blocks = [out_of(capsys, "margins", "--P-gain", P, "--D-gain", D) for P, D in (("0", "0"), ("200", "10"))]
    footer = blocks[0].splitlines()[-1]
    assert blocks[1].splitlines()[-1] == footer
    body = [b.rsplit(footer, 1)[0] for b in blocks]
    assert both == f"P_gain 0  D_gain 0:\n{body[0]}P_gain 200  D_gain 10:\n{body[1]}{footer}\n"


def test_passivity_pairs_and_one_value_pairs_with_all(capsys):
    paired = out_of(capsys, "passivity", "--P-gain", "0,200", "--D-gain", "10")
    lines = paired.splitlines()
    assert lines[0].startswith("P_gain 0  D_gain 10:") and lines[1].startswith("P_gain 200  D_gain 10:")
    assert out_of(capsys, "passivity", "--P-gain", "0,200", "--D-gain", "10,10") == paired


@pytest.mark.parametrize("argv,msg", [
    (["passivity", "--P-gain", "1,2", "--D-gain", "1,2,3"],
     "--P-gain '1,2' gives 2 values and --D-gain '1,2,3' 3; they pair up"),
    (["contact", "--P-gain", "0,200", "--D-gain", "0,10"],
     "gives 2 points; allowed: one point (contact scans the environment stiffness at one impedance)"),
    (["margins", "--P-gain", "lin:1:2", "--D-gain", "1"], "--P-gain = 'lin:1:2': expected 3 fields"),
    (["stability", "--P-gain", "-1", "--D-gain", "1"], "--P-gain = -1.0 is out of range; allowed: a finite number >= 0 (Nm/rad)"),
])
def test_point_errors_are_one_line(argv, msg, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and msg in err, err


@pytest.mark.parametrize("name", sorted(bundled_actuators()))
def test_options_lists_every_set_key_with_unit_and_every_option(name, capsys):
    out = out_of(capsys, "options", "--params", name)
    params = load_params(name)
    top = params.plant.topology
    rows = {r[0]: r for r in (re.split(r"\s{2,}", line.strip()) for line in out.splitlines() if line.startswith("  "))}
    for key in top.parameter_keys:
        assert rows[key][1] == top.units[key], key
        assert float(rows[key][2]) == pytest.approx(params.plant.as_dict()[key], rel=1e-5)
    for key in CONTROLLER_KEYS:
        assert key in rows
    assert rows["Ts"][1] == "s" and rows["f_c"][1] == "Hz"
    for field in LoopOptions.field_names():
        assert field in rows, field
    assert rows["pm_rule"][2] == "distance" and "min_abs" in rows["pm_rule"][3]
    assert rows["delay"][1:3] == ["int", "0"]


def test_options_shows_values_after_set_and_configuration(capsys):
    out = out_of(capsys, "options", "--configuration", "retracted", "--set", "beta=2.5")
    rows = {r[0]: r for r in (re.split(r"\s{2,}", line.strip()) for line in out.splitlines() if line.startswith("  "))}
    assert rows["beta"][2] == "2.5"
    assert float(rows["J_L2"][2]) == load_params().configuration("retracted").plant.J_L2


def test_reproduce_checks_the_configurations_before_any_work(tmp_path, capsys, monkeypatch):
    from haa_sym.paper import reproduce as rp
    monkeypatch.setattr(rp, "region_map", lambda *a, **k: pytest.fail("work started"))
    monkeypatch.setattr(rp, "Transaction", lambda *a, **k: pytest.fail("output staged"))
    t0 = time.perf_counter()
    rc = main(["reproduce", "--params", "sea", "--out", str(tmp_path / "r")])
    assert time.perf_counter() - t0 < 2.0
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1
    assert "sea.toml: Fig. 11 (d) of model/paper.toml" in err and "unknown configuration 'retracted'" in err
    assert list(tmp_path.iterdir()) == []
