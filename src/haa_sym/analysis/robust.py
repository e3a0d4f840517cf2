"""Regions robust to the leg: stable, PM >= 30 deg (and passive) for every leg configuration.

A leg is not only "retracted" or "extended": its inertia and stiffness (HyQ: J_L2, K_L2) move
continuously between them. The leg range is given by two configurations of the actuator file
(``[configurations.<name>]``; "nominal" names the file's own values):

* ``leg_mode = "segment"`` (default): every key either end overrides is interpolated linearly
  between the two ends, all together (t from 0 to 1);
* ``leg_mode = "box"``: every such key independently over its range (the box of all pairs).

A robust region intersects the requirement over configurations spread over the range: both
ends, then the midpoints, doubling the number of intervals until the result no longer changes
(:func:`robust_region` says how many that took). Each configuration's map is decided from the
exact boundaries (:func:`haa_sym.analysis.regions.region_map`).

Parameter uncertainty (issue 17, docs/uncertainty.md): ``uncertainty = {key: (lo, hi)}`` (plain
data, e.g. the 95 % confidence intervals of an identification) adds one axis per key with
``lo < hi`` and treats the box like ``leg_mode = "box"``: every key independently over its
interval, combined with every leg configuration (the product), sampled at the same ``n``
points per axis and refined by the same doubling. A key with ``lo == hi`` is fixed at that
value. The interval replaces the parameters' own value of the key (the fit's value is inside
it, not the file's). A key the leg range sets takes its interval as a :class:`Relative` one:
factors (lo / value, hi / value) of the fit, applied to each leg configuration's own value of
the key (one more axis of factors); an absolute interval of such a key is refused (its value is
the range's). :func:`uncertainty_box` turns a fit into that mapping, by
:data:`UNCERTAINTY_ON_LEG` (docs/uncertainty.md, "Keys the leg range sets").

Example
-------
>>> from haa_sym import ClosedLoop, load_params
>>> from haa_sym.analysis.robust import robust_region
>>> r = robust_region(ClosedLoop(load_params()), [100, 1000], [5, 20])      # doctest: +SKIP
>>> r.feasible, r.n_configurations                                           # doctest: +SKIP
"""
from __future__ import annotations

from dataclasses import dataclass, field
from itertools import product
from typing import NamedTuple

import numpy as np

from haa_sym.analysis.regions import CHUNK, region_map
from haa_sym.loop import ClosedLoop, loop_first
from haa_sym.errors import ParameterError
from haa_sym.io.budget import check_memory, sweep_bytes
from haa_sym.io.tasks import TaskRunner
from haa_sym.model.params import Params, gain_array

__all__ = ["LEG_MODES", "REQUIREMENTS", "meets", "leg_ends", "leg_values", "leg_text", "leg_configurations", "feasible_map",
           "feasible_task", "RobustRegion", "robust_region", "check_uncertainty", "uncertainty_text", "Relative", "UNCERTAINTY_ON_LEG",
           "UNCERTAINTY_ON_LEG_DEFAULT", "uncertainty_box", "uncertainty_meta", "box_text"]

LEG_MODES = ("segment", "box")
# what a gain point must satisfy: closed loop stable, impedance-loop PM >= 30 deg, passive port
REQUIREMENTS = ("stable", "pm", "passive")
NOMINAL = "nominal"
# doubling the number of leg intervals up to this many configurations per axis
MAX_LEG_POINTS = 33
# What a fitted key that the leg range also sets becomes (uncertainty_box): "relative" (default)
# the fit's interval relative to its value, applied to each leg configuration's value of the key
# (an identification's relative precision carries over, the range keeps its values); "unset" the
# key's interval left out, the range's values as they are (the box on the other keys only);
# "refuse" the command refused, naming the key (the behaviour before issue 26).
UNCERTAINTY_ON_LEG = ("relative", "unset", "refuse")
UNCERTAINTY_ON_LEG_DEFAULT = "relative"


class Relative(NamedTuple):
    """An uncertainty interval of a key the leg range sets: the factors ``lo`` <= ``hi`` (> 0)
    each leg configuration's value of the key is multiplied by (a fit's ci95 over its value)."""

    lo: float
    hi: float


