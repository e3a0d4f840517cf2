"""``haa-sym``: command line of haa_sym.

Examples, one per command:
  haa-sym regions --set beta=2 --P-gain log:1:20000:200 --D-gain lin:1:50:100 --out map.npz --plot map.png
  haa-sym boundary --params sea --out boundary.json --plot boundary.png
  haa-sym schedule --P-gain log:1:2000:30 --D-gain lin:1:50:20 --out schedule.csv --c-out ctrl/
  haa-sym passivity --P-gain 0,200,20000 --D-gain 0,10,50 --out cells.csv   # Table 2's columns
  haa-sym stability --P-gain 200,2000 --D-gain 10 --set N_av=10           # two points, one line each
  haa-sym margins --P-gain 200 --D-gain 10
  haa-sym contact --P-gain 200 --D-gain 10 --out contact.json
  haa-sym step --set K_L2=0 --out step.csv --plot step.png                 # Fig. 7
  haa-sym reproduce --out results/            every figure and table of the paper + REPORT.md
  haa-sym verify --params harmonic_drive      check the equations (any actuator: the generic rows)
  haa-sym compile my_actuator.toml            compile an actuator file's plant ahead of time
  haa-sym actuators                           the bundled actuators, their configurations and files
  haa-sym options --params sea                every --set key (units, allowed) and --option value

Gains: --P-gain (P_gain, Nm/rad) and --D-gain (D_gain, Nms/rad) take the same syntax in every
command, a grid of values: 'log:START:STOP:N' (N log-spaced, 0 < START <= STOP),
'lin:START:STOP:N' (N evenly spaced, 0 <= START <= STOP), 'V1,V2,...' or one value 'V', all
>= 0. regions, boundary and schedule take the two as the axes of a map (every P_gain with every
D_gain); passivity, stability, margins and contact take points: the i-th P_gain with the i-th
D_gain (the same number of values, as the columns of Table 2), a single value pairing with every
value of the other (contact: one point).

Every analysis command takes ``--params NAME|FILE`` (a bundled actuator, ``haa-sym actuators``,
or a TOML file; default hyq_haa), ``--configuration NAME`` (e.g. retracted), ``--set KEY=VALUE``
for any key of the parameter file,
in SI units (``--set beta=2 --set N_av=10 --set J_L2=0.129 --set
Ts=0.006``) and ``--option KEY=VALUE`` for the modelling options of ``haa_sym.LoopOptions``
(``--option port=dtheta_L1 --option delay=1``); ``haa-sym options`` lists both with units,
defaults and allowed values. Bad input exits with status 2 and a message naming the field;
nothing partial is written, and missing directories of an output path are created (and removed
again if the command fails). Results go to stdout; progress bars (on a terminal, for work longer
than 2 s) to stderr; ``--quiet`` silences them, ``--progress`` forces them. ``haa-sym
--version`` prints the version.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import threading
from pathlib import Path

import numpy as np

from haa_sym._version import __version__
from haa_sym.analysis.boundaries.combined import boundaries
from haa_sym.analysis.contact import contact_intervals
from haa_sym.analysis.margins import margins
from haa_sym.analysis.passivity import bands_beyond, corrected_phase, passivity
from haa_sym.analysis.regions import region_map
from haa_sym.analysis.robust import leg_text, leg_values, robust_region
from haa_sym.analysis.torque import STEP_CONVENTION, describe_step, step_response, torque_bandwidth
from haa_sym.check.verify import main as verify_main
from haa_sym.compiled.generated import evaluators
from haa_sym.compiled.plant_code import compile_topology
from haa_sym.design.schedule import schedule
from haa_sym.design.schedule_c import check_c_directory, write_c
from haa_sym.errors import CompilerError, ParameterError, StaleGeneratedCode, Terminated
from haa_sym.io.formats import save_json, save_npz
from haa_sym.io.gridspec import GRID_SYNTAX, grid
from haa_sym.io.outputs import Transaction, check_file, csv_text
from haa_sym.io.progress import message, set_progress
from haa_sym.loop import ClosedLoop, LoopOptions
from haa_sym.loop.options import ALLOWED as OPTION_ALLOWED
from haa_sym.model import filters
from haa_sym.model.params import (ALIASES, CONTROLLER_KEYS, CONTROLLER_UNITS, STRING_KEYS, actuator_path,
                                  bundled_actuators, gain_array, load_params, set_keys)
from haa_sym.paper.reproduce import reproduce

OUTPUT_SUFFIXES = {"regions": (".npz",), "passivity": (".csv", ".json"), "step": (".csv",),
                   "boundary": (".json",), "contact": (".json",), "schedule": (".csv",)}


def _parse_set(items: list[str], known: tuple[str, ...] | None = None) -> dict[str, float]:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise ParameterError(f"--set {item!r}: expected KEY=VALUE")
        key, value = key.strip(), value.strip()
        if key in STRING_KEYS:          # a choice by name (velocity_filter), checked by Controller
            out[key] = value
            continue
        try:
            # an integer stays one, so that messages show the value as typed (N_av = 0, not 0.0)
            out[key] = int(value) if value.lstrip("+-").isdigit() else float(value)
        except ValueError:
            if known is not None and key not in known:    # the key is the mistake, not the value
                raise ParameterError(f"--set {key}={value}: unknown parameter key(s) {[key]}; "
                                     f"allowed: {list(known)}") from None
            raise ParameterError(f"--set {key}={value}: {value!r} is not a number; allowed: a finite "
                                 "number") from None
    return out


def _parse_options(items: list[str]):
    fields = LoopOptions.field_names()
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep:
            raise ParameterError(f"--option {item!r}: expected KEY=VALUE")
        if key not in fields:
            raise ParameterError(f"--option {item!r}: unknown option {key!r}; allowed: {list(fields)}")
        kind, optional = LoopOptions.field_type(key)
        try:
            if optional and value.lower() == "none":        # the actuator file's default
                out[key] = None
            elif kind is bool:
                if value.lower() not in ("true", "false", "1", "0"):
                    raise ValueError
                out[key] = value.lower() in ("true", "1")
            elif kind is int:
                out[key] = int(value)
            elif kind is float:
                out[key] = float(value)
            else:
                out[key] = value
        except ValueError:
            allowed = {bool: "true or false", int: "an integer", float: "a number"}.get(kind, "text")
            raise ParameterError(f"--option {item!r}: {value!r} is not a valid {kind.__name__}; "
                                 f"allowed: {allowed}{' or none' if optional else ''}") from None
    try:
        options = LoopOptions(**out)
        # the one budget gate of the frequency grid, before any command builds or prints anything
        options.numerics.check_budget()
    except ParameterError as exc:
        raise ParameterError(f"--option {exc}") from None
    return options


class _Parser(argparse.ArgumentParser):
    """argparse with the project's error form: one line, exit status 2 (argparse's own usage
    block is what ``--help`` is for)."""

    def error(self, message: str):
        self.exit(2, f"haa-sym: error: {message}; see `{self.prog} --help`\n")


PARAMS_HELP = ("actuator: a TOML parameter file or a bundled name (hyq_haa or hyq, sea, harmonic_drive; "
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
    sets = _parse_set(args.set, tuple(params.plant.topology.parameter_keys) + CONTROLLER_KEYS)
    if not sets:
        return params
    try:                  # all at once: velocity_filter and its keys (f_c) are only valid together
        return params.with_values(**sets)
    except ParameterError as exc:
        msg = str(exc)
        named = [k for k in sets if msg.startswith((f"{k} ", f"unknown parameter key(s) ['{k}'"))]
        given = " ".join(f"--set {k}={v}" for k, v in sets.items() if not named or k in named)
        raise ParameterError(f"{given}: {msg}") from None


def _check_out(path: str | None, cmd: str, flag: str = "--out") -> Path | None:
    """Validate an output path before any computation: suffix, existing writable directory."""
    if path is None:
        return None
    p = Path(path)
    allowed = OUTPUT_SUFFIXES[cmd] if flag == "--out" else (".png", ".pdf", ".svg")
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
    spec, flag = getattr(args, name), GAIN_FLAGS[name][0]
    try:
        value = float(spec)
    except (TypeError, ValueError):
        return grid(spec, flag)
    # one value: the gain rule's own message, which names the unit (--P-gain = -200.0 is out of range)
    return gain_array(name, value, flag).reshape(1)


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
    units = {**params.plant.topology.units, **CONTROLLER_UNITS}
    sets = {**differences(now["plant"], base["plant"]), **differences(now["controller"], base["controller"])}
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


def _write_outputs(out, plot, write_out, figure) -> None:
    """``--out`` through ``write_out(path, tx)`` and ``--plot`` from ``figure()``, all or nothing
    (:mod:`haa_sym.io.outputs`): a failure leaves both as they were."""
    with Transaction() as tx:
        if out:
            write_out(out, tx)
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


def _say_leg(params, leg, leg_mode) -> str:
    """Before a leg-range analysis: a warning, shown even with --quiet, when the parameters' own
    values (a file's body tables, --set) lie outside the range, which replaces them. Returns the
    line saying which configurations and values it analyses, a progress message the command
    shows once its input has passed every check (a refused command prints one line only)."""
    line, warning = leg_text(leg_values(params, leg, leg_mode))
    if warning:
        print(f"haa-sym: warning: {warning}", file=sys.stderr)
    return line


def _requirements(args):
    return tuple(r.strip() for r in args.require.split(",") if r.strip())


def _cmd_regions(args) -> int:
    loop, out, plot = _setup(args, "regions")
    P, D = _axis(args, "P_gain"), _axis(args, "D_gain")
    robust_only = [f for f, given in (("--require", args.require != "stable,pm"), ("--leg", args.leg is not None),
                                      ("--leg-mode", args.leg_mode != "segment")) if given]
    if robust_only and not args.robust:
        raise ParameterError(f"{robust_only[0]} applies to the leg range; allowed: with --robust")
    if args.robust:
        plain_only = [f for f, given in (("--radius", args.radius), ("--method grid", args.method != "curves"),
                                         ("--configuration", args.configuration is not None)) if given]
        if plain_only:
            raise ParameterError(f"{plain_only[0]} with --robust: the robust map spans the leg range "
                                 "(decided from the curves); allowed: one of them")
        return _robust_regions(args, loop, out, plot, P, D)
    m = region_map(loop, P, D, radius=args.radius, method=args.method)

    def figure():
        b = boundaries(loop, P_range=(P.min(), P.max()), D_range=(D.min(), D.max())) \
            if loop.options.conventions.pm_loop == "impedance" else None
        return _plots().plot_region(m, title=args.figure_title, boundary=b)
    _write_outputs(out, plot, lambda path, tx: m.save(path, tx, "--out"), figure)
    print(f"{m.stable.size} points ({m.meta['method']}): {m.stable.sum()} stable, {m.low_pm.sum()} stable "
          f"with PM < 30 deg, {m.passive.sum()} passive" + _wrote(out))
    return 0


def _robust_regions(args, loop, out, plot, P, D) -> int:
    leg_line = _say_leg(loop.params, _leg(args, loop.params), args.leg_mode)
    r = robust_region(loop, P, D, requirements=_requirements(args), leg=_leg(args, loop.params),
                      leg_mode=args.leg_mode)
    message(leg_line)
    meta = {**r.meta, "n_configurations": r.n_configurations, "converged": r.converged, "history": r.history,
            "configurations": r.configurations}
    _write_outputs(out, plot,
                   lambda path, tx: save_npz(path, {"P_gain": r.P_gain, "D_gain": r.D_gain, "feasible": r.feasible},
                                             meta, tx, "--out"),
                   lambda: _plots().plot_robust(r, title=args.figure_title))
    print(f"{r.feasible.size} points: {int(r.feasible.sum())} meet {'+'.join(r.meta['requirements'])} for every leg "
          f"configuration ({r.meta['leg'][0]}..{r.meta['leg'][1]}, {r.meta['leg_mode']}, {r.n_configurations} "
          f"configurations{'' if r.converged else ', NOT converged'})" + _wrote(out))
    return 0


def _cmd_boundary(args) -> int:
    loop, out, plot = _setup(args, "boundary")
    P, D = _axis(args, "P_gain"), _axis(args, "D_gain")
    if loop.options.conventions.pm_loop != "impedance":
        raise ParameterError(f"--option pm_loop={loop.options.conventions.pm_loop}: the boundaries cover the "
                             "impedance loop's margin; allowed: pm_loop=impedance (the default)")
    b = boundaries(loop, P_range=(P.min(), P.max()), D_range=(D.min(), D.max()))
    b.stability.meta.update(loop.provenance(), omega_unit="rad/s", P_gain_unit="Nm/rad",
                            D_gain_unit="Nms/rad")
    _write_outputs(out, plot, lambda path, tx: b.save(path, tx, "--out"),
                   lambda: _plots().plot_boundary(b, title=args.figure_title))

    def summary(curves):
        return f"{len(curves)} curve(s), {sum(c.P_gain.size for c in curves)} points" if curves else "none in the box"
    print(f"boundaries in P_gain [{P.min():g}, {P.max():g}] x D_gain [{D.min():g}, {D.max():g}]: "
          f"stability {summary(b.stability.curves)}; PM = {b.pm_deg:g} deg {summary(b.phase_margin)}; "
          f"passivity {summary(b.passivity)}" + _wrote(out))
    return 0


def _cmd_contact(args) -> int:
    loop, out, plot = _setup(args, "contact")
    (P,), (D,) = _points(args, "contact scans the environment stiffness at one impedance")
    lo, sep, hi = args.K_range.partition(":")
    try:
        K_range = (float(lo), float(hi)) if sep else None
    except ValueError:
        K_range = None
    if K_range is None:
        raise ParameterError(f"--K-range {args.K_range!r}; allowed: LO:HI in Nm/rad, 0 < LO < HI")
    r = contact_intervals(loop, K_range, n_scan=args.n_scan, P_gain=float(P), D_gain=float(D), mode=args.mode)
    env = (f"K_env is a new stiffness to ground {r.key} of the port body (the file has none)" if r.ground_added
           else f"K_env {'replaces' if r.mode == 'replace' else 'adds to'} {r.key}")
    data = {"analysis": "contact stability", "environment": env, "ground_added": r.ground_added,
            "mode": r.mode, "stiffness_key": r.key, "P_gain": float(P), "D_gain": float(D),
            "K_range": list(K_range), "n_scan": args.n_scan, "rtol": r.rtol,
            "unstable_intervals": [list(i) for i in r.unstable],
            "not_passive_intervals": [list(i) for i in r.not_passive],
            "not_passive": "stable, and the corrected phase of Z leaves +-(90 + passivity_tol_deg) deg "
                           "somewhere on the options' frequency grid (meta: n_omega, omega_min); the "
                           "ends are exact for that grid"}
    _write_outputs(out, plot,
                   lambda path, tx: save_json(path, {**data, "meta": loop.provenance()}, tx, "--out"),
                   lambda: _plots().plot_contact(r.K_env, r.spectral_radius, unstable=r.unstable, key=r.key,
                                                 excess=r.phase_excess_deg, not_passive=r.not_passive,
                                                 tol=r.passivity_tol_deg, title=args.figure_title))

    def ends(iv):
        return ", ".join(f"{a:.10g}-{b:.10g}" for a, b in iv) + " Nm/rad" if iv else "none"
    print(f"unstable in contact ({data['environment']}): {ends(r.unstable)}; stable but not passive: "
          f"{ends(r.not_passive)}" + _wrote(out))
    return 0


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
    loop, out, plot = _setup(args, "schedule")
    if args.c_out is not None:
        check_c_directory(args.c_out)
    P, D = _axis(args, "P_gain"), _axis(args, "D_gain")
    beta_range = _range(args.beta_range, "--beta-range", "the torque-gain scale beta, Eq. 7")
    alphas = None if args.alpha_values is None else grid(args.alpha_values, "--alpha-values")
    leg_line = _say_leg(loop.params, _leg(args, loop.params), args.leg_mode)
    s = schedule(loop, P, D, beta_range=beta_range, beta_tol=args.beta_tol, alpha_values=alphas,
                 requirements=_requirements(args), leg=_leg(args, loop.params), leg_mode=args.leg_mode,
                 scheduler=args.scheduler)
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
          f"(tolerance {args.beta_tol:g}; leg {s.meta['leg'][0]}..{s.meta['leg'][1]}, {s.n_configurations} "
          f"configurations{'' if s.converged else ', NOT converged'}); beta = 1 fails for some leg at {unsafe} of "
          f"them; lookup safe on {s.meta['cells_safe']} of {s.meta['cells']} cells ({s.meta['cell_subdivisions'] + 1}^2 "
          f"sub-grid checked, {s.meta['grid_points_lowered_by_cell_check']} grid values lowered)"
          + _wrote(out) + (f"; C in {args.c_out}" if args.c_out else ""))
    return 0


def _cmd_passivity(args) -> int:
    loop, out, plot = _setup(args, "passivity")
    P, D = _points(args)
    r = passivity(loop, P, D)
    rows = []
    for i in range(P.size):
        rows.append({"P_gain": float(P[i]), "D_gain": float(D[i]), "status": str(r.status[i]),
                     "phase_excess_deg": float(r.phase_excess_deg[i]), "omega_worst_rad_s": float(r.omega_worst[i])})
        excess = (f"worst corrected phase excess {r.phase_excess_deg[i]:+.3f} deg at {r.omega_worst[i]:.4g} rad/s"
                  if np.isfinite(r.phase_excess_deg[i]) else "(the phase of Z of an unstable loop is not judged)")
        print(f"P_gain {P[i]:g}  D_gain {D[i]:g}: {r.status[i]:8s}  {excess}")
    curves = []
    if plot:
        for i in range(P.size):
            w, ph = corrected_phase(loop, P[i], D[i])
            curves.append((w, ph, f"P_gain = {P[i]:g}, D_gain = {D[i]:g}"))
            print(f"  |phase| > 90 deg for P_gain {P[i]:g}, D_gain {D[i]:g}: "
                  + (", ".join(f"{a:.1f}-{b:.1f} rad/s" for a, b in bands_beyond(w, ph)) or "never"))

    def write_out(path, tx):
        tx.write_text(path, json.dumps({"cells": rows, "meta": loop.provenance()}, indent=1) + "\n"
                      if path.suffix == ".json" else csv_text(rows), "--out")
    _write_outputs(out, plot, write_out, lambda: _plots().plot_corrected_phase(
        curves, f"corrected phase of Z(z)\n{args.figure_title}"))
    return 0


def _cmd_step(args) -> int:
    loop, out, plot = _setup(args, "step")
    s = step_response(loop, duration=args.duration)
    print(f"{describe_step(s)}, -3 dB bandwidth {torque_bandwidth(loop):.2f} rad/s")
    print(f"({STEP_CONVENTION})")
    rows = [{"t_s": f"{t:.6g}", "T_Nm": f"{v:.9g}"} for t, v in zip(s.t, s.T)]
    # the measured torque: the sensed coupling's (T_l of Eq. 2 for HyQ), or the current estimate
    ylabel, legend = measured_torque(loop.params.plant.topology)
    _write_outputs(out, plot, lambda path, tx: tx.write_text(path, csv_text(rows), "--out"),
                   lambda: _plots().plot_steps([("unit torque step, impedance loop open", [(s, legend, "-")])],
                                               args.figure_title, ylabel=ylabel))
    return 0


def _cmd_margins(args) -> int:
    params = _params(args)
    loop = ClosedLoop(params, _parse_options(args.option))
    Ps, Ds = _points(args)
    for P, D in zip(Ps, Ds):
        if Ps.size > 1:
            print(f"P_gain {P:g}  D_gain {D:g}:")
        _margins_of_point(loop, float(P), float(D))
    print("(PM = 180 + arg L at |L| = 1, wrapped to (-180, 180]; the maps' rule: "
          f"{loop.options.conventions.pm_rule}, see docs/model.md; crossovers located exactly "
          f"from {loop.options.numerics.omega_min:g} rad/s to Nyquist)")
    return 0


def _margins_of_point(loop, P: float, D: float) -> None:
    st = loop.stability(P, D, radius=True)
    print(f"closed loop: {'stable' if st.stable else 'UNSTABLE'}, spectral radius {float(st.spectral_radius):.9g}")
    for name, label in (("L_t", "torque loop (opened at the PI output)"),
                        ("L_imp", "impedance loop (opened at T_lref)")):
        m = margins(loop, P, D, which=name)
        pms = ", ".join(f"{pm:+.2f} deg @ {w:.6g} rad/s" for pm, w in zip(m.phase_margins_deg, m.gain_crossovers))
        gms = ", ".join(f"{g:+.2f} dB @ {w:.6g} rad/s" for g, w in zip(m.gain_margins_db, m.phase_crossovers))
        print(f"{label}:\n  PM {pms or 'none (|L| does not cross 1)'}"
              + (f"; nearest -1: {m.distance_deg:.2f} deg" if m.phase_margins_deg.size else "")
              + f"\n  GM {gms or 'none (arg L never reaches -180 deg)'}")
        if (m.gain_margins_db < 0).any():
            print("  (a negative GM is a gain-reduction margin: |L| > 1 where arg L = -180 deg, so "
                  "lowering the loop gain by that much reaches instability there)")


def _cmd_stability(args) -> int:
    """One line per point: the point (when there are several), stable, the spectral radius."""
    params = _params(args)
    P, D = _points(args)
    res = ClosedLoop(params, _parse_options(args.option)).stability(P, D, radius=True)
    for i in range(P.size):
        print((f"P_gain {P[i]:g}  D_gain {D[i]:g}: " if P.size > 1 else "")
              + f"stable: {bool(res.stable[i])}  spectral radius: {float(res.spectral_radius[i]):.12g}"
              + ("  (marginal: a pole at z = 1, the free position mode of a link without stiffness"
                 " to ground, which P_gain = 0 does not feed back; not asymptotically stable)"
                 if bool(res.marginal[i]) else "")
              + ("  (the decision is the generated Routh-Hurwitz test on the exact characteristic "
                 "polynomial, certified against its rounding; the radius comes from floating-point "
                 "eigenvalues of the explicit closed loop, whose error near |z| = 1 can exceed the "
                 "distance to the circle: the decision is the one to trust)"
                 if not bool(res.marginal[i]) and bool(res.stable[i]) != bool(res.spectral_radius[i] < 1)
                 and not bool(res.refined[i]) else ""))
    return 0


def _cmd_reproduce(args) -> int:
    params = _params(args)
    options = _parse_options(args.option)
    reproduce(args.out, params, options, quick=args.quick, field="--out")
    return 0


def _cmd_actuators(args) -> int:
    """The bundled actuators: name (and alias), what they are, their configurations and file."""
    aliases = {n: a for a, n in ALIASES.items()}
    for name, path in bundled_actuators().items():
        params = load_params(path)
        alias = f" (alias {aliases[name]})" if name in aliases else ""
        print(f"{name}{alias}: {params.about.get('name', '')}\n"
              f"  {params.about.get('description', '')}\n"
              f"  configurations: {', '.join(params.configurations) or 'none'}\n"
              f"  file: {path}")
    print("(--params NAME or --params FILE anywhere; copy a file to describe another actuator, "
          "docs/model.md \"Actuator files\")")
    return 0


def _table(rows: list[tuple], header: tuple[str, ...]) -> str:
    rows = [header] + [tuple(str(c) for c in r) for r in rows]
    widths = [max(len(r[i]) for r in rows) for i in range(len(header) - 1)]
    return "\n".join("  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)) + "  " + r[-1] for r in rows)


def _cmd_options(args) -> int:
    """What --set and --option accept: keys with units, allowed values and the current value."""
    params = _params(args)
    print(f"--set KEY=VALUE, keys of {params.source} ({params.about.get('name', '')}"
          f"{', configuration ' + args.configuration if args.configuration else ''}):")
    print(_table([(k, u, "-" if v is None else f"{v:g}" if isinstance(v, float) else v, allowed)
                  for k, u, allowed, v in set_keys(params)], ("key", "unit", "value", "allowed")))
    resolved = LoopOptions().resolved(params.plant.topology)
    print("--option KEY=VALUE, fields of haa_sym.LoopOptions (docs/model.md, \"Options\"):")
    rows = []
    for name in LoopOptions.field_names():
        kind, optional = LoopOptions.field_type(name)
        default = LoopOptions.field_default(name)
        shown = (f"none (here {getattr(resolved, name)})" if default is None
                 else str(default).lower() if isinstance(default, bool) else str(default))
        rows.append((name, kind.__name__ + (" or none" if optional else ""), shown, OPTION_ALLOWED[name]))
    print(_table(rows, ("option", "type", "default", "allowed")))
    print(f"--P-gain (Nm/rad) and --D-gain (Nms/rad): {GRID_SYNTAX} (haa-sym --help: which commands "
          "take a map's axes and which take points)")
    return 0


def _cmd_compile(args) -> int:
    args.file = str(actuator_path(args.file, "ACTUATOR"))
    params = load_params(args.file)
    top = params.plant.topology
    entry = evaluators().code.manifest["topologies"].get(top.fingerprint)
    if entry is not None:
        print(f"{args.file}: topology {top.fingerprint[:12]} is built in ({entry['function']} in "
              "the generated code); nothing to compile")
        return 0
    code = compile_topology(top, quiet=args.quiet)
    where = code.library if code.library is not None else f"{code.casadi_file} (CasADi's virtual machine)"
    print(f"{args.file}: topology {top.fingerprint[:12]} ({top.describe()}) compiled: {where}")
    return 0


def _progress_flags(p: argparse.ArgumentParser, default) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("-q", "--quiet", action="store_true", default=default,
                   help="no progress bars or progress messages on stderr")
    g.add_argument("--progress", action="store_true", default=default,
                   help="progress bars on stderr from the start, also when it is not a terminal "
                        "(default: on a terminal, for work longer than 2 s)")


# The D_gain axis of the maps (regions, boundary): the paper's Figs. 8-11 and model/paper.toml
# start at 1 Nms/rad, and one default for both means `boundary` finds the curves `regions --plot`
# draws. (boundary used 0..50 before issue 16; D_gain = 0 remains reachable with --D-gain.)
MAP_D_GAIN = "lin:1:50:100"
TITLE_HELP = ("text above the figure's automatic title (the actuator, then what differs from its file: --set values "
              "and non-default --option values), on a line of its own")
POINTS_ROLE = "points: the i-th P_gain with the i-th D_gain, one value pairing with all"


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


def main(argv: list[str] | None = None) -> int:
    ap = _Parser(prog="haa-sym", description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    _progress_flags(ap, False)
    sub = ap.add_subparsers(dest="cmd", required=True)
    v = sub.add_parser("verify", help="check the paper's equations")
    v.add_argument("--params", metavar="NAME|FILE", help=PARAMS_HELP)
    c = sub.add_parser("compile", help="compile the plant of an actuator file into the cache (ahead of first use)")
    c.add_argument("file", metavar="ACTUATOR", help="actuator file (TOML) or bundled name (haa-sym actuators)")
    sub.add_parser("actuators", help="the bundled actuators: name, description, configurations and file path")
    op = sub.add_parser("options", help="every --set key of an actuator (unit, value, allowed) and every --option "
                        "(type, default, allowed)")
    _common(op)                          # the values shown are those after --configuration and --set
    s = sub.add_parser("stability", help="stability of gain points, one line each")
    _common(s)
    _gain_flags(s, None, None, POINTS_ROLE + ", one line each")
    r = sub.add_parser("regions", help="stability / PM / passivity map on a gain grid (Figs. 8-11)")
    _common(r)
    _map_args(r, MAP_D_GAIN, "an axis of the map (every P_gain with every D_gain)", ".npz")
    r.add_argument("--radius", action="store_true",
                   help="also compute the spectral radius from eigenvalues (slower)")
    r.add_argument("--robust", action="store_true",
                   help="the gains meeting --require for every leg configuration of the range (npz: feasible)")
    _leg_args(r)
    r.add_argument("--method", choices=("curves", "grid"), default="curves",
                   help="decide the map from the exact boundaries (default) or every point on the grid "
                        "(with per-point phase margin and passivity excess)")
    bd = sub.add_parser("boundary", help="exact stability, phase-margin and passivity boundaries in the "
                        "(P_gain, D_gain) plane (parameter-space method)")
    _common(bd)
    _map_args(bd, MAP_D_GAIN, "its range is the box searched", ".json")
    sc = sub.add_parser("schedule", help="torque-gain scheduler: the largest beta per impedance that keeps "
                        "the joint stable with PM >= 30 deg for every leg configuration (CSV, embedded C)")
    _common(sc)
    _gain_flags(sc, "log:1:2000:30", "lin:1:50:20", "an axis of the schedule's table (at least 2 values, "
                "P_gain > 0)")
    sc.add_argument("--beta-range", default="0.1:8", help="LO:HI of beta (default 0.1:8)")
    sc.add_argument("--beta-tol", type=float, default=0.02, help="relative step of the beta grid (default 0.02)")
    sc.add_argument("--alpha-values", help="schedule alpha too, from these values (grid spec, e.g. 0,0.5,0.94)")
    _leg_args(sc)
    sc.add_argument("--scheduler", help="address of a dask.distributed scheduler (default: in-process)")
    sc.add_argument("--out", help="output .csv")
    sc.add_argument("--c-out", help="directory for haa_schedule.h and haa_schedule.c")
    sc.add_argument("--plot", help="output figure (.png/.pdf/.svg)")
    sc.add_argument("--title", help=TITLE_HELP)
    ct = sub.add_parser("contact", help="environment stiffnesses where the loop is unstable, or stable but not "
                        "passive (exact ends)")
    _common(ct)
    ct.add_argument("--K-range", default="1:100000", help="LO:HI environment stiffness, Nm/rad (default 1:100000)")
    ct.add_argument("--n-scan", type=int, default=400, help="log-spaced stiffnesses that bracket the ends (default 400)")
    ct.add_argument("--mode", choices=("replace", "add"), default="replace",
                    help="K_env replaces the port body's ground stiffness (default, the paper's reading) or adds to it")
    _gain_flags(ct, "0", "0", "one point (0 and 0: the torque loop alone)")
    ct.add_argument("--out", help="output .json")
    ct.add_argument("--plot", help="output figure (.png/.pdf/.svg)")
    ct.add_argument("--title", help=TITLE_HELP)
    p = sub.add_parser("passivity", help="passivity of Z(z) at gain pairs (Table 2, Fig. 12)")
    _common(p)
    _gain_flags(p, "0,200,20000", "0,10,50", POINTS_ROLE + " (Table 2's columns)")
    p.add_argument("--out", help="output .csv or .json")
    p.add_argument("--plot", help="corrected phase of Z, figure file")
    p.add_argument("--title", help=TITLE_HELP)
    st = sub.add_parser("step", help="unit torque step, impedance loop open (Fig. 7)")
    _common(st)
    st.add_argument("--duration", type=float, default=0.3, help="seconds")
    st.add_argument("--out", help="output .csv")
    st.add_argument("--plot", help="figure file")
    st.add_argument("--title", help=TITLE_HELP)
    mg = sub.add_parser("margins", help="phase and gain margins of the torque and impedance loops at gain points")
    _common(mg)
    _gain_flags(mg, "0", "0", POINTS_ROLE)
    rp = sub.add_parser("reproduce", help="every figure and table of the paper, and REPORT.md")
    _common(rp)
    rp.add_argument("--out", default="results")
    rp.add_argument("--quick", action="store_true", help="coarse grids (for tests)")
    for command in sub.choices.values():
        # also after the command (haa-sym reproduce --quiet); SUPPRESS keeps the global value
        _progress_flags(command, argparse.SUPPRESS)
    args = ap.parse_args(argv)
    set_progress(False if args.quiet else True if args.progress else None)
    with _sigterm_unwinds():
        return _run(args)


@contextlib.contextmanager
def _sigterm_unwinds():
    """SIGTERM raises :class:`Terminated` in the main thread while a command runs, so that it
    unwinds like SIGINT: without this, the default action kills the process mid-write and the
    outputs' temporaries (``.DIR.XXXX.tmp/``, ``.fig.png.XXXX.tmp``) stay behind. The previous
    handler is restored (main() is also called in-process, e.g. by the tests)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def terminate(signum, frame):
        raise Terminated()
    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _run(args) -> int:
    """Run the parsed command; the errors a user can fix become one line and exit status 2."""
    try:
        if args.cmd == "verify":
            return verify_main(["--params", str(actuator_path(args.params, "--params"))] if args.params else [])
        if args.cmd == "stability":
            return _cmd_stability(args)
        return {"regions": _cmd_regions, "boundary": _cmd_boundary, "schedule": _cmd_schedule, "contact": _cmd_contact, "passivity": _cmd_passivity, "step": _cmd_step,
                "margins": _cmd_margins, "reproduce": _cmd_reproduce, "compile": _cmd_compile,
                "actuators": _cmd_actuators, "options": _cmd_options}[args.cmd](args)
    except ParameterError as exc:
        print(f"haa-sym: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader of stdout went away (haa-sym ... | head): not an error of the command; the
        # recipe of the Python docs (signal module, "Note on SIGPIPE")
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except OSError as exc:
        print(f"haa-sym: error: {exc.strerror or exc}: {exc.filename or ''}", file=sys.stderr)
        return 2
    except RuntimeError as exc:
        # generated/ stale or damaged, or the C compiler failing: a fault the user fixes, not a bug
        if not isinstance(exc, (StaleGeneratedCode, CompilerError)):
            raise
        print(f"haa-sym: error: {exc}", file=sys.stderr)
        return 2
    except Terminated:
        # as SIGINT below: every staged output was rolled back; 128 + SIGTERM
        print("haa-sym: terminated (SIGTERM); no output written", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        # outputs are staged (haa_sym.io.outputs): an interrupted command leaves existing files as
        # they were; 128 + SIGINT, the shell's convention
        print("haa-sym: interrupted; no output written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
