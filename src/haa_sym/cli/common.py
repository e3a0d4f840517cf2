"""What every command of ``haa-sym`` shares: the common flags (--params, --configuration, --set,
--option), the gain flags and their one syntax, output checks, figure titles and the
all-or-nothing writing of a command's outputs."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from haa_sym.analysis.measured import agreement
from haa_sym.analysis.robust import (UNCERTAINTY_ON_LEG, UNCERTAINTY_ON_LEG_DEFAULT, check_uncertainty, leg_ends,
                                     leg_text, leg_values, uncertainty_box, uncertainty_text)
from haa_sym.errors import ParameterError
from haa_sym.io.gridspec import gain_axis
from haa_sym.io.measured import read_measured
from haa_sym.io.uncertainty import fit_box, fit_values, read_fit
from haa_sym.io.outputs import Transaction, check_file
from haa_sym.loop import ClosedLoop, LoopOptions
from haa_sym.loop.options import parse_options
from haa_sym.model import filters
from haa_sym.model.motor import motor_constants_warning
from haa_sym.model.drive import DRIVE_KEYS, DRIVE_UNITS
from haa_sym.model.params import (ALIASES, CONTROLLER_KEYS, CONTROLLER_UNITS, actuator_path, apply_sets,
                                  bundled_actuators, load_params, parse_set)


OUTPUT_SUFFIXES = {"regions": (".npz",), "passivity": (".csv", ".json"), "step": (".csv",),
                   "boundary": (".json",), "contact": (".json",), "schedule": (".csv",)}


# the one parser of --set and --option, shared with the explorer (haa_sym.explore.state)
_parse_set = parse_set
_parse_options = parse_options


def _bundled_names() -> str:
    """The bundled actuators' names with their aliases, from the model directory itself (a file
    added there is named in every command's --help without editing this text)."""
    alias = {stem: a for a, stem in ALIASES.items()}
    return ", ".join(f"{n} or {alias[n]}" if n in alias else n for n in bundled_actuators())


PARAMS_HELP = (f"actuator: a TOML parameter file or a bundled name ({_bundled_names()}; "
               "`haa-sym actuators` lists them with their files); default: hyq_haa")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", metavar="NAME|FILE", help=PARAMS_HELP)
    p.add_argument("--configuration", help="leg configuration of the parameter file, e.g. retracted")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any key of the parameter file (repeatable), the value in SI units whatever "
                        "unit the file gives (kg m^2, Nm/rad, Nms/rad, H, Ohm, Nm/A, V s/rad, Ts in s, f_c in Hz; "
                        "docs/model.md, \"Units\"; `haa-sym options --params NAME` lists the keys, units and "
                        "allowed values); " + filters.help_text())
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="modelling option of haa_sym.LoopOptions (repeatable): " + ", ".join(LoopOptions.field_names())
                        + " (`haa-sym options` lists types, defaults and allowed values)")


def _loaded(args):
    """The parameters as the file gives them (with ``--configuration``), before any ``--set``."""
    params = load_params(actuator_path(args.params, "--params"))
    return params.configuration(args.configuration) if args.configuration else params


def _params(args, params=None):
    """The parameters of the command: the file's (``params``, default :func:`_loaded`) with
    ``--set`` applied."""
    params = _loaded(args) if params is None else params
    sets = _parse_set(args.set, tuple(params.plant.topology.parameter_keys) + CONTROLLER_KEYS + DRIVE_KEYS)
    params = apply_sets(params, sets)
    _warn_motor_constants(args, params)
    return params


def _warn_motor_constants(args, params) -> None:
    """The plausibility of k_t against k_w (haa_sym.model.actuator.motor_constants_warning) on
    the values the command analyses (the file's, a configuration's, --set's), once a command."""
    text = motor_constants_warning(params.plant.as_dict(), params.motor_convention, params.source)
    warned = vars(args).setdefault("_warned", set())
    if text and text not in warned:
        warned.add(text)
        print(f"haa-sym: warning: {text}", file=sys.stderr)


