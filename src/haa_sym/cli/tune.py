"""``haa-sym tune``: the torque PI of widest bandwidth under the Sec. 3.2 margins, written as a
new actuator file (:mod:`haa_sym.design.tune`)."""
from __future__ import annotations

import math
from pathlib import Path

from haa_sym.io.inputs import read_text
from haa_sym.analysis.torque import BANDWIDTH_DEFINITIONS, SETTLING_BAND, step_response
from haa_sym.design.tune import GM_TARGET_DB, OBJECTIVES, PM_TARGET_DEG, TuneOptions, tune, tuned_text
from haa_sym.errors import ParameterError
from haa_sym.io.formats import save_json
from haa_sym.io.outputs import Transaction
from haa_sym.loop import ClosedLoop
from haa_sym.model.params import MAX_FILE_BYTES, actuator_path, load_params

from haa_sym.cli.common import (PARAMS_HELP, TITLE_HELP, _check_out, _parse_options, _plots, _warn_motor_constants,
                                measured_torque)


def _range(text: str, flag: str):
    """'LO:HI' (two finite numbers) or 'none' (stable-alpha only)."""
    if flag == "--stable-alpha" and text.strip().lower() == "none":
        return None
    lo, sep, hi = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return (float(lo), float(hi))
    except ValueError:
        raise ParameterError(f"{flag} {text!r}: not LO:HI; allowed: two numbers LO:HI"
                             + (" or none" if flag == "--stable-alpha" else "")) from None


# TuneOptions' field -> the flag that sets it (its messages name the flag)
FLAGS = {"pm_deg": "--pm", "gm_db": "--gm", "objective": "--objective", "stable_alpha": "--stable-alpha",
         "lead_range": "--lead-range", "integral_range": "--integral-range", "n_lead": "--n-lead",
         "n_integral": "--n-integral", "rtol": "--rtol", "step_duration": "--step-duration",
         "passive_at": "--passive-at", "passive_configurations": "--passive-configurations",
         "bandwidth": "--bandwidth"}


def _points(text: str | None) -> tuple:
    """'P:D[,P:D...]' impedance gains (Nm/rad, Nms/rad) -> ((P, D), ...)."""
    if not text:
        return ()
    out = []
    for item in text.split(","):
        P, sep, D = item.partition(":")
        try:
            if not sep:
                raise ValueError
            out.append((float(P), float(D)))
        except ValueError:
            raise ParameterError(f"--passive-at {text!r}: {item!r} is not P_GAIN:D_GAIN; allowed: "
                                 "P:D[,P:D...] in Nm/rad and Nms/rad") from None
    return tuple(out)


def _tune_options(args) -> TuneOptions:
    if args.passive_configurations is not None and not args.passive_at:
        raise ParameterError(f"--passive-configurations {args.passive_configurations!r} without --passive-at: it says "
                             "where the port must be passive, and no impedance gains say at which; allowed: "
                             "--passive-at P:D[,P:D...] with it, or neither")
    values = {"pm_deg": args.pm, "gm_db": args.gm, "objective": args.objective,
              "stable_alpha": _range(args.stable_alpha, "--stable-alpha"),
              "lead_range": _range(args.lead_range, "--lead-range"),
              "integral_range": _range(args.integral_range, "--integral-range"),
              "n_lead": args.n_lead, "n_integral": args.n_integral, "rtol": args.rtol,
              "step_duration": args.step_duration, "passive_at": _points(args.passive_at),
              "passive_configurations": tuple(c.strip() for c in (args.passive_configurations or "nominal").split(",")
                                             if c.strip()),
              "bandwidth": args.bandwidth}
    try:
        return TuneOptions(**values)
    except ParameterError as exc:
        msg = str(exc)
        name = msg.split(" = ", 1)[0]
        raise ParameterError(f"{FLAGS.get(name, name)}: {msg}") from None


def _load_modes(r, g) -> str:
    """'feature (configurations); ...' for the configurations whose |H_T| has a load mode near
    the bandwidth, grouped by identical text ('' if none)."""
    groups: dict = {}
    for c, m in zip(r.configurations, g.load_modes):
        if m is not None:
            groups.setdefault(m.describe(), []).append(c)
    return "; ".join(f"{text} ({', '.join(cs)}), below twice the bandwidth" for text, cs in groups.items())