def uncertainty_box(params: Params, box: dict, values: dict, leg=None,
                    on_leg: str = UNCERTAINTY_ON_LEG_DEFAULT) -> tuple[dict, list[str]]:
    """The uncertainty mapping the analyses take, from a fit's ``box`` ({key: (lo, hi)}) and its
    ``values`` ({key: value}, the centres), and the keys left out: a key the leg range sets
    becomes :class:`Relative` (lo / value, hi / value) with ``on_leg = "relative"``, is left out
    with ``"unset"``, and stays absolute with ``"refuse"`` (:func:`check_uncertainty` refuses it).
    Keys the range does not set stay as they are."""
    if on_leg not in UNCERTAINTY_ON_LEG:
        raise ParameterError(f"uncertainty on the leg's keys = {on_leg!r}; allowed: {list(UNCERTAINTY_ON_LEG)}")
    leg_keys = _span(params, leg)[2]
    out, dropped = {}, []
    for k, (lo, hi) in box.items():
        if k not in leg_keys or on_leg == "refuse":
            out[k] = (lo, hi)
        elif on_leg == "unset":
            dropped.append(k)
        else:
            v = float(values[k])
            if not (np.isfinite(v) and v > 0):
                raise ParameterError(f"uncertainty {k}: fitted value {v!r}; allowed: a value > 0 to take the "
                                     "interval relative to (or --uncertainty-on-leg unset)")
            out[k] = Relative(float(lo) / v, float(hi) / v)
    return out, dropped


def uncertainty_meta(box: dict) -> dict:
    """A checked uncertainty mapping as plain data: {key: [lo, hi]}, or for a :class:`Relative`
    interval {key: {"relative": [lo, hi]}} (factors of each leg configuration's value)."""
    return {k: {"relative": [v.lo, v.hi]} if isinstance(v, Relative) else list(v) for k, v in box.items()}


def box_text(box: dict) -> str:
    """``R 2.3..4.3, J_L2 x 0.98..1.02 of each configuration's value``: a box for people."""
    return ", ".join(f"{k} x {v.lo:.5g}..{v.hi:.5g} of each configuration's value" if isinstance(v, Relative)
                     else f"{k} {v[0]:.6g}..{v[1]:.6g}" for k, v in box.items())


def leg_ends(params: Params, leg: tuple[str, str] | None = None) -> tuple[str, str]:
    """The two configurations bounding the leg range: ``leg`` (names from the file's
    [configurations], or "nominal"); by default "retracted" and "extended" when the file has
    both, else its first two configurations, else "nominal" and its only one."""
    names = list(params.configurations)
    if leg is None:
        if {"retracted", "extended"} <= set(names):
            leg = ("retracted", "extended")
        elif len(names) >= 2:
            leg = (names[0], names[1])
        elif len(names) == 1:
            leg = (NOMINAL, names[0])
        else:
            raise ParameterError(f"{params.source}: no [configurations] to span a leg range; allowed: "
                                 "a file with at least one configuration, or the leg range given as FROM:TO")
    leg = tuple(leg)
    allowed = [NOMINAL] + names
    if len(leg) != 2 or leg[0] == leg[1] or any(n not in allowed for n in leg):
        raise ParameterError(f"leg = {':'.join(map(str, leg))!r}; allowed: two different names of "
                             f"{allowed} (FROM:TO)")
    return leg


def _end_values(params: Params, name: str) -> dict:
    return {} if name == NOMINAL else dict(params.configurations[name])


def _span(params: Params, leg=None):
    """``(a, b, keys, own, lo, hi)``: the two ends' names, the plant keys either end sets, the
    parameters' own values of those keys, and their values at each end (a key one end leaves
    unset keeps the parameters' own value there)."""
    a, b = leg_ends(params, leg)
    va, vb = _end_values(params, a), _end_values(params, b)
    keys = sorted(set(va) | set(vb))
    own = {k: float(getattr(params.plant, k)) for k in keys}
    lo = {k: float(va.get(k, own[k])) for k in keys}
    hi = {k: float(vb.get(k, own[k])) for k in keys}
    return a, b, keys, own, lo, hi


