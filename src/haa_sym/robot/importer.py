"""A robot description in (issue 25): the port body's inertia about a joint's axis and the
linearised gravity stiffness there, from a URDF or an MJCF, at named configurations.

MuJoCo's compiler reads the description (the optional extra ``haa_sym[mujoco]``; imported lazily,
so that the rest of the package never needs it): it builds the kinematic tree, fuses fixed joints
(their links' masses and inertias are added to the moving parent, as a rigid body is), and gives
every body's mass, centre of mass and principal inertia in the world frame at a configuration
(``mj_kinematics``). The sums below are this module's; docs/robot.md has the choice of MuJoCo over
pinocchio and yourdfpy.

At a configuration q (the chosen joint and every other at their given values, the rest at the
description's reference ``qpos0``, 0 for a URDF), with axis a (unit) through the point p of the
joint and the bodies B distal to it (mass m_b, centre of mass c_b, inertia I_b about c_b):

    J   = sum_b  a^T I_b a + m_b |a x (c_b - p)|^2                      (kg m^2)
    tau = sum_b  m_b g . (a x (c_b - p))                                (Nm, gravity's torque about a)
    K   = -dtau/dq = -sum_b m_b g . (a x (a x (c_b - p)))               (Nm/rad)

J is the diagonal of the joint-space mass matrix at that joint (the composite inertia of the
subtree about the axis); K is the second derivative of the potential energy -sum m_b g . c_b with
respect to this joint alone (every other joint held; an MJCF joint spring's stiffness about
the joint is added, a stiffness to ground for the linear model), so K > 0 is restoring, as the actuator
file's K of a body (Table 1's K_L2: the hanging leg). ``tau`` is the static torque the linear
model leaves out (0 where the joint hangs in equilibrium).

The base is held where the description puts it (a fixed base; a floating base at its reference
pose); gravity is ``GRAVITY`` along -z of the description's root (URDF: the root link; MJCF: the
world body) unless given, in that frame (a base tilted by R in the world sees gravity R^T g).
"""
from __future__ import annotations

import hashlib
import importlib.util
import math
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from haa_sym.errors import ParameterError
from haa_sym.io.inputs import read_bytes

__all__ = ["GRAVITY", "MUJOCO_MISSING", "MAX_DESCRIPTION_BYTES", "ConfigurationValues", "RobotImport",
           "parse_configuration", "parse_gravity", "mujoco_available", "import_joint"]

#: Gravity in the description's root frame, m/s^2 (MuJoCo's default, the standard 9.81 along -z).
GRAVITY = (0.0, 0.0, -9.81)
#: The message when MuJoCo is not installed (the package is on no index: the extra installs from a checkout).
MUJOCO_MISSING = ("reading a URDF or MJCF needs MuJoCo, the optional extra haa_sym[mujoco]: "
                  "pip install -e '.[mujoco]' in a checkout (or pip install 'mujoco>=4.0')")
#: The largest description read, bytes (HyQ's URDF is 37 KB; meshes are never read from a URDF).
MAX_DESCRIPTION_BYTES = 64 << 20
# A configuration's name becomes a TOML table name ([configurations.NAME]) and a flag's text
_CONFIG_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]*\Z")
# a gear ratio of exactly 1 is the identity transmission (the command is the joint torque): what
# ros_control's SimpleTransmission and MuJoCo's default gear write when no gearbox is described
IDENTITY_GEAR = 1.0
# MuJoCo's wrap type of a joint in a fixed tendon (mjWRAP_JOINT)
_WRAP_JOINT = 1


@dataclass(frozen=True)
class ConfigurationValues:
    """One configuration's result: ``joints`` (every 1-dof joint's value, rad or m), ``given``
    (the values the configuration named), ``J`` (kg m^2), ``K`` (Nm/rad), ``tau`` (Nm)."""

    name: str
    given: dict
    joints: dict
    J: float
    K: float
    tau: float

    def joints_text(self) -> str:
        return ", ".join(f"{k}={v!r}" for k, v in self.given.items()) or "the reference configuration"