def _cmd_tune(args) -> int:
    src = actuator_path(args.params, "--params")
    params = load_params(src)
    _warn_motor_constants(args, params)        # as every command that takes --params
    options = _parse_options(args.option)
    opts = _tune_options(args)
    names = ["nominal", *params.configurations]
    unknown = [c for c in opts.passive_configurations if c not in names]
    if unknown:
        raise ParameterError(f"--passive-configurations {args.passive_configurations!r}: {unknown} not in {src}; "
                             f"allowed: {names}")
    out = _check_out(args.out, "tune", "--out", (".toml",))
    report = _check_out(args.report, "tune", "--report", (".json",))
    plot = _check_out(args.plot, "tune", "--plot")
    if plot and args.title:
        _plots().check_title(args.title, "--title")
    text = read_text(src, "--params", limit=MAX_FILE_BYTES)
    r = tune(params, options, opts)
    new = tuned_text(text, r, str(src))           # checked: it parses and gives the new gains
    b, a = r.before, r.after
    print(f"{params.about.get('name') or Path(src).stem}: targets PM >= {opts.pm_deg:g} deg, GM >= {opts.gm_db:g} dB"
          + ("" if opts.stable_alpha is None else f", stable for alpha {opts.stable_alpha[0]:g}..{opts.stable_alpha[1]:g}")
          + ("" if not opts.passive_at else ", passive at (P_gain, D_gain) " + " ".join(
              f"({p:g}, {d:g})" for p, d in opts.passive_at) + " at " + ", ".join(opts.passive_configurations))
          + f"; objective: {opts.objective} bandwidth; {r.evaluations} PIs decided")
    print(f"bandwidth: {opts.bandwidth}, {BANDWIDTH_DEFINITIONS[opts.bandwidth]}; t90: from then on >= 90 % of the "
          f"final value; settling: last leaving +-{100 * SETTLING_BAND:g} % ({opts.step_duration:g} s step)")

    def fmt(x, unit, spec=".4g", none="n/a"):
        return f"{x:{spec}} {unit}" if math.isfinite(x) else none
    reports = (("before", b),) if r.unchanged else (("before", b), ("after", a))
    for label, g in reports:
        print(f"{label}: P_t0 = {g.P_t0:.6g} V/Nm, I_t0 = {g.I_t0:.6g} V/(Nm s); worst-case bandwidth "
              f"{fmt(g.worst_bandwidth, 'rad/s')}; targets met at {int(g.meets.sum())} of {g.meets.size}")
        for i, c in enumerate(r.configurations):
            print(f"  {c:14s} bandwidth {fmt(g.bandwidth_rad_s[i], 'rad/s'):>13s}  "
                  f"PM {fmt(g.pm_deg[i], 'deg', '.2f', 'no crossover'):>11s}  "
                  f"GM {fmt(g.gm_db[i], 'dB', '.2f', 'none'):>9s}  t90 {fmt(g.t90_s[i], 's', '.3f', 'not held'):>9s}  "
                  f"settling {fmt(g.settling_time_s[i], 's', '.3f', 'not settled'):>9s}"
                  + ("" if g.meets[i] else "  (misses a target)"))
        modes = _load_modes(r, g)
        if modes:
            print(f"  load mode dominates: {modes}")
    if r.unchanged:
        print("after: already at the optimum (no change): the tuned gains are the file's")
    elif r.within_tolerance:
        print(f"note: the file's PI was already at the optimum within the search's tolerance (--rtol {opts.rtol:g}): "
              "the tuned gains differ from it by no more than that")
    print(f"active constraint: {r.active}" + ("; the optimum lies on the search range's edge (widen "
                                             "--lead-range / --integral-range)" if r.at_range_edge else ""))

    def figure():
        steps, notes = [], []
        for label, g, ls in (("file's PI", b, "--"), ("tuned PI", a, "-")):
            if r.unchanged and label == "tuned PI":
                notes.append("tuned PI: already at the optimum (no change)")
                continue
            s = step_response(ClosedLoop(params.with_values(P_t0=g.P_t0, I_t0=g.I_t0), options),
                              duration=opts.step_duration)
            steps.append((s.t, s.T, f"{label} (nominal values)", ls))
            modes = _load_modes(r, g)
            notes.append(f"{label}, nominal: bandwidth ({opts.bandwidth}) {fmt(g.bandwidth_rad_s[0], 'rad/s')}, "
                         f"t90 {fmt(g.t90_s[0], 's', '.3f', 'not held')}, settling (5 %) "
                         f"{fmt(g.settling_time_s[0], 's', '.3f', 'not settled')}"
                         + (f"; load mode dominates: {modes}" if modes else ""))
        name = str(params.about.get("name") or Path(src).stem)
        title = "\n".join(([args.title] if args.title else []) + [
            f"{name}: torque PI tuned for PM >= {opts.pm_deg:g} deg, GM >= {opts.gm_db:g} dB at every configuration"])
        return _plots().plot_tune(r.lead_s, r.integral, r.grid_objective, (b.P_t0, b.I_t0), (a.P_t0, a.I_t0),
                                  steps, title, ylabel=measured_torque(params.plant.topology)[0],
                                  notes="\n".join(notes), band=SETTLING_BAND)

    with Transaction() as tx:
        tx.write_text(out, new, "--out")
        if report:
            save_json(report, r.to_json(), tx, "--report")
        if plot:
            _plots().save_figure(figure(), plot, tx, "--plot")
    print(f"wrote {out}" + (f", {report}" if report else "") + (f", {plot}" if plot else ""))
    return 0