def leg_values(params: Params, leg=None, leg_mode: str = "segment", uncertainty=None) -> dict:
    """What a leg range analyses, as plain data (``meta["leg_values"]``, messages, plot titles).

    The configurations of the range replace the parameters' own values of the keys they set: a
    value edited in the file's body tables or by ``--set`` is not analysed unless it is one of
    the ends (or "nominal" is). This says so.

    Returns
    -------
    dict
        ``leg`` (the two end names), ``leg_mode``, ``ends`` (end name -> {key: value}, SI units),
        ``own`` ({key: the parameters' own value}, which the range replaces) and ``outside``
        ({key: own value} of the keys whose own value lies outside the interval the ends span;
        empty when every own value is analysed or lies between the ends, key by key); with
        ``uncertainty`` also ``uncertainty`` ({key: [lo, hi]}, SI units, the box analysed) and
        ``uncertainty_own`` ({key: the parameters' own value}, which the box replaces).
    """
    a, b, keys, own, lo, hi = _span(params, leg)
    outside = {k: own[k] for k in keys if not min(lo[k], hi[k]) <= own[k] <= max(lo[k], hi[k])}
    out = {"leg": [a, b], "leg_mode": leg_mode, "ends": {a: lo, b: hi}, "own": own, "outside": outside}
    if uncertainty:
        box = check_uncertainty(params, uncertainty, leg)
        out["uncertainty"] = uncertainty_meta(box)
        out["uncertainty_own"] = {k: float(getattr(params.plant, k)) for k in box if not isinstance(box[k], Relative)}
    return out


def check_uncertainty(params: Params, uncertainty, leg=None) -> dict:
    """``uncertainty`` ({key: (lo, hi)}, SI units) checked against ``params``: keys of the
    actuator's plant that the leg range does not set, finite ``lo <= hi``, both ends allowed
    values of the key; a key the range sets only as :class:`Relative` factors (0 < lo <= hi,
    allowed values at both ends of the range). Returns {key: (lo, hi) as floats, or Relative},
    keys sorted; one-line ParameterError naming the key otherwise."""
    if not isinstance(uncertainty, dict) or not uncertainty:
        raise ParameterError(f"uncertainty = {uncertainty!r}; allowed: a non-empty mapping {{key: (lo, hi)}} of "
                             "plant keys")
    keys = list(params.plant.topology.parameter_keys)
    a, b, leg_keys, _, lo_end, hi_end = _span(params, leg)
    box = {}
    for k in sorted(uncertainty):
        if k not in keys:
            raise ParameterError(f"uncertainty key {k!r} is not a plant key of {params.source}; allowed: {keys}")
        relative = isinstance(uncertainty[k], Relative)
        if k in leg_keys and not relative:
            raise ParameterError(f"uncertainty key {k!r} is set by the leg range {a}..{b}, which gives its values; "
                                 f"allowed: keys the range does not set, {[x for x in keys if x not in leg_keys]}, "
                                 "or the interval relative to each configuration's value (--uncertainty-on-leg "
                                 "relative, docs/uncertainty.md)")
        if relative and k not in leg_keys:
            raise ParameterError(f"uncertainty {k} = {uncertainty[k]!r}: a relative interval applies to a key the "
                                 f"leg range {a}..{b} sets, {leg_keys}; allowed: (lo, hi) in the key's unit")
        if relative:
            f_lo, f_hi = (float(x) for x in uncertainty[k])
            if not (np.isfinite(f_lo) and np.isfinite(f_hi) and 0 < f_lo <= f_hi):
                raise ParameterError(f"uncertainty {k} = x ({f_lo:g}, {f_hi:g}) of each configuration's value; "
                                     "allowed: finite factors 0 < lo <= hi")
            for end in (lo_end[k], hi_end[k]):
                for f in (f_lo, f_hi):
                    try:
                        params.with_values(**{k: end * f})
                    except ParameterError as exc:
                        raise ParameterError(f"uncertainty {k} = x ({f_lo:g}, {f_hi:g}) of the leg's {end:g}: "
                                             f"{exc}") from None
            box[k] = Relative(f_lo, f_hi)
            continue
        try:
            lo, hi = (float(v) for v in uncertainty[k])
        except (TypeError, ValueError):
            raise ParameterError(f"uncertainty {k} = {uncertainty[k]!r}; allowed: two numbers (lo, hi)") from None
        if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
            raise ParameterError(f"uncertainty {k} = ({lo:g}, {hi:g}); allowed: finite lo <= hi")
        for v in (lo, hi):
            try:
                params.with_values(**{k: v})
            except ParameterError as exc:
                raise ParameterError(f"uncertainty {k} = ({lo:g}, {hi:g}): {exc}") from None
        box[k] = (lo, hi)
    return box


