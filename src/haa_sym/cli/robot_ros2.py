"""``haa-sym export-ros2``: the certified region as ros2_control parameters (a
``generate_parameter_library`` YAML whose bounds are the largest box inside the region) and as C
(``haa_region_contains``), :mod:`haa_sym.robot.ros2`; docs/robot.md, "Out to ros2_control"."""
from __future__ import annotations

import math
import sys
from pathlib import Path

from haa_sym._version import version
from haa_sym.design.schedule import CSV_CELL_CHECK, table_from_csv
from haa_sym.design.schedule_c import HEADER as SCHEDULE_HEADER, SOURCE as SCHEDULE_SOURCE, check_c_directory
from haa_sym.io.inputs import read_text
from haa_sym.errors import ParameterError
from haa_sym.robot import ros2

from haa_sym.loop import ClosedLoop

from haa_sym.cli.common import (MAP_D_GAIN, _axis, _check_out, _common, _gain_flags, _loaded, _params,
                                _parse_options, _requirements)

P_GAIN = "log:1:20000:200"
#: The largest schedule CSV read (bytes): a 200 x 200 schedule is about 3 MB.
MAX_SCHEDULE_BYTES = 64 << 20


def _measure(spec: str) -> str:
    """The box's measure along an axis: log for a ``log:`` grid spec, else linear (module docstring)."""
    return "log" if str(spec).strip().startswith("log:") else "linear"


def _cmd_export_ros2(args) -> int:
    params = _params(args, _loaded(args))
    loop = ClosedLoop(params, _parse_options(args.option))
    out = _check_out(args.out, "export-ros2", suffixes=(".yaml", ".yml"))
    names = (ros2.HEADER, ros2.SOURCE) + ((SCHEDULE_HEADER, SCHEDULE_SOURCE) if args.schedule else ())
    check_c_directory(args.c_out, "--c-out", names=names)
    schedule = None
    if args.schedule is not None:
        # the schedule's CSV (haa-sym schedule --out) as its lookup, checked before any work; the
        # provenance given here is used only for a CSV without the lookup's columns (an older one)
        schedule = table_from_csv(read_text(args.schedule, "--schedule", limit=MAX_SCHEDULE_BYTES), args.schedule,
                                  {"actuator": str(params.about.get("name") or Path(params.source).stem),
                                   "requirements": "those of the haa-sym schedule run that wrote the CSV",
                                   "tolerances": "those of the haa-sym schedule run that wrote the CSV",
                                   "haa_sym_version": version()})
    try:
        req = ros2._check_requirements(_requirements(args))
    except ParameterError:
        raise ParameterError(f"--require {args.require!r}; allowed: 'stable' and any of 'pm', 'passive', "
                             "comma-separated (e.g. stable,pm,passive)") from None
    if not (math.isfinite(args.region_rtol) and 0 < args.region_rtol < 1):
        raise ParameterError(f"--region-rtol {args.region_rtol!r}; allowed: 0 < value < 1")
    P, D = _axis(args, "P_gain"), _axis(args, "D_gain")
    ros2.params_yaml(ros2.Box(1.0, 2.0, 1.0, 2.0, "log", "linear"), {"actuator": "", "source": "",
                     "requirements": ""}, args.controller)          # a bad --controller before the work
    words = {"stable": "stable", "pm": "phase margin >= 30 deg", "passive": "passive"}
    meta = {"actuator": str(params.about.get("name") or Path(params.source).stem),
            "source": Path(params.source).name, "configuration": args.configuration,
            "requirements": ", ".join(words[r] for r in req),
            "map": f"P_gain {args.P_gain} Nm/rad x D_gain {args.D_gain} Nms/rad",
            "schedule": Path(args.schedule).name if args.schedule else None}
    table = ros2.certified_region(loop, P, D, req, rtol=args.region_rtol)
    if table.lo.size == 0:
        raise ParameterError(f"--require {','.join(req)}: no point of the map (--P-gain {args.P_gain}, --D-gain "
                             f"{args.D_gain}) meets the requirements; allowed: requirements or a map where some "
                             "gains meet them")
    box = ros2.certified_box(loop, table, req, _measure(args.P_gain), _measure(args.D_gain))
    ros2.write_outputs(out, args.c_out, table, box, meta, args.controller, schedule)
    if schedule is not None and schedule.meta["cell_check"] == CSV_CELL_CHECK:
        print(f"haa-sym: warning: --schedule {args.schedule}: the lookup's cells are not checked (the CSV holds beta "
              "at the grid points only); haa-sym schedule --c-out writes the cell-checked table", file=sys.stderr)
    P0, D0 = box.centre
    print(f"certified region ({meta['requirements']}): {table.D_rows.size} rows ({table.meta['inserted_rows']} "
          f"inserted), {table.lo.size} intervals; largest box P_gain [{box.P_lo:.6g}, {box.P_hi:.6g}] Nm/rad x "
          f"D_gain [{box.D_lo:.6g}, {box.D_hi:.6g}] Nms/rad (area in {box.P_measure} x {box.D_measure}; "
          f"{box.checked_points} points checked, {box.shrink_rounds} shrink rounds); default stiffness "
          f"{P0:.6g} Nm/rad, damping {D0:.6g} Nms/rad; wrote {out}, {Path(args.c_out) / ros2.HEADER}, "
          f"{Path(args.c_out) / ros2.SOURCE}"
          + (f", {Path(args.c_out) / SCHEDULE_HEADER}, {Path(args.c_out) / SCHEDULE_SOURCE} (the schedule "
             f"{args.schedule}: {schedule.shape[0]} x {schedule.shape[1]} points, {int(schedule.feasible.sum())} "
             "feasible)" if schedule is not None else ""))
    return 0


def _arguments(p) -> None:
    _common(p)
    _gain_flags(p, P_GAIN, MAP_D_GAIN, "an axis of the map the region is read from (at least 2 values; a log: "
                "axis is measured in log for the box)")
    p.add_argument("--require", default="stable,pm", help="stable[,pm][,passive]: the requirements the region "
                   "meets (pm: phase margin >= 30 deg; default stable,pm)")
    p.add_argument("--out", required=True, help="the parameter file (.yaml)")
    p.add_argument("--c-out", required=True, metavar="DIR", help="directory for haa_region.h and haa_region.c")
    p.add_argument("--schedule", metavar="SCHEDULE.csv", help="also emit the torque-gain schedule's lookup "
                   "(haa_schedule.h/.c, haa_schedule_lookup) into --c-out, from the CSV of haa-sym schedule --out: the "
                   "cell-checked table of its --c-out (an older CSV without the lookup's columns: unchecked, with a "
                   "warning; docs/robot.md)")
    p.add_argument("--controller", default=ros2.CONTROLLER_NAME,
                   help=f"the YAML's top-level entry (the generated C++ namespace; default {ros2.CONTROLLER_NAME})")
    p.add_argument("--region-rtol", type=float, default=ros2.REGION_RTOL, metavar="RTOL",
                   help="relative tolerance in P_gain of the table's interpolation between rows "
                        f"(default {ros2.REGION_RTOL:g})")


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"export-ros2": (_arguments, _cmd_export_ros2)}
