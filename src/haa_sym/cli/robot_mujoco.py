"""``haa-sym export-mujoco``: the actuator and its analysed controller as a MuJoCo model (issue 25;
docs/robot.md, "Export to MuJoCo")."""
from __future__ import annotations

import sys
from pathlib import Path

from haa_sym.errors import ParameterError
from haa_sym.io.outputs import Transaction, check_file
from haa_sym.loop import ClosedLoop
from haa_sym.robot.mujoco_export import INTEGRATORS, DEFAULT_INTEGRATOR, compile_check, export_mujoco

from haa_sym.cli.common import _common, _gain_flags, _loaded, _params, _parse_options, _points


def _cmd_export_mujoco(args) -> int:
    params = _params(args, _loaded(args))
    options = _parse_options(args.option)
    out = Path(args.out)
    if out.suffix.lower() != ".xml":
        raise ParameterError(f"--out {args.out!r}: unsupported file type; allowed: ['.xml']")
    controller = out.with_name(out.stem + "_controller.py")
    check_file(out, "--out")
    check_file(controller, "--out (the controller module beside it)")
    P, D = _points(args, "export-mujoco")
    if params.limits.active:
        print(f"haa-sym: warning: {params.source} [limits] ({', '.join(params.limits.active)}) are not exported: "
              "the MuJoCo model is the linear loop", file=sys.stderr)
    ex = export_mujoco(ClosedLoop(params, options), float(P[0]), float(D[0]), controller_module=controller.stem,
                       xml_name=out.name, integrator=args.integrator, steps_per_sample=args.steps_per_sample)
    compile_check(ex.xml)                    # MuJoCo absent: one line naming the extra
    with Transaction() as tx:
        tx.write_text(out, ex.xml, "--out")
        tx.write_text(controller, ex.controller, "--out")
    m = ex.meta
    n = len(m['joints'])
    print(f"export-mujoco: {n} hinge{'' if n == 1 else 's'} ({', '.join(m['joints'])}), controller of order "
          f"{len(m['Ac'])} at Ts = {m['Ts']:g} s, {m['integrator']} at timestep {m['timestep']:.4g} s "
          f"({m['steps_per_sample']} per sample); wrote {out} and {controller}")
    return 0


def _arguments(p) -> None:
    _common(p)
    _gain_flags(p, None, None, "the controller's gain point")
    p.add_argument("--out", required=True, metavar="model.xml",
                   help="the MJCF (.xml); the controller is written beside it as <stem>_controller.py")
    p.add_argument("--integrator", default=DEFAULT_INTEGRATOR, choices=list(INTEGRATORS),
                   help=f"MuJoCo's integrator (default {DEFAULT_INTEGRATOR})")
    p.add_argument("--steps-per-sample", type=int, default=None, metavar="N",
                   help="MuJoCo steps per controller sample (timestep Ts / N); default max(100, ceil(50 Ts R / L))")


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"export-mujoco": (_arguments, _cmd_export_mujoco)}