def uncertainty_text(params: Params, values: dict | None, box: dict) -> tuple[str, str | None]:
    """One line saying which box the uncertainty analyses, and a warning line (or None) when
    the parameters' own value of a key differs from the fit's value ``values`` ({key: value},
    the centre the box was estimated around; None: not known)."""
    absolute = {k: v for k, v in box.items() if not isinstance(v, Relative)}
    line = "uncertainty box " + box_text(box) + \
        ("; it replaces the parameters' own " + _values_text({k: float(getattr(params.plant, k)) for k in absolute})
         if absolute else "")
    differ = {k: (float(getattr(params.plant, k)), float(v)) for k, v in (values or {}).items()
              if k in absolute and not np.isclose(float(getattr(params.plant, k)), float(v), rtol=1e-9, atol=0.0)}
    if not differ:
        return line, None
    what = ", ".join(f"{k} = {own:.6g} (the fit's {fit:.6g})" for k, (own, fit) in differ.items())
    return line, (f"the parameters' own {what} differ from the fit's values; the box analysed is the fit's "
                  "interval around the fit's value, so the file's value is not its centre (use the fitted "
                  "file, or --set the fit's value, to make them agree)")


def _values_text(values: dict) -> str:
    return ", ".join(f"{k} = {v:.6g}" for k, v in values.items())


def leg_text(lv: dict) -> tuple[str, str | None]:
    """One line saying which configurations and values a leg range analyses, and a warning line
    (or None) when the parameters' own values lie outside it."""
    (a, va), (b, vb) = lv["ends"].items()
    line = (f"leg range {a} ({_values_text(va)}) .. {b} ({_values_text(vb)}), {lv['leg_mode']}; it replaces "
            f"the parameters' own {_values_text(lv['own'])}")
    if not lv["outside"]:
        return line, None
    spans = ", ".join(f"{k} = {v:.6g} (range {min(va[k], vb[k]):.6g}..{max(va[k], vb[k]):.6g})"
                      for k, v in lv["outside"].items())
    return line, (f"the parameters' own {spans} lie outside the leg range analysed, so they are not "
                  f"analysed; to include them, give the range with --leg (\"nominal\" names the "
                  f"parameters' own values, e.g. --leg nominal:{b}) or edit [configurations]")


def leg_configurations(params: Params, n: int, *, leg=None, leg_mode: str = "segment",
                       uncertainty=None) -> list[dict]:
    """Plant overrides of the leg configurations: ``n`` points per axis, evenly spaced from one
    end to the other (``n`` = 2: the ends). "segment": one axis, every differing key
    interpolated together; "box": one axis per key, the product (n^keys configurations).
    ``uncertainty`` ({key: (lo, hi)}, :func:`check_uncertainty`): one more axis per key with
    lo < hi, ``n`` points from lo to hi, the product with the leg's configurations."""
    if leg_mode not in LEG_MODES:
        raise ParameterError(f"leg_mode = {leg_mode!r}; allowed: {list(LEG_MODES)}")
    a, b, keys, base, lo, hi = _span(params, leg)
    keys = [k for k in keys if lo[k] != hi[k]]
    if not keys:
        raise ParameterError(f"leg = {a}:{b}: the two configurations do not differ; allowed: two "
                             "configurations with different plant values")
    t = np.linspace(0.0, 1.0, n)
    if leg_mode == "segment":
        configs = [{k: lo[k] + s * (hi[k] - lo[k]) for k in keys} for s in t]
    else:
        configs = [{k: lo[k] + s * (hi[k] - lo[k]) for k, s in zip(keys, ss)} for ss in product(t, repeat=len(keys))]
    if not uncertainty:
        return configs
    box = check_uncertainty(params, uncertainty, leg)
    # the same formula as the leg's axes: the ends are exactly lo and hi (factors for a Relative
    # key, times the configuration's value of the key: the range's, constant if it does not vary)
    axes = [[(k, u0 + s * (u1 - u0)) for s in (t if u0 < u1 else t[:1])] for k, (u0, u1) in box.items()]
    relative = [k for k, v in box.items() if isinstance(v, Relative)]
    out = []
    for c in configs:
        for vals in product(*axes):
            v = dict(vals)
            out.append({**c, **v, **{k: c.get(k, lo[k]) * v[k] for k in relative}})
    return out


