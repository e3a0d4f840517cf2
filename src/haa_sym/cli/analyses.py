"""The analysis commands of ``haa-sym`` on one closed loop: stability, regions, boundary,
contact, passivity, step and margins (schedule: haa_sym.cli.schedule; the actuator files'
commands: haa_sym.cli.actuators; verify and reproduce: haa_sym.cli.paper)."""
from __future__ import annotations

import json

import numpy as np

from haa_sym.analysis.boundaries.combined import boundaries
from haa_sym.analysis.contact import contact_intervals
from haa_sym.analysis.margins import margins
from haa_sym.analysis.passivity import bands_beyond, corrected_phase, passivity
from haa_sym.analysis.nonlinear_map import CLASSES, DEFAULT_DURATION, DEFAULT_MAX_DURATION, EXTEND_FACTOR, nonlinear_map
from haa_sym.analysis.regions import region_map
from haa_sym.analysis.simulate import EXPERIMENTS
from haa_sym.analysis.robust import box_text, robust_region
from haa_sym.analysis.sampled_port import MEASURES
from haa_sym.analysis.torque import STEP_CONVENTION, describe_step, step_response, torque_bandwidth
from haa_sym.errors import ParameterError
from haa_sym.io.formats import result_arrays, save_json, save_npz
from haa_sym.io.outputs import csv_text
from haa_sym.io.progress import message
from haa_sym.io.tasks import local_workers
from haa_sym.loop import ClosedLoop
from haa_sym.model.limits import limit_units

from haa_sym.cli.common import (MAP_D_GAIN, POINTS_ROLE, SCHEDULER_HELP, TITLE_HELP, _axis, _common,
                                _gain_flags, _leg, _leg_args, _map_args, _params, _parse_options, _plots,
                                _points, _requirements, _say_leg, _setup, _write_outputs, _wrote,
                                _agreement, _agreement_text, _measured, _uncertainty, measured_torque)




def _cmd_regions(args) -> int:
    local_workers(args.scheduler)            # a bad local:N is refused before any work
    loop, out, plot = _setup(args, "regions")
    P, D = _axis(args, "P_gain"), _axis(args, "D_gain")
    robust_only = [f for f, given in (("--require", args.require != "stable,pm"), ("--leg", args.leg is not None),
                                      ("--leg-mode", args.leg_mode != "segment"),
                                      ("--uncertainty", args.uncertainty is not None)) if given]
    if robust_only and not args.robust:
        raise ParameterError(f"{robust_only[0]} applies to the leg range; allowed: with --robust")
    nonlinear_only = [f for f, given in (("--experiment", args.experiment is not None),
                                         ("--amplitude", args.amplitude is not None),
                                         ("--duration", args.duration is not None),
                                         ("--max-duration", args.max_duration is not None),
                                         ("--no-continue-runs", not args.continue_runs)) if given]
    if nonlinear_only and not args.nonlinear:
        raise ParameterError(f"{nonlinear_only[0]} applies to the nonlinear map; allowed: with --nonlinear")
    if args.scheduler is not None and not (args.nonlinear or args.robust):
        raise ParameterError("--scheduler applies to the nonlinear map and the robust region (their tasks); "
                             "allowed: with --nonlinear or --robust")
    if args.nonlinear and (args.robust or args.measured):
        raise ParameterError(f"--nonlinear with {'--robust' if args.robust else '--measured'}; allowed: one of them")
    if args.nonlinear:
        return _nonlinear_regions(args, loop, out, plot, P, D)
    if args.robust:
        plain_only = [f for f, given in (("--radius", args.radius), ("--method grid", args.method != "curves"),
                                         ("--configuration", args.configuration is not None)) if given]
        if plain_only:
            raise ParameterError(f"{plain_only[0]} with --robust: the robust map spans the leg range "
                                 "(decided from the curves); allowed: one of them")
        return _robust_regions(args, loop, out, plot, P, D)
    points = _measured(args)
    m = region_map(loop, P, D, radius=args.radius, method=args.method)
    counts, drawn = _agreement(loop, points, P, D)
    if counts is not None:
        m.meta["measured"] = counts

    def figure():
        b = boundaries(loop, P_range=(P.min(), P.max()), D_range=(D.min(), D.max())) \
            if loop.options.conventions.pm_loop == "impedance" else None
        return _plots().plot_region(m, title=args.figure_title, boundary=b, measured=drawn)
    _write_outputs(out, plot, lambda path, tx: m.save(path, tx, "--out"), figure)
    print(f"{m.stable.size} points ({m.meta['method']}): {m.stable.sum()} stable, {m.low_pm.sum()} stable "
          f"with PM < 30 deg, {m.passive.sum()} passive" + _agreement_text(counts) + _wrote(out))
    return 0


