"""``import-robot --out FILE.toml``: a robot import written in the actuator file's own format.

Merged into an existing file (``--merge``), the file's TEXT is edited: the imported entries are
replaced or added in their sections, every other line (comments, order, other entries) stays.
Without ``--merge`` the new file is a template: the imported values on the port body ``link`` of
the bundled ``harmonic_drive`` topology (rotor --hd--> link, torque sensor on hd, encoder and port
on link), and the motor, the gearbox and the controller copied from that bundled file as
PLACEHOLDERS (source ``placeholder``, every description saying so): the file loads and analyses
run, but nothing in it but the imported entries is the robot's.

Written entries (flat names; ``--skip`` leaves any of them as the merged file has them):

=================  ==========================================================================
``J_<port>``       inertia about the joint's axis of everything distal to it, first configuration
``K_<port>``       linearised gravity stiffness there (K > 0 restoring)
``B_<port>``       the joint's viscous damping (URDF ``<dynamics damping>``, MJCF ``damping``)
``N``              the gear ratio, where the description gives one other than 1
``J_m``            the rotor inertia, motor side: ``drake:rotor_inertia``, or MJCF armature
                   (reflected, J_m N^2: the motor's joint's plus its actuators' times gear^2)
                   divided by N^2 (the description's N, else the file's)
``Fc_<port>``      ([limits]) the joint's Coulomb friction, where > 0
=================  ==========================================================================

plus ``J_<port>``, ``K_<port>`` in ``[configurations.NAME]`` for every configuration, and one
``[about.references]`` key naming the file (and its SHA-256), the joint, the configurations and
the gravity; every entry's ``source`` is that key and its description names the configuration.
The text is parsed with :func:`haa_sym.model.params.parse_params` and every written value read back
before it is returned.
"""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

from haa_sym.errors import ParameterError
from haa_sym.model.params import actuator_path, load_params, parse_params

__all__ = ["TEMPLATE", "TEMPLATE_PORT", "imported_text", "template_text", "written_keys"]

#: The bundled actuator whose topology and values the new file's template copies.
TEMPLATE = "harmonic_drive"
#: The port body's name in a new file (the template's, so its plant code is the bundled one).
TEMPLATE_PORT = "link"
PLACEHOLDER_KEY = "placeholder"
_HEADER = re.compile(r"^\s*\[\s*([^\[\]]+?)\s*\]\s*(#.*)?$")


def _num(x: float) -> str:
    # the shortest text that reads back as the same float (the checks compare to 1e-9)
    return repr(float(x))


def _esc(s: str) -> str:
    return s.replace("\\", "\\\\").replace('"', '\\"')


def _entry(value: float, unit: str, source: str, description: str) -> str:
    return f'{{ value = {_num(value)}, unit = "{unit}", source = "{source}", description = "{_esc(description)}" }}'


def template_text(name: str, description: str) -> str:
    """A new actuator file: :data:`TEMPLATE`'s topology and values as marked placeholders."""
    p = load_params(actuator_path(TEMPLATE))
    plant, c = p.plant, p.controller
    said = f"PLACEHOLDER copied from the bundled {TEMPLATE}.toml, not the robot's: replace it"
    motor = {"L": "H", "R": "Ohm", "k_t": "Nm/A", "k_w": "V s/rad", "J_m": "kg m^2", "B_m": "Nm s/rad", "N": "-"}
    ctrl = {"Ts": "s", "N_av": "samples", "alpha": "-", "beta": "-", "P_t0": "V/Nm", "I_t0": "V/(Nm s)"}
    port = TEMPLATE_PORT
    lines = [
        "# Written by haa-sym import-robot without --merge: the imported entries (source = the import's key",
        "# in [about.references]) on the port body of a rigid-gearbox template. Every entry whose source is",
        f'# "{PLACEHOLDER_KEY}" is NOT the robot\'s: the motor, the gearbox and the controller of the bundled',
        f"# {TEMPLATE}.toml, so that the file loads. Replace them (docs/model.md, docs/robot.md) and tune the",
        "# torque PI (haa-sym tune) before trusting any analysis of this file.",
        "",
        "[about]",
        f'name = "{_esc(name)}"',
        f'description = "{_esc(description)}"',
        "",
        "[about.references]",
        f'{PLACEHOLDER_KEY} = "PLACEHOLDER: a value of the bundled {TEMPLATE}.toml copied so that the file loads; '
        'not from the robot description, not the robot\'s"',
        "",
        "[motor]",
        *(f"{k:3s} = {_entry(getattr(plant, k), u, PLACEHOLDER_KEY, said)}" for k, u in motor.items()),
        "",
        f"[bodies.{port}]",
        f"J = {_entry(getattr(plant, f'J_{port}'), 'kg m^2', PLACEHOLDER_KEY, said)}",
        f"B = {_entry(getattr(plant, f'B_{port}'), 'Nm s/rad', PLACEHOLDER_KEY, said)}",
        f"K = {_entry(getattr(plant, f'K_{port}'), 'Nm/rad', PLACEHOLDER_KEY, said)}",
        "",
        "[couplings.hd]",
        f'between = ["rotor", "{port}"]',
        f"K = {_entry(plant.K_hd, 'Nm/rad', PLACEHOLDER_KEY, said)}",
        f"D = {_entry(plant.D_hd, 'Nm s/rad', PLACEHOLDER_KEY, said)}",
        "",
        "[sensors]",
        'torque = "hd"',
        "torque_damping = true",
        f'encoder = "{port}"',
        f'port = "{port}"',
        "",
        "[controller]",
        *(f"{k:5s} = {_entry(getattr(c, k), u, PLACEHOLDER_KEY, said)}" for k, u in ctrl.items()),
        "",
    ]
    return "\n".join(lines)