def _check_requirements(requirements) -> tuple[str, ...]:
    req = tuple(requirements)
    bad = [r for r in req if r not in REQUIREMENTS]
    if bad or "stable" not in req:
        raise ParameterError(f"requirements = {list(req)}; allowed: 'stable' and any of "
                             f"{list(REQUIREMENTS[1:])}")
    return req


@loop_first
def feasible_map(loop, P_gain, D_gain, beta: float, alpha: float, *,
                 requirements=("stable", "pm")) -> np.ndarray:
    """``(n_P, n_D)`` bool: the requirements hold at every grid point of ``loop`` (one
    configuration), decided from the exact boundaries."""
    req = _check_requirements(requirements)
    m = region_map(loop, P_gain, D_gain, beta=beta, alpha=alpha, passivity="passive" in req, progress=False,
                   blas_threads=None)
    return meets(m, req)


def feasible_task(params, config, P, D, beta, alpha, requirements, options, backend: str = "auto") -> np.ndarray:
    """:func:`feasible_map` of the loop of ``params`` with the plant overrides ``config``: a task
    of plain data (what a dask worker runs; :mod:`haa_sym.io.tasks`). The worker builds the loop
    itself: its compiled library and sampled plants are memoised per process
    (:mod:`haa_sym.compiled.cache`), so a worker's later tasks of the same configuration reuse them."""
    return feasible_map(ClosedLoop(params.with_values(**config), options, backend), P, D, beta, alpha,
                        requirements=requirements)


def meets(decisions, requirements) -> np.ndarray:
    """Where ``decisions`` (anything with ``stable``, ``low_pm``, ``passive``: a region map or
    point decisions) meet ``requirements``: stable, and PM >= 30 deg and passive if required."""
    ok = decisions.stable.copy()
    if "pm" in requirements:
        ok &= ~decisions.low_pm
    if "passive" in requirements:
        ok &= decisions.passive
    return ok


@dataclass(frozen=True)
class RobustRegion:
    """``feasible`` (n_P, n_D): the requirements hold for every leg configuration checked;
    ``n_configurations`` checked (per axis ``n_per_axis``); ``converged``: the result did not
    change when the number of leg intervals last doubled; ``history``: (configurations,
    feasible points) at every doubling."""

    P_gain: np.ndarray
    D_gain: np.ndarray
    feasible: np.ndarray
    n_configurations: int
    n_per_axis: int
    converged: bool
    history: list
    configurations: list = field(repr=False)
    meta: dict = field(default_factory=dict)


def _doubling(n: int) -> int:
    return 2 * n - 1