def _nonlinear_regions(args, loop, out, plot, P, D) -> int:
    """``regions --nonlinear``: the linear map and each point's class from a simulation with the
    file's [limits] (docs/simulate.md, "Nonlinear maps"), in one npz."""
    nl = nonlinear_map(loop, P, D, experiment=args.experiment or "disturbance-step", amplitude=args.amplitude,
                       duration=DEFAULT_DURATION if args.duration is None else args.duration,
                       max_duration=args.max_duration, scheduler=args.scheduler, continue_runs=args.continue_runs)
    m = region_map(loop, P, D, radius=args.radius, method=args.method)

    def write(path, tx):
        save_npz(path, {**result_arrays(m), **nl.arrays()}, {**m.meta, "nonlinear": nl.meta}, tx, "--out")

    def figure():
        b = boundaries(loop, P_range=(P.min(), P.max()), D_range=(D.min(), D.max())) \
            if loop.options.conventions.pm_loop == "impedance" else None
        # the title says what was simulated: the classes depend on the limits, the experiment and the runs' length
        return _plots().plot_nonlinear_region(m, nl.P_gain, nl.D_gain, nl.class_names,
                                              title=f"{args.figure_title}\nsimulated: {runs}; limits: {lim}",
                                              boundary=b)
    counts = ", ".join(f"{n} {c}" for c, n in nl.counts().items())
    units = limit_units(loop.params.plant.topology.body_names)
    lim = ", ".join((f"{k} = {v:g}" + (f" {units[k]}" if units.get(k) not in (None, "-") else ""))
                    if isinstance(v, (int, float)) else f"{k} = {v}"
                    for k, v in nl.meta["limits"].items()) or "none"
    unit = "rad" if nl.meta["experiment"] in ("impedance-step", "deflection") else "Nm"
    runs = (f"{nl.meta['experiment']}, A = {nl.meta['amplitude']:g} {unit}, {nl.meta['duration']:g} s each"
            + (f" (reruns up to {nl.meta['max_duration']:g} s)" if nl.meta["max_duration"] > nl.meta["duration"] else ""))
    _write_outputs(out, plot, write, figure)
    print(f"{m.stable.size} points, linear ({m.meta['method']}): {m.stable.sum()} stable; simulated with "
          f"{lim} ({runs}): {counts}" + _wrote(out))
    if nl.counts()["growing"]:
        message(f"growing: still growing when the runs ended (up to {nl.meta['max_duration']:g} s); a longer "
                "--max-duration may show limit cycles there (docs/simulate.md, Nonlinear maps)")
    return 0


