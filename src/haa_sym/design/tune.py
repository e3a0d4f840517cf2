"""Tuning the torque PI (Sec. 3.2): the widest torque bandwidth that keeps the paper's margins.

The torque PI of Eq. (7), ``P_t = beta P_t0`` and ``I_t = beta I_t0`` (backward Euler,
C(z) = P_t + I_t Ts z / (z - 1)), is chosen to maximise the torque-loop bandwidth subject to the
design targets of Sec. 3.2, with the impedance loop open (P_gain = D_gain = 0), at every
configuration of the actuator file and at its nominal values:

* the torque loop (opened at the PI output, :func:`haa_sym.analysis.torque.torque_loop_margins`,
  crossovers located exactly) has a phase margin of at least ``pm_deg`` (default 30 deg) at every
  gain crossover (min |PM|, the ``distance`` rule of :mod:`haa_sym.analysis.margins`);
* its gain margin is at least ``gm_db`` (default 12 dB) at every phase crossover, in both
  directions: min |GM| >= gm_db, so that any loop gain factor in [10^(-gm/20), 10^(gm/20)] keeps
  the loop stable (a negative GM, where |L| > 1 at arg L = -180 deg, is a margin against a gain
  *reduction* and counts by its size);
* the loop alone is stable (Routh-Hurwitz on the exact characteristic polynomial,
  :meth:`haa_sym.ClosedLoop.stability`; a pole at z = 1 of a link without stiffness to ground,
  which the torque does not see, is allowed, as in :func:`haa_sym.analysis.torque.torque_bandwidth_map`),
  and, as the paper also required, stable for every velocity-compensation gain alpha in
  ``stable_alpha`` (default 0 to 1, sampled at 11 values; margins are not required there);
* the bandwidth (:func:`haa_sym.analysis.torque.torque_bandwidth`, by ``bandwidth``: the
  tracking error's -3 dB point by default, the paper's -3 dB of |T / T_ref| as an option)
  exists below Nyquist;
* optionally (``passive_at``, default none: Sec. 3.2 has no such target) the port impedance Z is
  passive (:func:`haa_sym.analysis.passivity.passivity`: stable, corrected phase within +-90 deg)
  at the given impedance gains (P_gain, D_gain), at the configurations ``passive_configurations``
  (default the nominal values only: a drive may be passive nowhere in some configuration, the
  bundled harmonic drive with its gearbox damping 0.5 Nms/rad for one). The widest bandwidth
  can cost the outer loop its passivity (the paper: "it is not obvious that maximizing the
  bandwidth of the torque loop is always consistent with the specifications for the outer
  impedance loop"); docs/tune.md shows it on the bundled harmonic drive.

The objective (``objective``) is the smallest bandwidth over the configurations (``"worst"``,
default: the guaranteed bandwidth) or the nominal one (``"nominal"``). beta and alpha stay the
file's: the result is ``P_t0``, ``I_t0`` at the file's beta.

How it searches, and why
------------------------
The PI is written ``I_t (tau + Ts z / (z - 1))`` with the lead time ``tau = P_t0 / I_t0`` (s; its
zero at 1/tau rad/s) and the integral gain ``I_t0``. For a fixed tau, scaling ``I_t0`` is scaling
the loop gain, which the analyses take as the runtime argument beta: one :class:`ClosedLoop` per
(configuration, tau), every gain on it without rebuilding. The feasible set is not convex (the
bundled harmonic drive has unstable islands between feasible gains, where a resonance's phase
crossover passes through -1) and the best bandwidth often sits at tau -> 0 (a pure integrator:
the proportional part lifts the gain near the drive's resonance, where the gain margin binds), so:

1. a coarse grid: ``tau`` = 0 (pure integral) and ``n_lead`` log-spaced values in ``lead_range``
   (s), times ``n_integral`` log-spaced ``I_t0`` in ``integral_range`` times R / (k_t N) (1/s:
   the integral rate of a PI whose static loop gain P_t0 k_t N / R is one). Every point is
   decided at every configuration (stopping at the first that fails);
2. a local refinement on the active constraint from the best coarse point: for a given tau the
   gain is raised by grid steps from a feasible value until a constraint fails and the edge is
   bisected in log I_t0 to the relative width ``rtol``; tau itself is refined by golden sections
   between the best coarse point's neighbours (log tau; linear next to tau = 0) to ``rtol``.

The answer is the best feasible point evaluated (every point evaluated is decided at every
configuration: it meets the targets by construction, with the tolerance of the exact crossovers).
It is optimal to within ``rtol`` on the coarse point's ridge, not a certificate: a feasible
island narrower than a coarse step, or a better ridge whose coarse points are all infeasible,
is not searched. ``at_range_edge`` says when the answer lies on the search box's boundary.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import re
import tomllib
from dataclasses import dataclass, field

import numpy as np

from haa_sym.analysis.passivity import passivity
from haa_sym.model.structures import require as require_structure
from haa_sym.analysis.torque import (BANDWIDTH_DEFINITIONS, load_mode, step_figures, step_response, torque_bandwidth,
                                     torque_loop_margins)
from haa_sym.errors import ParameterError
from haa_sym.loop import ClosedLoop, LoopOptions
from haa_sym.model.params import parse_params

__all__ = ["PM_TARGET_DEG", "GM_TARGET_DB", "OBJECTIVES", "TuneOptions", "GainReport", "TuneResult", "tune",
           "evaluate_gains", "NOMINAL", "tuned_text", "rule_text"]

# Sec. 3.2: "a phase margin larger than 30 deg and a gain margin larger than 12 dB for the upper
# and lower bounds of J_L2 and K_L2 ... with alpha = 0.94"; and stable for alpha in [0, 1].
PM_TARGET_DEG = 30.0
GM_TARGET_DB = 12.0
STABLE_ALPHA = (0.0, 1.0)
OBJECTIVES = ("worst", "nominal")
NOMINAL = "nominal"


@dataclass(frozen=True)
class TuneOptions:
    """The choices of :func:`tune` (module docstring), with the defaults it documents.

    Attributes
    ----------
    pm_deg : float
        Phase-margin target, deg (Sec. 3.2: 30); every gain crossover's |PM| at least this.
    gm_db : float
        Gain-margin target, dB (Sec. 3.2: 12); every phase crossover's |GM| at least this.
    objective : {"worst", "nominal"}
        Maximise the smallest bandwidth over the configurations, or the nominal values' one.
    stable_alpha : (float, float) or None
        alpha range (dimensionless) where the torque loop must stay stable (Sec. 3.2: 0 to 1),
        sampled at ``n_alpha`` values; None: no such requirement.
    n_alpha : int
        Samples of ``stable_alpha`` (ends included).
    lead_range : (float, float)
        Lead time tau = P_t0 / I_t0 of the coarse grid, s (plus tau = 0, the pure integrator).
    n_lead : int
        Log-spaced tau values of the coarse grid in ``lead_range``.
    integral_range : (float, float)
        I_t0 of the coarse grid in units of R / (k_t N) (V/Nm, the static-gain-one P_t0), i.e.
        in 1/s.
    n_integral : int
        Log-spaced I_t0 values of the coarse grid.
    rtol : float
        Relative tolerance of the refinement, in I_t0 (the constraint's edge) and in tau.
    step_duration : float
        Window of the reported step responses, s.
    passive_at : tuple of (float, float)
        Impedance gains (P_gain Nm/rad, D_gain Nms/rad) where the port must be passive; default
        () none.
    passive_configurations : tuple of str
        Where ``passive_at`` is required: ``"nominal"`` and / or configuration names of the file
        (default ("nominal",)).
    bandwidth : {"tracking", "magnitude"}
        The bandwidth maximised and reported (:data:`haa_sym.analysis.torque.BANDWIDTH_DEFINITIONS`):
        ``"tracking"`` (default), where the tracking error |1 - H_T| first reaches -3 dB;
        ``"magnitude"``, the paper's -3 dB of |H_T| (which a load's anti-resonance or resonance
        can place at the load's mode instead of where the loop stops tracking).
    """

    pm_deg: float = PM_TARGET_DEG
    gm_db: float = GM_TARGET_DB
    objective: str = "worst"
    stable_alpha: tuple[float, float] | None = STABLE_ALPHA
    n_alpha: int = 11
    lead_range: tuple[float, float] = (1e-4, 10.0)
    n_lead: int = 16
    integral_range: tuple[float, float] = (1e-2, 1e4)
    n_integral: int = 25
    rtol: float = 1e-3
    step_duration: float = 5.0
    passive_at: tuple = ()
    passive_configurations: tuple = (NOMINAL,)
    bandwidth: str = "tracking"

    def __post_init__(self):
        def bad(name, allowed):
            raise ParameterError(f"{name} = {getattr(self, name)!r}; allowed: {allowed}")
        for name in ("pm_deg", "gm_db"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                bad(name, "a finite number >= 0 (pm_deg in deg, gm_db in dB)")
        if self.pm_deg >= 180:
            bad("pm_deg", "below 180 deg")
        if self.objective not in OBJECTIVES:
            bad("objective", list(OBJECTIVES))
        if self.bandwidth not in BANDWIDTH_DEFINITIONS:
            bad("bandwidth", list(BANDWIDTH_DEFINITIONS))
        for name in ("lead_range", "integral_range"):
            r = getattr(self, name)
            if (not isinstance(r, tuple) or len(r) != 2 or not all(isinstance(x, (int, float)) for x in r)
                    or not all(math.isfinite(x) and x > 0 for x in r) or not r[0] < r[1]):
                bad(name, "(lo, hi) with 0 < lo < hi, finite")
        if self.stable_alpha is not None:
            r = self.stable_alpha
            if (not isinstance(r, tuple) or len(r) != 2 or not all(isinstance(x, (int, float)) for x in r)
                    or not all(math.isfinite(x) and x >= 0 for x in r) or not r[0] <= r[1]):
                bad("stable_alpha", "None or (lo, hi) with 0 <= lo <= hi, finite")
        for name, lo in (("n_alpha", 2), ("n_lead", 2), ("n_integral", 3)):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < lo or v > 10_000:
                bad(name, f"an integer from {lo} to 10000")
        if not isinstance(self.rtol, (int, float)) or not 1e-9 <= self.rtol <= 0.5:
            bad("rtol", "a number from 1e-9 to 0.5")
        if not isinstance(self.step_duration, (int, float)) or not 0 < self.step_duration <= 60:
            bad("step_duration", "a time in (0, 60] s")
        pts = self.passive_at
        if (not isinstance(pts, tuple) or len(pts) > 1000
                or not all(isinstance(q, tuple) and len(q) == 2 and all(isinstance(x, (int, float)) and
                                                                         math.isfinite(x) and x >= 0 for x in q)
                           for q in pts)):
            bad("passive_at", "a tuple of (P_gain, D_gain) pairs, each finite and >= 0 (Nm/rad, Nms/rad)")
        if (not isinstance(self.passive_configurations, tuple) or not self.passive_configurations
                or not all(isinstance(c, str) for c in self.passive_configurations)):
            bad("passive_configurations", "a non-empty tuple of configuration names ('nominal' or the file's)")

    def to_dict(self) -> dict:
        return {k: ([list(q) for q in v] if k == "passive_at" else list(v) if isinstance(v, tuple) else v)
                for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class GainReport:
    """One PI (``P_t0`` V/Nm, ``I_t0`` V/(Nm s), at the file's beta) judged at every configuration.

    Arrays are per configuration (the order of :attr:`TuneResult.configurations`):
    ``bandwidth_rad_s`` (by :attr:`TuneOptions.bandwidth`; NaN unstable / undefined), ``pm_deg``
    (min |PM| over the gain crossovers, those below the analysed band included, deg; inf: none),
    ``gm_db`` (min |GM| over the phase crossovers, dB; inf: none), ``stable`` (the torque loop
    alone, and over ``stable_alpha``), ``meets`` (every target); of the unit torque step in
    ``step_duration`` (:func:`haa_sym.analysis.torque.step_figures`; NaN: not reached / not
    settled): ``t90_s`` (from then on at or above 90 % of the final value), ``rise_time_s``
    (the last 10 % before it to it), ``settling_time_s`` (last leaving +-5 %); ``passive`` (the
    port passive at every point of ``passive_at``; True when there are none); ``load_modes``
    (per configuration a :class:`haa_sym.analysis.torque.LoadMode` near the bandwidth, or None).
    """

    P_t0: float
    I_t0: float
    bandwidth_rad_s: np.ndarray
    pm_deg: np.ndarray
    gm_db: np.ndarray
    stable: np.ndarray
    meets: np.ndarray
    rise_time_s: np.ndarray
    t90_s: np.ndarray
    passive: np.ndarray
    settling_time_s: np.ndarray = None
    load_modes: tuple = ()

    @property
    def worst_bandwidth(self) -> float:
        """The smallest bandwidth over the configurations, rad/s (NaN if any is undefined)."""
        bw = self.bandwidth_rad_s
        return float("nan") if np.isnan(bw).any() else float(bw.min())


@dataclass(frozen=True)
class TuneResult:
    """What :func:`tune` found.

    Attributes
    ----------
    configurations : tuple of str
        ``"nominal"`` (the file's values) and the file's configurations.
    before, after : GainReport
        The file's PI and the tuned one.
    objective_rad_s : float
        The tuned PI's objective (bandwidth, rad/s).
    active : str
        The constraint that stops a higher gain at the optimum: "<target> at <configuration>"
        (``pm``, ``gm``, ``stability``, ``stability over alpha`` or ``bandwidth undefined``), or
        "search range" when the gain reached ``integral_range``'s top.
    at_range_edge : bool
        The optimum's tau or I_t0 lies on the search box's edge (tau = 0 is a true end, not an edge).
    lead_s, integral : (n_lead + 1,), (n_integral,) arrays
        The coarse grid: tau (s, the first 0) and I_t0 (V/(Nm s)).
    grid_objective : (n_lead + 1, n_integral) array
        The objective on the coarse grid, rad/s (NaN: infeasible).
    evaluations : int
        Gain points decided (each at up to every configuration).
    options : TuneOptions
    meta : dict
        Provenance (:meth:`ClosedLoop.provenance` of the nominal loop), the date.
    """

    configurations: tuple
    before: GainReport
    after: GainReport
    objective_rad_s: float
    active: str
    at_range_edge: bool
    lead_s: np.ndarray
    integral: np.ndarray
    grid_objective: np.ndarray
    evaluations: int
    options: TuneOptions
    meta: dict = field(default_factory=dict)

    @property
    def unchanged(self) -> bool:
        """The file's PI is already the optimum found: the tuned gains equal the file's."""
        return self.after.P_t0 == self.before.P_t0 and self.after.I_t0 == self.before.I_t0

    @property
    def within_tolerance(self) -> bool:
        """The tuned gains differ from the file's by at most the search's tolerance (``rtol``,
        relative, each gain): the file was already at the optimum the search can resolve."""
        tol = self.options.rtol
        return all(abs(a - b) <= tol * max(abs(a), abs(b)) for a, b in
                   ((self.after.P_t0, self.before.P_t0), (self.after.I_t0, self.before.I_t0)))

    def to_json(self) -> dict:
        """Plain JSON data (NaN and inf as null)."""
        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        def mode(m):
            return None if m is None else {"kind": m.kind, "omega_rad_s": m.omega, "depth_db": m.depth_db,
                                           "text": m.describe()}

        def report(g: GainReport) -> dict:
            return {"P_t0_V_per_Nm": g.P_t0, "I_t0_V_per_Nm_s": g.I_t0,
                    "worst_bandwidth_rad_s": num(g.worst_bandwidth),
                    "configurations": {c: {"bandwidth_rad_s": num(g.bandwidth_rad_s[i]), "pm_deg": num(g.pm_deg[i]),
                                           "gm_db": num(g.gm_db[i]), "stable": bool(g.stable[i]),
                                           "meets_targets": bool(g.meets[i]), "rise_time_s": num(g.rise_time_s[i]),
                                           "t90_s": num(g.t90_s[i]), "settling_time_5pct_s": num(g.settling_time_s[i]),
                                           "load_mode": mode(g.load_modes[i]),
                                           "passive_at_points": bool(g.passive[i])}
                                       for i, c in enumerate(self.configurations)}}
        return {"bandwidth_definition": {"name": self.options.bandwidth,
                                         "text": BANDWIDTH_DEFINITIONS[self.options.bandwidth]},
                "step_figures": "t90: from then on at or above 90 % of the final value; rise time: the last "
                                "10 % before it to it; settling: last leaving +-5 % (s, unit torque step)",
                "unchanged": self.unchanged, "within_tolerance_of_the_file": self.within_tolerance,
                "targets": {"pm_deg": self.options.pm_deg, "gm_db": self.options.gm_db,
                            "stable_alpha": None if self.options.stable_alpha is None else list(self.options.stable_alpha),
                            "passive_at": [list(q) for q in self.options.passive_at],
                            "passive_configurations": list(self.options.passive_configurations)},
                "objective": self.options.objective, "objective_rad_s": num(self.objective_rad_s),
                "active": self.active, "at_range_edge": self.at_range_edge,
                "before": report(self.before), "after": report(self.after),
                "evaluations": self.evaluations, "options": self.options.to_dict(), "meta": self.meta}


# ----------------------------------------------------------------------------- evaluation
class _Problem:
    """The configurations' parameters and the memo of loops (one per configuration and tau)."""

    def __init__(self, params, options: LoopOptions | None, opts: TuneOptions):
        self.params, self.options, self.opts = params, options, opts
        names = [NOMINAL, *params.configurations]
        self.configurations = tuple(names)
        plants = [params] + [params.configuration(c) for c in params.configurations]
        # identical plants (a configuration repeating the nominal values) are decided once
        self.unique, self.index = [], []
        for p in plants:
            for k, q in enumerate(self.unique):
                if q.plant == p.plant:
                    self.index.append(k)
                    break
            else:
                self.index.append(len(self.unique))
                self.unique.append(p)
        self.beta = float(params.controller.beta)
        self.alpha = float(params.controller.alpha)
        self._loops: dict = {}
        self.evaluations = 0
        a = opts.stable_alpha
        self.alphas = None if a is None else np.linspace(a[0], a[1], opts.n_alpha)
        self.passive_P = np.array([q[0] for q in opts.passive_at], float)
        self.passive_D = np.array([q[1] for q in opts.passive_at], float)
        unknown = [c for c in opts.passive_configurations if c not in self.configurations]
        if unknown:
            raise ParameterError(f"passive_configurations = {list(opts.passive_configurations)}: {unknown} not in "
                                 f"{params.source}; allowed: {list(self.configurations)}")
        self.passive_required = {k for c, k in zip(self.configurations, self.index)
                                 if c in opts.passive_configurations}

    def loop(self, k: int, tau: float) -> ClosedLoop:
        key = (k, tau)
        if key not in self._loops:
            # P_t0 = tau, I_t0 = 1: the runtime beta is then the integral gain beta_file * I_t0
            self._loops[key] = ClosedLoop(self.unique[k].with_values(P_t0=tau, I_t0=1.0), self.options)
        return self._loops[key]

    def decide(self, tau: float, I_t0: float, order=None):
        """(feasible, objective, failure) of one PI; failure names the first target missed and the
        configuration. Stops at the first configuration that fails."""
        self.evaluations += 1
        b = self.beta * I_t0
        bws = np.full(len(self.unique), np.nan)
        for k in (order or range(len(self.unique))):
            fail = self._fails(k, tau, b)
            if fail:
                return False, float("nan"), fail
            bws[k] = torque_bandwidth(self.loop(k, tau), beta=b, definition=self.opts.bandwidth)
            if not np.isfinite(bws[k]):
                return False, float("nan"), ("bandwidth undefined", k)
        per_cfg = bws[self.index]
        obj = float(per_cfg.min()) if self.opts.objective == "worst" else float(per_cfg[0])
        return True, obj, None

    def _fails(self, k: int, tau: float, b: float):
        loop = self.loop(k, tau)
        st = loop.stability(0.0, 0.0, b)
        if not bool((st.stable | st.marginal).all()):
            return ("stability", k)
        try:
            m = torque_loop_margins(loop, beta=b)
        except ParameterError:          # a crossover below the extended band: no use as a torque loop
            return ("pm", k)
        if m.distance_deg < self.opts.pm_deg:
            return ("pm", k)
        if m.gain_margins_db.size and float(np.abs(m.gain_margins_db).min()) < self.opts.gm_db:
            return ("gm", k)
        if self.alphas is not None:
            sa = loop.stability(np.zeros(self.alphas.size), 0.0, b, self.alphas)
            if not bool((sa.stable | sa.marginal).all()):
                return ("stability over alpha", k)
        if self.passive_P.size and k in self.passive_required and not bool(passivity(loop, self.passive_P, self.passive_D, beta=b,
                                                      progress=False).passive.all()):
            return ("passivity", k)
        return None

    def name(self, k: int) -> str:
        return ", ".join(c for c, i in zip(self.configurations, self.index) if i == k)


def evaluate_gains(params, P_t0: float, I_t0: float, options: LoopOptions | None = None,
                   tune_options: TuneOptions | None = None) -> GainReport:
    """Judge one PI (``P_t0`` V/Nm, ``I_t0`` V/(Nm s), at the file's beta and alpha) at the
    nominal values and every configuration of ``params``: :class:`GainReport`."""
    opts = tune_options or TuneOptions()
    for name, v in (("P_t0", P_t0), ("I_t0", I_t0)):
        if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise ParameterError(f"{name} = {v!r}; allowed: a finite gain >= 0")
    prob = _Problem(params, options, opts)
    n = len(prob.configurations)
    out = {k: np.full(n, np.nan) for k in ("bw", "pm", "gm", "rise", "t90", "settle")}
    modes = [None] * n
    stable, meets, passive = np.zeros(n, bool), np.zeros(n, bool), np.ones(n, bool)
    for i, p in enumerate([params] + [params.configuration(c) for c in params.configurations]):
        loop = ClosedLoop(p.with_values(P_t0=float(P_t0), I_t0=float(I_t0)), options)
        st = loop.stability(0.0, 0.0)
        ok = bool((st.stable | st.marginal).all())
        if ok and prob.alphas is not None:
            sa = loop.stability(np.zeros(prob.alphas.size), 0.0, None, prob.alphas)
            ok = bool((sa.stable | sa.marginal).all())
        stable[i] = ok
        m = torque_loop_margins(loop)
        out["pm"][i] = m.distance_deg
        out["gm"][i] = float(np.abs(m.gain_margins_db).min()) if m.gain_margins_db.size else np.inf
        if bool((st.stable | st.marginal).all()):
            out["bw"][i] = torque_bandwidth(loop, definition=opts.bandwidth)
            modes[i] = load_mode(loop, out["bw"][i])
            f = step_figures(step_response(loop, duration=opts.step_duration))
            out["rise"][i], out["t90"][i], out["settle"][i] = f["rise_time_s"], f["t90_s"], f["settling_time_s"]
        if prob.passive_P.size:
            passive[i] = bool(passivity(loop, prob.passive_P, prob.passive_D, progress=False).passive.all())
        meets[i] = (ok and out["pm"][i] >= opts.pm_deg and out["gm"][i] >= opts.gm_db
                    and np.isfinite(out["bw"][i])
                    and (passive[i] or prob.configurations[i] not in opts.passive_configurations))
    return GainReport(float(P_t0), float(I_t0), out["bw"], out["pm"], out["gm"], stable, meets, out["rise"],
                      out["t90"], passive, out["settle"], tuple(modes))


# ----------------------------------------------------------------------------- the search
WRITTEN_DIGITS = 6


def _rounded(x: float) -> float:
    return float(f"{x:.{WRITTEN_DIGITS}g}")


def tune(params, options: LoopOptions | None = None, tune_options: TuneOptions | None = None) -> TuneResult:
    """The torque PI (P_t0, I_t0) of widest bandwidth meeting the Sec. 3.2 targets at every
    configuration (module docstring).

    Parameters
    ----------
    params : Params
        The actuator file's parameters (nominal values and ``configurations``); beta and alpha
        are kept.
    options : LoopOptions, optional
        Modelling options of the loop (delay, velocity estimate, ...).
    tune_options : TuneOptions, optional
        Targets, objective, search box and tolerance.

    Returns
    -------
    TuneResult

    Raises
    ------
    ParameterError
        No point of the coarse grid meets the targets (the message says which target failed
        most often), or bad options.
    """
    require_structure(params.controller.structure, "torque_loop", "tune (the torque PI tuner)")
    opts = tune_options or TuneOptions()
    prob = _Problem(params, options, opts)
    pl = params.plant
    scale = float(pl.R / (pl.k_t * pl.N))               # V/Nm: static loop gain one
    taus = np.concatenate([[0.0], np.geomspace(*opts.lead_range, opts.n_lead)])
    I_grid = scale * np.geomspace(*opts.integral_range, opts.n_integral)
    q = I_grid[1] / I_grid[0]
    grid_obj = np.full((taus.size, I_grid.size), np.nan)
    fails: dict = {}
    order = list(range(len(prob.unique)))
    for i, tau in enumerate(taus):
        for j, I in enumerate(I_grid):
            ok, obj, fail = prob.decide(float(tau), float(I), order)
            if ok:
                grid_obj[i, j] = obj
            else:
                fails[fail] = fails.get(fail, 0) + 1
                # the configuration that failed is tried first next time: most points fail early
                order = [fail[1]] + [k for k in order if k != fail[1]]
    if not np.isfinite(grid_obj).any():
        (what, k), _ = max(fails.items(), key=lambda kv: kv[1])
        raise ParameterError(
            f"tune: no PI of the search grid meets the targets (pm_deg = {opts.pm_deg:g}, gm_db = {opts.gm_db:g}) at every "
            f"configuration; most often missed: {what} at {prob.name(k)}; allowed: looser targets, a wider "
            f"integral_range / lead_range (--integral-range / --lead-range), or another beta (the file's "
            f"[controller] beta)")

    best = {"obj": -np.inf}

    def record(tau, I, obj):
        if obj > best["obj"]:
            best.update(obj=obj, tau=tau, I=I)

    for i, j in zip(*np.nonzero(np.isfinite(grid_obj))):
        record(float(taus[i]), float(I_grid[j]), float(grid_obj[i, j]))
    i0 = int(np.flatnonzero(taus == best["tau"])[0])
    I_start = best["I"]
    I_top = float(I_grid[-1])
    edge_fail = {}

    def ridge(tau: float) -> float:
        """Best objective along tau: from a feasible gain up to the edge, bisected to rtol."""
        lo, obj_lo = None, -np.inf
        I = I_start
        for _ in range(4):                       # a feasible start near the coarse optimum's gain
            ok, obj, fail = prob.decide(tau, I, order)
            if ok:
                lo, obj_lo = I, obj
                record(tau, I, obj)
                break
            I /= q
        if lo is None:
            return -np.inf
        hi, fail_hi = None, None
        while hi is None:
            I = min(lo * q, I_top)
            if I <= lo:
                fail_hi = ("search range", None)
                break
            ok, obj, fail = prob.decide(tau, I, order)
            if ok:
                lo, obj_lo = I, max(obj_lo, obj)
                record(tau, I, obj)
            else:
                hi, fail_hi = I, fail
        while hi is not None and hi / lo > 1 + opts.rtol:
            mid = math.sqrt(lo * hi)
            ok, obj, fail = prob.decide(tau, mid, order)
            if ok:
                lo, obj_lo = mid, max(obj_lo, obj)
                record(tau, mid, obj)
            else:
                hi, fail_hi = mid, fail
        edge_fail[tau] = fail_hi
        return obj_lo

    # golden sections over tau between the best coarse point's neighbours
    a = float(taus[max(i0 - 1, 0)])
    b = float(taus[min(i0 + 1, taus.size - 1)])
    linear = a == 0.0
    fwd = (lambda x: x) if linear else math.log
    inv = (lambda x: x) if linear else math.exp
    x0, x1 = fwd(a), fwd(b)
    ridge(best["tau"])
    g = (math.sqrt(5) - 1) / 2
    c, d = x1 - g * (x1 - x0), x0 + g * (x1 - x0)
    fc, fd = ridge(inv(c)), ridge(inv(d))
    scale_x = (b if linear else 1.0)
    while abs(x1 - x0) > opts.rtol * scale_x:
        if fc >= fd:
            x1, d, fd = d, c, fc
            c = x1 - g * (x1 - x0)
            fc = ridge(inv(c))
        else:
            x0, c, fc = c, d, fd
            d = x0 + g * (x1 - x0)
            fd = ridge(inv(d))
    if best["tau"] not in edge_fail:
        ridge(best["tau"])
    what, k = edge_fail.get(best["tau"]) or ("search range", None)
    active = what if k is None else f"{what} at {prob.name(k)}"
    tau_opt, I_opt = best["tau"], best["I"]
    # tau = 0 is the end of the PI family, not of the box
    at_edge = bool(tau_opt >= taus[-1] * (1 - 1e-12) or I_opt >= I_top * (1 - 1e-12)
                   or I_opt <= I_grid[0] * (1 + 1e-12))
    ctrl = params.controller
    before = evaluate_gains(params, float(ctrl.P_t0), float(ctrl.I_t0), options, opts)
    # the file gets WRITTEN_DIGITS significant digits when they still meet every target
    after = evaluate_gains(params, _rounded(tau_opt * I_opt), _rounded(I_opt), options, opts)
    if not after.meets.all():
        after = evaluate_gains(params, tau_opt * I_opt, I_opt, options, opts)
    meta = ClosedLoop(params, options).provenance(
        tuned_utc=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        tune_options=opts.to_dict(), lead_time_s=tau_opt)
    return TuneResult(prob.configurations, before, after, float(best["obj"]), active, at_edge, taus, I_grid,
                      grid_obj, prob.evaluations, opts, meta)


# ----------------------------------------------------------------------------- the tuned file
_HEADER = re.compile(r"^\s*\[")                       # any table header ends [controller]
_CONTROLLER = re.compile(r"^\s*\[\s*controller\s*\]\s*(#.*)?$")
GAIN_UNITS = {"P_t0": "V/Nm", "I_t0": "V/(Nm s)"}


def _num(x: float, unit: str = "") -> str:
    return ("n/a" if not np.isfinite(x) else f"{x:.4g}") + (f" {unit}" if unit else "")


def rule_text(result: TuneResult, key: str, was: str) -> str:
    """The description of a tuned entry: the rule, the targets, what it achieves at every
    configuration, the active constraint, the date, and the value it replaces (``was``)."""
    o, a, b = result.options, result.after, result.before
    tau = a.P_t0 / a.I_t0 if a.I_t0 > 0 else float("nan")
    per = "; ".join(f"{c} {_num(a.bandwidth_rad_s[i], 'rad/s')}, PM {_num(a.pm_deg[i], 'deg')}, GM {_num(a.gm_db[i], 'dB')}"
                    for i, c in enumerate(result.configurations))
    alpha = ("" if o.stable_alpha is None else
             f" and the loop stable for alpha {o.stable_alpha[0]:g} to {o.stable_alpha[1]:g}")
    passive = "" if not o.passive_at else (
        ", and the port passive at (P_gain, D_gain) = " + ", ".join(f"({p:g}, {d:g})" for p, d in o.passive_at)
        + " at " + ", ".join(o.passive_configurations))
    shape = ("a pure integrator (P_t0 = 0)" if a.P_t0 == 0 else f"PI zero I_t0/P_t0 = {_num(1 / tau, 'rad/s')}")
    return (f"Rule (haa-sym tune, {result.meta.get('tuned_utc', '')[:10]}): the torque PI (at beta = "
            f"{result.meta['params']['controller']['beta']:g}, alpha = {result.meta['params']['controller']['alpha']:g}) "
            f"of widest {'worst-case' if o.objective == 'worst' else 'nominal'} torque bandwidth ({o.bandwidth}: "
            f"{BANDWIDTH_DEFINITIONS[o.bandwidth]}), impedance "
            f"loop open, with PM >= {o.pm_deg:g} deg and GM >= {o.gm_db:g} dB (focchi2016 Sec. 3.2){alpha} at the "
            f"nominal values and every configuration{passive}; {shape}. Achieved: {per}; active constraint: {result.active}. "
            f"Before: worst-case bandwidth {_num(b.worst_bandwidth, 'rad/s')}, targets met at "
            f"{int(b.meets.sum())} of {b.meets.size}; was {was}")


def tuned_text(text: str, result: TuneResult, source: str = "<tuned>") -> str:
    """The actuator file ``text`` with ``P_t0`` and ``I_t0`` of ``[controller]`` replaced by
    ``result.after``'s, each entry's description saying the rule (:func:`rule_text`); every
    other line kept as it is. The new text is parsed and checked to give the new gains and
    nothing else new.

    Raises
    ------
    ParameterError
        The file does not write the gains as one-line entries ``P_t0 = ...`` of ``[controller]``.
    """
    data = tomllib.loads(text)
    old = parse_params(data, source=source)
    lines = text.splitlines(keepends=True)
    start = next((i for i, ln in enumerate(lines) if _CONTROLLER.match(ln)), None)
    if start is None:
        raise ParameterError(f"{source}: no [controller] table header to rewrite; allowed: a file with a "
                             "[controller] table writing P_t0 and I_t0 on lines of their own")
    end = next((i for i in range(start + 1, len(lines)) if _HEADER.match(lines[i])), len(lines))
    raw = data["controller"]
    for key, value in (("P_t0", result.after.P_t0), ("I_t0", result.after.I_t0)):
        pat = re.compile(rf"^(\s*){key}(\s*)=(\s*)(.*?)(\r?\n)?$")
        hits = [i for i in range(start + 1, end) if pat.match(lines[i])]
        if len(hits) != 1:
            raise ParameterError(f"{source}: [controller] {key} is written {len(hits)} times as a line "
                                 f"'{key} = ...'; allowed: exactly one such line to rewrite")
        i = hits[0]
        m = pat.match(lines[i])
        rest, comment = m.group(4), ""
        for k in [k for k, ch in enumerate(rest) if ch == "#"]:
            try:
                tomllib.loads("x = " + rest[:k])
            except tomllib.TOMLDecodeError:
                continue
            rest, comment = rest[:k].rstrip(), " " + rest[k:]
            break
        entry = raw[key]
        if isinstance(entry, dict):
            was = f"{entry.get('value')} {entry.get('unit', GAIN_UNITS[key])}"
            if entry.get("description"):
                was += f" ({entry['description']})"
        else:
            was = f"{entry} {GAIN_UNITS[key]}"
        desc = json.dumps(rule_text(result, key, was), ensure_ascii=True)
        lines[i] = (f"{m.group(1)}{key}{m.group(2)}={m.group(3)}{{ value = {float(value)!r}, unit = "
                    f"\"{GAIN_UNITS[key]}\", source = \"-\", description = {desc} }}{comment}{m.group(5) or ''}")
    new = "".join(lines)
    check = parse_params(tomllib.loads(new), source=source)
    want = old.with_values(P_t0=result.after.P_t0, I_t0=result.after.I_t0)
    if check.to_dict() != want.to_dict() or check.configurations != old.configurations:
        raise ParameterError(f"{source}: rewriting P_t0 and I_t0 changed other values; allowed: a file whose "
                             "[controller] gains are one-line entries")
    return new
