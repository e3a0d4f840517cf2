"""Identification of an actuator's parameters from logged experiments (``haa-sym identify``).

Time-domain output error: the sampled model (:mod:`haa_sym.fit.model`), driven from rest by a
log's inputs, predicts its outputs; the fitted keys minimise the sum over logs and outputs of the
squared prediction errors, each output of each log weighted by 1 / sigma (its noise level,
estimated from its own residuals; a first pass weights by the signal's standard deviation).
The parameters are fitted as logarithms (positive by construction, the only bound the keys'
domains impose: ``>0`` or ``>=0``, fitted from a positive start) by Levenberg-Marquardt with the
exact Jacobian (sensitivities of the simulation, derivatives from CasADi), so a few iterations
suffice. Confidence intervals (``ci95``) are a sandwich (HAC) covariance H^-1 S H^-1 of the
log-parameters, S the long-run covariance of each log's score series (Newey-West, Bartlett kernel,
Andrews' bandwidth; :mod:`haa_sym.fit.diagnostics`), so they hold when the residuals are correlated
in time; Gauss-Newton's s^2 (J^T J)^-1, which assumes white residuals, is kept as ``ci95_white``.
95 % intervals are log p +- 1.96 sd, so they are asymmetric and positive. The residuals of each log
and output are tested for whiteness (Ljung-Box); :func:`validate` scores the fitted model (NRMSE,
VAF) on held-out or other logs; :func:`refuse_unreliable` refuses keys the logs cannot tell apart
and an unconverged fit (docs/identify.md).
"""
from __future__ import annotations

import dataclasses
import datetime
import warnings
from dataclasses import dataclass, field

import numpy as np

from haa_sym.analysis.sweep import blas_limits
from haa_sym.errors import ParameterError
from haa_sym.fit.closed import torque_loop_model
from haa_sym.fit.diagnostics import (WHITENESS_LAGS, WHITENESS_LEVEL, fit_quality, hac_covariance,
                                     near_null_keys, whiteness)
from haa_sym.fit.friction import (DEFAULT_MAX_SUBSTEP, friction_entries, is_friction_key,
                                  simulate_friction_stamps)
from haa_sym.fit.model import modal_check, open_loop_model, sample, simulate, simulate_stamps
from haa_sym.io.budget import check_memory, fit_bytes
from haa_sym.io.logs import OUTPUTS, Log
from haa_sym.model import structures
from haa_sym.model.drive import DRIVE_KEYS

__all__ = ["FitOptions", "FitResult", "Experiment", "identify", "INPUT_MODES", "INITIAL_STATES", "simulate_log",
           "validate", "refuse_unreliable", "CONDITION_LIMIT", "INTERVAL_METHODS"]

INPUT_MODES = ("voltage", "current", "torque_ref")
#: Levenberg-Marquardt does not simulate a step within this relative distance of one it has just
#: simulated and rejected: at lam 1e-5 .. 1e-2 the ramp fits' steps (docs/identify.md) differ by
#: 2e-4 .. 8e-3 and each was rejected again, a simulation apiece.
SAME_STEP = 1e-2
# the scaled normal matrix's condition number above which the fitted keys are refused
# (refuse_unreliable): the normal equations have then lost ten of their sixteen digits and the keys
# of its near-null direction change the outputs together. Measured (docs/identify.md, "Refusals"):
# the well-posed fits of the synthetic logs give 6-200, a near-collinear pair
# (e.g. an inertia and a stiffness seen only through their ratio) 1e12 and above
CONDITION_LIMIT = 1e10
# the keys of the motor's electrical equation L dI_m/dt = V_m - R I_m - k_w dtheta_m: a current-
# commanded model (--input current) does not contain them
ELECTRICAL_KEYS = ("L", "R", "k_w")
Z95 = 1.959963984540054          # the two-sided 95 % point of the normal distribution
# how ci95 is computed (FitOptions.intervals): the name and the text the report and the fitted
# file give
INTERVAL_METHODS = {
    "hac": "sandwich (HAC) covariance: Newey-West, Bartlett kernel, Andrews' AR(1) plug-in bandwidth per log, "
           "from each log's score series (holds with correlated residuals)",
    "white": "Gauss-Newton covariance s^2 (J^T J)^-1 (assumes white output noise)"}


@dataclass(frozen=True)
class FitOptions:
    """The choices of a fit, each with its default.

    Parameters
    ----------
    min_periods : float
        A log must last at least this many periods of the model's slowest oscillatory mode
        (2 pi / |lambda| of its lowest complex pair; 2 pi / |lambda| of the slowest real mode
        when it has none). Default 3.
    max_iterations : int
        Levenberg-Marquardt iterations per pass (two passes: signal-scaled, then noise-weighted).
    tolerance : float
        Stop when the relative decrease of the cost is below this.
    max_step : float
        Largest change of a log-parameter per iteration (1 = a factor e).
    first_pass_tolerance : float
        The first pass (signal-scaled weights) stops at this relative decrease.
    reweight_rtol : float
        The noise-weighted pass is repeated, each time with the noise levels of the residuals it
        left, until no output's level changes by more than this fraction (default 0.05): the
        first pass stops loosely, so its residuals can still carry model error, and weights taken
        from them alone made the values and intervals depend on the start (intervals 7x wider
        from a start 4-40x off than from one 20 % off, on the same log).
    max_reweights : int
        At most this many noise-weighted passes (default 5).
    initial_state : str
        ``"rest"`` (default): a log's first segment starts at rest (x = 0; a log whose outputs do
        not start within :data:`REST_FRACTION` of their rms of zero is refused); ``"estimate"``:
        its initial state is estimated too. Segments after a gap, and a window that does not
        start at the log's first sample, always start from an estimated state.
    intervals : str
        How ``ci95`` is computed: ``"hac"`` (default), the sandwich covariance H^-1 S H^-1 with S
        the long-run covariance of each log's score series (Newey-West, Bartlett kernel, Andrews'
        AR(1) plug-in bandwidth; :func:`haa_sym.fit.diagnostics.hac_covariance`), which holds when
        the residuals are correlated in time; ``"white"``, Gauss-Newton's s^2 (J^T J)^-1, which
        assumes white residuals. The other one is reported as well (``ci95_white`` is always).
    whiteness_lags : int
        Lags of the Ljung-Box test of each log's and output's residuals (default 20; even).
    whiteness_level : float
        A residual series is called white when the test's p-value is at least this (0.05).
    max_substep : float or None
        Longest substep (s) of the friction simulation (:mod:`haa_sym.fit.friction`), used when
        friction is in the model. None (default): chosen per fit by :func:`safe_substep`, the
        longest of 5e-4 s / 2^k whose estimated error is within :data:`SUBSTEP_RTOL`; a given
        value is used as it is, with a warning when its estimated error at the fitted values is
        above :data:`SUBSTEP_RTOL`, refused above :data:`SUBSTEP_GROSS` (docs/identify.md,
        "The default substep").
    """

    min_periods: float = 3.0
    max_substep: float | None = None
    max_iterations: int = 50
    tolerance: float = 1e-10
    max_step: float = 1.0
    first_pass_tolerance: float = 1e-3
    reweight_rtol: float = 0.05
    max_reweights: int = 5
    initial_state: str = "rest"
    intervals: str = "hac"
    whiteness_lags: int = WHITENESS_LAGS
    whiteness_level: float = WHITENESS_LEVEL

    def __post_init__(self):
        if self.intervals not in INTERVAL_METHODS:
            raise ParameterError(f"FitOptions.intervals {self.intervals!r}; allowed: {list(INTERVAL_METHODS)}")
        ms = self.max_substep
        if ms is not None and (isinstance(ms, bool) or not isinstance(ms, (int, float)) or not 0 < ms < float("inf")):
            raise ParameterError(f"--max-substep {ms!r}; allowed: a positive finite number of seconds (the "
                                 "friction simulation's longest substep)")