def _robust_regions(args, loop, out, plot, P, D) -> int:
    fit, points = _uncertainty(args, loop.params, _leg(args, loop.params)), _measured(args)
    leg_line = _say_leg(loop.params, _leg(args, loop.params), args.leg_mode, fit)
    r = robust_region(loop, P, D, requirements=_requirements(args), leg=_leg(args, loop.params),
                      leg_mode=args.leg_mode, uncertainty=(fit["box"] or None) if fit else None,
                      scheduler=args.scheduler, progress=None)
    message(leg_line)
    counts, drawn = _agreement(loop, points, P, D, r.configurations)
    meta = {**r.meta, "n_configurations": r.n_configurations, "converged": r.converged, "history": r.history,
            "configurations": r.configurations, **({"uncertainty_source": fit["source"]} if fit else {}),
            **({"measured": counts} if counts else {})}
    _write_outputs(out, plot,
                   lambda path, tx: save_npz(path, {"P_gain": r.P_gain, "D_gain": r.D_gain, "feasible": r.feasible},
                                             meta, tx, "--out"),
                   lambda: _plots().plot_robust(r, title=args.figure_title, measured=drawn))
    box = "" if not (fit and fit["box"]) else " and every value of " + box_text(fit["box"])
    print(f"{r.feasible.size} points: {int(r.feasible.sum())} meet {'+'.join(r.meta['requirements'])} for every leg "
          f"configuration ({r.meta['leg'][0]}..{r.meta['leg'][1]}, {r.meta['leg_mode']}){box}: {r.n_configurations} "
          f"configurations{'' if r.converged else ', NOT converged'}" + _agreement_text(counts) + _wrote(out))
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


def _beta_alpha(loop) -> tuple[float, float]:
    """The torque-gain scale and velocity compensation a loop is analysed at (the file's or --set's)."""
    c = loop.params.controller
    return float(c.beta), float(c.alpha)


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
            "not_passive": ("stable, and the corrected phase of Z leaves +-(90 + passivity_tol_deg) deg "
                            if loop.options.conventions.passivity == "corrected_phase" else
                            "stable, and the exact test's dissipation deficit exceeds passivity_tol_exact ")
                           + "somewhere on the options' frequency grid (meta: n_omega, omega_min); the "
                           "ends are exact for that grid"}
    _write_outputs(out, plot,
                   lambda path, tx: save_json(path, {**data, "meta": loop.provenance()}, tx, "--out"),
                   lambda: _plots().plot_contact(r.K_env, r.spectral_radius, unstable=r.unstable, key=r.key,
                                                 excess=r.measure[0], not_passive=r.not_passive,
                                                 tol=r.measure[1], measure=r.measure[2], title=args.figure_title,
                                                 gains=_plots().gains_text(float(P), float(D), *_beta_alpha(loop))))

    def ends(iv):
        return ", ".join(f"{a:.10g}-{b:.10g}" for a, b in iv) + " Nm/rad" if iv else "none"
    print(f"unstable in contact ({data['environment']}): {ends(r.unstable)}; stable but not passive: "
          f"{ends(r.not_passive)}" + _wrote(out))
    return 0


def _cmd_passivity(args) -> int:
    loop, out, plot = _setup(args, "passivity")
    P, D = _points(args)
    r = passivity(loop, P, D)
    rows = []
    for i in range(P.size):
        # each test's measure under its own name; the other test's field is absent (not run)
        name = MEASURES[loop.options.conventions.passivity]
        value = getattr(r, name)[i]
        rows.append({"P_gain": float(P[i]), "D_gain": float(D[i]), "status": str(r.status[i]),
                     name: float(value), "omega_worst_rad_s": float(r.omega_worst[i])})
        what = ("worst corrected phase excess {:+.3f} deg" if name == "phase_excess_deg"
                else "exact dissipation deficit {:+.4g}").format(value)
        excess = (f"{what} at {r.omega_worst[i]:.4g} rad/s"
                  if np.isfinite(value) else "(passivity of an unstable loop is not judged)")
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
        if name == "L_t" and not loop.structure.torque_loop:
            print(f"{label}: none (structure = {loop.structure.name!r} has no torque loop)")
            continue
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


def _stability_args(s) -> None:
    _common(s)
    _gain_flags(s, None, None, POINTS_ROLE + ", one line each")


