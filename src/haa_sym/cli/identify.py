"""``haa-sym identify``: fit chosen parameters of an actuator file to logged experiments
(docs/identify.md).

  haa-sym identify --params harmonic_drive --log run1.csv [--log run2.csv ...] --input voltage \\
      --output torque,theta --fit J_link,B_link,K_hd,D_hd --out fitted.toml --report fit.json --plot fit.png
"""
from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np

from haa_sym.io.inputs import read_text
from haa_sym.errors import ParameterError
from haa_sym.fit.fitted_file import fitted_text
from haa_sym.design.tune import NOMINAL
from haa_sym.fit.identify import INITIAL_STATES, INPUT_MODES, Experiment, FitOptions, identify
from haa_sym.io.formats import save_json
from haa_sym.io.logs import GAP_PERIODS, MAX_ANGLE, OUTPUTS, parse_window, read_log
from haa_sym.model.drive import DRIVE_KEYS
from haa_sym.io.outputs import Transaction, check_file
from haa_sym.loop import ClosedLoop
from haa_sym.model.params import MAX_FILE_BYTES, actuator_path, load_params

from haa_sym.cli.common import PARAMS_HELP, _check_out, _parse_options, _params, _plots

# the scaled normal matrix's condition beyond which a fit's intervals are not to be trusted: the
# keys are then nearly linearly dependent in the logs (e.g. an inertia and a stiffness seen only
# through their ratio), and the normal equations have lost ten of their sixteen digits
CONDITION_WARNING = 1e10


def register(sub) -> dict:
    p = sub.add_parser("identify", help="fit parameters of an actuator file to logged experiments (CSV logs)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
                   help="override a key of the file (SI units) before fitting: the starting values")
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
    p.add_argument("--initial-state", choices=INITIAL_STATES, default=FitOptions().initial_state,
                   help="a log's first segment starts at rest (checked) or from an estimated state (default "
                        "%(default)s; segments after gaps and windows inside a log are always estimated)")
    p.add_argument("--out", required=True, metavar="FITTED.toml",
                   help="the parameter file with the fitted values, their source and ci95")
    p.add_argument("--report", metavar="fit.json", help="the fit as JSON (parameters, rms_error, samples, sampling, meta)")
    p.add_argument("--plot", metavar="fit.png", help="measured against predicted: time traces and Bode (H1, coherence)")
    return {"identify": run}


def _split(text: str, flag: str) -> tuple[str, ...]:
    items = tuple(x.strip() for x in text.split(",") if x.strip())
    if not items:
        raise ParameterError(f"{flag} {text!r}: empty; allowed: comma-separated names")
    return items


def _refuse_repeated_logs(logs: list[str]) -> None:
    """Refuse a log given twice: the fit would count its samples twice and narrow every ci95 by
    sqrt(n) as if the copies were independent experiments (40 copies: 6.3x) with nothing to show it.
    The same file (by resolved path or by device and inode: a link, a second spelling) and a copy
    (the same bytes, by sha256) are both the same experiment. Only regular files are hashed; a
    missing or special file is left to read_log's refusal."""
    seen: dict = {}
    for text in logs:
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
                raise ParameterError(f"--log {text}: {how} as --log {seen[key]}; allowed: each experiment once (a "
                                     "repeated log counts its samples twice and narrows the ci95 as if it were new "
                                     "data)")
        for _, key in keys:
            seen.setdefault(key, text)


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
    _refuse_repeated_logs(args.log)
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
    experiments = []
    for log_path, conf, outs, window in zip(args.log, per_log, per_output, windows):
        base = file_params.configuration(conf) if conf else file_params
        args.configuration = conf                     # _params applies --set over this configuration
        params = _params(args, base)
        log = read_log(log_path, inputs, outs, window=window, gap=args.gap, max_angle=args.max_angle)
        experiments.append(Experiment(log, params, conf, outs))
    # the inputs are known now: an output that is one of them (--out the log, a link to it) is
    # refused before the fit's seconds, not only when the outputs are committed
    for target, flag in ((args.out, "--out"), (args.report, "--report"), (args.plot, "--plot")):
        if target is not None:
            check_file(target, flag)
    loop = ClosedLoop(experiments[0].params, loop_options, basis=False)
    options = FitOptions(min_periods=args.min_periods, initial_state=args.initial_state)
    result = identify(experiments, keys, inputs, outputs, options, loop_options,
                      provenance={**loop.provenance(), "params_file": str(path)}, figure_data=plot is not None)
    for k, v, (lo, hi) in zip(result.keys, result.value, result.ci95):
        # an interval reaching 0 or infinity: the logs do not determine the key (a fitted file cannot
        # carry it, and a zero-width one from a dropped direction would claim the opposite)
        if not (lo > 0 and np.isfinite(hi)):
            raise ParameterError(f"--fit {k}: these logs do not determine it (fitted {v:.6g}, ci95 {lo:.3g} .. "
                                 f"{hi:.3g}); allowed: keys the logs observe (fit fewer keys, log more outputs, a "
                                 "richer input; the time column in s)")
    date = result.meta["date"]
    text = fitted_text(read_text(path, "--params", limit=MAX_FILE_BYTES), str(path), file_params, result, date)
    with Transaction() as tx:
        tx.write_text(out, text, "--out")
        if report:
            save_json(report, result.report(), tx, "--report")
        if plot:
            name = str(file_params.about.get("name") or Path(path).stem)
            _plots().save_figure(_plots().plot_identify(result, title=f"{name}: identify {', '.join(keys)}"),
                                 plot, tx, "--plot")
    for e in experiments:                 # after the fit: a refused command prints one line only
        s = e.log.sampling
        print(f"{e.log.name}: {e.log.samples} samples"
              + (f" in {s['window'][0]:g} .. {s['window'][1]:g} s" if s["window"] else "")
              + f", mean period {s['mean_period']:.6g} s, jitter {s['jitter']:.2g} (max |dt - mean| / mean); "
              + ("uniform" if s["uniform"] else "simulated on its own intervals")
              + (f"; {s['segments']} segments (gaps > {s['gap_threshold']:.3g} s, longest interval "
                 f"{s['longest_interval']:.3g} s)" if s["segments"] > 1 else ""))
    if result.meta["condition_number"] > CONDITION_WARNING:
        print(f"haa-sym: warning: the fitted keys are nearly indistinguishable in these logs (condition number "
              f"{result.meta['condition_number']:.3g} of the scaled normal matrix): the intervals are not reliable; "
              "fit fewer keys or log more outputs", file=sys.stderr)
    if not result.meta["converged"]:
        print(f"haa-sym: warning: the fit stopped at the iteration limit ({FitOptions().max_iterations} per pass) "
              "while the error still fell: the values and intervals are not a minimum (check the log's time unit, "
              "seconds, and the start values)", file=sys.stderr)
    for k, v, v0, (lo, hi) in zip(result.keys, result.value, result.initial, result.ci95):
        print(f"{k} = {v:.6g} (ci95 {lo:.6g} .. {hi:.6g}; initial {v0:.6g})")
    rms = ", ".join(f"{o} {result.rms_initial[o]:.3g} -> {result.rms_fitted[o]:.3g}" for o in outputs)
    print(f"{result.samples} samples, {result.iterations} iterations; rms error {rms}; wrote {out}"
          + (f", {report}" if report else "") + (f", {plot}" if plot else ""))
    return 0