#: A log fitted from rest must start there: each output's first sample within this fraction of
#: the output's rms (a log started mid-motion gave k_t 30 % high with no word, issue 23).
REST_FRACTION = 0.1
INITIAL_STATES = ("rest", "estimate")


@dataclass(frozen=True)
class Experiment:
    """One log and the parameters (file, configuration, --set) it was taken with."""

    log: Log
    params: object
    configuration: str | None = None
    outputs: tuple | None = None           # this log's outputs (default: the fit's)


@dataclass(frozen=True)
class FitResult:
    """What a fit found: ``keys``, ``value`` and ``initial`` (SI), ``ci95`` (len(keys), 2),
    ``covariance`` of the log-parameters, ``rms_initial`` / ``rms_fitted`` per output
    (its unit), the iterations, and per log the traces and frequency responses for a figure."""

    keys: tuple
    value: np.ndarray
    initial: np.ndarray
    ci95: np.ndarray
    covariance: np.ndarray
    rms_initial: dict
    rms_fitted: dict
    iterations: int
    samples: int
    sampling: dict
    outputs: tuple
    inputs: tuple
    traces: list = field(default_factory=list, repr=False)
    bode: list = field(default_factory=list, repr=False)
    meta: dict = field(default_factory=dict, repr=False)
    offsets: dict = field(default_factory=dict)

    def report(self) -> dict:
        """The ``fit.json`` of the issue: parameters (value, initial, ci95 and, for comparison, the
        white-noise ci95_white), the interval method, converged, the residuals' whiteness per log
        and output, rms_error, samples, sampling, meta."""
        white = self.meta["intervals"]["ci95_white"]
        return {"parameters": {k: {"value": float(v), "initial": float(v0), "ci95": [float(lo), float(hi)],
                                   "ci95_white": [float(x) for x in w]}
                               for k, v, v0, (lo, hi), w in zip(self.keys, self.value, self.initial, self.ci95, white)},
                "ci95_method": self.meta["intervals"]["method"], "converged": bool(self.meta["converged"]),
                "residuals": self.meta["residuals"],
                "rms_error": {o: {"initial": self.rms_initial[o], "fitted": self.rms_fitted[o]} for o in self.outputs},
                "samples": self.samples, "sampling": self.sampling, "meta": self.meta,
                **({"offsets": self.offsets} if self.offsets else {})}


def _model(exp: Experiment, keys, values, inputs, outputs, options=None):
    """The model of ``exp`` with ``keys`` at ``values``: the sampled closed torque loop
    (``torque_ref``), else the continuous open-loop plant behind the file's drive."""
    keys, values = _plant_part(keys, values)
    params = exp.params.with_values(**dict(zip(keys, values)))
    if inputs[0] == "torque_ref":
        return torque_loop_model(params, keys, inputs, outputs, options)
    return open_loop_model(params.plant, keys, inputs, outputs, params.drive)


def _estimated(exp: Experiment, opt) -> tuple:
    """Per segment of ``exp``'s log: whether its initial state is estimated."""
    first = opt.initial_state == "estimate" or not exp.log.from_start
    return (first,) + (True,) * (len(exp.log.starts) - 1)


def _uniform_path(exp: Experiment, keys, opt) -> bool:
    """Whether ``exp`` is simulated at one period (uniform stamps, one segment, from rest, no
    delay): the fast path of :func:`haa_sym.fit.model.simulate`; else on its own intervals."""
    return (exp.log.uniform and not any(_estimated(exp, opt)) and exp.params.drive.delay_drive == 0
            and "delay_drive" not in keys)


def simulate_log(exp: Experiment, inputs, outputs=None, keys=(), values=(), *, options: "FitOptions | None" = None,
                 loop_options=None, sensitivities: bool = False, u: np.ndarray | None = None,
                 y: np.ndarray | None = None, scale: np.ndarray | None = None, friction: dict | None = None):
    """The model's outputs on ``exp``'s log, simulated as a fit simulates it: the one simulation
    path of the fit and of its validation (:func:`validate`).

    A uniform log from rest without a delay at its one period (:func:`haa_sym.fit.model.simulate`);
    any other on its own stamps (:func:`haa_sym.fit.model.simulate_stamps`: the input held over
    each true interval, the delayed command switching inside them, every segment after a gap
    restarted from an estimated state, the first from rest unless ``options.initial_state`` or a
    window says otherwise).

    Parameters
    ----------
    exp : Experiment
        The log and its parameters (``keys`` at ``values`` set over them; none: as they are).
    inputs, outputs : tuple of str
        The log's inputs and outputs (``exp.outputs`` when the experiment names its own).
    keys, values : sequence
        Keys set to values (SI) and, with ``sensitivities``, differentiated by.
    options : FitOptions, optional
        ``initial_state`` (default :class:`FitOptions`' ``"rest"``).
    u, y : ndarray, optional
        The log's input (N, m) and output (N, ny) columns when the caller has them already.
    scale : ndarray, optional
        Per output, the weights of the initial-state estimate (default the outputs' standard
        deviations).
    friction : dict, optional
        ``Fc_*`` (Nm) over the file's [limits]; with any friction (or an ``Fc_*`` key) the log is
        simulated with Coulomb friction (:func:`_friction_run`).

    Returns
    -------
    y_model : ndarray (N, ny)
    dy : ndarray (p, N, ny) or None
        d y_model / d values (with ``sensitivities``).
    n_initial : int
        The number of initial-state values estimated (degrees of freedom the fit used up).
    """
    opt = options or FitOptions()
    keys, inputs = tuple(keys), tuple(inputs)
    outs = tuple(exp.outputs or outputs)
    log = exp.log
    if u is None:
        u = np.column_stack([log.signals[i] for i in inputs])
    if y is None:
        y = np.column_stack([log.signals[x] for x in outs])
    if scale is None:
        scale = np.maximum(np.std(y, axis=0), 1e-300)
    if inputs[0] != "torque_ref" and _uses_friction(exp, keys, friction):
        return _friction_run(exp, keys, values, inputs, outs, friction, u, y, scale, opt, sensitivities)
    model = _model(exp, keys, values, inputs, outs, loop_options)
    if not hasattr(model, "A"):                                     # the sampled torque loop
        return simulate(model, u, sensitivities) + (0,)
    if _uniform_path(exp, keys, opt):
        return simulate(sample(model, log.Ts), u, sensitivities) + (0,)
    delay = dict(zip(keys, values)).get("delay_drive", exp.params.drive.delay_drive)
    return simulate_stamps(model, log.t, u, delay=delay, delay_key=keys.index("delay_drive") if "delay_drive" in keys
                           else None, starts=log.starts, estimate=_estimated(exp, opt), y=y, weights=scale,
                           sensitivities=sensitivities)