def _sections(lines: list[str]) -> dict:
    """Section name -> (header line index, index after its last line)."""
    heads = [(i, m.group(1)) for i, line in enumerate(lines) for m in [_HEADER.match(line)] if m]
    out = {}
    for n, (i, name) in enumerate(heads):
        end = heads[n + 1][0] if n + 1 < len(heads) else len(lines)
        out[name] = (i, end)
    return out


def _set(lines: list[str], section: str, key: str, rhs: str) -> None:
    """Replace ``key = ...`` in ``[section]`` by ``key = rhs``, add it after the section's last
    entry, or append the section."""
    secs = _sections(lines)
    if section not in secs:
        if lines and lines[-1].strip():
            lines.append("")
        lines += [f"[{section}]", f"{key} = {rhs}"]
        return
    start, end = secs[section]
    pattern = re.compile(rf"^(\s*){re.escape(key)}\s*=")
    last = start
    for i in range(start + 1, end):
        m = pattern.match(lines[i])
        if m:
            lines[i] = f"{m.group(1)}{key} = {rhs}"
            return
        if lines[i].strip() and not lines[i].lstrip().startswith("#"):
            last = i
    lines.insert(last + 1, f"{key} = {rhs}")


def _ref_key(data: dict, stem: str) -> str:
    refs = data.get("about", {}).get("references", {}) if isinstance(data.get("about"), dict) else {}
    base = "import_" + (re.sub(r"[^A-Za-z0-9_]", "_", stem) or "robot")
    key, i = base, 2
    while key in refs:
        key, i = f"{base}_{i}", i + 1
    return key


def written_keys(result, port: str, file_N: float | None) -> dict:
    """Flat name -> (section, key, value, unit, description) of what the import writes (before
    ``--skip``), ``file_N`` the merged file's gear ratio (to refer an MJCF armature to the motor)."""
    first = result.configurations[0]
    where = f"joint {result.joint} of {Path(result.source).name}"
    moving = ", ".join(result.bodies)
    out = {
        f"J_{port}": ("bodies." + port, "J", first.J, "kg m^2",
                      f"Inertia about the axis of {where} of everything distal to it ({moving}), configuration "
                      f"{first.name}: {first.joints_text()} (haa-sym import-robot)"),
        f"K_{port}": ("bodies." + port, "K", first.K, "Nm/rad",
                      f"Linearised gravity stiffness about the axis of {where} (d^2 V/dq^2, > 0 restoring; gravity "
                      f"{_vec(result.gravity)} m/s^2 in the root frame), configuration {first.name}: "
                      f"{first.joints_text()}; static gravity torque there {first.tau:.4g} Nm (not modelled)"),
    }
    if result.damping is not None:
        out[f"B_{port}"] = ("bodies." + port, "B", result.damping, "Nm s/rad",
                            f"Viscous damping of {where} ({'URDF <dynamics damping>' if result.kind == 'URDF' else 'MJCF damping'})")
    N = result.gear
    if N is not None:
        out["N"] = ("motor", "N", N, "-", f"Gear ratio of {where} ({result.gear_source})")
    if result.rotor_inertia is not None:
        out["J_m"] = ("motor", "J_m", result.rotor_inertia, "kg m^2",
                      f"Rotor inertia, motor side, of {where} (drake:rotor_inertia)")
    elif result.armature is not None and (N or file_N):
        n = N or file_N
        out["J_m"] = ("motor", "J_m", result.armature / n ** 2, "kg m^2",
                      f"Rotor inertia, motor side, of {where}: MJCF armature {result.armature:.6g} kg m^2 (reflected, "
                      f"J_m N^2) / N^2, N = {n:g} ({'the description' if N else 'the merged file'})")
    if result.friction:
        out[f"Fc_{port}"] = ("limits", f"Fc_{port}", result.friction, "Nm",
                             f"Coulomb friction of {where} ({'URDF <dynamics friction>' if result.kind == 'URDF' else 'MJCF frictionloss'})")
    return out


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:g}" for x in v) + ")"


