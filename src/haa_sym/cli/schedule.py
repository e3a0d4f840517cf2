"""``haa-sym schedule``: the torque-gain scheduler (haa_sym.design.schedule) as a CSV table and
embedded C."""
from __future__ import annotations

import sys

from haa_sym.design.schedule import CELL_ROUNDS, schedule
from haa_sym.design.schedule_c import check_c_directory, write_c
from haa_sym.errors import ParameterError
from haa_sym.io.gridspec import grid
from haa_sym.io.outputs import Transaction
from haa_sym.io.progress import message
from haa_sym.io.tasks import local_workers

from haa_sym.cli.common import (SCHEDULER_HELP, TITLE_HELP, _axis, _common, _gain_flags, _leg, _leg_args, _plots,
                                _requirements, _say_leg, _setup, _uncertainty, _wrote)


def _range(text: str, flag: str, what: str) -> tuple[float, float]:
    lo, sep, hi = str(text).partition(":")
    try:
        r = (float(lo), float(hi)) if sep else None
    except ValueError:
        r = None
    if r is None or not (0 < r[0] < r[1] < float("inf")):
        raise ParameterError(f"{flag} {text!r}; allowed: LO:HI with 0 < LO < HI ({what})")
    return r


def _cmd_schedule(args) -> int:
    local_workers(args.scheduler)            # a bad local:N is refused before any work
    loop, out, plot = _setup(args, "schedule")
    if args.c_out is not None:
        check_c_directory(args.c_out)
    P, D = _axis(args, "P_gain"), _axis(args, "D_gain")
    beta_range = _range(args.beta_range, "--beta-range", "the torque-gain scale beta, Eq. 7")
    alphas = None if args.alpha_values is None else grid(args.alpha_values, "--alpha-values")
    fit = _uncertainty(args, loop.params, _leg(args, loop.params))
    leg_line = _say_leg(loop.params, _leg(args, loop.params), args.leg_mode, fit)
    s = schedule(loop, P, D, beta_range=beta_range, beta_tol=args.beta_tol, alpha_values=alphas,
                 requirements=_requirements(args), leg=_leg(args, loop.params), leg_mode=args.leg_mode,
                 uncertainty=(fit["box"] or None) if fit else None, scheduler=args.scheduler,
                 cell_rounds=args.cell_rounds)
    message(leg_line)
    if not s.feasible.any():
        with_alpha = f" with --alpha-values {args.alpha_values}" if args.alpha_values is not None else ""
        raise ParameterError(f"--beta-range {args.beta_range}{with_alpha}: no beta in the range meets "
                             f"{'+'.join(s.meta['requirements'])} for every leg configuration at any impedance of "
                             "the grid; allowed: a range (or requirements) that some impedance meets")
    table = s.table() if args.c_out is not None else None
    with Transaction() as tx:
        if out:
            s.save_csv(out, tx, "--out")
        if table is not None:
            write_c(table, args.c_out, tx)
        if plot:
            _plots().save_figure(_plots().plot_schedule(s, title=args.figure_title), plot, tx, "--plot")
    feas = int(s.feasible.sum())
    at_limit = int(s.beta_at_limit.sum())
    if at_limit:
        # one line: the range, not the model, limits these rows (their bandwidth gain is the range's)
        print(f"warning: {at_limit} of {feas} feasible impedances have beta at the top of --beta-range "
              f"({beta_range[1]:g}): the range, not the model, limits them (CSV column beta_at_limit); raise "
              "the range's top if the hardware takes more", file=sys.stderr)
    unsafe = int((~s.beta_fixed_feasible & s.feasible).sum())
    print(f"{s.feasible.size} impedances: {feas} with a robust beta in [{beta_range[0]:g}, {beta_range[1]:g}] "
          f"(tolerance {args.beta_tol:g}; leg {s.meta['leg'][0]}..{s.meta['leg'][1]}"
          + ("".join(f", {k} {lo:.4g}..{hi:.4g}" for k, (lo, hi) in s.meta["uncertainty"].items())
             if s.meta["uncertainty"] else "") + f", {s.n_configurations} "
          f"configurations{'' if s.converged else ', NOT converged'}); beta = 1 fails for some "
          f"{'configuration' if s.meta['uncertainty'] else 'leg'} at {unsafe} of "
          f"them; lookup safe on {s.meta['cells_safe']} of {s.meta['cells']} cells ({s.meta['cell_subdivisions'] + 1}^2 "
          f"sub-grid checked, {s.meta['grid_points_lowered_by_cell_check']} grid values lowered)"
          + _wrote(out) + (f"; C in {args.c_out}" if args.c_out else ""))
    return 0


def _schedule_args(sc) -> None:
    _common(sc)
    _gain_flags(sc, "log:1:2000:30", "lin:1:50:20", "an axis of the schedule's table (at least 2 values, "
                "P_gain > 0)")
    sc.add_argument("--beta-range", default="0.1:8", help="LO:HI of beta (default 0.1:8)")
    sc.add_argument("--beta-tol", type=float, default=0.02, help="relative step of the beta grid (default 0.02)")
    sc.add_argument("--alpha-values", help="schedule alpha too, from these values (grid spec, e.g. 0,0.5,0.94)")
    _leg_args(sc)
    sc.add_argument("--scheduler", help=SCHEDULER_HELP)
    sc.add_argument("--cell-rounds", type=int, default=CELL_ROUNDS, metavar="N",
                    help=f"rounds of the cell check between grid points; cells still failing in the last are given "
                         f"up (no safe gain) instead of lowering shared corners (default {CELL_ROUNDS}; docs/schedule.md)")
    sc.add_argument("--out", help="output .csv")
    sc.add_argument("--c-out", help="directory for haa_schedule.h and haa_schedule.c")
    sc.add_argument("--plot", help="output figure (.png/.pdf/.svg)")
    sc.add_argument("--title", help=TITLE_HELP)


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"schedule": (_schedule_args, _cmd_schedule)}
