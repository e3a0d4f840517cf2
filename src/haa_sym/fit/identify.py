"""Identification of an actuator's parameters from logged experiments (``haa-sym identify``).

Time-domain output error: the sampled model (:mod:`haa_sym.fit.model`), driven from rest by a
log's inputs, predicts its outputs; the fitted keys minimise the sum over logs and outputs of the
squared prediction errors, each output of each log weighted by 1 / sigma (its noise level,
estimated from its own residuals; a first pass weights by the signal's standard deviation).
The parameters are fitted as logarithms (positive by construction, the only bound the keys'
domains impose: ``>0`` or ``>=0``, fitted from a positive start) by Levenberg-Marquardt with the
exact Jacobian (sensitivities of the simulation, derivatives from CasADi), so a few iterations
suffice. Confidence intervals are Gauss-Newton's: cov(log p) = s^2 (J^T J)^-1 with s^2 the
weighted residual variance; 95 % intervals are log p +- 1.96 sd, so they are asymmetric and
positive. They assume white, Gaussian output noise, a correct model and an input known exactly;
coloured residuals (a model error) make them too narrow (docs/identify.md).
"""
from __future__ import annotations

import datetime
from dataclasses import dataclass, field

import numpy as np

from haa_sym.analysis.sweep import blas_limits
from haa_sym.errors import ParameterError
from haa_sym.fit.closed import torque_loop_model
from haa_sym.fit.friction import friction_entries, is_friction_key, simulate_friction
from haa_sym.fit.model import open_loop_model, sample, simulate
from haa_sym.io.budget import check_memory, fit_bytes
from haa_sym.io.logs import OUTPUTS, Log

__all__ = ["FitOptions", "FitResult", "Experiment", "identify", "INPUT_MODES"]

INPUT_MODES = ("voltage", "current", "torque_ref")
Z95 = 1.959963984540054          # the two-sided 95 % point of the normal distribution


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
    max_substep : float
        Longest substep (s) of the friction simulation (:mod:`haa_sym.fit.friction`), used when
        friction is in the model (default 2.5e-4 s; docs/identify.md, "Friction and offsets").
    """

    min_periods: float = 3.0
    max_substep: float = 2.5e-4
    max_iterations: int = 50
    tolerance: float = 1e-10
    max_step: float = 1.0
    first_pass_tolerance: float = 1e-3
    reweight_rtol: float = 0.05
    max_reweights: int = 5


@dataclass(frozen=True)
class Experiment:
    """One log and the parameters (file, configuration, --set) it was taken with."""

    log: Log
    params: object
    configuration: str | None = None


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
        """The ``fit.json`` of the issue: parameters, rms_error, samples, sampling, meta."""
        return {"parameters": {k: {"value": float(v), "initial": float(v0), "ci95": [float(lo), float(hi)]}
                               for k, v, v0, (lo, hi) in zip(self.keys, self.value, self.initial, self.ci95)},
                "rms_error": {o: {"initial": self.rms_initial[o], "fitted": self.rms_fitted[o]} for o in self.outputs},
                "samples": self.samples, "sampling": self.sampling, "meta": self.meta,
                **({"offsets": self.offsets} if self.offsets else {})}


def _model(exp: Experiment, keys, values, inputs, outputs, options=None):
    """The sampled model of ``exp`` with ``keys`` at ``values`` (the linear model: friction keys
    left out)."""
    keys, values = _plant_part(keys, values)
    params = exp.params.with_values(**dict(zip(keys, values)))
    if inputs[0] == "torque_ref":
        return torque_loop_model(params, keys, inputs, outputs, options)
    return sample(open_loop_model(params.plant, keys, inputs, outputs), exp.log.Ts)


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


def _friction_run(exp: Experiment, keys, values, inputs, outputs, friction, u, sens, max_substep):
    """Outputs and sensitivities of ``exp`` with Coulomb friction (:mod:`haa_sym.fit.friction`)
    on the log's own intervals (``log.dt`` when the log carries them, else its uniform period)."""
    vals = dict(zip(keys, values))
    pk, pv = _plant_part(keys, values)
    params = exp.params.with_values(**dict(zip(pk, pv)))
    model = open_loop_model(params.plant, pk, inputs, outputs)
    fmap = _friction_of(exp, friction)
    fmap.update({k[3:]: vals[k] for k in keys if is_friction_key(k)})
    fr = friction_entries(params.plant, keys, inputs, model.A.shape[0], fmap, params.limits.friction_velocity)
    # the Fc keys' rows of dA ... dD are zero (they act in the recursion only)
    idx = [pk.index(k) if k in pk else None for k in keys]

    def full(d):
        return np.stack([d[i] if i is not None else np.zeros(d.shape[1:]) for i in idx]) if keys else d
    model = type(model)(model.A, model.B, model.C, model.D, full(model.dA), full(model.dB), full(model.dC),
                        full(model.dD))
    dt = getattr(exp.log, "dt", None)
    dt = np.full(len(u) - 1, exp.log.Ts) if dt is None else np.asarray(dt, float)
    return simulate_friction(model, fr, dt, u, sensitivities=sens, max_substep=max_substep)


