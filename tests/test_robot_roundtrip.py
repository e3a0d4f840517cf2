"""Export then import (issue 25, "Import of an MJCF with armature and gear round-trips with the
export"; docs/robot.md, "The round trip"): the MJCF export-mujoco writes, read by import-robot
into the same actuator file, gives back the port body's J, K, B and the motor's N and J_m."""
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.cli import main
from haa_sym.robot.importer import mujoco_available
from haa_sym.robot.mujoco_export import export_mujoco

pytestmark = pytest.mark.skipif(not mujoco_available(), reason="MuJoCo (haa_sym[mujoco]) not installed")


@pytest.mark.parametrize("name", ["hyq_haa", "sea", "qdd_leg"])
def test_export_then_import_gives_the_same_values(tmp_path, capsys, name):
    params = load_params(f"model/{name}.toml")
    port = params.plant.topology.port
    xml = tmp_path / f"{name}.xml"
    xml.write_text(export_mujoco(ClosedLoop(params), 100.0, 1.0).xml)
    out = tmp_path / "back.toml"
    assert main(["import-robot", str(xml), "--joint", port, "--configuration", "exported:",
                 "--merge", name, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "through the fixed tendon(s)" in text           # the motor found on the rotor's joint
    back = load_params(out).plant
    for flat in (f"J_{port}", f"K_{port}", f"B_{port}", "N", "J_m"):
        want = getattr(params.plant, flat)
        assert want > 0, flat                   # a value the import must find, not one it leaves
        assert getattr(back, flat) == pytest.approx(want, rel=1e-9, abs=0), flat
    c = load_params(out).configurations["exported"]
    assert c[f"J_{port}"] == pytest.approx(params.plant.as_dict()[f"J_{port}"], rel=1e-9)
    assert c[f"K_{port}"] == pytest.approx(params.plant.as_dict()[f"K_{port}"], rel=1e-9)


def test_import_writes_what_the_export_read(tmp_path, capsys):
    """The round trip through a file whose N, J_m, J, K and B differ from the merged one's: the
    values come from the MJCF, not from the file merged into."""
    changed = load_params("model/hyq_haa.toml").with_values(N=80.0, J_m=7e-5, J_L2=0.3, K_L2=9.5, B_L2=0.5)
    xml = tmp_path / "m.xml"
    xml.write_text(export_mujoco(ClosedLoop(changed), 100.0, 1.0).xml)
    out = tmp_path / "back.toml"
    assert main(["import-robot", str(xml), "--joint", "L2", "--configuration", "c:", "--merge", "hyq_haa",
                 "--out", str(out)]) == 0
    back = load_params(out).plant
    for flat, v in (("N", 80), ("J_m", 7e-5), ("J_L2", 0.3), ("K_L2", 9.5), ("B_L2", 0.5)):
        assert getattr(back, flat) == pytest.approx(v, rel=1e-9, abs=0), flat
