"""``haa-sym simulate``: the nonlinear sampled-data simulation of one gain point (docs/simulate.md)."""
from __future__ import annotations

import math
import warnings

import numpy as np

from haa_sym.analysis.describing import compare_cycle, limit_cycles, limit_nonlinearities
from haa_sym.analysis.excitation import EXCITATIONS, excitation_signal
from haa_sym.analysis.simulate import CSV_COLUMNS, DEFAULT_AMPLITUDE, EXPERIMENTS, FORCED_EXPERIMENTS, simulate
from haa_sym.errors import ParameterError
from haa_sym.io.budget import CSV_BYTES_PER_SAMPLE, check_memory
from haa_sym.io.formats import save_json
from haa_sym.io.outputs import csv_text
from haa_sym.loop import ClosedLoop
from haa_sym.model.limits import limit_units

from haa_sym.cli.common import (TITLE_HELP, _check_out, _common, _gain_flags, _loaded, _params, cycle_comparison,
                                _parse_options, _plots, _points, _wrote, figure_title)
from haa_sym.io.outputs import Transaction

EXPERIMENT_HELP = "; ".join(f"{k}: {v}" for k, v in EXPERIMENTS.items())


def _cmd_simulate(args) -> int:
    file_params = _loaded(args)
    params, options = _params(args, file_params), _parse_options(args.option)
    out = _check_out(args.out, "simulate", suffixes=(".csv",))
    plot = _check_out(args.plot, "simulate", "--plot")
    meta_out = _check_out(args.meta, "simulate", "--meta", suffixes=(".json",))
    if plot and args.title:
        _plots().check_title(args.title, "--title")
    P, D = _points(args, "simulate")
    log_out, excitation = _log_args(args, params)
    loop = ClosedLoop(params, options)
    if out or plot:
        # the CSV's formatted rows and the figure cost about 5x the simulation itself: refused
        # here, before the run (a bad duration is left to simulate's own message)
        d, Ts = args.duration, params.controller.Ts
        if math.isfinite(d) and d > 0:
            n = int(math.ceil(d / Ts - 1e-9)) + 1
            check_memory(n * CSV_BYTES_PER_SAMPLE, f"--duration {d:g} ({n} samples at Ts = {Ts:g} s, "
                                                   "written to --out / --plot)")
    title = figure_title(loop, file_params, args.configuration, args.title)
    s = simulate(loop, float(P[0]), float(D[0]), experiment=args.experiment, amplitude=args.amplitude,
                 duration=args.duration, seed=args.seed, excitation=excitation)
    cols = s.columns()
    # the figure says what was run: the base title names only the actuator and its overrides
    unit = "rad" if args.experiment in ("impedance-step", "deflection") else "Nm"
    units = limit_units(loop.params.plant.topology.body_names)
    lim = ", ".join((f"{k} = {v:g}" + (f" {units[k]}" if units.get(k) not in (None, "-") else ""))
                    if isinstance(v, (int, float)) else f"{k} = {v}"
                    for k, v in s.meta["limits"].items()) or "none (the linear loop)"
    title += (f"\n{args.experiment}, A = {s.meta['amplitude']:g} {unit}; P_gain = {float(P[0]):g} Nm/rad, "
              f"D_gain = {float(D[0]):g} Nms/rad; limits: {lim}")
    verdict = verdict_line(s)
    predicted = _predictions(loop, float(P[0]), float(D[0]), s, cols)
    note = "\n".join([verdict] + [f"{p}\n  {q}" if q else p for p, q, _ in predicted])
    m = s.meta
    m["describing_functions"] = [c for _, _, c in predicted]

    # a current command's held command is a current (A): its column says so (docs/simulate.md)
    names = csv_names(loop)

    def write_csv(path, tx):
        # formatted only when written: the rows' strings are 5x the run's own memory (1 kB a
        # sample; CSV_BYTES_PER_SAMPLE); a run that diverged at once has no row: the header alone
        rows = [{names[c]: f"{cols[c][k]:.12g}" for c in CSV_COLUMNS} for k in range(len(s.time))]
        text = csv_text(rows) if rows else ",".join(names[c] for c in CSV_COLUMNS) + "\n"
        del rows
        tx.write_text(path, text, "--out")

    with Transaction() as tx:
        if out:
            write_csv(out, tx)
        if meta_out:
            save_json(meta_out, _plain(m), tx, "--meta")
        if log_out:
            tx.write_text(log_out, _log_text(args, loop, P, D, s), "--log-out")
        if plot:
            with warnings.catch_warnings():
                # a run near overflow (|values| ~ 1e307) makes matplotlib's tick arithmetic
                # overflow: the figure is still drawn, the warning is noise beside the verdict
                warnings.simplefilter("ignore", RuntimeWarning)
                _plots().save_figure(_plots().plot_simulation(
                    s.time, cols, s.saturated, title, note,
                    "current command (A)" if loop.structure.command == "current" else "voltage (V)"), plot, tx,
                                     "--plot")
    integ = m["integrator"] + (f", {m['n_sub']:.3g} substeps per sample" if m["n_sub"] > 1 else "")
    if "n_sub_max" in m:
        integ += f" (at most {m['n_sub_max']}; rtol {m['rtol']:g})"
    dr = m["drive"]
    if dr["tau_drive"] or dr["delay_drive"]:         # docs/simulate.md, "The drive"
        integ += (f"; drive: lag {dr['tau_drive']:g} s, dead time {dr['delay_drive']:g} s "
                  f"({dr['delay_whole_samples']} samples + {dr['delay_fraction_s']:.6g} s)")
    print(f"{args.experiment} (A = {s.meta['amplitude']:g} {unit}), {len(s.time)} samples over "
          f"{s.time[-1] if len(s.time) else 0.0:.6g} s; limits: {lim}; {integ}")
    print(f"time in saturation: {s.saturation_time:.6g} s ({100 * s.saturation_time / max(args.duration, 1e-300):.3g} %)"
          + _wrote(out) + ("" if not meta_out else f"; wrote {meta_out}"))
    for line, sim, _ in predicted:
        print(f"{line}; {sim}" if sim else line)
    print(verdict)
    if log_out:
        print(f"wrote {log_out}: the run as a log for haa-sym identify")
    return 0