def validate(result: "FitResult", cases, loop_options=None, options: "FitOptions | None" = None,
             friction: dict | None = None) -> tuple[dict, list]:
    """NRMSE and VAF (:func:`haa_sym.fit.diagnostics.fit_quality`) of the fitted model per output
    on each of ``cases``.

    Parameters
    ----------
    result : FitResult
        The fit (its keys and values are set on each case's parameters).
    cases : list of (label, Experiment, start, stop)
        A log with its parameters, simulated whole by :func:`simulate_log` as a fitted log is
        (its own stamps, segments after gaps from estimated states: a segment's initial state is
        estimated from the whole segment, so a segment that runs on past the held-out boundary
        uses those samples for its n state values, never for the parameters), and the samples
        ``start:stop`` scored: the fitted part of a fitted log, its held-out last part, a
        validation log's window.
    loop_options : LoopOptions, optional
    options : FitOptions, optional
        The fit's (``initial_state``, ``max_substep``).
    friction : dict, optional
        The fit's ``friction`` (:func:`identify`).

    An output with a fitted offset gets its log's offset (a fitted log's part and held-out part);
    a log that was not fitted gets its own, the mean error over its scored samples (a tare is
    per log: it says nothing about another log's).

    Returns
    -------
    quality : dict
        ``{label: {output: {"nrmse", "vaf_percent", "samples"}}}``.
    traces : list of dict
        Per case ``name``, ``t`` (s), ``measured`` and ``fitted`` over the scored samples, for a figure.
    """
    quality, traces = {}, []
    fr = result.meta.get("friction")
    if fr and (options is None or options.max_substep is None):
        # the fit's own substep (chosen per fit by default)
        options = dataclasses.replace(options or FitOptions(), max_substep=fr["max_substep"])
    with blas_limits(1):
        for label, exp, start, stop in cases:
            if result.inputs[0] == "torque_ref":
                m = _model(exp, result.keys, result.value, result.inputs, result.outputs, loop_options)
                if abs(exp.log.Ts - m.Ts) > 1e-6 * m.Ts or not (exp.log.uniform and exp.log.from_start):
                    raise ParameterError(f"--validate {exp.log.name!r}: mean period {exp.log.Ts:.6g} s"
                                         f"{'' if exp.log.uniform else ', non-uniform stamps'}; allowed: a uniform "
                                         f"log at the torque loop's Ts = {m.Ts:g} s with --input torque_ref")
            outs = tuple(exp.outputs or result.outputs)
            yp = simulate_log(exp, result.inputs, outs, result.keys, result.value, options=options,
                              loop_options=loop_options, friction=friction)[0]
            y = np.column_stack([exp.log.signals[o] for o in outs])
            sl = slice(start, stop)
            own = result.offsets.get(exp.log.name)
            for i, o in enumerate(outs):
                if own is not None and o in own:
                    yp[:, i] += own[o]
                elif own is None and o in result.meta.get("offsets", ()):
                    yp[:, i] += np.mean(y[sl, i] - yp[sl, i])
            quality[label] = {o: fit_quality(y[sl, i], yp[sl, i]) for i, o in enumerate(outs)}
            traces.append({"name": label, "t": (exp.log.t - exp.log.t[0])[sl], "measured": y[sl],
                           "fitted": yp[sl], "outputs": outs})
    return quality, traces


def refuse_unreliable(result: "FitResult", allow_unconverged: bool = False,
                      condition_limit: float = CONDITION_LIMIT) -> None:
    """Refuse a fit whose values are not a result (the CLI writes nothing then).

    Raises
    ------
    ParameterError
        The scaled normal matrix's condition number above ``condition_limit`` (the keys of its
        near-null direction named: the logs see them only together), or the fit stopped at its
        iteration limit while the cost still fell, unless ``allow_unconverged``.
    """
    cond = result.meta["condition_number"]
    if not cond <= condition_limit:
        group = result.meta.get("near_null_keys") or list(result.keys)
        if len(group) == 1:
            # a near-null direction along one key is no pair to tell apart: the logs do not see that
            # key where the fit took it (e.g. the QDD leg's tau_drive run to 0 with delay_drive free)
            i = result.keys.index(group[0])
            what = (f"do not determine {group[0]} (run from {result.initial[i]:.3g} to {result.value[i]:.3g})")
        else:
            what = f"cannot tell {', '.join(group)} apart"
        raise ParameterError(f"--fit {','.join(result.keys)}: these logs {what} "
                             f"(condition number {cond:.3g} of the scaled normal matrix, above {condition_limit:.0e}); "
                             "allowed: keys the logs distinguish (fit fewer keys, log more outputs, a richer input)")
    if not result.meta["converged"] and not allow_unconverged:
        its = result.meta["options"]["max_iterations"]
        raise ParameterError(f"--fit {','.join(result.keys)}: the fit stopped at its iteration limit ({its} per "
                             "pass) while the error still fell, so the values are not a minimum; allowed: a converged "
                             "fit (check the time column is in s and the start values), or --allow-unconverged to "
                             "write the file marked as not converged")


def _plant_part(keys, values):
    """The plant keys of ``keys`` and their values (the ``Fc_*`` keys are [limits] entries)."""
    pairs = [(k, v) for k, v in zip(keys, values) if not is_friction_key(k)]
    return tuple(k for k, _ in pairs), [v for _, v in pairs]


def _friction_of(exp: Experiment, friction: dict | None) -> dict:
    """The experiment's Coulomb friction by entry (``"m"``, bodies), Nm: the file's [limits],
    then ``friction`` (start values given to :func:`identify`)."""
    out = dict(exp.params.limits.friction)
    out.update({k[3:]: float(v) for k, v in (friction or {}).items()})
    return out


def _uses_friction(exp: Experiment, keys, friction) -> bool:
    """Whether ``exp`` is simulated with Coulomb friction: a fitted ``Fc_*`` key, or a nonzero one in
    the file's [limits] or in ``friction``."""
    return any(is_friction_key(k) for k in keys) or any(v > 0 for v in _friction_of(exp, friction).values())


def _friction_run(exp: Experiment, keys, values, inputs, outputs, friction, u, y, scale, opt, sens):
    """:func:`simulate_log`'s friction path: the plant behind the file's drive (its lag a state
    appended after the plant's, no friction on it), Coulomb friction on the rotor and the bodies
    (:mod:`haa_sym.fit.friction`), on the log's own stamps with the delayed command and its
    segments, as the linear path (:func:`haa_sym.fit.friction.simulate_friction_stamps`)."""
    vals = dict(zip(keys, values))
    pk, pv = _plant_part(keys, values)
    params = exp.params.with_values(**dict(zip(pk, pv)))
    model = open_loop_model(params.plant, pk, inputs, outputs, params.drive)
    fmap = _friction_of(exp, friction)
    fmap.update({k[3:]: vals[k] for k in keys if is_friction_key(k)})
    fr = friction_entries(params.plant, keys, inputs, model.A.shape[0], fmap, params.limits.friction_velocity)
    # the Fc keys' rows of dA ... dD are zero (they act in the recursion only)
    idx = [pk.index(k) if k in pk else None for k in keys]

    def full(d):
        return np.stack([d[i] if i is not None else np.zeros(d.shape[1:]) for i in idx]) if keys else d
    model = type(model)(model.A, model.B, model.C, model.D, full(model.dA), full(model.dB), full(model.dC),
                        full(model.dD))
    log = exp.log
    return simulate_friction_stamps(model, fr, log.t, u, delay=params.drive.delay_drive,
                                    delay_key=keys.index("delay_drive") if "delay_drive" in keys else None,
                                    starts=log.starts, estimate=_estimated(exp, opt), y=y, weights=scale,
                                    sensitivities=sens, max_substep=opt.max_substep or DEFAULT_MAX_SUBSTEP)