def _check_out(path: str | None, cmd: str, flag: str = "--out", suffixes: tuple[str, ...] | None = None) -> Path | None:
    """Validate an output path before any computation: suffix (``suffixes``, default the command's
    ``--out`` types of OUTPUT_SUFFIXES, or a figure's), existing writable directory."""
    if path is None:
        return None
    p = Path(path)
    allowed = suffixes or (OUTPUT_SUFFIXES[cmd] if flag == "--out" else (".png", ".pdf", ".svg"))
    if p.suffix.lower() not in allowed:
        raise ParameterError(f"{flag} {path!r}: unsupported file type; allowed: {list(allowed)}")
    return check_file(p, flag)


def _wrote(out) -> str:
    """The end of a command's summary line: which file it wrote, if any."""
    return f"; wrote {out}" if out else ""


GAIN_FLAGS = {"P_gain": ("--P-gain", "impedance stiffness P_gain", "Nm/rad"),
              "D_gain": ("--D-gain", "impedance damping D_gain", "Nms/rad")}
GRID_SHORT = "log:START:STOP:N, lin:START:STOP:N, V1,V2,... or one value V (>= 0)"


def _axis(args, name: str) -> np.ndarray:
    """The values of ``--P-gain`` / ``--D-gain``: a grid spec, a list or one value (one syntax,
    :mod:`haa_sym.io.gridspec`, in every command)."""
    return gain_axis(getattr(args, name), GAIN_FLAGS[name][0], name)