def csv_names(loop) -> dict[str, str]:
    """The CSV's header per column of :data:`CSV_COLUMNS`: ``voltage`` is the held command, which
    for a current-commanded structure is the current command (A), ``current_command``."""
    return {c: ("current_command" if c == "voltage" and loop.structure.command == "current" else c)
            for c in CSV_COLUMNS}


def verdict_line(s) -> str:
    """The run's one verdict with the linear loop's beside it (docs/simulate.md, "The verdict of
    a run")."""
    text = f"verdict: {s.verdict}"
    if s.verdict == "diverged":
        text += (f" (a state overflowed at t = {s.diverged_at:.6g} s; the run stops there, "
                 f"{len(s.time)} samples kept)")
    elif s.verdict == "limit cycle" and s.oscillation.kind == "irregular":
        text += (f" (irregular: no period repeats; torque half peak-to-peak {s.cycle_amplitude:.6g} Nm, "
                 f"{100 * s.oscillation.growth_per_cycle:+.3g} % an eighth of the last half)")
    elif s.verdict == "limit cycle":
        text += f" (torque: amplitude {s.cycle_amplitude:.6g} Nm, frequency {s.cycle_frequency:.6g} Hz)"
    elif s.oscillation is not None and s.oscillation.kind != "none":
        o = s.oscillation
        # a rate or a period the trace does not determine is not printed as nan
        periodic = math.isfinite(o.frequency_hz)
        # without a period, the growth is the swing's from one eighth of the last half to the next
        rate = (f", {100 * o.growth_per_cycle:+.3g} % {'a cycle' if periodic else 'an eighth of the last half'}"
                if math.isfinite(o.growth_per_cycle) else "")
        at = f" at {o.frequency_hz:.6g} Hz" if periodic else ", no period measured"
        text += f" (torque oscillation {o.kind}{rate}{at})"
    if s.linear_stable is None:
        return text + "; linear loop at this point: not decided"
    return (text + f"; linear loop at this point: {'stable' if s.linear_stable else 'UNSTABLE'} "
            f"(spectral radius {s.spectral_radius:.6g})")


