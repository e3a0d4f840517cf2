"""Nonlinear gain maps: each gain point classed from a simulation with the limits (issue 19;
docs/simulate.md, "Nonlinear maps").

Every point of a P_gain x D_gain grid is simulated (:func:`haa_sym.analysis.simulate.simulate_batch`:
the same experiment, limits and duration at each point) and classed by the rules below, in this
order; the first that applies decides. The linear model decides what it can decide exactly
(the certified stability test of the linear loop, :meth:`ClosedLoop.stability`); the simulation
decides what only it can tell (a limit cycle and its amplitude, saturation on every step).
The rules are :func:`haa_sym.analysis.oscillation.classify`'s, the one verdict of a run that
``haa-sym simulate`` prints too (docs/simulate.md, "The verdict of a run"): diverged, the linear
regime (converging / growing), forced response (the chirp), limit cycle, saturating, growing,
converging, undecided.

Points classed ``growing`` or ``undecided`` are run again, ``EXTEND_FACTOR``
times longer each time, up to ``max_duration``: their class is that of their longest run.

Runs are independent tasks (:class:`haa_sym.io.tasks.TaskRunner`): in-process one after the other
(:data:`IN_PROCESS_THREADS`), or on a dask.distributed cluster (``--scheduler local:N`` or an
address) whose workers build the loop and the simulation setup from the parameters and options
themselves, once per process (:func:`_warm`). There is no barrier between the first runs and the
longer ones: a task's points still growing or undecided are submitted again as soon as its result
arrives (:meth:`TaskRunner.stream`), ahead of the first runs still waiting. Tasks are sized to the
workers (:func:`task_size`). Each point's runs depend on that point alone, so the classes, and every
array of the map, are the same bytes whatever the order, the task size or the scheduler.

A longer run continues the point's last run from the state where it stopped
(``continue_runs``, default True; :class:`haa_sym.analysis.simulate.Continuation`): the plant's
and the controller's state, the drive's delay line and the friction integrator's level come out of
the C loop and go back in, the inputs are the longer run's from that sample on, so the run takes
exactly the steps of one run from t = 0 (the same bits). Two choices make that so. The friction
integrator's error bound is relative to each state's peak in the run without friction over the
first run's length (``scale_duration``), for every length of the point (a run's own length before
2026-11-26: a longer run raised it). The verdict reads the last half of the whole run, which with
EXTEND_FACTOR = 3 lies in the continuation except after a length capped at ``max_duration``
(9 -> 10 s reads from 5 s): each run returns, with its state, the outputs from the first sample
the next length's verdict reads (:func:`haa_sym.analysis.simulate.keep_from`; 9 -> 10 s: 4,001
samples) and of the samples before only their saturation flags and the torque's peak. The chirp
(its sweep rate set by the run's length) is run again from t = 0
(:func:`haa_sym.analysis.simulate.continuable`); torque noise with jitter continues since
2026-11-26 (each draws from its own seeded stream, :data:`haa_sym.analysis.simulate.JITTER_STREAM`).
HyQ with 24 V and 0.02 Nm rotor friction, 60 x 40 points: 162 of its 2,400 points run again,
3.78 M simulated samples instead of 5.74 M, the same classes (docs/simulate.md).

Example
-------
>>> from haa_sym import ClosedLoop, load_params
>>> from haa_sym.model.limits import Limits
>>> m = nonlinear_map(ClosedLoop(load_params()), [100.0, 20000.0], [5.0],
...                   limits=Limits(V_max=24.0), progress=False)           # doctest: +SKIP
>>> m.class_names                                                           # doctest: +SKIP
"""
from __future__ import annotations

import pickle
from dataclasses import dataclass, field

import numpy as np

from haa_sym.analysis.oscillation import SATURATING_FRACTION, VERDICTS, classify
from haa_sym.analysis.simulate import (DEFAULT_RTOL, FORCED_EXPERIMENTS, _Setup, batch_setup, continuable,
                                       limits_act_every_step, simulate_batch)
from haa_sym.errors import ParameterError
from haa_sym.io.formats import save_npz
from haa_sym.io.tasks import TaskRunner, scheduler_kind
from haa_sym.loop import ClosedLoop, loop_first
from haa_sym.model.limits import Limits
from haa_sym.model.params import gain_array