def _check_keys(exps, keys, inputs, friction=None):
    if not keys:
        raise ParameterError("--fit: no keys; allowed: one or more parameter keys, comma separated")
    top = exps[0].params.plant.topology
    dup = sorted({k for k in keys if keys.count(k) > 1})
    if dup:
        raise ParameterError(f"--fit {','.join(keys)}: {dup} given twice; allowed: each key once")
    for k in keys:
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
                                 f"{list(top.parameter_keys)}")
        for e in exps:
            v = getattr(e.params.plant, k)
            if not v > 0:
                raise ParameterError(f"--fit {k}: initial value {v!r} (domain {top.domain[k]}); allowed: a "
                                     f"positive start (fitted as log {k}; --set {k}=VALUE)")
        if inputs[0] == "current" and k in ("L", "R", "k_w"):
            raise ParameterError(f"--fit {k}: with --input current the drive imposes the current, so {k} "
                                 "does not act on the outputs; allowed: mechanical keys")
        confs = {e.configuration for e in exps if e.configuration and
                 k in e.params.configurations.get(e.configuration, {})}
        if confs:
            raise ParameterError(f"--fit {k}: configuration {sorted(confs)[0]} sets it (the fitted file's entry "
                                 "would not be the value the log was fitted with); allowed: keys the configurations "
                                 "leave alone")


