"""A torque-gain scheduler over the impedance range, robust to the leg (the paper's Sec. 6 outlook).

For every impedance (P_gain, D_gain) of a grid, the largest torque-gain scale beta (Eq. 7: the
torque PI gains are beta P_t0, beta I_t0) such that the requirements hold for every leg
configuration of the range (:mod:`haa_sym.analysis.robust`): by default the closed loop stable with an
impedance-loop phase margin of at least 30 deg; passivity at the port as an option. Optionally
alpha (Eq. 6) is scheduled too, from a set of values.

How beta is found
-----------------
beta runs over a logarithmic grid from ``beta_range[0]`` to ``beta_range[1]`` with ratio at most
``1 + beta_tol`` (the stated tolerance). Every ``coarse_step``-th value (ratio about 1.25) is
decided on the whole impedance grid at once, one map per (leg configuration, beta, alpha) from
the exact boundaries; each point's largest feasible coarse value and the next coarse value
bracket its answer, and every fine value inside the bracket is decided for the points that need
it. The answer is the largest feasible value found: feasible at every leg configuration, with
the next grid value (1 + beta_tol higher) infeasible for at least one unless it is the range's
end. A feasible island of beta narrower than one coarse step above an infeasible coarse value
is not searched (documented limit). The leg configurations double (2, 3, 5, 9, ...) until the
schedule no longer changes (``n_configurations`` says how many it took).

The torque bandwidth reported with each row is the paper's (Sec. 3.3): the -3 dB frequency of
torque tracking with the leg free in the air (the port body's stiffness set to 0), at the
scheduled beta and alpha, the file's nominal plant otherwise.

Large sweeps
------------
Every map is one task (one call of the evaluators on a whole gain grid; a task ships a few
numbers and returns one boolean array). Tasks run on dask: in-process (dask's threaded
scheduler) by default, or on an existing dask.distributed cluster (``scheduler`` = its address
or a ``distributed.Client``). The result is the same, byte for byte.

Example
-------
>>> from haa_sym import load_params
>>> from haa_sym.design.schedule import schedule
>>> s = schedule(load_params(), [10.0, 300.0], [2.0, 20.0])                  # doctest: +SKIP
>>> s.beta                                                                   # doctest: +SKIP
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from haa_sym.loop.closed_loop import LoopOptions
from haa_sym.errors import ParameterError
from haa_sym.model.params import Params, gain_array
from haa_sym.analysis.robust import MAX_LEG_POINTS, _check_requirements, leg_configurations, leg_ends

__all__ = ["Schedule", "schedule", "beta_grid", "CSV_COLUMNS", "DEFAULT_P_GAIN", "DEFAULT_D_GAIN"]

CSV_COLUMNS = ("P_gain", "D_gain", "beta", "alpha", "torque_bandwidth_rad_s", "feasible")
# HyQ's locomotion range (the issue): P_gain log 1..2000 Nm/rad, D_gain 1..50 Nms/rad
DEFAULT_P_GAIN = "log:1:2000:30"
DEFAULT_D_GAIN = "lin:1:50:20"
COARSE_RATIO = 1.25
# |L|^2 of a grid sample next to a hidden peak: a peak reaching |L| = 1 between samples of the
# default grid (1000 points, 0.1 rad/s to Nyquist) shows |L| > 0.1 on its neighbours down to a
# damping ratio of about 3e-4
PEAK_FLOOR = 1e-2


def beta_grid(beta_range=(0.1, 8.0), beta_tol: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """The fine beta grid (log, ratio <= 1 + beta_tol, both ends included) and the indices of
    its coarse values (ratio about 1.25, both ends included)."""
    lo, hi = (float(v) for v in beta_range)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise ParameterError(f"beta_range = {lo:g}:{hi:g}; allowed: 0 < LO < HI (a range of the "
                             "torque-gain scale beta, Eq. 7)")
    if not (np.isfinite(beta_tol) and 1e-4 <= beta_tol <= 0.25):
        raise ParameterError(f"beta_tol = {beta_tol!r}; allowed: 1e-4 <= beta_tol <= 0.25 (relative step)")
    n = int(np.ceil(np.log(hi / lo) / np.log1p(beta_tol))) + 1
    fine = np.geomspace(lo, hi, n)
    step = max(1, int(round(np.log(COARSE_RATIO) / np.log(fine[1] / fine[0])))) if n > 1 else 1
    coarse = np.unique(np.append(np.arange(0, n, step), n - 1))
    return fine, coarse


@dataclass(frozen=True)
class Schedule:
    """The schedule on the impedance grid; arrays (n_P, n_D).

    ``beta`` and ``alpha`` (NaN where ``feasible`` is False), ``torque_bandwidth_rad_s`` (rad/s,
    the leg free in the air, at the scheduled gains), ``feasible``; ``beta_fixed_feasible``:
    whether beta = 1 (the file's tuning) meets the requirements at every leg configuration;
    ``n_configurations``, ``converged`` and ``history`` of the leg doubling; ``meta``: what
    produced it.
    """

    P_gain: np.ndarray
    D_gain: np.ndarray
    beta: np.ndarray
    alpha: np.ndarray
    torque_bandwidth_rad_s: np.ndarray
    feasible: np.ndarray
    n_configurations: int
    converged: bool
    history: list
    meta: dict = field(default_factory=dict)
    beta_fixed_feasible: np.ndarray = None

    def csv_text(self) -> str:
        """One row per grid point, columns :data:`CSV_COLUMNS` (empty numbers where infeasible)."""
        lines = [",".join(CSV_COLUMNS)]
        for i, P in enumerate(self.P_gain):
            for j, D in enumerate(self.D_gain):
                ok = bool(self.feasible[i, j])
                num = (lambda v: f"{v:.12g}" if ok and np.isfinite(v) else "")
                # the grid exactly (17 digits round-trip): fed back to the C lookup, a grid point
                # must hit the table's grid point, not a neighbour's cell
                lines.append(f"{P:.17g},{D:.17g},{num(self.beta[i, j])},{num(self.alpha[i, j])},"
                             f"{num(self.torque_bandwidth_rad_s[i, j])},{'true' if ok else 'false'}")
        return "\n".join(lines) + "\n"

    def save_csv(self, path, tx=None, field: str | None = None):
        """Write :meth:`csv_text` (all or nothing, :mod:`haa_sym.io.outputs`)."""
        from haa_sym.io.outputs import write_text
        return write_text(path, self.csv_text(), tx, field)

    def table(self):
        """The schedule as a :class:`haa_sym.design.schedule_c.ScheduleTable` (for the embedded C)."""
        from haa_sym.design.schedule_c import ScheduleTable
        if not self.feasible.any():
            raise ParameterError("the schedule has no feasible point, so there is no gain to emit; "
                                 "allowed: a beta range or requirements that some impedance meets")
        m = self.meta
        meta = {"actuator": m["actuator"], "source": m["source"], "requirements": m["requirements"],
                "tolerances": {"beta_tol": m["beta_tol"], "pm_deg": 30.0},
                "haa_sym_version": m["haa_sym"], "leg": m["leg"], "leg_mode": m["leg_mode"],
                "leg_configurations": self.n_configurations, "beta_range": m["beta_range"]}
        alpha = self.alpha if m.get("alpha_scheduled") else None
        return ScheduleTable(self.P_gain, self.D_gain, self.beta, self.feasible, meta, alpha=alpha)


# ------------------------------------------------------------------------------ the tasks
# Module-level functions of plain data: what a dask worker runs (one map or one point set).

def _task_map(params, config, P, D, beta, alpha, requirements, options):
    from haa_sym.analysis.robust import feasible_map
    return feasible_map(params.with_values(**config), P, D, beta, alpha, requirements=requirements,
                        options=options)


def _task_points(params, config, P, D, beta, alpha, requirements, options):
    from haa_sym.loop.closed_loop import ClosedLoop
    from haa_sym.analysis.regions import decide_points
    loop = ClosedLoop(params.with_values(**config), options)
    st, low, passive = decide_points(loop, P, D, beta, alpha, passivity="passive" in requirements)
    ok = st.copy()
    if "pm" in requirements:
        ok &= ~low
    if "passive" in requirements:
        ok &= passive
    return ok


def _golden(f, lo, hi, sign, steps: int = 40):
    """Maximise sign * f(x) on every bracket [lo, hi] at once (golden sections)."""
    g = 0.3819660112501051
    a, b = lo.copy(), hi.copy()
    x1, x2 = a + g * (b - a), b - g * (b - a)
    f1, f2 = sign * f(x1), sign * f(x2)
    for _ in range(steps):
        left = f1 >= f2                                  # the maximum is in [a, x2]
        b = np.where(left, x2, b)
        a = np.where(left, a, x1)
        x1n = np.where(left, a + g * (b - a), x2)
        x2n = np.where(left, x1, b - g * (b - a))
        fn = sign * f(np.where(left, x1n, x2n))
        f1, f2 = np.where(left, fn, f2), np.where(left, f1, fn)
        x1, x2 = x1n, x2n
    x = np.where(f1 >= f2, x1, x2)
    return x, sign * np.maximum(f1, f2)


def exact_low_pm(loop, P, D, beta: float, alpha: float, pm_deg: float = 30.0) -> np.ndarray:
    """Per gain point: the phase margin of the options' ``pm_loop`` (the impedance loop by
    default), from crossovers located exactly, is below ``pm_deg`` (the options' rule chooses
    the crossover, as in the maps).

    The maps locate a crossover between two grid samples by interpolation and miss a pair that
    a resonance narrower than the grid step hides; near a lightly damped mode both can be wrong
    by tens of degrees (measured: the SEA's light link at beta 7.6, grid PM 124.9 deg, true
    crossovers at 340 and 342 rad/s with -96 and 173 deg). Here every sign change of |L| - 1
    on the grid, and every local extremum of |L| whose neighbours stay on one side of 1 but
    which refined by golden sections reaches the other side, is located by the Illinois method
    on the loop's exact frequency response, and the margin taken there.
    """
    from haa_sym.analysis.sweep import gain_rows, monomial_rows, product_form
    X = gain_rows(P, D)
    coef = loop.loop_coefficients(beta=beta, alpha=alpha)
    which = "L_imp" if loop.options.conventions.pm_loop == "impedance" else "L_t"     # as the maps
    lw = np.log(coef.omega)
    L_grid = getattr(coef, which)
    mag2 = monomial_rows(X) @ product_form(L_grid, L_grid).real      # (n, n_omega)

    def L_at(rows, x):
        return np.einsum("ij,ij->i", X[rows],
                         getattr(loop.loop_coefficients(np.exp(x), beta, alpha, cached=False), which))

    # brackets of |L|^2 - 1: sign changes on the grid ...
    rows, i = np.nonzero((mag2[:, 1:] > 1) != (mag2[:, :-1] > 1))
    br = [(rows, lw[i], lw[i + 1])]
    # ... and hidden pairs around narrow peaks (below 1 on the grid) or notches (above)
    up = np.diff(mag2, axis=1)
    for mask, sign in (((up[:, :-1] > 0) & (up[:, 1:] < 0) & (mag2[:, 1:-1] < 1) & (mag2[:, 1:-1] > PEAK_FLOOR), 1.0),
                       ((up[:, :-1] < 0) & (up[:, 1:] > 0) & (mag2[:, 1:-1] > 1) & (mag2[:, 1:-1] < 1 / PEAK_FLOOR), -1.0)):
        r, k = np.nonzero(mask)
        if not r.size:
            continue
        k = k + 1
        xe, fe = _golden(lambda x: np.abs(L_at(r, x)) ** 2, lw[k - 1], lw[k + 1], sign)
        hit = sign * (fe - 1.0) > 0
        br += [(r[hit], lw[k - 1][hit], xe[hit]), (r[hit], xe[hit], lw[k + 1][hit])]
    rows = np.concatenate([b[0] for b in br])
    a = np.concatenate([b[1] for b in br])
    b = np.concatenate([b[2] for b in br])
    low = np.zeros(X.shape[0], bool)
    if not rows.size:
        return low
    from haa_sym.analysis.rootfind import illinois
    a, b = illinois(lambda x: np.abs(L_at(rows, x)) ** 2 - 1.0, a, b, xtol=1e-12)   # |L| = 1 in log omega
    L = L_at(rows, 0.5 * (a + b))
    margin = np.degrees(np.angle(L)) + 180.0
    margin = (margin + 180.0) % 360.0 - 180.0
    margin = np.where(margin == -180.0, 180.0, margin)
    rule = loop.options.conventions.pm_rule
    key = np.abs(margin) if rule == "min_abs" else margin
    order = np.lexsort((key, rows))
    first = order[np.unique(rows[order], return_index=True)[1]]
    low[rows[first]] = margin[first] < pm_deg
    return low


class _Runner:
    """Runs task lists on dask (threaded, in-process) or on a dask.distributed cluster."""

    def __init__(self, scheduler, progress):
        self.client, self.own = None, False
        self.progress = progress
        if scheduler is None:
            return
        try:
            from distributed import Client
        except ImportError as e:               # pragma: no cover - a dependency
            raise ParameterError(f"--scheduler {scheduler!r}: dask.distributed is not installed ({e})")
        if isinstance(scheduler, Client):
            self.client = scheduler
            return
        address = str(scheduler)
        try:
            self.client = Client(address, timeout="2s")
        except (OSError, TimeoutError, ValueError) as e:
            raise ParameterError(f"--scheduler {address!r}: no dask scheduler answers there ({type(e).__name__}: "
                                 f"{str(e).splitlines()[0] if str(e) else 'timed out'}); allowed: the address of "
                                 "a running dask.distributed scheduler, e.g. tcp://127.0.0.1:8786") from None
        self.own = True

    def close(self):
        if self.own and self.client is not None:
            self.client.close()

    def run(self, fn, args_list: list, label: str) -> list:
        from haa_sym.io.progress import progress as progress_bar
        if not args_list:
            return []
        with progress_bar(len(args_list), label, "task", self.progress) as bar:
            if self.client is not None:
                from distributed import as_completed
                futures = [self.client.submit(fn, *a, pure=False) for a in args_list]
                for _ in as_completed(futures):
                    bar.update(1)
                return self.client.gather(futures)
            import dask
            from dask.callbacks import Callback

            class _Bar(Callback):
                def _posttask(self, key, result, dsk, state, worker_id):
                    if str(key[0] if isinstance(key, tuple) else key).startswith("task-"):
                        bar.update(1)
            tasks = [dask.delayed(fn, pure=False)(*a, dask_key_name=f"task-{k}") for k, a in enumerate(args_list)]
            with _Bar():
                return list(dask.compute(*tasks, scheduler="threads", num_workers=2))


def _verify(params, configs, P, D, fine, alphas, best_k, req, options):
    """Lower each point's beta until its phase margin from exactly located crossovers
    (:func:`exact_low_pm`) is at least 30 deg at every leg configuration and the maps'
    requirements still hold; returns the new indices and how many points were lowered."""
    from haa_sym.loop.closed_loop import ClosedLoop
    from haa_sym.analysis.regions import decide_points
    loops = [ClosedLoop(params.with_values(**c), options) for c in configs]
    PP, DD = np.meshgrid(P, D, indexing="ij")
    PP, DD = PP.ravel(), DD.ravel()
    best_k = best_k.copy()
    lowered = set()
    for a in range(alphas.size):
        todo = np.flatnonzero(best_k[a] >= 0)
        checked_maps = False                   # the first round's values passed the maps already
        while todo.size:
            bad = np.zeros(best_k.shape[1], bool)
            for k in np.unique(best_k[a, todo]):
                pts = todo[best_k[a, todo] == k]
                for loop in loops:
                    fail = exact_low_pm(loop, PP[pts], DD[pts], float(fine[k]), float(alphas[a])) \
                        if "pm" in req else np.zeros(pts.size, bool)
                    if checked_maps:
                        st, low, passive = decide_points(loop, PP[pts], DD[pts], float(fine[k]), float(alphas[a]),
                                                         passivity="passive" in req)
                        fail |= ~st | (low if "pm" in req else False) | (~passive if "passive" in req else False)
                    bad[pts[fail]] = True
            todo = np.flatnonzero(bad)
            lowered.update(todo.tolist())
            best_k[a, todo] -= 1                # -1: no beta of the range is left
            todo = todo[best_k[a, todo] >= 0]
            checked_maps = True
    return best_k, len(lowered)


def _free_in_the_air(params: Params) -> Params:
    """The file's plant with the port body's stiffness to ground at 0 (Sec. 3.3: the torque
    bandwidth with the leg free to move in the air); unchanged if the port has none."""
    key = f"K_{params.plant.topology.port}"
    return params.with_values(**{key: 0.0}) if key in params.plant.topology.parameter_keys else params


def schedule(params: Params, P_gain=None, D_gain=None, *, beta_range=(0.1, 8.0), beta_tol: float = 0.02,
             alpha=None, alpha_values=None, requirements=("stable", "pm"), leg=None,
             leg_mode: str = "segment", options: LoopOptions | None = None, scheduler=None,
             progress: bool | None = None, max_per_axis: int = MAX_LEG_POINTS) -> Schedule:
    """The largest robust beta (and alpha) for every impedance of the grid.

    Parameters
    ----------
    params : Params
        The actuator and controller (``P_t0``, ``I_t0``, ``Ts``, ``N_av`` ... from here).
    P_gain, D_gain : array_like, optional
        The impedance grid, Nm/rad and Nms/rad (default log 1..2000 x lin 1..50, 30 x 20).
    beta_range : (float, float)
        Range of the torque-gain scale beta (Eq. 7), 0 < lo < hi.
    beta_tol : float
        Relative step of the beta grid: the stated tolerance of the answer.
    alpha : float, optional
        Velocity compensation (Eq. 6) when not scheduled (default the controller's).
    alpha_values : sequence of float, optional
        Schedule alpha too, from these values: per impedance the largest robust beta over them,
        ties broken by the larger torque bandwidth.
    requirements : sequence of {"stable", "pm", "passive"}
    leg, leg_mode
        The leg range (:func:`haa_sym.analysis.robust.leg_configurations`).
    scheduler : None, str or distributed.Client
        None: dask's threaded scheduler in this process; an address ("tcp://host:port") or a
        Client: that dask.distributed cluster.
    progress : bool or None
        Progress bars on stderr.

    Returns
    -------
    Schedule
    """
    from haa_sym._version import __version__
    from haa_sym.analysis.regions import grid
    P = gain_array("P_gain", grid(DEFAULT_P_GAIN) if P_gain is None else P_gain).ravel()
    D = gain_array("D_gain", grid(DEFAULT_D_GAIN) if D_gain is None else D_gain).ravel()
    for name, arr in (("P_gain", P), ("D_gain", D)):
        if arr.size < 2 or np.any(np.diff(arr) <= 0):
            raise ParameterError(f"{name}: {arr.size} value(s); allowed: at least 2, strictly increasing")
    if P[0] <= 0:
        raise ParameterError(f"P_gain starts at {P[0]:g}; allowed: P_gain > 0 (the schedule interpolates in log P_gain)")
    req = _check_requirements(requirements)
    fine, coarse = beta_grid(beta_range, beta_tol)
    ctrl = params.controller
    if alpha_values is None:
        alphas = np.array([ctrl.alpha if alpha is None else float(alpha)])
    else:
        alphas = gain_array("alpha_values", alpha_values).ravel()
        if alphas.size == 0:
            raise ParameterError("alpha_values is empty; allowed: at least one value >= 0")
    ends = leg_ends(params, leg)
    leg_configurations(params, 2, leg=leg, leg_mode=leg_mode)        # checks the range now
    options = options or LoopOptions()
    runner = _Runner(scheduler, progress)
    maps: dict = {}                     # (config key, beta index, alpha index) -> (n_P, n_D) bool
    points: dict = {}                   # (config key, beta index, alpha index) -> {flat index: bool}

    def key_of(c):
        return tuple(sorted(c.items()))

    def coarse_maps(configs):
        todo = [(c, k, a) for c in configs for k in coarse for a in range(alphas.size)
                if (key_of(c), k, a) not in maps]
        res = runner.run(_task_map, [(params, c, P, D, float(fine[k]), float(alphas[a]), req, options)
                                     for c, k, a in todo], "schedule: maps")
        for (c, k, a), r in zip(todo, res):
            maps[(key_of(c), k, a)] = np.asarray(r, bool)

    def solve(configs):
        coarse_maps(configs)
        n_pts = P.size * D.size
        best_k = np.full((alphas.size, n_pts), -1)
        for a in range(alphas.size):
            F = np.ones((coarse.size, n_pts), bool)
            for c in configs:
                F &= np.stack([maps[(key_of(c), k, a)].ravel() for k in coarse])
            any_ok = F.any(axis=0)
            top = coarse.size - 1 - np.argmax(F[::-1], axis=0)          # largest feasible coarse
            kc = np.where(any_ok, top, -1)
            best_k[a] = np.where(any_ok, coarse[np.maximum(kc, 0)], -1)
            # fine values inside each point's bracket (coarse[kc], coarse[kc + 1])
            need: dict = {}
            for p in np.flatnonzero(any_ok & (kc < coarse.size - 1)):
                for k in range(coarse[kc[p]] + 1, coarse[kc[p] + 1]):
                    need.setdefault(k, []).append(p)
            todo = []
            for c in configs:
                for k, pts in need.items():
                    done = points.setdefault((key_of(c), k, a), {})
                    missing = [p for p in pts if p not in done]
                    if missing:
                        todo.append((c, k, missing))
            PP, DD = np.meshgrid(P, D, indexing="ij")
            PP, DD = PP.ravel(), DD.ravel()
            res = runner.run(_task_points, [(params, c, PP[m], DD[m], float(fine[k]), float(alphas[a]), req, options)
                                            for c, k, m in todo], "schedule: refine")
            for (c, k, m), r in zip(todo, res):
                points[(key_of(c), k, a)].update(zip(m, np.asarray(r, bool).tolist()))
            for k in sorted(need):
                ok = np.array([all(points[(key_of(c), k, a)][p] for c in configs) for p in need[k]])
                pts = np.array(need[k])
                best_k[a, pts[ok]] = np.maximum(best_k[a, pts[ok]], k)
        return best_k

    try:
        n = 2
        configs = leg_configurations(params, n, leg=leg, leg_mode=leg_mode)
        current = solve(configs)
        history = [(len(configs), int((current.max(axis=0) >= 0).sum()))]
        converged = False
        while 2 * n - 1 <= max_per_axis:
            n = 2 * n - 1
            configs = leg_configurations(params, n, leg=leg, leg_mode=leg_mode)
            nxt = solve(configs)
            history.append((len(configs), int((nxt.max(axis=0) >= 0).sum())))
            same = np.array_equal(nxt, current)
            current = nxt
            if same:
                converged = True
                break
        current, lowered = _verify(params, configs, P, D, fine, alphas, current, req, options)
        # beta = 1 (the file's own torque gains) at the file's alpha, for the comparison
        res = runner.run(_task_map, [(params, c, P, D, 1.0, float(ctrl.alpha if alpha is None else alpha), req,
                                      options) for c in configs], "schedule: beta = 1")
        fixed = np.logical_and.reduce([np.asarray(r, bool) for r in res])
    finally:
        runner.close()

    # per point: the alpha with the largest beta, ties to the larger torque bandwidth
    free = _free_in_the_air(params)
    bw_cache: dict = {}

    def bandwidth(k, a):
        if (k, a) not in bw_cache:
            from haa_sym.analysis.torque import torque_bandwidth
            bw_cache[(k, a)] = torque_bandwidth(free, beta=float(fine[k]), alpha=float(alphas[a]), options=options)
        return bw_cache[(k, a)]
    n_pts = P.size * D.size
    beta_out, alpha_out, bw_out = np.full(n_pts, np.nan), np.full(n_pts, np.nan), np.full(n_pts, np.nan)
    feasible = current.max(axis=0) >= 0
    for p in np.flatnonzero(feasible):
        kmax = current[:, p].max()
        cand = [a for a in range(alphas.size) if current[a, p] == kmax]
        a = max(cand, key=lambda a: (bandwidth(kmax, a), -a)) if len(cand) > 1 else cand[0]
        beta_out[p], alpha_out[p], bw_out[p] = fine[kmax], alphas[a], bandwidth(kmax, a)
    shape = (P.size, D.size)
    from haa_sym.analysis.torque import torque_bandwidth
    bw_1 = torque_bandwidth(free, beta=1.0, alpha=float(ctrl.alpha if alpha is None else alpha), options=options)
    meta = {"actuator": str((getattr(params, "about", None) or {}).get("name", params.source)),
            "source": str(params.source), "requirements": list(req), "beta_range": [float(fine[0]), float(fine[-1])],
            "beta_tol": float(beta_tol), "beta_grid": int(fine.size), "coarse_values": int(coarse.size),
            "alpha_scheduled": alpha_values is not None, "alpha_values": alphas.tolist(),
            "leg": list(ends), "leg_mode": leg_mode, "haa_sym": __version__,
            "scheduler": "dask threads (in-process)" if scheduler is None else "dask.distributed",
            "torque_bandwidth_beta_1_rad_s": bw_1, "lowered_by_exact_margins": lowered,
            "options": options.resolved(params.plant.topology).to_dict()}
    return Schedule(P, D, beta_out.reshape(shape), alpha_out.reshape(shape), bw_out.reshape(shape),
                    feasible.reshape(shape), len(configs), converged, history, meta,
                    fixed.reshape(shape))
