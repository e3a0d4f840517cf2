"""``haa-sym identify``: fit chosen parameters of an actuator file to logged experiments
(docs/identify.md).

  haa-sym identify --params harmonic_drive --log run1.csv [--log run2.csv ...] --input voltage \\
      --output torque,theta --fit J_link,B_link,K_hd,D_hd --out fitted.toml --report fit.json --plot fit.png
"""
from __future__ import annotations

import argparse
import hashlib
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from haa_sym.io.inputs import read_text
from haa_sym.errors import ParameterError
from haa_sym.fit.fitted_file import fitted_text
from haa_sym.design.tune import NOMINAL
from haa_sym.fit.identify import (INITIAL_STATES, INPUT_MODES, Experiment, FitOptions, identify, refuse_unreliable,
                                  validate)
from haa_sym.io.formats import save_json
from haa_sym.io.logs import GAP_PERIODS, MAX_ANGLE, OUTPUT_UNITS, OUTPUTS, parse_window, read_log
from haa_sym.model.drive import DRIVE_KEYS
from haa_sym.io.outputs import Transaction, check_file
from haa_sym.loop import ClosedLoop
from haa_sym.model.limits import FRICTION_SET_KEYS, with_friction_sets
from haa_sym.model.params import MAX_FILE_BYTES, actuator_path, load_params, parse_set

from haa_sym.cli.common import PARAMS_HELP, _check_out, _parse_options, _params, _plots



def _arguments(p) -> None:
    p.description = __doc__
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--params", metavar="NAME|FILE", help=PARAMS_HELP)
    p.add_argument("--log", action="append", required=True, metavar="LOG.csv",
                   help="a CSV log: header with time (s) and the signals (voltage, current, T_dist, torque_ref; "
                        "torque, theta, current, velocity); repeatable: the logs are fitted jointly")
    p.add_argument("--input", required=True, metavar="KIND[,T_dist]",
                   help=f"what drives the logged experiment: one of {', '.join(INPUT_MODES)} (voltage: the open-"
                        "loop plant; current: a current-commanded drive, no electrical dynamics; torque_ref: the "
                        "file's torque loop closed), optionally ,T_dist when the log has the port torque")
    p.add_argument("--output", required=True, action="append", metavar="NAME[,NAME...]",
                   help=f"logged outputs the fit matches: {', '.join(OUTPUTS)}; once for every log, or once per "
                        "--log in the same order (logs with different outputs fitted jointly)")
    p.add_argument("--fit", required=True, metavar="KEY[,KEY...]", help="plant parameter keys to fit (e.g. K_hd,D_hd)")
    p.add_argument("--configuration", action="append", default=[], metavar="NAME",
                   help="configuration of the file the logs were taken in: once for every log, or once per --log "
                        "in the same order")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key of the file (SI units) before fitting: the starting values; also the "
                        "[limits] friction: Fc_m, Fc_<body> (Nm; a fitted Fc key needs a start > 0) and "
                        "friction_velocity (rad/s)")
    p.add_argument("--offsets", metavar="NAME[,NAME...]",
                   help="outputs with a constant offset per log (a sensor's tare), fitted with the keys "
                        "(eliminated by variable projection) and reported; default none")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="loop option (haa_sym.LoopOptions) of the torque loop, --input torque_ref only")
    p.add_argument("--window", action="append", default=[], metavar="START:STOP",
                   help="fit only START <= t < STOP (s of the log's time column; either may be empty): once for "
                        "every log, or once per --log")
    p.add_argument("--gap", type=float, default=None, metavar="SECONDS",
                   help=f"an interval longer than this splits a log into segments, each restarted from an "
                        f"estimated state (default {GAP_PERIODS:g} median periods of the log)")
    p.add_argument("--min-periods", type=float, default=FitOptions().min_periods, metavar="N",
                   help="a log must last N periods of the model's slowest mode (default %(default)g)")
    p.add_argument("--max-angle", type=float, default=MAX_ANGLE, metavar="RAD",
                   help="largest span of a log's theta column: the model is linear about an operating point "
                        "(default %(default)g rad)")
    p.add_argument("--max-substep", type=float, default=FitOptions().max_substep, metavar="SECONDS",
                   help="longest substep of the friction simulation (with Fc_* fitted or in the file's [limits]; "
                        "default: chosen per fit, the longest 5e-4 s / 2^k whose estimated error is within 5e-4 of "
                        "the outputs' spread; a given value is used, with a warning when it is less accurate: "
                        "docs/identify.md)")
    p.add_argument("--initial-state", choices=INITIAL_STATES, default=FitOptions().initial_state,
                   help="a log's first segment starts at rest (checked) or from an estimated state (default "
                        "%(default)s; segments after gaps and windows inside a log are always estimated)")
    p.add_argument("--allow-unconverged", action="store_true",
                   help="write the fit even if it stopped at its iteration limit, marked as not converged (a "
                        "comment in the fitted file, \"converged\": false in the report); default: refused")
    p.add_argument("--validate", action="append", default=[], metavar="LOG.csv",
                   help="a log not fitted, only predicted: NRMSE and VAF per output (repeatable; the same columns "
                        "as --log, taken in the configuration given once, else the file's own)")
    p.add_argument("--validate-window", action="append", default=[], metavar="START:STOP",
                   help="the samples of a --validate log scored, START <= t < STOP in s of the log's time column "
                        "(either may be empty, as --window); once for every --validate log or once per --validate; "
                        "the log is simulated from its start")
    p.add_argument("--holdout", type=float, metavar="FRACTION",
                   help="the last FRACTION (0 < F < 1) of every --log is not fitted, only predicted (the model "
                        "simulated over the whole log) and scored")
    p.add_argument("--out", required=True, metavar="FITTED.toml",
                   help="the parameter file with the fitted values, their source and ci95")
    p.add_argument("--report", metavar="fit.json", help="the fit as JSON (parameters, rms_error, samples, sampling, meta)")
    p.add_argument("--plot", metavar="fit.png", help="measured against predicted: time traces and Bode (H1, coherence)")


