"""haa-sym import-robot (issue 25, item 1): a joint's leg inertia and gravity stiffness from a URDF
or MJCF, written into an actuator file.

The HyQ values are checked against a computation written here independently of the import (no
MuJoCo: the URDF's <inertial> tags and joint transforms parsed with xml.etree, the kinematics in
numpy), within 1e-9 relative; the gravity stiffness also against a second difference of the
potential energy. tests/data/robots/hyq_description holds HyQ's URDF with its Apache-2.0 licence.
"""
import math
import tomllib
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from conftest import ROOT

from haa_sym.cli import main
from haa_sym.model.params import load_params
from haa_sym.robot.importer import mujoco_available

# every test but the last needs MuJoCo (the test extra installs it); the last checks its absence
needs_mujoco = pytest.mark.skipif(not mujoco_available(), reason="MuJoCo (haa_sym[mujoco]) not installed")

DATA = ROOT / "tests" / "data" / "robots"
HYQ = DATA / "hyq_description" / "hyq_no_sensors.urdf"
MJCF = DATA / "two_link_leg.xml"
# the LF leg at the HFE/KFE limits of the URDF (the text of its <limit> tags)
EXTENDED = {"lf_hfe_joint": 0.0, "lf_kfe_joint": -0.349065850399}
FOLDED = {"lf_hfe_joint": 1.2217304764, "lf_kfe_joint": -2.44346095279}
G = np.array([0.0, 0.0, -9.81])


# ---- the independent reference: URDF kinematics in numpy -----------------------------------------
def _rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx                       # URDF: fixed-axis roll, pitch, yaw


def _origin(el):
    o = el.find("origin") if el is not None else None
    xyz = [float(v) for v in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()]
    rpy = [float(v) for v in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()]
    return _rpy(*rpy), np.array(xyz)


def _axis_angle(axis, q):
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(q) * K + (1 - math.cos(q)) * K @ K


def _rigid(I):
    """The import's documented rule: a tensor that is not a rigid body's loses its products."""
    e = np.linalg.eigvalsh(I)
    if not I.any() or (e.min() > 0 and e[0] + e[1] >= e[2]):
        return I
    return np.diag(np.diag(I))


def reference(path, joint, values, g=G):
    """(J, K, potential energy function) of the links distal to ``joint`` at ``values``."""
    root = ET.parse(path).getroot()
    joints = {j.get("name"): j for j in root.findall("joint")}     # not <transmission>'s
    links = {l.get("name"): l for l in root.findall("link")}
    parent_joint = {j.find("child").get("link"): j for j in joints.values()}
    base = next(n for n in links if n not in parent_joint)

    def poses(q):
        out = {base: (np.eye(3), np.zeros(3))}

        def pose(link):
            if link not in out:
                j = parent_joint[link]
                Rp, pp = pose(j.find("parent").get("link"))
                Ro, po = _origin(j)
                R, p = Rp @ Ro, pp + Rp @ po
                if j.get("type") in ("revolute", "continuous"):
                    ax = np.array([float(v) for v in j.find("axis").get("xyz").split()])
                    R = R @ _axis_angle(ax, q.get(j.get("name"), 0.0))
                out[link] = (R, p)
            return out[link]
        for n in links:
            pose(n)
        return out

    distal, todo = set(), [joints[joint].find("child").get("link")]
    while todo:
        n = todo.pop()
        distal.add(n)
        todo += [j.find("child").get("link") for j in joints.values() if j.find("parent").get("link") == n]

    def bodies(q):
        P = poses(q)
        for n in distal:
            inertial = links[n].find("inertial")
            if inertial is None:
                continue
            R, p = P[n]
            Ri, pi = _origin(inertial)
            t = inertial.find("inertia")
            v = {k: float(t.get(k, 0)) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
            I = _rigid(np.array([[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]],
                                 [v["ixz"], v["iyz"], v["izz"]]]))
            yield float(inertial.find("mass").get("value")), p + R @ pi, (R @ Ri) @ I @ (R @ Ri).T

    j = joints[joint]
    P = poses(values)
    Rp, pp = P[j.find("parent").get("link")]
    Ro, po = _origin(j)
    ax = np.array([float(v) for v in j.find("axis").get("xyz").split()])
    a, p0 = Rp @ Ro @ (ax / np.linalg.norm(ax)), pp + Rp @ po
    J = K = 0.0
    for m, c, I in bodies(values):
        r = c - p0
        J += a @ I @ a + m * np.cross(a, r) @ np.cross(a, r)
        K += m * (g @ r - (g @ a) * (a @ r))        # -m g . (a x (a x r)), expanded
    V = lambda dq: -sum(m * g @ c for m, c, _ in bodies({**values, joint: values.get(joint, 0.0) + dq}))
    return J, K, V


