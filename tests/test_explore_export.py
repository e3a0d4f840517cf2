"""The explorer's export (haa_sym.explore.export): the actuator file it writes loads back as the
parameters analysed (the configuration, the slider's position and the overrides applied), for
every bundled actuator; PNG and JSON are written with it, all or nothing."""
import json

import pytest

from haa_sym.errors import ParameterError
from haa_sym.explore.export import EXPORT_NAMES, actuator_toml, export_view
from haa_sym.explore.state import ViewState, resolve, to_query
from haa_sym.model.params import bundled_actuators, load_params
from haa_sym.model.structures import STRUCTURES


@pytest.mark.parametrize("name", sorted(bundled_actuators()))
def test_actuator_file_round_trip(name, tmp_path):
    p = load_params(bundled_actuators()[name])
    torque_pi = "beta" in STRUCTURES[p.controller.structure].keys    # the virtual wall has none
    state = ViewState(params=name).with_set("Ts", "0.0005")
    if torque_pi:
        state = state.with_set("beta", "2.5")
    key = p.plant.topology.parameter_keys[0]
    state = state.with_set(key, repr(getattr(p.plant, key) * 1.25))
    if len(p.configurations) >= 2:
        a, b = list(p.configurations)[:2]
        state = state.replace(configuration=a, blend_to=b, blend="0.3")
    analysed = resolve(state).params
    path = tmp_path / "a.toml"
    path.write_text(actuator_toml(analysed))
    back = load_params(path)
    assert back.plant == analysed.plant
    assert back.controller == analysed.controller
    assert back.configurations == analysed.configurations
    assert back.controller.beta == (2.5 if torque_pi else 1.0) and back.controller.Ts == 0.0005
    assert back.controller.structure == p.controller.structure


def test_export_view_writes_all_three(tmp_path):
    state = ViewState(P_gain="log:1:20000:30", D_gain="lin:1:50:15", point="200,10").with_set("beta", "2")
    paths = export_view(state, str(tmp_path / "out"))
    assert sorted(p.name for p in paths) == sorted(EXPORT_NAMES)
    data = json.loads((tmp_path / "out" / "view.json").read_text())
    assert data["query"] == to_query(state) and data["point"]["P_gain"] == 200.0
    assert (tmp_path / "out" / "view.png").read_bytes()[:4] == b"\x89PNG"


def test_export_refuses_before_writing(tmp_path):
    with pytest.raises(ParameterError, match="J_L2 = -1"):
        export_view(ViewState().with_set("J_L2", "-1"), str(tmp_path / "out"))
    assert not (tmp_path / "out").exists()


SMALL = ViewState(P_gain="log:1:20000:10", D_gain="lin:1:50:5")


def test_export_never_replaces_a_file(tmp_path):
    """Issue 26 item 2: an existing view.json was replaced without a word; now the export takes
    the first numbered set of names none of which exists."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "view.json").write_text("mine\n")
    (out / "view-3.png").symlink_to(tmp_path / "nowhere")             # a dangling link is a file too
    first = export_view(SMALL, str(out))
    assert [p.name for p in first] == ["actuator-2.toml", "view-2.png", "view-2.json"]
    assert (out / "view.json").read_text() == "mine\n"
    second = export_view(SMALL.with_set("beta", "2"), str(out))
    assert [p.name for p in second] == ["actuator-4.toml", "view-4.png", "view-4.json"]
    assert json.loads((out / "view-2.json").read_text())["query"] == to_query(SMALL)
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["view.json", "view-3.png"] + [p.name for p in first + second])


def test_export_never_replaces_the_file_explored(tmp_path, monkeypatch):
    """The export overwrote the actuator file being explored (its comments lost): it is kept,
    and writing over it is refused even if the names pointed at it (a hard link included)."""
    from haa_sym.errors import OutputError
    from haa_sym.explore import export
    out = tmp_path / "out"
    out.mkdir()
    source = out / "actuator.toml"
    text = "# my notes on this drive\n" + bundled_actuators()["sea"].read_text()
    source.write_text(text)
    state = SMALL.replace(params=str(source)).with_set("beta", "2")
    paths = export_view(state, str(out))
    assert source.read_text() == text and paths[0].name == "actuator-2.toml"
    assert load_params(paths[0]).controller.beta == 2.0
    link = tmp_path / "link.toml"
    link.hardlink_to(source)
    for target in (source, link):
        monkeypatch.setattr(export, "export_paths", lambda d, t=target: [t, out / "x.png", out / "x.json"])
        with pytest.raises(OutputError, match="is one of this command's inputs"):
            export_view(state, str(out))
        assert source.read_text() == text