@dataclass(frozen=True)
class RobotImport:
    """What :func:`import_joint` read.

    Attributes
    ----------
    source : str
        The description's path as given; ``sha256`` its content's hash; ``kind`` "URDF" or "MJCF".
    joint : str
        The joint; ``bodies`` the bodies that move with it (MuJoCo's, after fixed joints are fused).
    gravity : tuple of float
        m/s^2 in the root frame.
    configurations : tuple of ConfigurationValues
        In the order given.
    damping : float or None
        The joint's viscous damping, Nm s/rad (URDF ``<dynamics damping>``, MJCF ``damping``).
    friction : float or None
        The joint's Coulomb friction torque, Nm (URDF ``<dynamics friction>``, MJCF ``frictionloss``).
    gear : float or None
        The gear ratio (URDF ``mechanicalReduction`` or ``drake:gear_ratio``, MJCF actuator
        ``gear``), None where none is given or it is the identity (1); ``gear_source`` says which.
    rotor_inertia : float or None
        The rotor's inertia on the motor side, kg m^2 (``drake:rotor_inertia``), None if not given.
    armature : float or None
        MJCF armature: the rotor's inertia reflected to the joint (J_m N^2), kg m^2: the motor's
        joint's ``armature`` plus its actuators' ``armature`` (motor side) times gear^2; the
        motor's joint is the joint itself or, where no actuator acts on it, the one joint that
        fixed tendons tie it to (:func:`_motor_of`).
    notes : tuple of str
        What the import changed or left out (e.g. an inertia tensor MuJoCo would refuse).
    """

    source: str
    sha256: str
    kind: str
    joint: str
    bodies: tuple
    gravity: tuple
    configurations: tuple
    damping: float | None
    friction: float | None
    gear: float | None
    gear_source: str
    rotor_inertia: float | None
    armature: float | None
    mujoco_version: str
    notes: tuple = field(default=())


def mujoco_available() -> bool:
    """Whether MuJoCo can be imported."""
    return importlib.util.find_spec("mujoco") is not None


def _mujoco():
    try:
        import mujoco
    except ImportError:
        raise ParameterError(MUJOCO_MISSING) from None
    return mujoco


def parse_configuration(text: str, flag: str = "--configuration") -> tuple[str, dict]:
    """``'NAME:JOINT=VALUE[,JOINT=VALUE...]'`` -> (NAME, {JOINT: VALUE}); VALUE in rad (m for a
    prismatic joint), the description's own units. ``'NAME:'`` is the reference configuration."""
    name, sep, rest = text.partition(":")
    name = name.strip()
    if not sep or not _CONFIG_NAME.match(name) or name == "nominal":
        raise ParameterError(f"{flag} {text!r}: not NAME:JOINT=VALUE[,JOINT=VALUE...]; allowed: NAME letters, "
                             "digits, '_' or '-' starting with a letter (not 'nominal': the file's own values), "
                             "then ':' and joint values in rad")
    values = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        joint, eq, value = item.partition("=")
        try:
            if not eq:
                raise ValueError
            v = float(value)
            if not math.isfinite(v):
                raise ValueError
        except ValueError:
            raise ParameterError(f"{flag} {text!r}: {item!r} is not JOINT=VALUE; allowed: a joint name, '=' and "
                                 "a finite number (rad)") from None
        if joint.strip() in values:
            raise ParameterError(f"{flag} {text!r}: joint {joint.strip()!r} given twice; allowed: each joint once")
        values[joint.strip()] = v
    return name, values


def parse_gravity(text: str | None, flag: str = "--gravity") -> tuple[float, float, float]:
    """``'X,Y,Z'`` (m/s^2, the root frame) -> a tuple; None -> :data:`GRAVITY`."""
    if text is None:
        return GRAVITY
    try:
        g = tuple(float(s) for s in text.split(","))
        if len(g) != 3 or not all(math.isfinite(x) for x in g):
            raise ValueError
    except ValueError:
        raise ParameterError(f"{flag} {text!r}: not X,Y,Z; allowed: three finite numbers, m/s^2 in the "
                             "description's root frame (default 0,0,-9.81)") from None
    return g


def _local(tag: str) -> str:
    """An element's name without its namespace (``{uri}gear_ratio``, ``drake:gear_ratio``)."""
    return tag.rsplit("}", 1)[-1].rsplit(":", 1)[-1]