def _check_keys(exps, keys, inputs, friction=None):
    if not keys:
        raise ParameterError("--fit: no keys; allowed: one or more parameter keys, comma separated")
    top = exps[0].params.plant.topology
    dup = sorted({k for k in keys if keys.count(k) > 1})
    if dup:
        raise ParameterError(f"--fit {','.join(keys)}: {dup} given twice; allowed: each key once")
    for k in keys:
        if k in DRIVE_KEYS:
            _check_drive_key(exps, k, inputs)
            continue
        if is_friction_key(k):
            allowed = ["Fc_m"] + [f"Fc_{b}" for b in top.body_names]
            if k not in allowed:
                raise ParameterError(f"--fit {k}: not a friction entry of {top.source}; allowed: {allowed}")
            if inputs[0] == "torque_ref":
                raise ParameterError(f"--fit {k}: friction with --input torque_ref is not modelled; allowed: "
                                     "--input voltage or current")
            for e in exps:
                v = _friction_of(e, friction).get(k[3:], 0.0)
                if not v > 0:
                    raise ParameterError(f"--fit {k}: initial value {v!r}; allowed: a positive start ([limits] "
                                         f"{k} in the file, or --set {k}=VALUE)")
            continue
        if k not in top.parameter_keys:
            raise ParameterError(f"--fit {k}: not a plant parameter of {top.source}; allowed: "
                                 f"{list(top.parameter_keys) + list(DRIVE_KEYS)}")
        if inputs[0] == "current" and k in ELECTRICAL_KEYS:
            # the drive's current loop imposes I_m: the electrical equation L dI/dt = V - R I - k_w w
            # is not in the model (haa_sym.fit.model._open_loop removes its state), so these keys
            # act on nothing the log shows
            kept = [x for x in top.parameter_keys if x not in ELECTRICAL_KEYS]
            raise ParameterError(f"--fit {k}: the current-commanded model (--input current: the drive imposes the "
                                 f"current, the electrical state removed) does not contain "
                                 f"{', '.join(ELECTRICAL_KEYS)}; allowed: its keys "
                                 f"{kept + list(DRIVE_KEYS) + ['Fc_m'] + [f'Fc_{b}' for b in top.body_names]}")
        for e in exps:
            v = getattr(e.params.plant, k)
            if not v > 0:
                raise ParameterError(f"--fit {k}: initial value {v!r} (domain {top.domain[k]}); allowed: a "
                                     f"positive start (fitted as log {k}; --set {k}=VALUE)")
        confs = {e.configuration for e in exps if e.configuration and
                 k in e.params.configurations.get(e.configuration, {})}
        if confs:
            raise ParameterError(f"--fit {k}: configuration {sorted(confs)[0]} sets it (the fitted file's entry "
                                 "would not be the value the log was fitted with); allowed: keys the configurations "
                                 "leave alone")


def _check_command(exps, inputs):
    """``--input torque_ref`` needs the file's torque loop: a current-commanded structure
    (``impedance_current``: the impedance PD's T_ref / (k_t N) is the drive's current command) has
    none, and its logs are fitted from that command, ``--input current``."""
    if inputs[0] != "torque_ref":
        return
    for e in exps:
        name = e.params.controller.structure
        if structures.get(name).command == "current":
            raise ParameterError(f"--input torque_ref: {e.params.source} has structure = {name!r}, whose controller "
                                 "commands the motor's current (T_ref / (k_t N)) through no torque loop; allowed: "
                                 "--input current (the log's current command, A)")


def _check_drive_key(exps, k, inputs):
    """A drive key is fitted only where the file's ``[drive]`` declares it (the fitted file writes
    it there), from a positive start (fitted as a logarithm), around an open-loop model."""
    if inputs[0] == "torque_ref":
        raise ParameterError(f"--fit {k} with --input torque_ref: the closed torque loop's fit does not model the "
                             "drive; allowed: --input current or voltage")
    for e in exps:
        src = e.params.source
        if k not in e.params.drive.declared:
            raise ParameterError(f"--fit {k}: {src} has no [drive] {k}; allowed: add [drive] {k} = <start> (s)")
        v = getattr(e.params.drive, k)
        if not v > 0:
            raise ParameterError(f"--fit {k}: initial value {v!r} s; allowed: a positive start (fitted as log {k}; "
                                 f"--set {k}=VALUE)")


def _slow_period_continuous(A) -> float:
    """:func:`_slow_period` from the continuous eigenvalues."""
    lam = np.linalg.eigvals(A).astype(complex)
    mag = np.abs(lam)
    osc = mag[(np.abs(lam.imag) > 1e-9 * np.maximum(mag, 1e-300))]
    use = osc if osc.size else mag[mag > 1e-9 * max(1.0, mag.max())]
    return float(2 * np.pi / use.min()) if use.size else 0.0


def _slow_period(model) -> float:
    """2 pi / |s| of the slowest oscillatory mode (else the slowest nonzero real one), s =
    log(z) / Ts from the sampled model's eigenvalues z (open or closed loop alike)."""
    lam = np.log(np.linalg.eigvals(model.Phi).astype(complex)) / model.Ts
    mag = np.abs(lam)
    osc = mag[(np.abs(lam.imag) > 1e-9 * np.maximum(mag, 1e-300))]
    use = osc if osc.size else mag[mag > 1e-9 * max(1.0, mag.max())]
    return float(2 * np.pi / use.min()) if use.size else 0.0


#: A key whose column of the Jacobian (the outputs' sensitivity to its logarithm) is below this
#: fraction of the largest key's is refused: the logs do not see it (the normal matrix would be
#: singular to rounding).
DEAD_SENSITIVITY = 1e-12
#: The friction simulation's error the default substep allows: the step-doubling estimate
#: rms(y(h) - y(h / 2)) of the extrapolated scheme's error at h, over each output's standard
#: deviation in the log, the largest over the logs and outputs. Measured (docs/identify.md, "The
#: default substep"): the haptic wall's four-key fit (1 % noise) is inside every ci95 with white
#: residuals at an estimate of 2.1e-4 (h = 62.5 us) and biased outside tau_drive's ci95 with
#: coloured residuals at 1.3e-3 (125 us); the ITregear chirp's estimate at 0.5 ms is 3.8e-4, its
#: values within a tenth of their intervals of the 0.25 ms fit's. 5e-4 lies between (their
#: geometric mean 5.3e-4) and keeps the real logs at 0.5 ms.
SUBSTEP_RTOL = 5e-4
#: A given ``--max-substep`` whose estimated error at the fitted values is above this is refused:
#: the haptic wall's 0.5 ms (estimate 0.10, ten times its noise) stopped at the iteration limit
#: with tau_drive 5.7x its truth; at 0.25 ms (1.1e-2) the error still equals the noise.
SUBSTEP_GROSS = 1e-2
#: Halvings of :data:`haa_sym.fit.friction.DEFAULT_MAX_SUBSTEP` the default's search tries (to 7.8 us).
SUBSTEP_HALVINGS = 6
#: Refits at a finer substep when the fitted values need one (the search ran at the start values).
SUBSTEP_REFITS = 2
#: The default's substep is not rechecked at the fitted values when its estimate at the start was
#: below SUBSTEP_RTOL over this: the estimate changed at most 3.5x between start and fit in the
#: cases measured (the haptic wall at 0.5 ms, Fc_m and tau_drive 1.5x off: 2.9e-2 -> 0.10), and a
#: recheck costs a simulation at h / 2 (on the ITregear ramps' 3-4-iteration fits a fifth of the fit).
SUBSTEP_RECHECK_MARGIN = 10