# identify's log columns (docs/identify.md, "Logs") a run writes with --log-out: the inputs it can
# be driven by and every output; the simulation's own names are identify's
LOG_COLUMNS = ("time", "voltage", "current", "torque_ref", "torque", "theta", "velocity")
LOG_OUTPUTS = ("torque", "theta", "velocity", "current")


def _log_args(args, params):
    """``(--log-out path or None, the excitation's samples or None)``, checked before the run."""
    log_out = _check_out(args.log_out, "simulate", "--log-out", (".csv",))
    if not (args.log_noise >= 0 and math.isfinite(args.log_noise)):
        raise ParameterError(f"--log-noise {args.log_noise!r}; allowed: a fraction >= 0 of each output's standard "
                             "deviation")
    if args.log_noise and not log_out:
        raise ParameterError("--log-noise applies to the log; allowed: with --log-out")
    if args.excitation is None:
        return log_out, None
    if args.experiment != "chirp":
        raise ParameterError(f"--excitation {args.excitation}: a torque reference of the forced experiment; "
                             f"allowed: with --experiment chirp (not {args.experiment})")
    Ts, d = params.controller.Ts, args.duration
    if not (math.isfinite(d) and d > 0):
        return log_out, None                      # simulate's own message names --duration
    n = int(math.ceil(d / Ts - 1e-9)) + 1
    return log_out, excitation_signal(args.excitation, n, Ts, args.seed)


def _log_text(args, loop, P, D, s) -> str:
    """The run as identify's CSV log: ``#`` lines saying how it was made, then ``time`` and the
    signals; the outputs with Gaussian noise of ``--log-noise`` times each one's standard
    deviation (seeded by --seed: its own stream, ``default_rng([seed, 1])``, apart from the run's
    noise and jitter), the inputs exact (as logged)."""
    cols = s.columns()
    rng = np.random.default_rng([args.seed, 1])
    data = {}
    columns = LOG_COLUMNS
    if loop.structure.command == "current":
        # a current command: identify's input `current` is the command the drive receives
        # (identify --input current passes it through the file's [drive] as this run did); no
        # motor voltage is modelled, and the current the motor carried is that input's response
        cols = dict(cols, current=cols["voltage"])
        columns = tuple(c for c in LOG_COLUMNS if c != "voltage")
    for c in columns:
        v = np.asarray(cols[c], float)
        if c in LOG_OUTPUTS and args.log_noise and not (c == "current" and columns != LOG_COLUMNS):
            v = v + args.log_noise * np.std(v) * rng.standard_normal(v.size)
        data[c] = v
    how = args.excitation or ("the sweep of --experiment chirp" if args.experiment == "chirp" else "none")
    head = [f"# haa-sym simulate --log-out: {loop.params.source}"
            + (f" --configuration {args.configuration}" if args.configuration else "")
            + "".join(f" --set {x}" for x in args.set),
            f"# P_gain = {float(P[0]):g} Nm/rad, D_gain = {float(D[0]):g} Nms/rad; {args.experiment}, excitation "
            f"{how}, amplitude {s.meta['amplitude']:g}; duration {args.duration:g} s; seed {args.seed}; "
            f"output noise {args.log_noise:g} x std",
            "# units: time s, " + ("voltage V, current A" if columns == LOG_COLUMNS else
                                   "current A (the current command, held from t_k)")
            + ", torque_ref Nm, torque Nm, theta rad, velocity rad/s (docs/identify.md, Logs)"]
    rows = [",".join(columns)] + [",".join(f"{data[c][k]:.12g}" for c in columns) for k in range(len(s.time))]
    return "\n".join(head + rows) + "\n"