def _float_attr(el, attr: str, where: str) -> float:
    try:
        v = float(el.get(attr))
        if not math.isfinite(v):
            raise ValueError
    except (TypeError, ValueError):
        raise ParameterError(f"{where}: {attr} = {el.get(attr)!r}; allowed: a finite number") from None
    return v


def _tensor_ok(M: np.ndarray) -> bool:
    """Whether a 3x3 inertia tensor is a rigid body's as MuJoCo requires: positive principal
    moments (or all zero: a point mass) that satisfy the triangle inequality."""
    e = np.linalg.eigvalsh(M)
    if not M.any():
        return True
    return bool(e.min() > 0 and e[0] + e[1] >= e[2])


def _urdf_for_mujoco(root, shown: str) -> tuple[str, dict, dict]:
    """The URDF reduced to what the dynamics need (links' inertials, joints) with a MuJoCo
    compiler element; the transmissions' gear ratios and rotor inertias by joint; notes by link.

    Geometry is dropped: a URDF's inertias are explicit (``inertiafromgeom="false"``: no inertia
    is invented from a collision shape), and its meshes (``package://...``) need not exist here.
    A tensor that is not a rigid body's (MuJoCo refuses it) loses its products of inertia; a note
    says so. HyQ's URDF has such placeholders (1e-6 kg, every entry 1e-6) on its base and feet."""
    out = ET.Element("robot", {"name": root.get("name", "robot")})
    notes = {}
    for el in root:
        if el.tag == "joint":
            out.append(el)
        elif el.tag == "link":
            link = ET.SubElement(out, "link", {"name": el.get("name", "")})
            for inertial in el.findall("inertial"):
                t = inertial.find("inertia")
                if t is not None:
                    where = f"{shown}: link {el.get('name')!r} <inertia>"
                    I = {k: _float_attr(t, k, where) if t.get(k) is not None else 0.0
                         for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
                    M = np.array([[I["ixx"], I["ixy"], I["ixz"]], [I["ixy"], I["iyy"], I["iyz"]],
                                  [I["ixz"], I["iyz"], I["izz"]]])
                    if not _tensor_ok(M) and _tensor_ok(np.diag(np.diag(M))):
                        for k in ("ixy", "ixz", "iyz"):
                            t.set(k, "0")
                        notes[el.get("name")] = (f"link {el.get('name')!r}: its inertia tensor is not a rigid body's "
                                     f"(principal moments {', '.join(f'{x:.3g}' for x in np.linalg.eigvalsh(M))} "
                                     "kg m^2); its products of inertia dropped, the diagonal kept")
                link.append(inertial)
    mj = ET.SubElement(out, "mujoco")
    ET.SubElement(mj, "compiler", {"discardvisual": "true", "inertiafromgeom": "false", "fusestatic": "true",
                                   "angle": "radian"})
    gears: dict = {}
    for tr in root.iter("transmission"):
        joints = [j.get("name") for j in tr.iter() if _local(j.tag) == "joint" and j.get("name")]
        found = {}
        for el in tr.iter():
            name = _local(el.tag)
            if name == "mechanicalReduction" and (el.text or "").strip():
                try:
                    found["mechanicalReduction"] = float(el.text)
                except ValueError:
                    raise ParameterError(f"{shown}: transmission {tr.get('name')!r} mechanicalReduction = "
                                         f"{el.text.strip()!r}; allowed: a number") from None
            elif name in ("gear_ratio", "rotor_inertia") and el.get("value") is not None:
                found[f"drake:{name}"] = _float_attr(el, "value", f"{shown}: transmission {tr.get('name')!r} "
                                                     f"drake:{name}")
        for j in joints:
            gears.setdefault(j, {}).update(found)
    return ET.tostring(out, encoding="unicode"), gears, notes


def _urdf_distal_links(root, joint: str) -> set:
    """The URDF links that move with ``joint``: its child link and every link below it."""
    children = {}
    child_of = {}
    for j in root.findall("joint"):              # not a <transmission>'s <joint>
        p, c = j.find("parent"), j.find("child")
        if p is not None and c is not None:
            children.setdefault(p.get("link"), []).append(c.get("link"))
            child_of[j.get("name")] = c.get("link")
    out, todo = set(), [child_of.get(joint)]
    while todo:
        link = todo.pop()
        if link is not None and link not in out:
            out.add(link)
            todo.extend(children.get(link, []))
    return out


def _compile(mujoco, shown: str, kind: str, xml: str | None, path: str | None):
    try:
        if xml is not None:
            return mujoco.MjModel.from_xml_string(xml)
        return mujoco.MjModel.from_xml_path(path)
    except ValueError as exc:
        msg = "; ".join(s.strip() for s in str(exc).splitlines() if s.strip())
        raise ParameterError(f"{shown}: MuJoCo {mujoco.__version__} cannot compile this {kind}: {msg}; allowed: "
                             "a description MuJoCo reads (docs/robot.md)") from None


def _subtree(m, body: int) -> list[int]:
    out = []
    for b in range(m.nbody):
        a = b
        while a > 0 and a != body:
            a = m.body_parentid[a]
        if a == body:
            out.append(b)
    return out


def _port_values(m, d, mujoco, jid: int, bodies: list, g: np.ndarray) -> tuple[float, float, float]:
    mujoco.mj_kinematics(m, d)
    p, a = d.xanchor[jid].copy(), d.xaxis[jid].copy()
    J = K = tau = 0.0
    for b in bodies:
        mass = m.body_mass[b]
        R = d.ximat[b].reshape(3, 3)
        r = d.xipos[b] - p
        axr = np.cross(a, r)
        J += a @ R @ np.diag(m.body_inertia[b]) @ R.T @ a + mass * (axr @ axr)
        tau += mass * (g @ axr)
        K -= mass * (g @ np.cross(a, axr))
    return float(J), float(K), float(tau)


def _motor_of(m, jid: int) -> tuple[int, list, list]:
    """The joint whose actuators drive joint ``jid`` and those actuators (joint transmission):
    ``jid``'s own; if it has none, the actuators on the joints that fixed tendons tie to it,
    directly or through other joints (a motor's rotor joint coupled to the link by a tendon
    spring: MuJoCo's series elastic element, mujoco #1524, and export-mujoco's layout). All of
    them on one joint, else none (an ambiguous motor). Returns (motor joint, actuators, the
    tendons' names on the way)."""
    def on(j):
        return [i for i in range(m.nu) if m.actuator_trntype[i] == 0 and m.actuator_trnid[i, 0] == j]
    if on(jid):
        return jid, on(jid), []
    links: dict = {}
    for t in range(m.ntendon):
        adr, num = int(m.tendon_adr[t]), int(m.tendon_num[t])
        js = [int(m.wrap_objid[w]) for w in range(adr, adr + num) if m.wrap_type[w] == _WRAP_JOINT]
        if len(js) != num:                       # a spatial tendon: a cable, not a drive train
            continue
        for a in js:
            for b in js:
                if a != b:
                    links.setdefault(a, []).append((b, m.tendon(t).name or str(t)))
    seen, todo, found = {jid: []}, [jid], []
    while todo:
        j = todo.pop(0)
        if on(j):
            found.append(j)
            continue                             # the motor ends the train
        for b, name in links.get(j, []):
            if b not in seen:
                seen[b] = seen[j] + [name]
                todo.append(b)
    if len(found) != 1:
        return jid, [], []
    return found[0], on(found[0]), seen[found[0]]


_TYPES = {0: "free (floating, 6 degrees of freedom)", 1: "ball (3 rotational degrees of freedom)",
          2: "slide (prismatic)", 3: "hinge (revolute)"}


def import_joint(description: str | os.PathLike, joint: str, configurations, *, gravity=GRAVITY,
                 field_name: str = "DESCRIPTION") -> RobotImport:
    """Read ``description`` (URDF or MJCF) and compute the port values of ``joint``.

    Parameters
    ----------
    description : str or os.PathLike
        A ``.urdf`` (root element ``<robot>``) or MJCF (``<mujoco>``) file.
    joint : str
        A hinge (URDF revolute or continuous) joint.
    configurations : sequence of (name, {joint: value})
        Joint values in rad (m for prismatic joints), within the joints' limits; the joints not
        named stay at the description's reference (0 for a URDF).
    gravity : 3 floats
        m/s^2 in the description's root frame (default :data:`GRAVITY`).

    Raises
    ------
    ParameterError
        One line: MuJoCo missing (:data:`MUJOCO_MISSING`), a file MuJoCo cannot compile, a joint
        not in the file (naming those that are), a joint that is not a hinge, a configuration
        outside a joint's limits, no mass moving with the joint.
    """
    mujoco = _mujoco()
    shown = os.fspath(description)
    raw = read_bytes(description, field_name, limit=MAX_DESCRIPTION_BYTES)
    try:
        root = ET.fromstring(raw)
    except ET.ParseError as exc:
        raise ParameterError(f"{field_name} {shown!r}: not XML ({exc}); allowed: a URDF or MJCF file") from None
    notes, gears = [], {}
    if root.tag == "robot":
        kind = "URDF"
        if not any(link.find("inertial") is not None for link in root.iter("link")):
            raise ParameterError(f"{field_name} {shown!r}: no link has an <inertial> (a kinematic-only description); "
                                 "allowed: a URDF whose links carry <inertial> mass and inertia (J and K need them; "
                                 "meshes they do not)")
        xml, gears, link_notes = _urdf_for_mujoco(root, shown)
        m = _compile(mujoco, shown, kind, xml, None)
        urdf_types = {j.get("name"): j.get("type") for j in root.findall("joint") if j.get("name")}
        distal = _urdf_distal_links(root, joint)
        # only the links that move with the joint enter J and K
        notes = [t for link, t in link_notes.items() if link in distal]
        if len(link_notes) > len(notes):
            notes.append(f"{len(link_notes) - len(notes)} other link(s) whose inertia MuJoCo would refuse likewise "
                         f"had their products of inertia dropped; they do not move with {joint!r}")
    elif root.tag == "mujoco":
        kind = "MJCF"
        # meshes and includes resolve beside the file; an MJCF's geoms may carry its inertias
        m = _compile(mujoco, shown, kind, None, str(Path(shown).resolve()))
        urdf_types = {}
    else:
        raise ParameterError(f"{field_name} {shown!r}: root element <{root.tag}>; allowed: <robot> (URDF) or "
                             "<mujoco> (MJCF)")
    names = [m.joint(i).name for i in range(m.njnt)]
    if joint not in names:
        if urdf_types.get(joint) == "fixed":
            raise ParameterError(f"--joint {joint!r}: a fixed joint in {shown} (no degree of freedom); allowed: "
                                 f"a revolute joint: {', '.join(n for n in names if n) or 'none'}")
        if urdf_types.get(joint) == "floating":
            raise ParameterError(f"--joint {joint!r}: a floating joint in {shown} (6 degrees of freedom, no axis); "
                                 f"allowed: a revolute joint: "
                                 f"{', '.join(n for n, i in zip(names, range(m.njnt)) if m.jnt_type[i] == 3)}")
        raise ParameterError(f"--joint {joint!r}: no such joint in {shown}; allowed: "
                             f"{', '.join(n or '(unnamed)' for n in names) or 'none (no moving joint)'}")
    jid = names.index(joint)
    if m.jnt_type[jid] != 3:
        hinges = [n for i, n in enumerate(names) if m.jnt_type[i] == 3]
        floating = "a floating joint: " if m.jnt_type[jid] in (0, 1) else ""
        raise ParameterError(f"--joint {joint!r}: {floating}{_TYPES[int(m.jnt_type[jid])]} in {shown}; allowed: a "
                             f"hinge (revolute) joint, the axis the inertia is taken about: {', '.join(hinges)}")
    bodies = _subtree(m, int(m.jnt_bodyid[jid]))
    if not m.body_subtreemass[m.jnt_bodyid[jid]] > 0:
        raise ParameterError(f"{shown}: no mass moves with joint {joint!r} (bodies {[m.body(b).name for b in bodies]}: "
                             "no <inertial> elements); allowed: a description whose links carry inertials")
    d = mujoco.MjData(m)
    g = np.asarray(gravity, dtype=float)
    results, seen = [], set()
    for name, given in configurations:
        if name in seen:
            raise ParameterError(f"--configuration {name!r} given twice; allowed: each name once")
        seen.add(name)
        d.qpos[:] = m.qpos0
        for jn, v in given.items():
            where = f"--configuration {name}: {jn}={v!r}"
            if jn not in names:
                raise ParameterError(f"{where}: no such joint in {shown}; allowed: "
                                     f"{', '.join(n for i, n in enumerate(names) if m.jnt_type[i] in (2, 3))}")
            k = names.index(jn)
            if m.jnt_type[k] not in (2, 3):
                raise ParameterError(f"{where}: a floating joint ({_TYPES[int(m.jnt_type[k])]}); allowed: hinge "
                                     "and slide joints (the base stays at its reference pose)")
            lo, hi = (float(x) for x in m.jnt_range[k])
            if m.jnt_limited[k] and not lo <= v <= hi:
                raise ParameterError(f"{where}: outside the joint's limits; allowed: {lo!r} to {hi!r} (rad)")
            d.qpos[m.jnt_qposadr[k]] = v
        J, K, tau = _port_values(m, d, mujoco, jid, bodies, g)
        # a joint spring about the joint (MJCF stiffness, springref) is, with every other joint
        # held, a stiffness to ground: d^2/dq^2 of 1/2 k (q - q_spring)^2 adds k to the gravity's
        # K, and its torque -k (q - q_spring) to the static torque the linear model leaves out
        k_spring = float(m.jnt_stiffness[jid])
        K += k_spring
        tau -= k_spring * (float(d.qpos[m.jnt_qposadr[jid]]) - float(m.qpos_spring[m.jnt_qposadr[jid]]))
        if K < 0:
            raise ParameterError(f"--configuration {name}: the gravity stiffness about {joint!r} is {K:.6g} Nm/rad "
                                 "(gravity turns the leg away: an inverted configuration); allowed: configurations "
                                 "where K >= 0 (the file's K is a stiffness to ground >= 0)")
        values = {n: float(d.qpos[m.jnt_qposadr[i]]) for i, n in enumerate(names) if m.jnt_type[i] in (2, 3)}
        results.append(ConfigurationValues(name, dict(given), values, J, K, tau))
    dof = m.jnt_dofadr[jid]
    gear, gear_source, rotor = None, "", None
    armature = float(m.dof_armature[dof]) if kind == "MJCF" else None
    if kind == "URDF":
        t = gears.get(joint, {})
        for key in ("drake:gear_ratio", "mechanicalReduction"):
            if key in t:
                gear, gear_source = t[key], key
                break
        rotor = t.get("drake:rotor_inertia")
    else:
        motor_joint, acts, train = _motor_of(m, jid)
        ratios = sorted({float(m.actuator_gear[i, 0]) for i in acts})
        via = (f" on joint {names[motor_joint]!r}, which drives {joint!r} through the fixed tendon(s) "
               f"{', '.join(train)}" if motor_joint != jid else "")
        if len(ratios) == 1:
            gear, gear_source = ratios[0], f"actuator {m.actuator(acts[0]).name or acts[0]!r} gear{via}"
            # the rotor reflected to the joint the motor drives: the joint's own armature plus the
            # actuators' (MuJoCo >= 4: an actuator's armature is motor side, reflected by gear^2)
            act_arm = getattr(m, "actuator_armature", np.zeros(m.nu))
            armature = float(m.dof_armature[m.jnt_dofadr[motor_joint]]) \
                + sum(float(act_arm[i]) * ratios[0] ** 2 for i in acts)
        elif len(ratios) > 1:
            notes.append(f"actuators on {joint!r}{via} have gears {ratios}: no single gear ratio, N not imported")
    if gear is not None and gear == IDENTITY_GEAR:
        notes.append(f"{gear_source} = 1 on {joint!r}: the identity transmission (the command is the joint "
                     "torque), no gear ratio imported")
        gear = None
    elif gear is not None and not gear > 0:
        notes.append(f"{gear_source} = {gear:g} on {joint!r}: not a gear ratio > 0, not imported")
        gear = None
    if armature == 0.0:
        armature = None
    return RobotImport(source=shown, sha256=hashlib.sha256(raw).hexdigest(), kind=kind, joint=joint,
                       bodies=tuple(m.body(b).name for b in bodies), gravity=tuple(float(x) for x in g),
                       configurations=tuple(results), damping=float(m.dof_damping[dof]),
                       friction=float(m.dof_frictionloss[dof]), gear=gear, gear_source=gear_source,
                       rotor_inertia=rotor, armature=armature, mujoco_version=mujoco.__version__,
                       notes=tuple(notes))