# ---- the command ----------------------------------------------------------------------------------
def _import(tmp_path, capsys, *extra, description=HYQ, joint="lf_haa_joint"):
    out = tmp_path / "out.toml"
    rc = main(["import-robot", str(description), "--joint", joint, *extra, "--out", str(out)])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    return out, printed


def _cfg(name, values):
    return ["--configuration", f"{name}:" + ",".join(f"{k}={v!r}" for k, v in values.items())]


@needs_mujoco
def test_hyq_inertia_and_gravity_stiffness_against_numpy(tmp_path, capsys):
    assert "package://" in HYQ.read_text()        # meshes that are not here: the import must not need them
    out, printed = _import(tmp_path, capsys, *_cfg("extended", EXTENDED), *_cfg("retracted", FOLDED),
                           "--merge", "hyq_haa", "--skip", "B_L2")
    p = load_params(out)
    for name, values in (("extended", EXTENDED), ("retracted", FOLDED)):
        J, K, V = reference(HYQ, "lf_haa_joint", values)
        c = p.configurations[name]
        assert c["J_L2"] == pytest.approx(J, rel=1e-9, abs=0)
        assert c["K_L2"] == pytest.approx(K, rel=1e-9, abs=0)
        h = 1e-3                                   # K = d^2 V / dq^2 > 0: restoring (sign and formula)
        assert (V(h) - 2 * V(0) + V(-h)) / h ** 2 == pytest.approx(K, rel=1e-5)
    # the first configuration is the body's own value; everything else of hyq_haa stays
    assert p.plant.J_L2 == p.configurations["extended"]["J_L2"] and p.plant.K_L2 == p.configurations["extended"]["K_L2"]
    base = load_params("hyq_haa")
    assert {k: v for k, v in p.plant.as_dict().items() if k not in ("J_L2", "K_L2")} == \
           {k: v for k, v in base.plant.as_dict().items() if k not in ("J_L2", "K_L2")}
    assert p.controller == base.controller
    # the measured range, and within 4-7 % of Table 1 (0.439 / 0.129 kg m^2, 11.2 / 7.17 Nm/rad)
    e, f = p.configurations["extended"], p.configurations["retracted"]
    assert e["J_L2"] == pytest.approx(0.4542, abs=1e-4) and f["J_L2"] == pytest.approx(0.1336, abs=1e-4)
    assert e["K_L2"] == pytest.approx(11.93, abs=0.01) and f["K_L2"] == pytest.approx(7.365, abs=0.01)
    for got, table in ((e["J_L2"], 0.439), (f["J_L2"], 0.129), (e["K_L2"], 11.2), (f["K_L2"], 7.17)):
        assert 0.02 < got / table - 1 < 0.07
    data = tomllib.loads(out.read_text())
    ref = data["bodies"]["L2"]["J"]["source"]
    cite = data["about"]["references"][ref]
    assert "hyq_no_sensors.urdf" in cite and "lf_haa_joint" in cite and "lf_kfe_joint=-0.349065850399" in cite
    assert data["bodies"]["L2"]["B"]["source"] == "I"              # --skip B_L2: the identified damping stays
    assert "# HyQ hip abduction/adduction (HAA) joint" in out.read_text()   # comments kept
    assert "lf_foot" in printed and "mechanicalReduction = 1" in printed