def _regions_args(r) -> None:
    _common(r)
    _map_args(r, MAP_D_GAIN, "an axis of the map (every P_gain with every D_gain)", ".npz")
    r.add_argument("--radius", action="store_true",
                   help="also compute the spectral radius from eigenvalues (slower)")
    r.add_argument("--robust", action="store_true",
                   help="the gains meeting --require for every leg configuration of the range (npz: feasible)")
    _leg_args(r)
    r.add_argument("--measured", metavar="POINTS.csv",
                   help="measured stability points (CSV columns P_gain,D_gain,outcome; outcome stable, unstable or "
                        "limit_cycle): drawn over the map with the paper's symbols, and how many agree with the "
                        "model (docs/uncertainty.md)")
    r.add_argument("--method", choices=("curves", "grid"), default="curves",
                   help="decide the map from the exact boundaries (default) or every point on the grid "
                        "(with per-point phase margin and passivity excess)")
    r.add_argument("--nonlinear", action="store_true",
                   help="also class every point as " + " / ".join(CLASSES) + " from a simulation with the "
                        "file's [limits] (npz: nonlinear_class, ...; docs/simulate.md, Nonlinear maps)")
    r.add_argument("--experiment", choices=list(EXPERIMENTS), metavar="KIND",
                   help="with --nonlinear: the experiment of every run (default disturbance-step; choices: "
                        + ", ".join(EXPERIMENTS) + ")")
    r.add_argument("--amplitude", type=float, metavar="A",
                   help="with --nonlinear: the experiment's amplitude (Nm or rad; haa-sym simulate's default)")
    r.add_argument("--duration", type=float, metavar="S",
                   help=f"with --nonlinear: seconds simulated per point (default {DEFAULT_DURATION:g})")
    r.add_argument("--max-duration", type=float, metavar="S",
                   help=f"with --nonlinear: points still growing or undecided are run again, {EXTEND_FACTOR:g}x longer "
                        f"each time, up to S seconds (default max({DEFAULT_MAX_DURATION:g}, --duration))")
    r.add_argument("--no-continue-runs", dest="continue_runs", action="store_false",
                   help="with --nonlinear: run every longer run from t = 0 instead of continuing the point's "
                        "shorter run from where it stopped (the default; the same map to the bit, for fewer "
                        "simulated samples): to check that against runs from t = 0, or to time the difference")
    r.add_argument("--scheduler", help="with --nonlinear or --robust: where their tasks run (a simulation's "
                   "points; a leg configuration's map): " + SCHEDULER_HELP)


def _boundary_args(bd) -> None:
    _common(bd)
    _map_args(bd, MAP_D_GAIN, "its range is the box searched", ".json")


def _contact_args(ct) -> None:
    _common(ct)
    ct.add_argument("--K-range", default="1:100000", help="LO:HI environment stiffness, Nm/rad (default 1:100000)")
    ct.add_argument("--n-scan", type=int, default=400, help="log-spaced stiffnesses that bracket the ends (default 400)")
    ct.add_argument("--mode", choices=("replace", "add"), default="replace",
                    help="K_env replaces the port body's ground stiffness (default, the paper's reading) or adds to it")
    _gain_flags(ct, "0", "0", "one point (0 and 0: the torque loop alone)")
    ct.add_argument("--out", help="output .json")
    ct.add_argument("--plot", help="output figure (.png/.pdf/.svg)")
    ct.add_argument("--title", help=TITLE_HELP)


def _passivity_args(p) -> None:
    _common(p)
    _gain_flags(p, "0,200,20000", "0,10,50", POINTS_ROLE + " (Table 2's columns)")
    p.add_argument("--out", help="output .csv or .json")
    p.add_argument("--plot", help="corrected phase of Z, figure file")
    p.add_argument("--title", help=TITLE_HELP)


def _step_args(st) -> None:
    _common(st)
    st.add_argument("--duration", type=float, default=0.3, help="seconds")
    st.add_argument("--out", help="output .csv")
    st.add_argument("--plot", help="figure file")
    st.add_argument("--title", help=TITLE_HELP)


def _margins_args(mg) -> None:
    _common(mg)
    _gain_flags(mg, "0", "0", POINTS_ROLE)


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"stability": (_stability_args, _cmd_stability), "regions": (_regions_args, _cmd_regions),
             "boundary": (_boundary_args, _cmd_boundary), "contact": (_contact_args, _cmd_contact),
             "passivity": (_passivity_args, _cmd_passivity), "step": (_step_args, _cmd_step),
             "margins": (_margins_args, _cmd_margins)}