def _arguments(t) -> None:
    t.add_argument("--params", metavar="NAME|FILE", help=PARAMS_HELP)
    t.add_argument("--out", required=True, help="the tuned actuator file (.toml): the input's text with P_t0 "
                   "and I_t0 replaced, their descriptions saying the rule")
    t.add_argument("--report", help="before/after per configuration, the search (.json)")
    t.add_argument("--plot", help="output figure (.png/.pdf/.svg): the search grid and the torque steps")
    t.add_argument("--title", help=TITLE_HELP)
    t.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="modelling option of haa_sym.LoopOptions (repeatable; `haa-sym options`)")
    t.add_argument("--pm", type=float, default=PM_TARGET_DEG, metavar="DEG",
                   help=f"phase-margin target, deg, at every gain crossover (default {PM_TARGET_DEG:g}, Sec. 3.2)")
    t.add_argument("--gm", type=float, default=GM_TARGET_DB, metavar="DB",
                   help=f"gain-margin target, dB, at every phase crossover, both directions (min |GM|; default "
                        f"{GM_TARGET_DB:g}, Sec. 3.2)")
    t.add_argument("--objective", choices=OBJECTIVES, default="worst",
                   help="maximise the smallest bandwidth over the configurations (worst, default) or the nominal one")
    d = TuneOptions()
    t.add_argument("--stable-alpha", default=f"{d.stable_alpha[0]:g}:{d.stable_alpha[1]:g}", metavar="LO:HI|none",
                   help="alpha range where the torque loop must stay stable (default 0:1, Sec. 3.2; none: not required)")
    t.add_argument("--lead-range", default=f"{d.lead_range[0]:g}:{d.lead_range[1]:g}", metavar="LO:HI",
                   help=f"lead time tau = P_t0/I_t0 of the search grid, s (plus tau = 0; default {d.lead_range[0]:g}:{d.lead_range[1]:g})")
    t.add_argument("--integral-range", default=f"{d.integral_range[0]:g}:{d.integral_range[1]:g}", metavar="LO:HI",
                   help="I_t0 of the search grid in units of R/(k_t N) per s (default "
                        f"{d.integral_range[0]:g}:{d.integral_range[1]:g})")
    t.add_argument("--n-lead", type=int, default=d.n_lead, help=f"tau values of the grid (default {d.n_lead})")
    t.add_argument("--n-integral", type=int, default=d.n_integral,
                   help=f"I_t0 values of the grid (default {d.n_integral})")
    t.add_argument("--rtol", type=float, default=d.rtol, help=f"relative tolerance of the refinement (default {d.rtol:g})")
    t.add_argument("--step-duration", type=float, default=d.step_duration,
                   help=f"window of the reported torque steps, s (default {d.step_duration:g})")
    t.add_argument("--passive-at", metavar="P:D[,P:D...]",
                   help="impedance gains (P_gain Nm/rad : D_gain Nms/rad) where the port must also be passive at "
                        "configuration of --passive-configurations (default: none, as Sec. 3.2)")
    t.add_argument("--passive-configurations", default=None, metavar="NAME[,NAME...]",
                   help="where --passive-at is required: nominal and/or the file's configurations (default nominal; "
                        "only with --passive-at)")
    t.add_argument("--bandwidth", choices=tuple(BANDWIDTH_DEFINITIONS), default=d.bandwidth,
                   help="the bandwidth maximised and reported: tracking (default), where the tracking error "
                        "|1 - H_T| first reaches -3 dB; magnitude, the paper's -3 dB of |H_T| (Sec. 3.3)")


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"tune": (_arguments, _cmd_tune)}