def _plain(x):
    """``x`` with NaN and inf as None (JSON has neither) and numpy scalars as Python's."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _predictions(loop, P, D, s, cols) -> list[tuple[str, str, dict | None]]:
    """Per [limits] entry with a describing function (:func:`limit_nonlinearities`): a line of
    the predicted stable limit cycle (the largest; docs/describing.md), a line of how this run
    bears it out (:func:`haa_sym.analysis.describing.compare_cycle`: relative errors, agreement,
    and when the prediction is not to be trusted) and that comparison as data."""
    out = []
    Ts = loop.params.controller.Ts
    # the limits in force (the friction model's settings are not limits of their own)
    n_limits = len([k for k in loop.params.limits.active if k not in ("friction_model", "friction_velocity")])
    for nl in limit_nonlinearities(loop.params.limits, loop.structure.command):
        (key, value), = nl.items()
        r = limit_cycles(loop, P, D, nonlinearity=nl)
        ok = np.flatnonzero(r.stable)
        head = f"describing function, {key} = {value:g} {r.value_unit}:"
        if not ok.size:
            out.append((f"{head} no stable limit cycle predicted", "", None))
            continue
        k = ok[np.argmax(r.amplitude[ok])]
        A, f = float(r.amplitude[k]), float(r.frequency_hz[k])
        c = compare_cycle(r, k, cols, Ts, port=loop.params.plant.topology.port, n_limits=n_limits)
        text = f"{head} A = {A:.4g} {r.unit} at {f:.4g} Hz"
        if c["signal"] in ("voltage", "current command"):
            text += f" (output fundamental N(A) A = {c['predicted_amplitude']:.4g} {r.unit})"
        if s.meta["experiment"] in FORCED_EXPERIMENTS:
            sim = f"not compared: the {s.meta['experiment']} forces the loop (its oscillation is the input's)"
            c["untrusted"] = []
        else:
            sim = cycle_comparison(c, "simulated", r.unit)
        out.append((text, sim, dict(c, nonlinearity=key, value=value)))
    return out


def _arguments(p) -> None:
    _common(p)
    _gain_flags(p, None, None, "one gain point")
    p.add_argument("--experiment", required=True, choices=list(EXPERIMENTS), metavar="KIND",
                   help=f"{EXPERIMENT_HELP} (choices: {', '.join(EXPERIMENTS)})")
    p.add_argument("--amplitude", type=float, default=None, metavar="A",
                   help="the experiment's amplitude A (Nm or rad); default "
                        + ", ".join(f"{k} {v:g}" for k, v in DEFAULT_AMPLITUDE.items()))
    p.add_argument("--duration", type=float, required=True, metavar="S", help="seconds")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the torque noise, the jitter, --log-noise and a prbs excitation (default 0)")
    p.add_argument("--out", help="output .csv: " + ", ".join(CSV_COLUMNS))
    p.add_argument("--plot", help="figure file (.png/.pdf/.svg)")
    p.add_argument("--meta", help="the run's metadata as JSON (.json): the verdict, the linear verdict, the "
                                  "limits, the integrator, the describing-function comparisons")
    p.add_argument("--title", help=TITLE_HELP)
    p.add_argument("--excitation", metavar="SPEC",
                   help="with --experiment chirp: the torque reference's shape instead of the sweep, peak "
                        "--amplitude: " + "; ".join(EXCITATIONS.values()))
    p.add_argument("--log-out", metavar="LOG.csv",
                   help="the run as a log for haa-sym identify (time, voltage, current, torque_ref, torque, theta, "
                        "velocity; docs/simulate.md)")
    p.add_argument("--log-noise", type=float, default=0.0, metavar="FRACTION",
                   help="Gaussian noise on the log's outputs, FRACTION x each one's standard deviation (default 0)")


# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"simulate": (_arguments, _cmd_simulate)}
