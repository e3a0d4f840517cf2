"""``haa-sym import-robot``: a joint's port body (inertia about its axis, linearised gravity
stiffness) over named configurations, from a URDF or MJCF, written into an actuator file
(:mod:`haa_sym.robot.importer`, :mod:`haa_sym.robot.imported_file`; docs/robot.md)."""
from __future__ import annotations

import sys

from haa_sym.io.inputs import read_text
from haa_sym.io.outputs import Transaction
from haa_sym.model.params import MAX_FILE_BYTES, actuator_path
from haa_sym.robot.importer import (MUJOCO_MISSING, import_joint, mujoco_available, parse_configuration,
                                    parse_gravity)
from haa_sym.robot.imported_file import TEMPLATE, imported_text

from haa_sym.cli.common import _check_out


def _cmd_import_robot(args) -> int:
    if not mujoco_available():
        print(f"haa-sym: error: {MUJOCO_MISSING}", file=sys.stderr)
        return 2
    out = _check_out(args.out, "import-robot", "--out", (".toml",))
    configs = [parse_configuration(text) for text in args.configuration]
    gravity = parse_gravity(args.gravity)
    skip = tuple(s.strip() for s in (args.skip or "").split(",") if s.strip())
    base_text = base_source = None
    if args.merge is not None:
        base = actuator_path(args.merge, "--merge")
        base_text, base_source = read_text(base, "--merge", limit=MAX_FILE_BYTES), str(base)
    r = import_joint(args.description, args.joint, configs, gravity=gravity)
    new = imported_text(r, base_text, base_source, skip)      # checked: it parses and reads back
    lines = []      # printed once the file is written: a refused output prints nothing
    lines.append(f"{r.kind} {r.source}: joint {r.joint}, moving with it {', '.join(r.bodies)}; gravity "
          f"({', '.join(f'{x:g}' for x in r.gravity)}) m/s^2 in the root frame (MuJoCo {r.mujoco_version})")
    for c in r.configurations:
        lines.append(f"  {c.name:12s} J = {c.J:.6g} kg m^2  K = {c.K:.6g} Nm/rad  static gravity torque {c.tau:.3g} Nm  "
              f"({c.joints_text()})")
    lines.append(f"  damping {r.damping:g} Nm s/rad, friction {r.friction:g} Nm; gear ratio "
          + (f"{r.gear:g} ({r.gear_source})" if r.gear else "none") + "; rotor inertia "
          + (f"{r.rotor_inertia:g} kg m^2 (motor side)" if r.rotor_inertia is not None else
             f"armature {r.armature:g} kg m^2 (reflected to the joint, J_m N^2)" if r.armature is not None else "none"))
    lines += [f"  note: {note}" for note in r.notes]
    if args.merge is None:
        lines.append(f"  new file: the motor, gearbox and controller are PLACEHOLDERS from the bundled {TEMPLATE}.toml "
              "(source \"placeholder\"): replace them before trusting an analysis")
    with Transaction() as tx:
        tx.write_text(out, new, "--out")
    print("\n".join(lines))
    print(f"wrote {out}" + (f" (merged into a copy of {base_source})" if base_source else "")
          + (f"; skipped {', '.join(skip)}" if skip else ""))
    return 0


def _arguments(p) -> None:
    p.add_argument("description", metavar="DESCRIPTION", help="the robot's URDF (<robot>) or MJCF (<mujoco>) file")
    p.add_argument("--joint", required=True, metavar="NAME", help="the hinge joint of the actuator (e.g. lf_haa_joint)")
    p.add_argument("--configuration", action="append", required=True, metavar="NAME:JOINT=VALUE[,JOINT=VALUE...]",
                   help="a named configuration: other joints' values in rad, within their limits; the joints not "
                        "named at the description's reference (0). Repeatable; the first also gives [bodies.PORT]")
    p.add_argument("--merge", metavar="ACTUATOR", help="an actuator file (or bundled name) to merge into: its text with "
                   "the imported entries replaced or added, the rest kept (default: a new file whose motor, gearbox "
                   f"and controller are marked placeholders from {TEMPLATE})")
    p.add_argument("--gravity", metavar="X,Y,Z", help="gravity in the description's root frame, m/s^2 (default "
                   "0,0,-9.81; a base tilted by R in the world: R^T g)")
    p.add_argument("--skip", metavar="NAME[,NAME...]", help="flat names the import leaves as the merged file has them "
                   "(e.g. B_L2: keep an identified damping rather than the description's)")
    p.add_argument("--out", required=True, help="the actuator file written (.toml); never one of the inputs")


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"import-robot": (_arguments, _cmd_import_robot)}