def imported_text(result, base_text: str | None, base_source: str, skip=()) -> str:
    """The actuator file's text with ``result`` (a :class:`~haa_sym.robot.importer.RobotImport`)
    written in: merged into ``base_text`` (read from ``base_source``), or into
    :func:`template_text` when ``base_text`` is None.

    Raises
    ------
    ParameterError
        A ``--skip`` name the import does not write, a merged file whose layout the editor cannot
        change (e.g. a body written inline in [bodies]), or a text that does not read back as the
        imported values.
    """
    if base_text is None:
        base_text = template_text(f"{result.joint} of {Path(result.source).name} (imported; placeholders)",
                                  f"{result.joint} of {Path(result.source).name}: the port body's inertia and "
                                  "gravity stiffness imported by haa-sym import-robot; motor, gearbox and controller "
                                  "are placeholders")
        base_source = f"the template of {TEMPLATE}"
    try:
        data = tomllib.loads(base_text)
        base = parse_params(data, base_source)
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"--merge {base_source}: not valid TOML ({exc})") from None
    if "plant" in data:
        raise ParameterError(f"--merge {base_source}: the legacy [plant] format; allowed: a file with [motor], "
                             "[bodies], [couplings], [sensors] (docs/model.md)")
    port = base.plant.topology.port
    keys = written_keys(result, port, None if result.gear else float(base.plant.N))
    unknown = [k for k in skip if k not in keys]
    if unknown:
        raise ParameterError(f"--skip {','.join(skip)}: {unknown} not written by this import; allowed: {list(keys)}")
    ref = _ref_key(data, Path(result.source).stem)
    lines = base_text.splitlines()
    for flat, (section, key, value, unit, said) in keys.items():
        if flat not in skip:
            _set(lines, section, key, _entry(value, unit, ref, said))
    for c in result.configurations:
        for flat, value, unit, what in ((f"J_{port}", c.J, "kg m^2", "inertia"),
                                        (f"K_{port}", c.K, "Nm/rad", "gravity stiffness")):
            if flat not in skip:
                _set(lines, f"configurations.{c.name}", flat,
                     _entry(value, unit, ref, f"The {what} of [bodies.{port}] at {c.joints_text()} "
                                              f"(joint {result.joint}; static gravity torque {c.tau:.4g} Nm)"))
    configs = "; ".join(f"{c.name}: {c.joints_text()}" for c in result.configurations)
    cite = (f"haa-sym import-robot: {result.kind} {Path(result.source).name} (sha256 {result.sha256[:16]}), joint "
            f"{result.joint}, bodies moving with it {', '.join(result.bodies)}, read by MuJoCo "
            f"{result.mujoco_version}; configurations {configs}; gravity {_vec(result.gravity)} m/s^2 in the root "
            "frame; other joints at the description's reference (0)"
            + ("; notes: " + "; ".join(result.notes) if result.notes else ""))
    _set(lines, "about.references", ref, f'"{_esc(cite)}"')
    new = "\n".join(lines) + "\n"
    try:
        check = parse_params(tomllib.loads(new), base_source)
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"--merge {base_source}: the imported entries cannot be added to its layout ({exc}); "
                             "allowed: sections written as [bodies.X], [motor], [configurations.NAME] tables") from None
    expect = {k: v[2] for k, v in keys.items() if k not in skip and not k.startswith("Fc_")}
    got_configs = [(f"configurations.{c.name}", f, v) for c in result.configurations
                   for f, v in ((f"J_{port}", c.J), (f"K_{port}", c.K)) if f not in skip]
    for flat, value in expect.items():
        got = getattr(check.plant, flat)
        if not abs(got - value) <= 1e-12 * abs(value):
            raise ParameterError(f"--out: {flat} reads back as {got!r}, not {value!r}; allowed: a file this editor can "
                                 "change (docs/robot.md)")
    if f"Fc_{port}" in keys and f"Fc_{port}" not in skip:
        value, got = keys[f"Fc_{port}"][2], check.limits.friction.get(port)
        if got is None or not abs(got - value) <= 1e-12 * abs(value):
            raise ParameterError(f"--out: [limits] Fc_{port} reads back as {got!r}, not {value!r}")
    for section, flat, value in got_configs:
        got = check.configurations[section.split(".", 1)[1]][flat]
        if not abs(got - value) <= 1e-12 * abs(value):
            raise ParameterError(f"--out: [{section}] {flat} reads back as {got!r}, not {value!r}")
    return new