def _substep_error(experiments, outs, inputs, keys, values, opt, U, Y, friction, h, y_h=None):
    """The step-doubling estimate of the friction simulation's error at substep ``h`` (s):
    max over logs and outputs of rms(y(h) - y(h / 2)) / std(measured output) (the extrapolated
    scheme converges 4-8x a halving on these logs, so this is y(h)'s error to within its first
    digit). ``y_h``: the runs at ``h`` when known. Returns (error, the runs at h / 2)."""
    err, halves = 0.0, []
    for i, (e, o, u, y) in enumerate(zip(experiments, outs, U, Y)):
        sd = np.maximum(np.std(y, axis=0), 1e-300)
        runs = []
        for step in ((h,) if y_h is None else ()) + (h / 2,):
            runs.append(simulate_log(e, inputs, o, keys, values, options=dataclasses.replace(opt, max_substep=step),
                                     u=u, y=y, scale=sd, friction=friction)[0])
        a, b = (runs[0], runs[1]) if y_h is None else (y_h[i], runs[0])
        err = max(err, float(np.max(np.sqrt(np.mean((a - b) ** 2, axis=0)) / sd)))
        halves.append(b)
    return err, halves


def safe_substep(experiments, outs, inputs, keys, values, opt, U, Y, friction, start=DEFAULT_MAX_SUBSTEP,
                 y_start=None):
    """The longest substep start / 2^k (k <= :data:`SUBSTEP_HALVINGS`) whose estimated error
    (:func:`_substep_error`) is within :data:`SUBSTEP_RTOL`, at ``values``.

    ``y_start``: the runs at ``start`` when known (the fit's own first evaluation).

    Returns
    -------
    h : float
        The substep (s).
    error : float
        Its estimated error.
    levels : list of [h, error]
        Every substep tried.

    Raises
    ------
    ParameterError
        No substep down to start / 2^SUBSTEP_HALVINGS is accurate enough.
    """
    h, prev, levels = start, y_start, []
    for _ in range(SUBSTEP_HALVINGS + 1):
        err, prev = _substep_error(experiments, outs, inputs, keys, values, opt, U, Y, friction, h, prev)
        levels.append([h, err])
        if err <= SUBSTEP_RTOL:
            return h, err, levels
        h /= 2
    raise ParameterError(f"friction simulation: no substep down to {levels[-1][0]:.3g} s brings its estimated error "
                         f"within {SUBSTEP_RTOL:g} of the outputs' spread ({levels[-1][1]:.3g} there); allowed: a "
                         "smoother friction (a larger friction_velocity), or --max-substep given (used as it is, "
                         "its error reported)")