def _slow_period(model) -> float:
    """2 pi / |s| of the slowest oscillatory mode (else the slowest nonzero real one), s =
    log(z) / Ts from the sampled model's eigenvalues z (open or closed loop alike)."""
    lam = np.log(np.linalg.eigvals(model.Phi).astype(complex)) / model.Ts
    mag = np.abs(lam)
    osc = mag[(np.abs(lam.imag) > 1e-9 * np.maximum(mag, 1e-300))]
    use = osc if osc.size else mag[mag > 1e-9 * max(1.0, mag.max())]
    return float(2 * np.pi / use.min()) if use.size else 0.0


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
    _check_keys(experiments, keys, inputs, friction)
    offsets = tuple(offsets)
    if any(o not in outputs for o in offsets) or len(set(offsets)) != len(offsets):
        raise ParameterError(f"--offsets {','.join(offsets)}; allowed: distinct names of --output {list(outputs)}")
    theta0 = np.log([_friction_of(experiments[0], friction)[k[3:]] if is_friction_key(k)
                     else getattr(experiments[0].params.plant, k) for k in keys])
    use_friction = any(is_friction_key(k) for k in keys) or any(
        v > 0 for e in experiments for v in _friction_of(e, friction).values())
    if use_friction and inputs[0] == "torque_ref":
        raise ParameterError("[limits] friction with --input torque_ref is not modelled; allowed: --input voltage or "
                             "current (or a file without friction)")
    off_cols = [outputs.index(o) for o in offsets]
    with blas_limits(1):          # small matrices, long signals: BLAS threads only contend
        models0 = [_model(e, keys, np.exp(theta0), inputs, outputs, loop_options) for e in experiments]
        for e, m in zip(experiments, models0):
            if inputs[0] == "torque_ref" and abs(e.log.Ts - m.Ts) > 1e-6 * m.Ts:
                raise ParameterError(f"--log {e.log.name!r}: mean period {e.log.Ts:.6g} s; allowed: the torque "
                                     f"loop's Ts = {m.Ts:g} s with --input torque_ref (the controller runs at Ts)")
            slow = _slow_period(m)
            if e.log.duration < opt.min_periods * slow:
                raise ParameterError(f"--log {e.log.name!r}: {e.log.duration:.3g} s long, {opt.min_periods:g} periods "
                                     f"of the model's slowest mode are {opt.min_periods * slow:.3g} s; allowed: a "
                                     "longer log")
        # before the fit allocates its trajectories and sensitivities (a 10 M-row log reached
        # 9.9 GB and died): refused in one line when over the memory budget
        check_memory(sum(fit_bytes(e.log.samples, m.Phi.shape[0], len(outputs), len(keys))
                         for e, m in zip(experiments, models0)), f"fitting {len(keys)} key(s) to "
                     f"{sum(e.log.samples for e in experiments)} samples")
        U = [np.column_stack([e.log.signals[i] for i in inputs]) for e in experiments]
        Y = [np.column_stack([e.log.signals[o] for o in outputs]) for e in experiments]
        sigma = [np.maximum(np.std(y, axis=0), 1e-300) for y in Y]

        cache: dict = {}
        offset_of: dict = {}          # the offsets each cached point's simulation found, per log

        def run(theta, sens=True):
            """Unweighted errors y - y_model and, with ``sens``, d y_model / d log p, per log; a
            point's simulation is kept so that reweighting and the reports re-run nothing."""
            key = theta.tobytes()
            if key not in cache or (sens and cache[key][1] is None):
                errs, sens_, offs = [], [], {}
                for e, u, y in zip(experiments, U, Y):
                    if use_friction:
                        yp, dy = _friction_run(e, keys, np.exp(theta), inputs, outputs, friction, u, sens,
                                               opt.max_substep)
                    else:
                        m = _model(e, keys, np.exp(theta), inputs, outputs, loop_options)
                        yp, dy = simulate(m, u, sens)
                    if off_cols:
                        # variable projection of the offsets: the model plus the mean error
                        yp = yp.copy()
                        off = np.mean(y[:, off_cols] - yp[:, off_cols], axis=0)
                        yp[:, off_cols] += off
                        offs[e.log.name] = {o: float(v) for o, v in zip(offsets, off)}
                        if dy is not None:
                            dy = dy.copy()
                            dy[:, :, off_cols] -= np.mean(dy[:, :, off_cols], axis=1, keepdims=True)
                    errs.append(y - yp)
                    sens_.append(None if dy is None else dy * np.exp(theta)[:, None, None])
                cache.clear() if len(cache) > 8 else None
                cache[key] = (errs, sens_ if sens else None)
                offset_of[key] = offs
            return cache[key]

        def evaluate(theta, sens=True):
            errs, dys = run(theta, sens)
            r = np.concatenate([(err / s).ravel() for err, s in zip(errs, sigma)])
            if not sens:
                return r, None
            return r, np.vstack([(-dy / s).reshape(len(keys), -1).T for dy, s in zip(dys, sigma)])

        # the first pass only finds the neighbourhood (its weights are provisional); the second,
        # with the noise levels of the residuals as weights, converges
        theta, it1, _ = _levenberg_marquardt(evaluate, theta0, opt, keys, tolerance=opt.first_pass_tolerance)
        it2, scale = 0, sigma
        for n_pass in range(max(opt.max_reweights, 1)):
            new = [np.maximum(np.sqrt(np.mean(err ** 2, axis=0)), 1e-12 * s) for err, s in zip(run(theta)[0], scale)]
            if n_pass and all(np.all(np.abs(a / b - 1) <= opt.reweight_rtol) for a, b in zip(new, sigma)):
                break
            sigma = new          # evaluate() reads sigma when called: the new weights apply
            theta, it, converged = _levenberg_marquardt(evaluate, theta, opt, keys)
            it2 += it
        r, J = evaluate(theta)
        pred = [y - err for y, err in zip(Y, run(theta)[0])]
        fitted_offsets = offset_of.get(theta.tobytes(), {})
        pred0 = [y - err for y, err in zip(Y, run(theta0, False)[0])]
    dof = max(r.size - len(keys), 1)
    s2 = float(r @ r) / dof
    # the scaled normal matrix's condition: keys the logs cannot tell apart make it huge (and the
    # intervals meaningless); reported in meta, warned about by the CLI
    H = J.T @ J
    d = np.sqrt(np.maximum(np.diag(H), 1e-300))
    Hs = H / np.outer(d, d)
    condition = float(np.linalg.cond(Hs))
    # inverted in the scaled coordinates: pinv(H) itself would drop, as below its rcond, the
    # direction of a key the logs barely see (e.g. a damping run towards 0, where d y / d log p
    # vanishes) and give it a zero-width interval, the opposite of the truth
    cov = s2 * np.linalg.pinv(Hs) / np.outer(d, d)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(over="ignore"):       # an undetermined key's interval is (0, inf): said so, not warned
        ci = np.exp(np.column_stack([theta - Z95 * sd, theta + Z95 * sd]))

    def rms(preds):
        return {o: float(np.sqrt(np.mean(np.concatenate([(y[:, i] - p[:, i]) ** 2 for y, p in zip(Y, preds)]))))
                for i, o in enumerate(outputs)}
    traces, bode = [], []
    for e, u, y, p0, p1 in zip(experiments, U, Y, pred0, pred):
        traces.append({"name": e.log.name, "t": np.arange(len(y)) * e.log.Ts, "u": u, "measured": y,
                       "initial": p0, "fitted": p1})
        if figure_data:
            bode.append(_bode(e, keys, np.exp(theta0), np.exp(theta), inputs, outputs, u, y, loop_options))
    meta = {**(provenance or {}), "inputs": list(inputs), "outputs": list(outputs), "method":
            "time-domain output error, Levenberg-Marquardt on log-parameters, exact Jacobian (CasADi AD, "
            "Van Loan ZOH derivative)", "iterations": [it1, it2], "converged": converged, "residual_variance": s2,
            "condition_number": condition,
            "friction": ({"start": {f"Fc_{b}": v for b, v in _friction_of(experiments[0], friction).items()},
                          "friction_velocity": experiments[0].params.limits.friction_velocity,
                          "max_substep": opt.max_substep, "method": "exact ZOH per interval, friction torque "
                          "implicit at each substep's end"} if use_friction else None),
            "logs": {e.log.name: {"sha256": e.log.sha256, "samples": e.log.samples, "configuration": e.configuration}
                     for e in experiments},
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "options": {k: getattr(opt, k) for k in FitOptions.__dataclass_fields__}}
    return FitResult(keys, np.exp(theta), np.exp(theta0), ci, cov, rms(pred0), rms(pred), it1 + it2,
                     int(sum(len(y) for y in Y)), {e.log.name: e.log.sampling for e in experiments},
                     outputs, inputs, traces, bode, meta, fitted_offsets)