@needs_mujoco
def test_new_file_is_a_loading_template_with_marked_placeholders(tmp_path, capsys):
    out, printed = _import(tmp_path, capsys, *_cfg("extended", EXTENDED))
    p = load_params(out)
    J, K, _ = reference(HYQ, "lf_haa_joint", EXTENDED)
    assert p.plant.J_link == pytest.approx(J, rel=1e-9) and p.plant.K_link == pytest.approx(K, rel=1e-9)
    assert p.plant.B_link == 0.1                                   # <dynamics damping="0.1">
    data = tomllib.loads(out.read_text())
    assert all(e["source"] == "placeholder" for e in data["motor"].values())
    assert all(e["source"] == "placeholder" for e in data["controller"].values())
    assert "PLACEHOLDER" in printed


@needs_mujoco
def test_mjcf_armature_gear_damping_friction(tmp_path, capsys):
    out, _ = _import(tmp_path, capsys, "--configuration", "straight:", "--configuration", "bent:knee=-1.5",
                     "--merge", "sea", description=MJCF, joint="hip")
    p = load_params(out)
    assert p.plant.N == 50 and p.plant.J_m == pytest.approx(0.02 / 50 ** 2, rel=1e-12)
    assert p.plant.B_link == 0.3 and p.limits.friction["link"] == 0.2
    # straight: thigh (1.5 kg, 0.1 m below the axis, I_xx 0.012), shank (0.4 kg, 0.37 m, 0.003)
    J = 0.012 + 1.5 * 0.1 ** 2 + 0.003 + 0.4 * 0.37 ** 2
    assert p.configurations["straight"]["J_link"] == pytest.approx(J, rel=1e-12)
    assert p.configurations["straight"]["K_link"] == pytest.approx(9.81 * (1.5 * 0.1 + 0.4 * 0.37), rel=1e-12)
    # bent: the shank's centre of mass at 0.25 m down then 0.12 m rotated by -1.5 rad about x
    c = np.array([0.0, 0.0, -0.25]) + 0.12 * np.array([0.0, math.sin(1.5), -math.cos(1.5)])
    Jb = 0.012 + 1.5 * 0.01 + 0.003 + 0.4 * (c[1] ** 2 + c[2] ** 2)
    assert p.configurations["bent"]["J_link"] == pytest.approx(Jb, rel=1e-12)
    assert p.configurations["bent"]["K_link"] == pytest.approx(9.81 * (1.5 * 0.1 - 0.4 * c[2]), rel=1e-12)


@needs_mujoco
def test_drake_transmission_tags(tmp_path, capsys):
    urdf = tmp_path / "d.urdf"
    urdf.write_text(_URDF.replace("</robot>", """<transmission name="t"><joint name="hip"/>
      <actuator name="m"><drake:rotor_inertia value="1.5e-5"/><drake:gear_ratio value="30"/></actuator></transmission>
      </robot>""").replace('<robot name="r">', '<robot name="r" xmlns:drake="http://drake.mit.edu">'))
    out, _ = _import(tmp_path, capsys, "--configuration", "a:", "--merge", "sea", description=urdf, joint="hip")
    p = load_params(out)
    assert p.plant.N == 30 and p.plant.J_m == 1.5e-5


_URDF = """<robot name="r">
  <link name="base"><inertial><mass value="2"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="hip" type="revolute"><parent link="base"/><child link="leg"/><origin xyz="0 0 -0.1"/>
    <axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <link name="leg"><inertial><origin xyz="0 0 -0.2"/><mass value="1"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><mesh filename="package://nowhere/leg.stl"/></geometry></visual>
    <collision><geometry><mesh filename="package://nowhere/leg.stl"/></geometry></collision></link>
</robot>"""


# ---- bad input: one line, exit 2, nothing written --------------------------------------------------
@needs_mujoco
def test_unknown_joint_names_the_joints(assert_refused):
    assert_refused(["import-robot", str(HYQ), "--joint", "lf_haa", "--configuration", "a:", "--out", "x.toml"],
                   ("--joint 'lf_haa': no such joint", "lf_haa_joint", "rh_kfe_joint"))


@needs_mujoco
def test_floating_joint(assert_refused, tmp_path):
    urdf = tmp_path / "f.urdf"
    urdf.write_text(_URDF.replace('<link name="base">', '<link name="world"/><joint name="free" type="floating">'
                                  '<parent link="world"/><child link="base"/></joint><link name="base">'))
    assert_refused(["import-robot", str(urdf), "--joint", "free", "--configuration", "a:", "--out", "x.toml"],
                   ("--joint 'free': a floating joint", "allowed: a hinge", "hip"))