@loop_first
def robust_region(loop, P_gain, D_gain, *, beta: float | None = None, alpha: float | None = None,
                  requirements=("stable", "pm"), leg=None, leg_mode: str = "segment",
                  uncertainty=None, max_per_axis: int = MAX_LEG_POINTS, scheduler=None,
                  progress: bool | None = False) -> RobustRegion:
    """The gains meeting ``requirements`` for every leg configuration of the range.

    Parameters
    ----------
    loop : ClosedLoop
        The loop whose parameters give the leg range (their configurations) and whose options
        judge every configuration.
    P_gain, D_gain : array_like
        The grid (Nm/rad, Nms/rad).
    beta, alpha : float, optional
        Inner gains (default the controller's).
    requirements : sequence of {"stable", "pm", "passive"}
        "stable" always; "pm": impedance-loop phase margin >= 30 deg; "passive": the port.
    leg : (str, str), optional
        The two configurations bounding the range (see :func:`leg_ends`).
    leg_mode : {"segment", "box"}
    uncertainty : dict, optional
        ``{key: (lo, hi)}``, plant keys in SI units (e.g. an identification's 95 % confidence
        intervals), or :class:`Relative` factors for a key the leg range sets
        (:func:`uncertainty_box`): the gains must meet the requirements for every value in the
        box too (module docstring; :func:`check_uncertainty` says what is allowed).
    max_per_axis : int
        Stop doubling at this many configurations per axis (``converged`` says whether the
        last doubling changed nothing).
    scheduler : None, str or distributed.Client
        Where the configurations' maps run, one task each (:func:`feasible_task`): None (default)
        in this process, one after the other (each map runs its own chunks on two threads);
        ``"local:N"`` a local cluster of N worker processes (:func:`haa_sym.io.tasks.cluster`);
        an address or a Client: that dask.distributed cluster. The result is the same, byte for byte.
    progress : bool or None
        The progress bar of the maps' tasks (:func:`haa_sym.io.progress.progress`); default off.

    Returns
    -------
    RobustRegion
    """
    P = gain_array("P_gain", P_gain).ravel()
    D = gain_array("D_gain", D_gain).ravel()
    params = loop.params
    _, _, beta, alpha = loop.gain_points(0.0, 0.0, beta, alpha)
    req = _check_requirements(requirements)
    maps: dict = {}
    n_omega = loop.options.numerics.n_omega

    def check(n_maps: int) -> None:
        # one region map at a time, plus the kept (n_P, n_D) bool maps and the running result
        check_memory(sweep_bytes(P.size * D.size, n_omega, CHUNK) + P.size * D.size * (n_maps + 1),
                     f"a robust region of {P.size} x {D.size} (P_gain x D_gain) points over {n_maps} leg "
                     f"configurations on n_omega = {n_omega} frequencies")

    def region(configs):
        keys = [tuple(sorted(c.items())) for c in configs]
        check(len(set(maps) | set(keys)))
        # the configurations not mapped yet, one task each (the doubling keeps the others' maps)
        todo = list({k: c for k, c in zip(keys, configs) if k not in maps}.items())
        res = runner.run(feasible_task, [(params, c, P, D, beta, alpha, req, loop.options, loop.backend)
                                         for _, c in todo], "regions --robust: leg configurations", "map")
        maps.update((k, np.asarray(r, bool)) for (k, _), r in zip(todo, res))
        out = np.ones((P.size, D.size), bool)
        for k in keys:
            out &= maps[k]
        return out

    # in-process: one map at a time (threads=1), each map running its chunks on two threads as
    # before; on a cluster, one map per worker
    runner = TaskRunner(scheduler, progress, threads=1)
    try:
        n = 2
        configs = leg_configurations(params, n, leg=leg, leg_mode=leg_mode, uncertainty=uncertainty)
        current = region(configs)
        history = [(len(configs), int(current.sum()))]
        converged = False
        while _doubling(n) <= max_per_axis:
            n2 = _doubling(n)
            configs2 = leg_configurations(params, n2, leg=leg, leg_mode=leg_mode, uncertainty=uncertainty)
            nxt = region(configs2)
            history.append((len(configs2), int(nxt.sum())))
            same = np.array_equal(nxt, current)
            n, configs, current = n2, configs2, nxt
            if same:
                converged = True
                break
    finally:
        runner.close()
    extra = {"uncertainty": uncertainty_meta(check_uncertainty(params, uncertainty, leg))} if uncertainty else {}
    return RobustRegion(P, D, current, len(configs), n, converged, history, configs,
                        loop.provenance(leg=list(leg_ends(params, leg)), leg_mode=leg_mode,
                                        leg_values=leg_values(params, leg, leg_mode, uncertainty),
                                        requirements=list(req), beta=beta, alpha=alpha, **extra))