def _is_limit_set(item: str) -> bool:
    """Whether a --set item names a [limits] friction key (Fc_*, friction_velocity)."""
    key = item.partition("=")[0].strip()
    return key.startswith("Fc_") or key in FRICTION_SET_KEYS


def _split(text: str, flag: str) -> tuple[str, ...]:
    items = tuple(x.strip() for x in text.split(",") if x.strip())
    if not items:
        raise ParameterError(f"{flag} {text!r}: empty; allowed: comma-separated names")
    return items


def _refuse_repeated_logs(logs: list[str], flags: list[str] | None = None) -> None:
    """Refuse a log given twice: the fit would count its samples twice and narrow every ci95 by
    sqrt(n) as if the copies were independent experiments (40 copies: 6.3x) with nothing to show it.
    The same file (by resolved path or by device and inode: a link, a second spelling) and a copy
    (the same bytes, by sha256) are both the same experiment. Only regular files are hashed; a
    missing or special file is left to read_log's refusal. ``flags``: each log's flag (default
    --log; a --validate log that is a fitted one would be scored on the data it was fitted to)."""
    seen: dict = {}
    flags = flags or ["--log"] * len(logs)
    for text, flag in zip(logs, flags):
        path = Path(text)
        try:
            st = path.stat()
        except OSError:
            continue
        keys = [("the same file", str(path.resolve())), ("the same file", (st.st_dev, st.st_ino))]
        if path.is_file():
            digest = hashlib.sha256()
            with open(path, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    digest.update(block)
            keys.append(("identical content (sha256)", digest.hexdigest()))
        for how, key in keys:
            if key in seen:
                raise ParameterError(f"{flag} {text}: {how} as {seen[key]}; allowed: each experiment once (a "
                                     "repeated log counts its samples twice and narrows the ci95 as if it were new "
                                     "data; a validation log must not be a fitted one)")
        for _, key in keys:
            seen.setdefault(key, f"{flag} {text}")


def _head(log, n: int):
    """The log's first ``n`` samples (the fitted part of a log with --holdout): its signals, stamps
    and the segments that start inside them; the sampling says how many samples are held out."""
    starts = tuple(s for s in log.starts if s < n)
    t = log.t[:n]
    return replace(log, signals={k: v[:n] for k, v in log.signals.items()}, t=t, starts=starts,
                   Ts=float((t[-1] - t[0]) / (n - 1)),
                   sampling={**log.sampling, "segments": len(starts), "held_out_samples": log.samples - n})


def _validation_cases(args, experiments, inputs, outputs, base_params, fitted_logs) -> list:
    """(label, Experiment, start, stop) of every scored data set: each fitted log's fitted part,
    its held-out part (label ``NAME:holdout``), each --validate log's window."""
    cases = []
    for e, full in zip(experiments, fitted_logs):
        n = e.log.samples
        cases.append((e.log.name, Experiment(full, e.params, e.configuration, outputs=e.outputs), 0, n))
        if full.samples > n:
            cases.append((f"{e.log.name}:holdout", Experiment(full, e.params, e.configuration, outputs=e.outputs),
                          n, full.samples))
    wins = args.validate_window
    if len(wins) not in (0, 1, len(args.validate)) or (wins and not args.validate):
        raise ParameterError(f"--validate-window given {len(wins)} times for {len(args.validate)} --validate logs; "
                             "allowed: once (every --validate log) or once per --validate")
    wins = [parse_window(w, "--validate-window") for w in wins]
    wins = wins * len(args.validate) if len(wins) == 1 else (wins or [(-np.inf, np.inf)] * len(args.validate))
    for path, (lo, hi) in zip(args.validate, wins):
        log = read_log(path, inputs, outputs, gap=args.gap, max_angle=args.max_angle, label=f"--validate {path!r}")
        t = log.t                                  # s of the log's time column, as --window
        inside = np.flatnonzero((t >= lo) & (t < hi))
        if inside.size < 2:
            raise ParameterError(f"--validate-window {lo:g}:{hi:g} holds {inside.size} samples of --validate {path} "
                                 f"({t[0]:g} to {t[-1]:g} s); allowed: a window inside the log")
        label = log.name if log.name not in {c[0] for c in cases} else str(path)
        cases.append((label, Experiment(log, base_params), int(inside[0]), int(inside[-1]) + 1))
    return cases


def run(args) -> int:
    inputs, keys = _split(args.input, "--input"), _split(args.fit, "--fit")
    if len(args.output) not in (1, len(args.log)):
        raise ParameterError(f"--output given {len(args.output)} times for {len(args.log)} logs; allowed: once (every "
                             "log) or once per --log")
    per_output = [_split(o, "--output") for o in args.output] * (len(args.log) if len(args.output) == 1 else 1)
    outputs = tuple(dict.fromkeys(x for o in per_output for x in o))
    if len(args.window) not in (0, 1, len(args.log)):
        raise ParameterError(f"--window given {len(args.window)} times for {len(args.log)} logs; allowed: once (every "
                             "log) or once per --log")
    windows = [parse_window(w) for w in args.window]
    windows = windows * len(args.log) if len(windows) == 1 else (windows or [None] * len(args.log))
    if args.gap is not None and not args.gap > 0:
        raise ParameterError(f"--gap {args.gap!r}; allowed: a threshold > 0 (s)")
    if not args.min_periods >= 0:
        raise ParameterError(f"--min-periods {args.min_periods!r}; allowed: a number >= 0")
    if not args.max_angle > 0:
        raise ParameterError(f"--max-angle {args.max_angle!r}; allowed: an angle > 0 (rad)")
    FitOptions(max_substep=args.max_substep)   # checks --max-substep before the logs are read
    out = _check_out(args.out, "identify", "--out", (".toml",))
    report = _check_out(args.report, "identify", "--report", (".json",))
    plot = _check_out(args.plot, "identify", "--plot")
    if inputs[0] not in INPUT_MODES or any(i != "T_dist" for i in inputs[1:]) or len(set(inputs)) != len(inputs):
        raise ParameterError(f"--input {args.input}; allowed: one of {list(INPUT_MODES)}, optionally followed by "
                             ",T_dist")
    for o in per_output:
        if any(x not in OUTPUTS for x in o) or len(set(o)) != len(o):
            raise ParameterError(f"--output {','.join(o)}; allowed: distinct names of {list(OUTPUTS)}, comma separated")
    if args.option and inputs[0] != "torque_ref":
        raise ParameterError(f"--option {args.option[0]}: the loop options apply to the closed torque loop; "
                             "allowed: with --input torque_ref")
    if args.holdout is not None and not 0 < args.holdout < 1:
        raise ParameterError(f"--holdout {args.holdout!r}; allowed: a fraction 0 < F < 1 of each log's end")
    offsets = _split(args.offsets, "--offsets") if args.offsets is not None else ()
    if any(o not in outputs for o in offsets) or len(set(offsets)) != len(offsets):
        raise ParameterError(f"--offsets {args.offsets}; allowed: distinct names of --output {list(outputs)}")
    _refuse_repeated_logs(args.log + args.validate, ["--log"] * len(args.log) + ["--validate"] * len(args.validate))
    path = actuator_path(args.params, "--params")
    file_params = load_params(path)
    for k in keys:
        # checked on the file, before --set (which would declare it): the fitted file writes the key
        # into the file's own [drive] entry
        if k in DRIVE_KEYS and k not in file_params.drive.declared:
            raise ParameterError(f"--fit {k}: {path} has no [drive] {k}; allowed: add [drive] {k} = <start> (s)")
    confs = args.configuration
    if len(confs) not in (0, 1, len(args.log)):
        raise ParameterError(f"--configuration given {len(confs)} times for {len(args.log)} logs; allowed: once "
                             "(every log) or once per --log")
    per_log = confs * len(args.log) if len(confs) == 1 else (confs or [None] * len(args.log))
    # "nominal" names the file's own values, as in tune and the reports: pairs a nominal log with
    # a configuration's log (--configuration nominal --configuration heavy)
    per_log = [None if c == NOMINAL else c for c in per_log]
    loop_options = _parse_options(args.option) if inputs[0] == "torque_ref" else None
    # --set's [limits] friction keys act on the limits; the rest are parameters (_params)
    limit_sets = parse_set([x for x in args.set if _is_limit_set(x)])
    args.set = [x for x in args.set if not _is_limit_set(x)]
    bodies = file_params.plant.topology.body_names

    def with_limits(params):
        return replace(params, limits=with_friction_sets(params.limits, limit_sets, bodies)) if limit_sets else params
    experiments, fitted_logs = [], []
    for log_path, conf, outs, window in zip(args.log, per_log, per_output, windows):
        base = file_params.configuration(conf) if conf else file_params
        args.configuration = conf                     # _params applies --set over this configuration
        params = with_limits(_params(args, base))
        log = read_log(log_path, inputs, outs, window=window, gap=args.gap, max_angle=args.max_angle)
        fitted_logs.append(log)
        if args.holdout is not None:
            log = _head(log, int(round((1 - args.holdout) * log.samples)))
        experiments.append(Experiment(log, params, conf, outs))
    # the --validate logs' parameters: the configuration given once, else the file's own
    args.configuration = per_log[0] if len(set(per_log)) == 1 else None
    validate_params = with_limits(_params(args, file_params.configuration(args.configuration) if args.configuration
                                          else file_params))
    # the inputs are known now: an output that is one of them (--out the log, a link to it) is
    # refused before the fit's seconds, not only when the outputs are committed
    for target, flag in ((args.out, "--out"), (args.report, "--report"), (args.plot, "--plot")):
        if target is not None:
            check_file(target, flag)
    cases = _validation_cases(args, experiments, inputs, outputs, validate_params, fitted_logs)
    loop = ClosedLoop(experiments[0].params, loop_options, basis=False)
    options = FitOptions(min_periods=args.min_periods, initial_state=args.initial_state, max_substep=args.max_substep)
    result = identify(experiments, keys, inputs, outputs, options, loop_options,
                      provenance={**loop.provenance(), "params_file": str(path)}, figure_data=plot is not None,
                      offsets=offsets)
    # keys the logs cannot tell apart, a fit stopped at its iteration limit: one line, nothing written
    refuse_unreliable(result, allow_unconverged=args.allow_unconverged)
    for k, v, (lo, hi) in zip(result.keys, result.value, result.ci95):
        # an interval reaching 0 or infinity: the logs do not determine the key (a fitted file cannot
        # carry it, and a zero-width one from a dropped direction would claim the opposite)
        if not (lo > 0 and np.isfinite(hi)):
            raise ParameterError(f"--fit {k}: these logs do not determine it (fitted {v:.6g}, ci95 {lo:.3g} .. "
                                 f"{hi:.3g}); allowed: keys the logs observe (fit fewer keys, log more outputs, a "
                                 "richer input; the time column in s)")
    quality, val_traces = validate(result, cases, loop_options, options)
    date = result.meta["date"]
    text = fitted_text(read_text(path, "--params", limit=MAX_FILE_BYTES), str(path), file_params, result, date)
    with Transaction() as tx:
        tx.write_text(out, text, "--out")
        if report:
            save_json(report, {**result.report(), "validation": quality}, tx, "--report")
        if plot:
            name = str(file_params.about.get("name") or Path(path).stem)
            _plots().save_figure(_plots().plot_identify(result, title=f"{name}: identify {', '.join(keys)}",
                                                          validation=(val_traces, quality)),
                                 plot, tx, "--plot")
    for e, full in zip(experiments, fitted_logs):  # after the fit: a refused command prints one line only
        s = e.log.sampling
        print(f"{e.log.name}: {full.samples} samples"
              + (f" in {s['window'][0]:g} .. {s['window'][1]:g} s" if s["window"] else "")
              + f", mean period {s['mean_period']:.6g} s, jitter {s['jitter']:.2g} (max |dt - mean| / mean); "
              + ("uniform" if s["uniform"] else "simulated on its own intervals")
              + (f"; {s['segments']} segments (gaps > {s['gap_threshold']:.3g} s, longest interval "
                 f"{s['longest_interval']:.3g} s)" if s["segments"] > 1 else "")
              + (f"; the last {full.samples - e.log.samples} held out (--holdout)" if full.samples > e.log.samples
                 else ""))
    if not result.meta["converged"]:
        print(f"haa-sym: warning: the fit stopped at its iteration limit "
              f"({result.meta['options']['max_iterations']} per pass) while the error still fell (--allow-unconverged): the values are not a "
              "minimum; the file says so",
              file=sys.stderr)
    for k, v, v0, (lo, hi) in zip(result.keys, result.value, result.initial, result.ci95):
        print(f"{k} = {v:.6g} (ci95 {lo:.6g} .. {hi:.6g}; initial {v0:.6g})")
    for log_name, off in result.offsets.items():
        print(f"{log_name}: offsets " + ", ".join(f"{o} {v:.6g} {OUTPUT_UNITS[o]}" for o, v in off.items()))
    print(f"ci95: {result.meta['intervals']['method'].split(':')[0]}; residuals: "
          + "; ".join(f"{log} " + ", ".join(f"{o} lag-1 {w['lag1']:.2f} {'white' if w['white'] else 'NOT white'} "
                                            f"(Ljung-Box p {w['p_value']:.2g})" for o, w in res.items())
                      for log, res in result.meta["residuals"].items()))
    for label, q in quality.items():
        print(f"validation {label}: " + ", ".join(f"{o} NRMSE {v['nrmse']:.3g} VAF {v['vaf_percent']:.4g} %"
                                                  for o, v in q.items()) + f" ({next(iter(q.values()))['samples']} samples)")
    rms = ", ".join(f"{o} {result.rms_initial[o]:.3g} -> {result.rms_fitted[o]:.3g}" for o in outputs)
    print(f"{result.samples} samples, {result.iterations} iterations; rms error {rms}; wrote {out}"
          + (f", {report}" if report else "") + (f", {plot}" if plot else ""))
    return 0



# {command: (add its arguments to its parser, run(args) -> exit status)}: haa_sym.cli.COMMANDS
ARGUMENTS = {"identify": (_arguments, run)}