def identify(experiments: list[Experiment], keys: tuple[str, ...], inputs: tuple[str, ...],
             outputs: tuple[str, ...], options: FitOptions | None = None, loop_options=None,
             provenance: dict | None = None, figure_data: bool = False, friction: dict | None = None,
             offsets: tuple[str, ...] = ()) -> FitResult:
    """Fit ``keys`` to the experiments (jointly) by output error; see the module docstring.

    Parameters
    ----------
    experiments : list of Experiment
        Logs with the parameters each was taken with (the fitted keys shared by all).
    keys : tuple of str
        Plant parameter keys to fit (SI units).
    inputs : tuple of str
        ``("voltage" | "current" | "torque_ref", ["T_dist"])``: the log's inputs.
    outputs : tuple of str
        Log outputs (``torque``, ``theta``, ``current``, ``velocity``).
    options : FitOptions, optional
    loop_options : LoopOptions, optional
        The torque loop's options (``--input torque_ref`` only).
    provenance : dict, optional
        Added to ``meta``.
    figure_data : bool
        Also compute the Welch H1 estimates, coherences and model responses (``bode``) for a
        figure (Welch and 2 x ny frequency responses: only when a figure is drawn).
    friction : dict, optional
        Coulomb friction torques (``Fc_m``, ``Fc_<body>``: Nm) over the file's ``[limits]``:
        the start of fitted ones, the value of the others. With any friction (fitted or in the
        file) every log is simulated with it (:mod:`haa_sym.fit.friction`).
    offsets : tuple of str
        Outputs with a constant offset per log (a sensor's tare): linear, so eliminated inside
        every evaluation (the residual and its Jacobian are centred per log and output: the
        offset's least-squares value is the residual's mean); reported in ``FitResult.offsets``.

    Raises
    ------
    ParameterError
        Bad keys or inputs, a log shorter than ``min_periods`` of the slowest mode, a key the
        outputs do not depend on.
    """
    opt = options or FitOptions()
    keys, inputs, outputs = tuple(keys), tuple(inputs), tuple(outputs)
    if not inputs or inputs[0] not in INPUT_MODES or any(i != "T_dist" for i in inputs[1:]):
        raise ParameterError(f"--input {','.join(inputs)}; allowed: one of {list(INPUT_MODES)}, optionally "
                             "followed by ,T_dist")
    if not outputs or any(o not in OUTPUTS for o in outputs) or len(set(outputs)) != len(outputs):
        raise ParameterError(f"--output {','.join(outputs)}; allowed: distinct names of {list(OUTPUTS)}")
    _check_command(experiments, inputs)
    _check_keys(experiments, keys, inputs, friction)
    if opt.initial_state not in INITIAL_STATES:
        raise ParameterError(f"--initial-state {opt.initial_state!r}; allowed: one of {list(INITIAL_STATES)}")
    outs = [tuple(e.outputs or outputs) for e in experiments]
    for e, o in zip(experiments, outs):
        if any(x not in OUTPUTS for x in o) or len(set(o)) != len(o):
            raise ParameterError(f"--output {','.join(o)}; allowed: distinct names of {list(OUTPUTS)}")
    all_outputs = tuple(dict.fromkeys(x for o in outs for x in o))
    offsets = tuple(offsets)
    if any(o not in all_outputs for o in offsets) or len(set(offsets)) != len(offsets):
        raise ParameterError(f"--offsets {','.join(offsets)}; allowed: distinct names of --output "
                             f"{list(all_outputs)}")
    e0 = experiments[0]
    values0 = [_friction_of(e0, friction)[k[3:]] if is_friction_key(k)
               else getattr(e0.params.drive if k in DRIVE_KEYS else e0.params.plant, k) for k in keys]
    theta0 = np.log(values0)
    use_friction = any(_uses_friction(e, keys, friction) for e in experiments)
    if use_friction and inputs[0] == "torque_ref":
        raise ParameterError("[limits] friction with --input torque_ref is not modelled; allowed: --input voltage or "
                             "current (or a file without friction)")
    with blas_limits(1):          # small matrices, long signals: BLAS threads only contend
        models0 = [_model(e, keys, np.exp(theta0), inputs, o, loop_options) for e, o in zip(experiments, outs)]
        for e, o, m in zip(experiments, outs, models0):
            if inputs[0] == "torque_ref":
                if not (e.log.uniform and e.log.from_start) or e.params.drive.active or \
                        opt.initial_state != "rest":
                    raise ParameterError(f"--log {e.log.name!r} with --input torque_ref: the closed loop is fitted "
                                         "on uniform logs from rest without a [drive] lag or delay; allowed: such "
                                         "a log (or --input current/voltage)")
                if abs(e.log.Ts - m.Ts) > 1e-6 * m.Ts:
                    raise ParameterError(f"--log {e.log.name!r}: mean period {e.log.Ts:.6g} s; allowed: the torque "
                                         f"loop's Ts = {m.Ts:g} s with --input torque_ref (the controller runs at Ts)")
                slow = _slow_period(m)
            else:
                if not _uniform_path(e, keys, opt):
                    modal_check(m.A, f"--log {e.log.name!r}")
                slow = _slow_period_continuous(m.A)
            if e.log.duration < opt.min_periods * slow:
                raise ParameterError(f"--log {e.log.name!r}: {e.log.duration:.3g} s long, {opt.min_periods:g} periods "
                                     f"of the model's slowest mode are {opt.min_periods * slow:.3g} s; allowed: a "
                                     "longer log (or --min-periods)")
            if _estimated(e, opt)[0] is False:
                # an output with an offset starts at its tare, not at 0: the others say whether the
                # log starts at rest
                for x in (x for x in o if x not in offsets):
                    v = e.log.signals[x]
                    rms = float(np.sqrt(np.mean(v ** 2)))
                    if abs(float(v[0])) > REST_FRACTION * rms:
                        raise ParameterError(f"--log {e.log.name!r}: {x} starts at {float(v[0]):.4g} (rms {rms:.3g}): "
                                             "not at rest; allowed: --initial-state estimate (its initial state "
                                             "fitted), or a log or --window that starts at rest")
        # before the fit allocates its trajectories and sensitivities (a 10 M-row log reached
        # 9.9 GB and died): refused in one line when over the memory budget
        n_states = [m.A.shape[0] if hasattr(m, "A") else m.Phi.shape[0] for m in models0]
        check_memory(sum(fit_bytes(e.log.samples * (1 if _uniform_path(e, keys, opt) else 2), n, len(o), len(keys))
                         for e, n, o in zip(experiments, n_states, outs)), f"fitting {len(keys)} key(s) to "
                     f"{sum(e.log.samples for e in experiments)} samples")
        U = [np.column_stack([e.log.signals[i] for i in inputs]) for e in experiments]
        Y = [np.column_stack([e.log.signals[x] for x in o]) for e, o in zip(experiments, outs)]
        sigma = [np.maximum(np.std(y, axis=0), 1e-300) for y in Y]
        # the initial states are estimated with these fixed weights (any positive weights give
        # a consistent estimate; fixed, they keep a point's simulation independent of the pass)
        scale = list(sigma)

        cache: dict = {}
        offset_of: dict = {}          # the offsets each cached point's simulation found, per log
        # the friction simulation's substep: given, or the longest one accurate at the start values
        # (SUBSTEP_RTOL); checked again at the fitted values below
        sub = {"opt": opt, "levels": [], "error": None}

        def run(theta, sens=True):
            """Unweighted errors y - y_model and, with ``sens``, d y_model / d log p, per log; a
            point's simulation is kept so that reweighting and the reports re-run nothing."""
            key = theta.tobytes()
            if key not in cache or (sens and cache[key][1] is None):
                errs, sens_, n0, offs = [], [], 0, {}
                for e, o, u, y, w in zip(experiments, outs, U, Y, scale):
                    yp, dy, n_init = simulate_log(e, inputs, o, keys, np.exp(theta), options=sub["opt"],
                                                  loop_options=loop_options, sensitivities=sens, u=u, y=y, scale=w,
                                                  friction=friction)
                    off_cols = [o.index(x) for x in offsets if x in o]
                    if off_cols:
                        # variable projection of the offsets: the model plus the mean error (after the
                        # initial states' projection, not jointly with it)
                        yp = yp.copy()
                        off = np.mean(y[:, off_cols] - yp[:, off_cols], axis=0)
                        yp[:, off_cols] += off
                        offs[e.log.name] = {o[c]: float(v) for c, v in zip(off_cols, off)}
                        if dy is not None:
                            dy = dy.copy()
                            dy[:, :, off_cols] -= np.mean(dy[:, :, off_cols], axis=1, keepdims=True)
                    errs.append(y - yp)
                    n0 += n_init
                    sens_.append(None if dy is None else dy * np.exp(theta)[:, None, None])
                cache.clear() if len(cache) > 8 else None
                cache[key] = (errs, sens_ if sens else None, n0 + sum(len(v) for v in offs.values()))
                offset_of[key] = offs
            return cache[key]

        def model_runs(theta, sens):
            """The model's outputs per log at ``theta`` (the cached run's, its offsets taken off)."""
            errs = run(theta, sens)[0]
            offs = offset_of.get(theta.tobytes(), {})
            out = []
            for e, o, y, err in zip(experiments, outs, Y, errs):
                yp = y - err
                for c, x in enumerate(o):
                    yp[:, c] -= offs.get(e.log.name, {}).get(x, 0.0)
                out.append(yp)
            return out

        if use_friction and opt.max_substep is None:
            # the fit's first evaluation (at 0.5 ms) is the search's first run: only the finer ones cost
            h, _, sub["levels"] = safe_substep(experiments, outs, inputs, keys, np.exp(theta0), opt, U, Y, friction,
                                               y_start=model_runs(theta0, True))
            sub["opt"] = dataclasses.replace(opt, max_substep=h)
            if h != DEFAULT_MAX_SUBSTEP:
                cache.clear()

        def evaluate(theta, sens=True):
            errs, dys, _ = run(theta, sens)
            r = np.concatenate([(err / s).ravel() for err, s in zip(errs, sigma)])
            if not sens:
                return r, None
            return r, np.vstack([(-dy / s).reshape(len(keys), -1).T for dy, s in zip(dys, sigma)])

        # the first pass only finds the neighbourhood (its weights are provisional); the second,
        # with the noise levels of the residuals as weights, converges
        origin: dict = {}
        theta, it1, _ = _levenberg_marquardt(evaluate, theta0, opt, keys, tolerance=opt.first_pass_tolerance,
                                             origin=origin)
        it2, scale0 = 0, sigma
        for n_pass in range(max(opt.max_reweights, 1)):
            new = [np.maximum(np.sqrt(np.mean(err ** 2, axis=0)), 1e-12 * s) for err, s in zip(run(theta)[0], scale0)]
            if n_pass and all(np.all(np.abs(a / b - 1) <= opt.reweight_rtol) for a, b in zip(new, sigma)):
                break
            sigma = new          # evaluate() reads sigma when called: the new weights apply
            theta, it, converged = _levenberg_marquardt(evaluate, theta, opt, keys, origin=origin)
            it2 += it
        recheck = use_friction and not (opt.max_substep is None and
                                        sub["levels"][-1][1] <= SUBSTEP_RTOL / SUBSTEP_RECHECK_MARGIN)
        if use_friction and not recheck:
            sub["error"], sub["at"] = sub["levels"][-1][1], "start values"
        for refit in range(SUBSTEP_REFITS + 1) if recheck else ():
            sub["at"] = "fitted values"
            h = sub["opt"].max_substep
            y_h = model_runs(theta, False)           # the fit's own run at h, cached
            sub["error"] = _substep_error(experiments, outs, inputs, keys, np.exp(theta), sub["opt"], U, Y, friction,
                                          h, y_h)[0]
            if sub["error"] <= SUBSTEP_RTOL or refit == SUBSTEP_REFITS:
                break
            if opt.max_substep is not None:
                safe = safe_substep(experiments, outs, inputs, keys, np.exp(theta), opt, U, Y, friction,
                                    start=min(h, DEFAULT_MAX_SUBSTEP) / 2)[0]
                words = (f"--max-substep {h:g} s: the friction simulation's estimated error at the fitted values is "
                         f"{sub['error']:.2g} of the outputs' spread (allowed {SUBSTEP_RTOL:g}; a substep of {safe:.3g} "
                         "s or less keeps it)")
                if sub["error"] > SUBSTEP_GROSS:
                    raise ParameterError(f"{words}, above {SUBSTEP_GROSS:g}: the values would be wrong; allowed: "
                                         f"--max-substep {safe:.3g} or less, or the default (chosen per fit)")
                warnings.warn(f"{words}: the values carry its bias")
                break
            # the fitted values need a finer substep than the start's: refit from them at it
            h, _, levels = safe_substep(experiments, outs, inputs, keys, np.exp(theta), opt, U, Y, friction,
                                        start=h / 2)
            sub["opt"], sub["levels"] = dataclasses.replace(opt, max_substep=h), sub["levels"] + levels
            cache.clear()
            theta, it, converged = _levenberg_marquardt(evaluate, theta, sub["opt"], keys, origin=origin)
            it2 += it
        if use_friction and opt.max_substep is None and sub["error"] > SUBSTEP_RTOL:
            warnings.warn(f"the friction simulation's estimated error at the fitted values is {sub['error']:.2g} of "
                          f"the outputs' spread at the substep {sub['opt'].max_substep:.3g} s after {SUBSTEP_REFITS} "
                          f"refits (allowed {SUBSTEP_RTOL:g}): the values carry its bias")
        r, J = evaluate(theta)
        n_initial = run(theta)[2]
        pred = [y - err for y, err in zip(Y, run(theta)[0])]
        fitted_offsets = offset_of.get(theta.tobytes(), {})
        n_initial -= sum(len(v) for v in fitted_offsets.values())
        pred0 = [y - err for y, err in zip(Y, run(theta0, False)[0])]
    outputs = all_outputs
    # the estimated initial states took their degrees of freedom too
    dof = max(r.size - len(keys) - n_initial - sum(len(v) for v in fitted_offsets.values()), 1)
    s2 = float(r @ r) / dof
    # the scaled normal matrix's condition: keys the logs cannot tell apart make it huge (and the
    # intervals meaningless); reported in meta with the keys of its near-null direction, refused
    # by the CLI (haa_sym.fit.identify.refuse_unreliable)
    H = J.T @ J
    d = np.sqrt(np.maximum(np.diag(H), 1e-300))
    Hs = H / np.outer(d, d)
    condition = float(np.linalg.cond(Hs))
    # inverted in the scaled coordinates: pinv(H) itself would drop, as below its rcond, the
    # direction of a key the logs barely see (e.g. a damping run towards 0, where d y / d log p
    # vanishes) and give it a zero-width interval, the opposite of the truth
    cov_white = s2 * np.linalg.pinv(Hs) / np.outer(d, d)
    errs = run(theta)[0]
    # the residuals of each log and output, tested for whiteness; the sandwich covariance from
    # each log's score series (J_t^T r_t summed over its outputs), so that correlated residuals
    # widen the intervals as much as they weaken the information (docs/identify.md, "Intervals")
    # A log's score series is cut at its segments' starts: samples across a gap are not
    # neighbours, so no lagged product spans one (haa_sym.fit.diagnostics.hac_covariance)
    residuals = {e.log.name: {x: whiteness(err[:, i], opt.whiteness_lags, opt.whiteness_level)
                              for i, x in enumerate(o)} for e, o, err in zip(experiments, outs, errs)}
    scores, row = [], 0
    for e, y in zip(experiments, Y):
        rows = y.size
        v = np.einsum("tok,to->tk", J[row:row + rows].reshape(len(y), y.shape[1], len(keys)),
                      r[row:row + rows].reshape(len(y), y.shape[1]))
        scores.append(np.split(v, list(e.log.starts[1:])))
        row += rows
    cov_hac, bandwidths = hac_covariance(H, scores)
    cov = cov_hac if opt.intervals == "hac" else cov_white
    with np.errstate(over="ignore"):       # an undetermined key's interval is (0, inf): said so, not warned
        ci = _interval(theta, cov)
        ci_white = _interval(theta, cov_white)

    def rms(preds):
        return {x: float(np.sqrt(np.mean(np.concatenate([(y[:, o.index(x)] - p[:, o.index(x)]) ** 2
                                                         for y, p, o in zip(Y, preds, outs) if x in o]))))
                for x in outputs}
    traces, bode = [], []
    for e, o, u, y, p0, p1 in zip(experiments, outs, U, Y, pred0, pred):
        traces.append({"name": e.log.name, "t": e.log.t - e.log.t[0], "u": u, "measured": y,
                       "initial": p0, "fitted": p1, "outputs": o})
        if figure_data:
            bode.append(_bode(e, keys, np.exp(theta0), np.exp(theta), inputs, o, u, y, loop_options))
    meta = {**(provenance or {}), "inputs": list(inputs), "outputs": list(outputs), "method":
            "time-domain output error, Levenberg-Marquardt on log-parameters, exact Jacobian (CasADi AD, "
            "Van Loan ZOH derivative)", "iterations": [it1, it2], "converged": converged, "residual_variance": s2,
            "initial_state_values": n_initial,
            "condition_number": condition,
            "near_null_keys": near_null_keys(Hs, d, keys),
            "intervals": {"method": INTERVAL_METHODS[opt.intervals], "ci95_white": ci_white.tolist(),
                          "bandwidth": {e.log.name: b for e, b in zip(experiments, bandwidths)}},
            "residuals": residuals,
            "friction": ({"start": {f"Fc_{b}": v for b, v in _friction_of(experiments[0], friction).items()},
                          "friction_velocity": experiments[0].params.limits.friction_velocity,
                          "max_substep": sub["opt"].max_substep,
                          "max_substep_rule": ("given (--max-substep)" if opt.max_substep is not None else
                                               f"default: the longest {DEFAULT_MAX_SUBSTEP:g} s / 2^k whose "
                                               f"estimated error is within {SUBSTEP_RTOL:g}"),
                          "substep_error": sub["error"], "substep_error_at": sub.get("at"),
                          "substep_search": sub["levels"],
                          "method": "exact ZOH per substep of the log's own "
                          "intervals (the delayed command switching inside them, segments from estimated states), "
                          "friction torque implicit at each substep's end, Richardson-extrapolated over substeps h "
                          "and h / 2 (second order); d/d delay_drive the scheme's exact derivative"}
                         if use_friction else None),
            "offsets": list(offsets),
            "logs": {e.log.name: {"sha256": e.log.sha256, "samples": e.log.samples, "configuration": e.configuration}
                     for e in experiments},
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "options": {k: getattr(opt, k) for k in FitOptions.__dataclass_fields__}}
    return FitResult(keys, np.exp(theta), np.exp(theta0), ci, cov, rms(pred0), rms(pred), it1 + it2,
                     int(sum(len(y) for y in Y)), {e.log.name: e.log.sampling for e in experiments},
                     outputs, inputs, traces, bode, meta, fitted_offsets)