__all__ = ["NonlinearMap", "nonlinear_map", "classify", "CLASSES", "DEFAULT_DURATION", "DEFAULT_MAX_DURATION",
           "EXTEND_FACTOR", "SATURATING_FRACTION", "POINTS_PER_TASK", "task_size"]

#: The classes, by their code in ``NonlinearMap.nonlinear_class``: the verdicts of a run.
CLASSES = VERDICTS
#: Seconds simulated per point: the HyQ limit cycle (beta 3, P 20000, D 10, 24 V) settles within
#: 0.6 s; the linear regime's decision does not depend on the run's length.
DEFAULT_DURATION = 1.0
#: The longest run (s) of a point still growing or undecided: such points are run again,
#: EXTEND_FACTOR times longer each time, until they are something else or this length is reached
#: (HyQ at beta 3 with 24 V: the growing points fall from 120 at 1 s to 27 at 10 s).
DEFAULT_MAX_DURATION = 10.0
EXTEND_FACTOR = 3.0
#: Most gain points per first-run task (a task's overhead on dask is about a millisecond; a
#: point at 1 s and 1 ms about a millisecond too).
POINTS_PER_TASK = 250
#: First-run tasks per worker (the automatic task size, :func:`task_size`): with 8, the last
#: task to finish adds at most about 1/8 of a worker's share to the time.
CHUNKS_PER_WORKER = 8
#: Fewest gain points per automatic task (tens of milliseconds of work against a task's
#: millisecond of overhead).
MIN_POINTS_PER_TASK = 8
#: Threads of an in-process map: one. Most of a point's time is Python holding the GIL (the
#: controller, the trace classifier; the C loop is about a quarter), and two dask threads were
#: slower than one in benchmarks/bench_nonlinear_map.py (7.5 s vs 4.3 s on 100 x 50, load 4.5).
IN_PROCESS_THREADS = 1


@dataclass(frozen=True)
class NonlinearMap:
    """The classes of a P_gain x D_gain grid.

    Attributes
    ----------
    P_gain, D_gain : ndarray
        The axes, Nm/rad (n_P) and Nms/rad (n_D).
    nonlinear_class : ndarray of int8, (n_P, n_D)
        Index into :data:`CLASSES`.
    linear_stable : ndarray of bool, (n_P, n_D)
        The linear loop's certified stability decision.
    cycle_amplitude, cycle_frequency : ndarray, (n_P, n_D)
        The torque signal's sustained oscillation (Nm, half peak-to-peak; Hz); NaN where none.
    saturation_fraction : ndarray, (n_P, n_D)
        Fraction of the last half's samples in saturation.
    run_duration : ndarray, (n_P, n_D)
        Seconds of the run that decided the point (longer where it was run again).
    meta : dict
        ``loop.provenance()`` with the experiment, the limits, the rules' options and the counts.
    """

    P_gain: np.ndarray
    D_gain: np.ndarray
    nonlinear_class: np.ndarray
    linear_stable: np.ndarray
    cycle_amplitude: np.ndarray
    cycle_frequency: np.ndarray
    saturation_fraction: np.ndarray
    run_duration: np.ndarray
    meta: dict = field(repr=False)

    @property
    def class_names(self) -> np.ndarray:
        """The class of every point by name, (n_P, n_D)."""
        return np.asarray(CLASSES)[self.nonlinear_class]

    def counts(self) -> dict[str, int]:
        """Points per class."""
        return {c: int((self.nonlinear_class == k).sum()) for k, c in enumerate(CLASSES)}

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in ("P_gain", "D_gain", "nonlinear_class", "linear_stable",
                                              "cycle_amplitude", "cycle_frequency", "saturation_fraction",
                                              "run_duration")}

    def save(self, path, tx=None, field: str | None = None):
        """Write an ``.npz`` (arrays + ``meta``; :func:`haa_sym.io.formats.save_npz`)."""
        return save_npz(path, self.arrays(), self.meta, tx, field)


