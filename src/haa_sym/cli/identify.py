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
from haa_sym.fit.identify import INPUT_MODES, Experiment, FitOptions, identify
from haa_sym.io.formats import save_json
from haa_sym.io.logs import BIAS_JITTER, MAX_JITTER, OUTPUTS, read_log
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
    p.add_argument("--output", required=True, metavar="NAME[,NAME...]",
                   help=f"logged outputs the fit matches: {', '.join(OUTPUTS)}")
    p.add_argument("--fit", required=True, metavar="KEY[,KEY...]", help="plant parameter keys to fit (e.g. K_hd,D_hd)")
    p.add_argument("--configuration", action="append", default=[], metavar="NAME",
                   help="configuration of the file the logs were taken in: once for every log, or once per --log "
                        "in the same order")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key of the file (SI units) before fitting: the starting values")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="loop option (haa_sym.LoopOptions) of the torque loop, --input torque_ref only")
    p.add_argument("--max-jitter", type=float, default=MAX_JITTER, metavar="FRACTION",
                   help=f"largest sampling jitter max|dt - mean|/mean accepted (resampled onto the mean period "
                        f"above 1e-6); default {MAX_JITTER:g}")
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
    inputs, outputs, keys = _split(args.input, "--input"), _split(args.output, "--output"), _split(args.fit, "--fit")
    out = _check_out(args.out, "identify", "--out", (".toml",))
    report = _check_out(args.report, "identify", "--report", (".json",))
    plot = _check_out(args.plot, "identify", "--plot")
    if not (args.max_jitter >= 0):
        raise ParameterError(f"--max-jitter {args.max_jitter!r}; allowed: a fraction >= 0")
    if inputs[0] not in INPUT_MODES or any(i != "T_dist" for i in inputs[1:]) or len(set(inputs)) != len(inputs):
        raise ParameterError(f"--input {args.input}; allowed: one of {list(INPUT_MODES)}, optionally followed by "
                             ",T_dist")
    if any(o not in OUTPUTS for o in outputs) or len(set(outputs)) != len(outputs):
        raise ParameterError(f"--output {args.output}; allowed: distinct names of {list(OUTPUTS)}, comma separated")
    if args.option and inputs[0] != "torque_ref":
        raise ParameterError(f"--option {args.option[0]}: the loop options apply to the closed torque loop; "
                             "allowed: with --input torque_ref")
    _refuse_repeated_logs(args.log)
    path = actuator_path(args.params, "--params")
    file_params = load_params(path)
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
    for log_path, conf in zip(args.log, per_log):
        base = file_params.configuration(conf) if conf else file_params
        args.configuration = conf                     # _params applies --set over this configuration
        params = _params(args, base)
        log = read_log(log_path, inputs, outputs, max_jitter=args.max_jitter)
        experiments.append(Experiment(log, params, conf))
    # the inputs are known now: an output that is one of them (--out the log, a link to it) is
    # refused before the fit's seconds, not only when the outputs are committed
    for target, flag in ((args.out, "--out"), (args.report, "--report"), (args.plot, "--plot")):
        if target is not None:
            check_file(target, flag)
    loop = ClosedLoop(experiments[0].params, loop_options, basis=False)
    result = identify(experiments, keys, inputs, outputs, FitOptions(), loop_options,
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
        print(f"{e.log.name}: {e.log.samples} samples, mean period {s['mean_period']:.6g} s, jitter "
              f"{s['jitter']:.2g} (max |dt - mean| / mean)"
              + ("; resampled onto the mean period" if s["resampled"] else "; uniform"))
        if s["jitter"] > BIAS_JITTER:
            print(f"haa-sym: warning: {e.log.name}: resampling a jitter of {s['jitter']:.2g} biases the fitted "
                  f"values beyond their ci95 (measured from {BIAS_JITTER:g} on; docs/identify.md, \"Sampling\")",
                  file=sys.stderr)
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