def _levenberg_marquardt(evaluate, theta, opt: FitOptions, keys, tolerance: float | None = None):
    """Minimise |r(theta)|^2 from ``theta``: Levenberg-Marquardt (Marquardt's diagonal scaling)
    with the exact Jacobian. Returns (theta, iterations, converged): not converged when
    ``max_iterations`` ran out while the cost still fell by more than the tolerance."""
    r, J = evaluate(theta)
    cost = float(r @ r)
    norms = np.linalg.norm(J, axis=0)
    dead = [k for k, nrm in zip(keys, norms) if not nrm > 1e-12 * max(norms.max(), 1e-300)]
    if dead:
        raise ParameterError(f"--fit {dead[0]}: the logged outputs do not depend on it (zero sensitivity); "
                             "allowed: keys the chosen --input/--output observe")
    lam = 1e-3
    it, done, improved = 0, False, True
    for it in range(1, opt.max_iterations + 1):
        H, g = J.T @ J, J.T @ r
        improved = False
        while lam < 1e12:
            step = np.linalg.solve(H + lam * np.diag(np.diag(H)), -g)
            big = np.max(np.abs(step))
            if big > opt.max_step:
                step *= opt.max_step / big
            r1, J1 = evaluate(theta + step)
            c1 = float(r1 @ r1)
            if np.isfinite(c1) and c1 < cost:
                theta, r, J, improved = theta + step, r1, J1, True
                done = (cost - c1) <= (opt.tolerance if tolerance is None else tolerance) * cost \
                    or np.max(np.abs(step)) < 1e-10
                cost = c1
                lam = max(lam / 10, 1e-12)
                break
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
    for i in range(y.shape[1]):
        _, Puy = scipy.signal.csd(u[:, 0], y[:, i], fs=1 / Ts, nperseg=nper)
        _, coh = scipy.signal.coherence(u[:, 0], y[:, i], fs=1 / Ts, nperseg=nper)
        out["H1"].append(Puy[1:] / Puu[1:])
        out["coherence"].append(coh[1:])
        for name, m in zip(("initial", "fitted"), models):
            X = np.linalg.solve(z * np.eye(m.Phi.shape[0]) - m.Phi, np.broadcast_to(m.Gamma[:, :1], (len(z),) + m.Gamma[:, :1].shape))
            out[name].append(X[:, :, 0] @ m.C[i] + m.D[i, 0])
    return out