#: Loops and simulation setups a process keeps for its next tasks (a dask worker builds the loop
#: and the setup of each run length once, not per task), keyed by the task's plain inputs pickled;
#: the least recently used dropped beyond WARM_ENTRIES.
_LOOPS: dict = {}
_SETUPS: dict = {}
WARM_ENTRIES = 8


def _recent(cache: dict, key, make):
    value = cache.pop(key) if key in cache else make()
    cache[key] = value
    while len(cache) > WARM_ENTRIES:
        cache.pop(next(iter(cache)))
    return value


def _warm(params, options, backend, limits, experiment, amplitude, duration, seed, rtol, scale_duration=None):
    """(loop, setup) of these inputs: built at this process's first task of them, then reused."""
    lk = pickle.dumps((params, options, backend))
    loop = _recent(_LOOPS, lk, lambda: ClosedLoop(params, options, basis=False, backend=backend))
    sk = (lk, pickle.dumps((limits, experiment, amplitude, duration, seed, rtol, scale_duration)))
    setup = _recent(_SETUPS, sk, lambda: batch_setup(loop, limits, experiment, amplitude, duration, seed, rtol,
                                                     scale_duration))
    return loop, setup


def _task(params, options, backend, limits, P, D, experiment, amplitude, duration, seed, rtol, stable,
          scale_duration=None, start=None, continue_to=None):
    """One task of plain data (what a dask worker runs); the loop and the setup come from the
    process's :func:`_warm` cache. ``start``, ``continue_to``: the runs continue the points'
    shorter ones and return the state a run of ``continue_to`` s continues
    (:func:`haa_sym.analysis.simulate.simulate_batch`)."""
    loop, setup = _warm(params, options, backend, limits, experiment, amplitude, duration, seed, rtol,
                        scale_duration)
    b = simulate_batch(loop, P, D, limits=limits, experiment=experiment, amplitude=amplitude,
                       duration=duration, seed=seed, rtol=rtol, linear_stable=stable, setup=setup,
                       start=start, continue_to=continue_to)
    return b.oscillation, b.tail_saturation, b.cycle_amplitude, b.cycle_frequency, b.continuations