@needs_mujoco
def test_description_without_inertials(assert_refused, tmp_path):
    urdf = tmp_path / "n.urdf"
    text = _URDF
    while "<inertial>" in text:
        text = text[:text.index("<inertial>")] + text[text.index("</inertial>") + len("</inertial>"):]
    urdf.write_text(text)
    assert_refused(["import-robot", str(urdf), "--joint", "hip", "--configuration", "a:", "--out", "x.toml"],
                   "no link has an <inertial>")


@needs_mujoco
def test_missing_meshes_do_not_fail(tmp_path, capsys):
    urdf = tmp_path / "m.urdf"
    urdf.write_text(_URDF)
    out, _ = _import(tmp_path, capsys, "--configuration", "a:hip=0.5", description=urdf, joint="hip")
    p = load_params(out)
    assert p.plant.J_link == pytest.approx(0.01 + 1 * 0.2 ** 2, rel=1e-12)      # 1 kg 0.2 m below the axis
    assert p.plant.K_link == pytest.approx(9.81 * 0.2 * math.cos(0.5), rel=1e-12)


@needs_mujoco
def test_configuration_outside_the_limits(assert_refused):
    assert_refused(["import-robot", str(HYQ), "--joint", "lf_haa_joint", "--configuration",
                    "extended:lf_hfe_joint=0,lf_kfe_joint=-0.3", "--out", "x.toml"],
                   ("lf_kfe_joint=-0.3: outside the joint's limits", "-2.44346095279 to -0.349065850399"))


@needs_mujoco
def test_merge_never_replaces_its_input(assert_refused, tmp_path):
    mine = tmp_path / "mine.toml"
    mine.write_bytes((ROOT / "model" / "hyq_haa.toml").read_bytes())
    assert_refused(["import-robot", str(HYQ), "--joint", "lf_haa_joint", *_cfg("extended", EXTENDED),
                    "--merge", str(mine), "--out", str(mine)], "--out")


@needs_mujoco
def test_skip_of_a_key_not_written(assert_refused):
    assert_refused(["import-robot", str(HYQ), "--joint", "lf_haa_joint", *_cfg("extended", EXTENDED),
                    "--merge", "hyq_haa", "--skip", "N", "--out", "x.toml"], ("--skip N", "allowed: ['J_L2'"))


def test_without_mujoco_one_line_naming_the_extra(assert_refused, monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "mujoco", None)            # import mujoco raises ImportError
    monkeypatch.setattr("haa_sym.cli.robot_import.mujoco_available", lambda: False)
    assert_refused(["import-robot", str(HYQ), "--joint", "lf_haa_joint", "--configuration", "a:", "--out", "x.toml"],
                   "pip install -e '.[mujoco]'")
    from haa_sym.errors import ParameterError
    from haa_sym.robot.importer import import_joint
    with pytest.raises(ParameterError, match=r"haa_sym\[mujoco\]"):
        import_joint(HYQ, "lf_haa_joint", [("a", {})])


@needs_mujoco
def test_gravity_option_is_in_the_root_frame(tmp_path, capsys):
    """--gravity: a base tilted in the world (here gravity 12 deg off -z, in no plane of the axes)."""
    g = np.array([1.0, -2.0, -9.5])
    out, printed = _import(tmp_path, capsys, *_cfg("extended", EXTENDED), "--gravity", "1,-2,-9.5", "--merge",
                           "hyq_haa")
    J, K, V = reference(HYQ, "lf_haa_joint", EXTENDED, g=g)
    c = load_params(out).configurations["extended"]
    assert c["J_L2"] == pytest.approx(J, rel=1e-9, abs=0) and c["K_L2"] == pytest.approx(K, rel=1e-9, abs=0)
    assert abs(K / reference(HYQ, "lf_haa_joint", EXTENDED)[1] - 1) > 0.01     # the option changes K
    assert "gravity (1, -2, -9.5)" in printed


@needs_mujoco
def test_bad_gravity(assert_refused):
    assert_refused(["import-robot", str(HYQ), "--joint", "lf_haa_joint", "--configuration", "a:", "--gravity", "0,0",
                    "--out", "x.toml"], ("--gravity '0,0'", "three finite numbers"))
