"""``haa-sym describe``: describing-function predictions of limit cycles (docs/describing.md)."""
from __future__ import annotations

import math

from haa_sym.analysis.describing import DISTORTION_STRONG, NONLINEARITIES, confirm_cycles, limit_cycles, limit_nonlinearities
from haa_sym.errors import ParameterError
from haa_sym.io.formats import save_json
from haa_sym.loop import ClosedLoop
from haa_sym.model import structures

from haa_sym.cli.common import (TITLE_HELP, _check_out, _common, _gain_flags, _loaded, _params, _parse_options,
                                cycle_comparison,
                                _plots, _points, _write_outputs, _wrote, figure_title)

LIMIT_HELP = ("a nonlinearity and its parameter, KEY=VALUE (repeatable, each predicted alone): V_max (V, "
              "saturation of the voltage command), I_max (A, saturation of a current command), T_res or torque_resolution (Nm, rounding of the torque the loop "
              "reads), Fc_m or Fc_<body> (Nm, Coulomb friction on the rotor or a body); default: those of the "
              "file's [limits] section")


def _limits(items: list[str], params) -> list[dict]:
    """The nonlinearities of ``--limit``, else those of the file's ``[limits]`` section (one name per
    concept: ``torque_resolution``, the [limits] key, is read as the describing function's ``T_res``)."""
    if not items:
        command = structures.get(params.controller.structure).command
        from_file = limit_nonlinearities(params.limits, command)
        if not from_file:
            raise ParameterError("--limit missing and the parameter file's [limits] has no "
                                 + ("V_max, torque_resolution" if command == "voltage" else "I_max")
                                 + " or Coulomb friction; allowed: KEY=VALUE with KEY one of "
                                 + ", ".join(NONLINEARITIES) + " (e.g. --limit V_max=24)")
        return from_file
    out = []
    for item in items:
        key, sep, value = item.partition("=")
        try:
            v = float(value)
        except ValueError:
            v = math.nan
        if not sep or not math.isfinite(v):
            raise ParameterError(f"--limit {item!r}; allowed: KEY=VALUE with a finite number, e.g. V_max=24")
        key = key.strip()
        out.append({"T_res" if key == "torque_resolution" else key: v})
    return out


def _cmd_describe(args) -> int:
    file_params = _loaded(args)
    params, options = _params(args, file_params), _parse_options(args.option)
    out = _check_out(args.out, "describe", suffixes=(".json",))
    plot = _check_out(args.plot, "describe", "--plot")
    if plot and args.title:
        _plots().check_title(args.title, "--title")
    limits = _limits(args.limit, params)
    P, D = (float(v[0]) for v in _points(args, one="describe predicts at one gain point"))
    loop = ClosedLoop(params, options)
    try:
        results = [limit_cycles(loop, P, D, nonlinearity=nl) for nl in limits]
    except ParameterError as exc:
        raise ParameterError(f"--limit: {exc}") from None
    # the linear verdict at the point: "no limit cycle" reads as harmless, but at a linearly
    # unstable point it means the harmonic balance bounds nothing
    lin = loop.stability([P], [D], radius=True)
    lin_stable, radius = bool(lin.stable[0]), float(lin.spectral_radius[0])
    # every stable predicted cycle checked by a short simulation with that nonlinearity alone
    confirmed = [confirm_cycles(loop, P, D, r) if args.confirm else [None] * r.amplitude.size for r in results]
    several = len(results) > 1 or len([k for k in params.limits.active
                                       if k not in ("friction_model", "friction_velocity")]) > 1
    for r, conf in zip(results, confirmed):
        head = f"{r.nonlinearity} = {r.value:g} {r.value_unit} on the {r.signal}:"
        if not r.amplitude.size:
            print(f"{head} no limit cycle predicted (no phase crossover of G meets -1/N(A))")
        for A, w, s, d, c in zip(r.amplitude, r.omega, r.stable, r.distortion, conf):
            print(f"{head} limit cycle A = {A:.6g} {r.unit} at {w:.6g} rad/s ({w / (2 * math.pi):.6g} Hz), "
                  f"{'stable' if s else 'unstable'} (Loeb), distortion {d:.3g}"
                  + ("  (strong harmonics, not confirmed by a simulation: do not trust it without one)"
                     if c is None and s and d > DISTORTION_STRONG else ""))
            if c is not None:
                if several:
                    c["untrusted"].insert(0, "several nonlinearities at once (each predicted alone)")
                print("  " + _confirmation(c))

    unbounded = [r.nonlinearity for r in results if not r.stable.any()]
    print(f"linear loop at this point: {'stable' if lin_stable else 'UNSTABLE'} (spectral radius {radius:.6g})"
          + ("" if lin_stable or not unbounded else
             f"; no stable cycle predicted for {', '.join(unbounded)}: the harmonic balance bounds no oscillation "
             "there (one larger than any unstable cycle grows until another limit acts)"))

    def write(path, tx):
        save_json(path, {"P_gain": P, "D_gain": D, "linear": {"stable": lin_stable, "spectral_radius": radius},
                         "predictions": [_with_confirmation(r.to_dict(), conf) for r, conf in zip(results, confirmed)]},
                  tx, "--out")

    def figure():
        panels = [dict(label=f"{r.nonlinearity} = {r.value:g} {r.value_unit} on the {r.signal}", G=r.G_curve, minus_inv_N=r.minus_inv_N,
                       unit=r.unit, points=list(zip(r.G_crossing, r.amplitude, r.omega, r.stable)))
                  for r in results]
        return _plots().plot_describing(panels, title=figure_title(loop, file_params, args.configuration, args.title)
                                        + f"\nP_gain = {P:g} Nm/rad, D_gain = {D:g} Nms/rad")
    _write_outputs(out, plot, write, figure)
    print(f"(harmonic balance 1 + N(A) G(j omega) = 0; docs/describing.md){_wrote(out)}")
    return 0


def _confirmation(c: dict) -> str:
    """One line: how the confirming simulation bears a predicted cycle out."""
    return cycle_comparison(c, f"simulation ({c['experiment']}, {c['duration_s']:.3g} s; verdict {c['verdict']}),")


def _with_confirmation(d: dict, conf: list) -> dict:
    for cycle, c in zip(d["limit_cycles"], conf):
        cycle["simulation"] = c
    return d


def _arguments(p) -> None:
    _common(p)
    _gain_flags(p, "0", "0", "one gain point (0 and 0: the torque loop alone)")
    p.add_argument("--limit", action="append", default=[], metavar="KEY=VALUE", help=LIMIT_HELP)
    p.add_argument("--no-confirm", dest="confirm", action="store_false",
                   help="skip the short simulation that checks every stable predicted cycle (default: run it)")
    p.add_argument("--out", help="the predictions as JSON (.json)")
    p.add_argument("--plot", help="Nyquist-type figure of G and -1/N(A) with the predicted cycles (.png, .pdf, .svg)")
    p.add_argument("--title", help=TITLE_HELP)


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"describe": (_arguments, _cmd_describe)}