def _interval(theta: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """95 % intervals exp(log p +- 1.96 sd) of log-parameters ``theta`` with covariance ``cov``:
    positive and asymmetric in p."""
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return np.exp(np.column_stack([theta - Z95 * sd, theta + Z95 * sd]))


def _levenberg_marquardt(evaluate, theta, opt: FitOptions, keys, tolerance: float | None = None,
                         origin: dict | None = None):
    """Minimise |r(theta)|^2 from ``theta``: Levenberg-Marquardt (Marquardt's diagonal scaling)
    with the exact Jacobian. Returns (theta, iterations, converged): not converged when
    ``max_iterations`` ran out while the cost still fell by more than the tolerance.

    Converged, too, when a rejected step changed the cost by no more than the tolerance and the
    linear model predicted no larger decrease for it (MINPACK lmder's ``ftol`` test): a larger
    lam only shortens the step, so what the rest of the ladder (each rung a simulation) could
    still gain is below the tolerance. A step within :data:`SAME_STEP` of one already simulated
    and rejected is not simulated again (lam far below the scaled H's spectrum barely moves it).
    """
    tol = opt.tolerance if tolerance is None else tolerance
    r, J = evaluate(theta)
    cost = float(r @ r)
    norms = np.linalg.norm(J, axis=0)
    ratio = norms / max(norms.max(), 1e-300)
    # ``origin``: an empty dict on the fit's first call records the start and each key's
    # sensitivity over the largest there; the later calls (the reweighted passes) read it, so that
    # a key below DEAD_SENSITIVITY is refused with the true reason: never seen at its start, or run
    # by the earlier passes to where the logs no longer see it (it used to say "zero sensitivity")
    if origin is not None and not origin:
        origin.update(theta=theta.copy(), ratio=ratio)
    dead = [i for i, x in enumerate(ratio) if not x > DEAD_SENSITIVITY]
    if dead:
        i = dead[0]
        big = keys[int(np.argmax(norms))]
        if origin and origin["ratio"][i] > DEAD_SENSITIVITY:
            v0, v = np.exp(origin["theta"][i]), np.exp(theta[i])
            raise ParameterError(
                f"--fit {keys[i]}: the fit ran it from {v0:.4g} to {v:.4g}, where the logs no longer see it (the "
                f"outputs' sensitivity to log {keys[i]} {ratio[i]:.2g} of log {big}'s, below {DEAD_SENSITIVITY:g}; "
                f"{origin['ratio'][i]:.2g} at the start): these logs do not determine it (the logs do not excite "
                "what it sets, e.g. a stiffness whose mode lies above their band runs towards rigid); allowed: keys "
                "the logs observe (hold it at a known value, a richer input)")
        raise ParameterError(f"--fit {keys[i]}: the logged outputs do not depend on it at {np.exp(theta[i]):.4g} "
                             f"(their sensitivity to log {keys[i]} {ratio[i]:.2g} of log {big}'s, below "
                             f"{DEAD_SENSITIVITY:g}); allowed: keys the chosen --input/--output observe")
    lam = 1e-3
    it, done, improved = 0, False, True
    for it in range(1, opt.max_iterations + 1):
        H, g = J.T @ J, J.T @ r
        improved, rejected = False, None
        while lam < 1e12:
            step = np.linalg.solve(H + lam * np.diag(np.diag(H)), -g)
            big = np.max(np.abs(step))
            if big > opt.max_step:
                step *= opt.max_step / big
            if rejected is not None and np.linalg.norm(step - rejected) <= SAME_STEP * np.linalg.norm(rejected):
                lam *= 10
                continue
            r1, J1 = evaluate(theta + step)
            c1 = float(r1 @ r1)
            if np.isfinite(c1) and c1 < cost:
                theta, r, J, improved = theta + step, r1, J1, True
                done = (cost - c1) <= tol * cost or np.max(np.abs(step)) < 1e-10
                cost = c1
                lam = max(lam / 10, 1e-12)
                break
            predicted = cost - float(np.sum((r + J @ step) ** 2))
            if np.isfinite(c1) and c1 - cost <= tol * cost and predicted <= tol * cost:
                done = True
                break
            rejected = step
            lam *= 10
        if not improved or done:
            break
    # no step lowered the cost up to lam = 1e12: a minimum to rounding, converged as well
    return theta, it, bool(done or not improved)


def _bode(exp, keys, v0, v1, inputs, outputs, u, y, loop_options):
    """H1 = P_uy / P_uu (Welch) and coherence from the first input to every output, and the
    model's response before and after at the same frequencies (rad/s)."""
    # scipy.signal takes about 0.7 s to import (docs/startup.md): only a fit that draws its figure pays it
    import scipy.signal
    Ts = exp.log.Ts
    nper = int(min(len(u) // 8, 4096))
    if nper < 16:
        return None
    f, Puu = scipy.signal.welch(u[:, 0], fs=1 / Ts, nperseg=nper)
    out = {"name": exp.log.name, "omega": 2 * np.pi * f[1:], "H1": [], "coherence": [], "initial": [], "fitted": []}
    z = np.exp(1j * 2 * np.pi * f[1:] * Ts)[:, None, None]
    models = [_model(exp, keys, v, inputs, outputs, loop_options) for v in (v0, v1)]
    delays = [dict(zip(keys, v)).get("delay_drive", exp.params.drive.delay_drive) for v in (v0, v1)]
    for i in range(y.shape[1]):
        _, Puy = scipy.signal.csd(u[:, 0], y[:, i], fs=1 / Ts, nperseg=nper)
        _, coh = scipy.signal.coherence(u[:, 0], y[:, i], fs=1 / Ts, nperseg=nper)
        out["H1"].append(Puy[1:] / Puu[1:])
        out["coherence"].append(coh[1:])
        for name, m, d in zip(("initial", "fitted"), models, delays):
            if hasattr(m, "A"):          # the continuous plant with the drive's delay
                s = 1j * out["omega"][:, None, None]
                X = np.linalg.solve(s * np.eye(m.A.shape[0]) - m.A, np.broadcast_to(m.B[:, :1], (len(s),) + m.B[:, :1].shape))
                out[name].append((X[:, :, 0] @ m.C[i] + m.D[i, 0]) * np.exp(-1j * out["omega"] * d))
                continue
            X = np.linalg.solve(z * np.eye(m.Phi.shape[0]) - m.Phi, np.broadcast_to(m.Gamma[:, :1], (len(z),) + m.Gamma[:, :1].shape))
            out[name].append(X[:, :, 0] @ m.C[i] + m.D[i, 0])
    return out