def task_size(points: int, workers: int, given: int | None = None) -> int:
    """Gain points per first-run task: ``given``, else enough tasks for
    :data:`CHUNKS_PER_WORKER` per worker (the slowest task then decides little of the time),
    at most :data:`POINTS_PER_TASK` and at least :data:`MIN_POINTS_PER_TASK` (a task's
    overhead stays below a few percent)."""
    if given is not None:
        return given
    want = -(-points // (CHUNKS_PER_WORKER * max(1, workers)))
    return int(min(POINTS_PER_TASK, max(MIN_POINTS_PER_TASK, want)))


@loop_first
def nonlinear_map(loop, P_gain, D_gain, *, limits: Limits | None = None, experiment: str = "disturbance-step",
                  amplitude: float | None = None, duration: float = DEFAULT_DURATION,
                  max_duration: float | None = None, seed: int = 0,
                  rtol: float = DEFAULT_RTOL, saturating_fraction: float = SATURATING_FRACTION,
                  scheduler=None, progress: bool | None = None,
                  points_per_task: int | None = None, continue_runs: bool = True) -> NonlinearMap:
    """Class every point of the P_gain x D_gain grid from a simulation with the limits.

    Parameters
    ----------
    loop : ClosedLoop
        The linear loop (its stability evaluator decides the linear regime); its parameters and
        options are what the tasks simulate.
    P_gain, D_gain : array_like
        The grid's axes (Nm/rad, Nms/rad), finite.
    limits : Limits, optional
        Default the parameter file's ``[limits]``; a file without one is refused (a map of the
        linear loop is ``haa-sym regions``).
    experiment, amplitude, duration, seed, rtol
        Of every run (:func:`haa_sym.analysis.simulate.simulate`); ``duration`` in s, default
        :data:`DEFAULT_DURATION`.
    max_duration : float, optional
        Points classed growing (not overflowed) or undecided are run again, :data:`EXTEND_FACTOR`
        times longer each time, up to this many seconds; default ``max(DEFAULT_MAX_DURATION,
        duration)``; ``max_duration = duration`` runs every point once.
    saturating_fraction : float
        The saturating rule's threshold (:func:`classify`), in (0, 1]; default :data:`SATURATING_FRACTION`.
    scheduler : None, str or distributed.Client
        None: in-process; an address or a Client: that dask.distributed cluster.
    progress : bool or None
        The progress bar (:func:`haa_sym.io.progress.progress`).
    points_per_task : int, optional
        Gain points per first-run task (>= 1); default: sized to the workers
        (:func:`task_size`). The classes do not depend on it.
    continue_runs : bool
        Default True: a longer run continues the point's last run from the state where it
        stopped (:func:`haa_sym.analysis.simulate.continuable` experiments and limits; else from
        t = 0); False: from t = 0. The same numbers either way (the friction integrator's error
        scale is the first run's in both), False costing the samples of every shorter run again.

    Returns
    -------
    NonlinearMap
    """
    P = gain_array("P_gain", P_gain).ravel()
    D = gain_array("D_gain", D_gain).ravel()
    if P.size == 0 or D.size == 0:
        raise ParameterError("P_gain, D_gain: an empty axis; allowed: at least one value each")
    if limits is None:
        if not loop.params.limits.active:
            raise ParameterError("limits: the parameter file has no [limits] section; allowed: a [limits] "
                                 "section (V_max, I_max, Fc_*, ...; docs/simulate.md) or limits given")
        limits = loop.params.limits
    if isinstance(saturating_fraction, bool) or not isinstance(saturating_fraction, (int, float)) \
            or not 0 < saturating_fraction <= 1:
        raise ParameterError(f"saturating_fraction = {saturating_fraction!r}; allowed: a number in (0, 1]")
    if points_per_task is not None and (isinstance(points_per_task, bool) or not isinstance(points_per_task, int)
                                        or points_per_task < 1):
        raise ParameterError(f"points_per_task = {points_per_task!r}; allowed: an integer >= 1")
    # every argument checked here, before any task runs (a worker's error would not be one line)
    setup = _Setup(loop, limits, experiment, amplitude, duration, seed, None)
    if isinstance(rtol, bool) or not isinstance(rtol, (int, float)) or not 0 < rtol < 0.1:
        raise ParameterError(f"rtol = {rtol!r}; allowed: a number in (0, 0.1)")
    if max_duration is None:
        max_duration = max(DEFAULT_MAX_DURATION, setup.duration)
    if isinstance(max_duration, bool) or not isinstance(max_duration, (int, float)) \
            or not setup.duration <= max_duration < float("inf"):
        raise ParameterError(f"max_duration = {max_duration!r} s; allowed: a finite number >= duration "
                             f"({setup.duration:g} s)")
    _Setup(loop, limits, experiment, amplitude, max_duration, seed, None)     # its sample count checked
    PP, DD = (a.ravel() for a in np.meshgrid(P, D, indexing="ij"))
    stable = np.asarray(loop.stability(PP, DD).stable, bool)
    always = limits_act_every_step(limits)
    forced = experiment in FORCED_EXPERIMENTS
    # a longer run continues the point's last one where its inputs allow (not the chirp:
    # simulate.continuable), with the first run's friction error scale
    if not isinstance(continue_runs, bool):
        raise ParameterError(f"continue_runs = {continue_runs!r}; allowed: True or False")
    scale_s = setup.duration if continuable(setup) else None
    cont = continue_runs and scale_s is not None

    n_pts = PP.size
    kind = np.empty(n_pts, dtype=object)    # a later run's kind may be a longer string
    ts, amp, freq = np.empty(n_pts), np.empty(n_pts), np.empty(n_pts)
    cls = np.empty(n_pts, dtype=np.int8)
    run_s = np.full(n_pts, setup.duration)
    depth = np.zeros(n_pts, int)            # how many times a point was run again
    simulated = [0]                         # controller steps over every run
    again = (CLASSES.index("growing"), CLASSES.index("undecided"))
    state = np.full(n_pts, None, dtype=object)      # per point the Continuation of its last run

    def samples(seconds):
        return int(np.ceil(seconds / setup.Ts - 1e-9)) + 1

    def longer_than(seconds):
        # by samples: 3 x 0.15 s is 0.44999... s, the samples of max_duration = 0.45 s
        return min(seconds * EXTEND_FACTOR, max_duration) if samples(seconds) < samples(max_duration) else None

    def task(idx, seconds, start=None):
        simulated[0] += idx.size * (samples(seconds) - (0 if start is None else start[0].k))
        return (loop.params, loop.options, loop.backend, limits, PP[idx], DD[idx], experiment, setup.amplitude,
                seconds, seed, rtol, stable[idx].astype(float), scale_s, start,
                longer_than(seconds) if cont else None)

    def chunks(idx, per):
        # strided, not contiguous: a point's cost grows with its gains (the friction integrator's
        # substeps), so contiguous chunks of the P-major grid differ up to tenfold in time, and
        # the slowest would decide the map's end on many workers
        n = -(-idx.size // per)
        return [idx[k::n] for k in range(n)]

    # No barrier between the first runs and the longer ones: a task's points still growing or
    # undecided are run again as soon as its result arrives, while the other tasks run (each
    # point's run depends on that point alone, so the classes do not depend on the order).
    # Longer runs cost more per point: their tasks hold proportionally fewer points, and a
    # cluster starts them first (priority = the round), so that the chains of reruns, the
    # critical path, start early.
    runner = TaskRunner(scheduler, progress, threads=IN_PROCESS_THREADS)
    try:
        per = task_size(n_pts, runner.workers(), points_per_task)
        first = [task(c, setup.duration) for c in chunks(np.arange(n_pts), per)]
        where = {id(a): c for a, c in zip(first, chunks(np.arange(n_pts), per))}
        seconds_of = {id(a): setup.duration for a in first}

        def then(a, result):
            idx, seconds = where.pop(id(a)), seconds_of.pop(id(a))
            k2, t2, a2, f2, c2 = result
            kind[idx], ts[idx], amp[idx], freq[idx] = k2, t2, a2, f2
            run_s[idx] = seconds
            cls[idx] = classify(kind[idx], ts[idx], stable[idx], always, saturating_fraction, forced)
            if longer_than(seconds) is None:
                return []
            rerun = np.isin(cls[idx], again)
            longer = idx[rerun]
            if not longer.size:
                return []
            if c2 is not None:                          # kept for the points run again only
                state[longer] = [c for c, r in zip(c2, rerun) if r]
            nxt = longer_than(seconds)
            depth[longer] += 1
            out = []
            # sized by the run's length, not its new samples: a continued run's task then holds
            # less work than a first-run task (2/3 to 1/10 of it), so that the chain of a point's
            # reruns, the critical path on many workers, is short
            for c in chunks(longer, max(1, int(round(per * setup.duration / nxt)))):
                b = task(c, nxt, list(state[c]) if cont else None)
                state[c] = None
                where[id(b)], seconds_of[id(b)] = c, nxt
                out.append((b, int(depth[c[0]])))
            return out
        runner.stream(_task, first, then, "regions --nonlinear: runs", "task")
    finally:
        runner.close()
    rounds = int(depth.max()) if n_pts else 0
    shape = (P.size, D.size)
    meta = loop.provenance(
        analysis="nonlinear_map", classes=list(CLASSES), experiment=experiment, amplitude=setup.amplitude,
        duration=setup.duration, max_duration=max_duration, extend_factor=EXTEND_FACTOR, longer_rounds=rounds,
        seed=seed, rtol=rtol, limits=limits.active, limits_act_every_step=always,
        saturating_fraction=saturating_fraction, samples_per_run=setup.n,
        samples_simulated=simulated[0], longer_runs_continue=cont, friction_scale_duration=scale_s,
        scheduler="in-process" if scheduler is None else scheduler_kind(scheduler),
        rules="docs/simulate.md, Nonlinear maps", P_gain_unit="Nm/rad", D_gain_unit="Nms/rad",
        cycle_amplitude_unit="Nm", cycle_frequency_unit="Hz")
    m = NonlinearMap(P, D, cls.reshape(shape), stable.reshape(shape), amp.reshape(shape), freq.reshape(shape),
                     ts.reshape(shape), run_s.reshape(shape), meta)
    meta["counts"] = m.counts()
    return m