def _points(args, one: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The gain points of a point command: the i-th P_gain with the i-th D_gain, a single value
    pairing with every value of the other (see the module docstring). ``one``: the command takes
    exactly one point (its name, for the message)."""
    P, D = _axis(args, "P_gain"), _axis(args, "D_gain")
    if P.size != D.size and 1 not in (P.size, D.size):
        raise ParameterError(f"--P-gain {args.P_gain!r} gives {P.size} values and --D-gain {args.D_gain!r} "
                             f"{D.size}; they pair up (the i-th with the i-th), so give the same number; "
                             "allowed: equal counts, or one value for either")
    P, D = np.broadcast_arrays(P, D)
    if one is not None and P.size != 1:
        raise ParameterError(f"--P-gain {args.P_gain!r} --D-gain {args.D_gain!r} gives {P.size} points; "
                             f"allowed: one point ({one})")
    return P.copy(), D.copy()


def _gain_flags(parser, P_default: str | None, D_default: str | None, role: str) -> None:
    """``--P-gain`` and ``--D-gain`` with the one syntax, their units, ``role`` (what the command
    makes of them) and their defaults in the help."""
    for name, default in (("P_gain", P_default), ("D_gain", D_default)):
        flag, what, unit = GAIN_FLAGS[name]
        parser.add_argument(flag, default=default, required=default is None, metavar="GRID",
                            help=f"{what}, {unit}: {GRID_SHORT}; {role}; "
                                 + ("required" if default is None else f"default {default}"))


def differences(now: dict, base: dict) -> dict:
    """The entries of ``now`` whose value differs from ``base``'s, or that ``base`` lacks (what a
    figure's title says of its parameters and options)."""
    return {k: v for k, v in now.items() if k not in base or base[k] != v}


def _value(key: str, value, units: dict) -> str:
    unit = units.get(key, "")
    text = f"{value:g}" if isinstance(value, (int, float)) and not isinstance(value, bool) else str(value)
    return f"{key} = {text}" + (f" {unit}" if unit and unit not in ("-", "samples") else "")


def figure_title(loop, file_params, configuration: str | None = None, user_title: str | None = None) -> str:
    """A figure's title: the actuator (its file's [about] name, else the file's name), the
    configuration, then what differs from the file: the ``--set`` values (the loop's parameters
    against the file's) and the options that are not LoopOptions' defaults. The user's
    ``--title`` comes first, on a line of its own (prepended, not replacing: a figure always
    says what it shows)."""
    params = loop.params
    name = str(params.about.get("name") or Path(params.source).stem)
    head = name + (f", {configuration} configuration" if configuration else "")
    now, base = params.to_dict(), file_params.to_dict()
    units = {**params.plant.topology.units, **CONTROLLER_UNITS, **DRIVE_UNITS}
    sets = {**differences(now["plant"], base["plant"]), **differences(now["controller"], base["controller"]),
            **differences(now["drive"], base["drive"])}
    opts = differences(loop.options.to_dict(), LoopOptions().resolved(params.plant.topology).to_dict())
    said = ", ".join(_value(k, v, units) for k, v in sets.items())
    if opts:
        said += ("; " if said else "") + "option" + "s" * (len(opts) > 1) + " " + ", ".join(
            _value(k, v, {}) for k, v in opts.items())
    lines = [user_title] if user_title else []
    return "\n".join(lines + [head, said or "the file's values, default options"])


def _setup(args, cmd: str):
    """What every analysis command starts with: the closed loop of the parameters and options,
    and the output paths, all checked before any computation; sets ``args.figure_title`` (what
    the figure of ``--plot`` is titled, :func:`figure_title`)."""
    file_params = _loaded(args)
    params, options = _params(args, file_params), _parse_options(args.option)
    out, plot = _check_out(args.out, cmd), _check_out(args.plot, cmd, "--plot")
    if plot and getattr(args, "title", None):
        _plots().check_title(args.title, "--title")
    loop = ClosedLoop(params, options)
    args.figure_title = figure_title(loop, file_params, args.configuration, getattr(args, "title", None))
    return loop, out, plot


def measured_torque(topology) -> tuple[str, str]:
    """(axis label with its unit, legend) of the torque the torque loop measures: the sensed
    coupling's transmitted torque, or the estimate k_t N I_m of a current-sensing drive
    (``[sensors] torque``)."""
    if topology.sensor == "current":
        return "torque estimate k_t N I_m (Nm)", "torque from the motor current, k_t N I_m"
    damping = "spring and damper" if topology.torque_damping else "spring only"
    return (f"sensed torque T_{topology.sensor} (Nm)",
            f"T_{topology.sensor}: torque sensor on coupling {topology.sensor} ({damping})")


def _plots():
    """haa_sym.io.plots, imported only when a figure is asked for (matplotlib is slow to import)."""
    from haa_sym.io import plots
    return plots


def _write_outputs(out, plot, write_out, figure, extra=()) -> None:
    """``--out`` through ``write_out(path, tx)`` and ``--plot`` from ``figure()``, all or nothing
    (:mod:`haa_sym.io.outputs`): a failure leaves both as they were; ``extra``: more outputs,
    ``(path or None, write(path, tx))`` each, in the same transaction."""
    with Transaction() as tx:
        if out:
            write_out(out, tx)
        for path, write in extra:
            if path:
                write(path, tx)
        if plot:
            _plots().save_figure(figure(), plot, tx, "--plot")


def _leg(args, params):
    if args.leg is None:
        return None
    a, sep, b = args.leg.partition(":")
    if not sep:
        raise ParameterError(f"--leg {args.leg!r}; allowed: FROM:TO, two configuration names of the file "
                             f"(or 'nominal'): {['nominal'] + list(params.configurations)}")
    return (a.strip(), b.strip())


def _say_leg(params, leg, leg_mode, fit=None) -> str:
    """Before a leg-range analysis: a warning, shown even with --quiet, when the parameters' own
    values (a file's body tables, --set) lie outside the range, which replaces them, or differ
    from the values of an identification ``fit`` (:func:`_uncertainty`), whose box replaces
    them. Returns the line saying which configurations and values it analyses, a progress
    message the command shows once its input has passed every check (a refused command prints
    one line only)."""
    box = fit["box"] if fit is not None else None
    line, warning = leg_text(leg_values(params, leg, leg_mode, box))
    lines, warnings = [line], [warning]
    if fit is not None and box:
        u_line, u_warning = uncertainty_text(params, fit_values(fit), box)
        lines.append(f"{u_line} (from {fit['source']})")
        warnings.append(u_warning)
    if fit is not None and fit["dropped"]:
        lines.append(f"the fit's interval of {', '.join(fit['dropped'])} not analysed: the leg range sets "
                     f"{'it' if len(fit['dropped']) == 1 else 'them'} (--uncertainty-on-leg unset)")
    for w in warnings:
        if w:
            print(f"haa-sym: warning: {w}", file=sys.stderr)
    return "; ".join(lines)


def _uncertainty(args, params, leg):
    """The report of ``--uncertainty`` (None without), read and checked before any computation:
    the schema (:func:`haa_sym.io.uncertainty.read_fit`), its keys against the actuator's plant
    keys, and its box against the leg range (:func:`haa_sym.analysis.robust.check_uncertainty`)."""
    if getattr(args, "uncertainty", None) is None:
        return None
    fit = read_fit(args.uncertainty, "--uncertainty", keys=tuple(params.plant.topology.parameter_keys))
    leg_ends(params, leg)            # a bad --leg is the leg's mistake, not the report's
    try:
        # fit["box"]: what the analyses take (a key the range sets by --uncertainty-on-leg);
        # fit["dropped"]: the keys left out ("unset")
        fit["box"], fit["dropped"] = uncertainty_box(params, fit_box(fit), fit_values(fit), leg,
                                                     args.uncertainty_on_leg)
        if fit["box"]:
            check_uncertainty(params, fit["box"], leg)
    except ParameterError as exc:
        raise ParameterError(f"--uncertainty {args.uncertainty!r}: {exc}") from None
    return fit


def _measured(args):
    """The points of ``--measured`` (None without), read and checked before any computation."""
    return None if getattr(args, "measured", None) is None else read_measured(args.measured, "--measured")


def _agreement(loop, points, P, D, configurations=None):
    """The model's agreement with measured ``points`` (None without): the counts (for meta and
    the summary line) and the plain data the figure draws; a warning for points outside the
    map's axes (counted, not drawn)."""
    if points is None:
        return None, None
    a = agreement(loop, points.P_gain, points.D_gain, points.outcome, configurations=configurations)
    outside = int((~((a.P_gain >= P.min()) & (a.P_gain <= P.max()) & (a.D_gain >= D.min())
                     & (a.D_gain <= D.max()))).sum())
    if outside:
        print(f"haa-sym: warning: {outside} of {a.P_gain.size} measured points of {points.source} lie outside "
              "the map's axes: counted, not drawn", file=sys.stderr)
    counts = {**a.counts, "source": points.source, "outside_axes": outside}
    drawn = {"P_gain": a.P_gain, "D_gain": a.D_gain, "outcome": a.outcome, "agrees": a.agrees,
             "configurations": a.counts["configurations"]}
    return counts, drawn


def _agreement_text(counts) -> str:
    """The summary's clause on measured points: how many agree, per outcome."""
    if counts is None:
        return ""
    per = ", ".join(f"{counts[o]['agree']}/{counts[o]['points']} {o}" for o in ("stable", "unstable", "limit_cycle")
                    if counts[o]["points"])
    strict = f" ({counts['agree_all']} for every configuration)" if counts["configurations"] > 1 else ""
    return (f"; measured: {counts['agree']} of {counts['points']} agree with the model{strict} [{per}; "
            "limit_cycle agrees with unstable or PM < 30 deg]")


def _requirements(args):
    return tuple(r.strip() for r in args.require.split(",") if r.strip())



# The D_gain axis of the maps (regions, boundary): the paper's Figs. 8-11 and model/paper.toml
# start at 1 Nms/rad, and one default for both means `boundary` finds the curves `regions --plot`
# draws. (boundary used 0..50 before issue 16; D_gain = 0 remains reachable with --D-gain.)
MAP_D_GAIN = "lin:1:50:100"
TITLE_HELP = ("text above the figure's automatic title (the actuator, then what differs from its file: --set values "
              "and non-default --option values), on a line of its own")
POINTS_ROLE = "points: the i-th P_gain with the i-th D_gain, one value pairing with all"
# where the tasks of regions --nonlinear/--robust and schedule run (haa_sym.io.tasks)

SCHEDULER_HELP = ("local:N starts N worker processes on this machine (no network port; stopped at the "
                  "end; at most 8 per core, and above the cores they share them, with a warning), or the address of a running dask.distributed scheduler, e.g. "
                  "tcp://127.0.0.1:8786 (docs/schedule.md); default: in-process")


def _map_args(parser, D_default: str, what: str, suffix: str) -> None:
    """The gain-plane arguments of ``regions`` and ``boundary``."""
    _gain_flags(parser, "log:1:20000:200", D_default, what)
    parser.add_argument("--out", help=f"output {suffix}")
    parser.add_argument("--plot", help="output figure (.png/.pdf/.svg)")
    parser.add_argument("--title", help=TITLE_HELP)


def _leg_args(parser) -> None:
    """The leg range and the requirements of ``regions --robust`` and ``schedule``."""
    parser.add_argument("--require", default="stable,pm", help="stable[,pm][,passive] (default stable,pm)")
    parser.add_argument("--leg", help="FROM:TO configurations bounding the leg range (default "
                        "retracted:extended, or the file's first two)")
    parser.add_argument("--leg-mode", choices=("segment", "box"), default="segment",
                        help="the leg range: the segment between the two (default) or the box of every pair")
    parser.add_argument("--uncertainty", metavar="FIT.json",
                        help="the report of haa-sym identify: the gains must hold for every value in the 95 %% "
                             "confidence box of its fitted keys too (a box, combined with the leg range; "
                             "docs/uncertainty.md)")
    parser.add_argument("--uncertainty-on-leg", choices=UNCERTAINTY_ON_LEG, default=UNCERTAINTY_ON_LEG_DEFAULT,
                        help="a fitted key the leg range also sets: 'relative' (default) the fit's interval "
                             "relative to its value, around each leg configuration's value; 'unset' left out (the "
                             "box on the other keys); 'refuse' refused")


def cycle_comparison(c: dict, head: str, unit: str = "") -> str:
    """One line: how a simulation bears out a describing function's predicted cycle (the dict of
    :func:`haa_sym.analysis.describing.compare_cycle`), after ``head``; ``unit`` of the signal
    (the voltage's simulated amplitude is its fundamental's, as the prediction's)."""
    if c["simulated_kind"] == "sustained":
        amp = "" if c["simulated_amplitude"] is None or c["amplitude_error"] is None else \
            (("fundamental " if c["signal"] in ("voltage", "current command") else "") + f"{c['simulated_amplitude']:.4g}"
             + (f" {unit}" if unit else "") + f" (error {100 * c['amplitude_error']:.3g} %) ")
        text = (f"{head} {c['signal']}: {amp}at {c['simulated_frequency_hz']:.4g} Hz (error "
                f"{100 * c['frequency_error']:.3g} %): {'agrees' if c['agrees'] else 'DISAGREES'} within "
                f"{100 * c['tolerance']:.3g} %")
    else:
        text = (f"{head} {c['signal']}: no sustained periodic oscillation "
                f"({c['simulated_kind'] or 'no usable trace'})")
    if c["untrusted"]:
        text += "; the prediction cannot be trusted here: " + "; ".join(c["untrusted"])
    return text

