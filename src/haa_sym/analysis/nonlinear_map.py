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

Runs are independent tasks (``points_per_task`` points each) (:class:`haa_sym.io.tasks.TaskRunner`):
in-process one after the other (:data:`IN_PROCESS_THREADS`), or on a dask.distributed cluster whose workers build the loop from the parameters and options
themselves. The classes are the same either way.

Example
-------
>>> from haa_sym import ClosedLoop, load_params
>>> from haa_sym.model.limits import Limits
>>> m = nonlinear_map(ClosedLoop(load_params()), [100.0, 20000.0], [5.0],
...                   limits=Limits(V_max=24.0), progress=False)           # doctest: +SKIP
>>> m.class_names                                                           # doctest: +SKIP
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from haa_sym.analysis.oscillation import SATURATING_FRACTION, VERDICTS, classify
from haa_sym.analysis.simulate import DEFAULT_RTOL, FORCED_EXPERIMENTS, _Setup, limits_act_every_step, simulate_batch
from haa_sym.errors import ParameterError
from haa_sym.io.formats import save_npz
from haa_sym.io.tasks import TaskRunner
from haa_sym.loop import ClosedLoop, loop_first
from haa_sym.model.limits import Limits
from haa_sym.model.params import gain_array

__all__ = ["NonlinearMap", "nonlinear_map", "classify", "CLASSES", "DEFAULT_DURATION", "DEFAULT_MAX_DURATION",
           "EXTEND_FACTOR", "SATURATING_FRACTION", "POINTS_PER_TASK"]

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
#: Gain points per task (a task's overhead on dask is about a millisecond; a point at 1 s and
#: 1 ms about a millisecond too).
POINTS_PER_TASK = 250
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


def _task(params, options, backend, limits, P, D, experiment, amplitude, duration, seed, rtol, stable):
    """One task of plain data (what a dask worker runs): the loop is built here."""
    loop = ClosedLoop(params, options, basis=False, backend=backend)
    b = simulate_batch(loop, P, D, limits=limits, experiment=experiment, amplitude=amplitude,
                       duration=duration, seed=seed, rtol=rtol, linear_stable=stable)
    return b.oscillation, b.tail_saturation, b.cycle_amplitude, b.cycle_frequency


@loop_first
def nonlinear_map(loop, P_gain, D_gain, *, limits: Limits | None = None, experiment: str = "disturbance-step",
                  amplitude: float | None = None, duration: float = DEFAULT_DURATION,
                  max_duration: float | None = None, seed: int = 0,
                  rtol: float = DEFAULT_RTOL, saturating_fraction: float = SATURATING_FRACTION,
                  scheduler=None, progress: bool | None = None,
                  points_per_task: int = POINTS_PER_TASK) -> NonlinearMap:
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
    points_per_task : int
        Gain points per task (>= 1).

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
    if isinstance(points_per_task, bool) or not isinstance(points_per_task, int) or points_per_task < 1:
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
    runner = TaskRunner(scheduler, progress, threads=IN_PROCESS_THREADS)

    simulated = [0]                     # controller steps over every run

    def simulate_points(idx, seconds):
        simulated[0] += idx.size * (int(np.ceil(seconds / setup.Ts - 1e-9)) + 1)
        chunks = [idx[a:a + points_per_task] for a in range(0, idx.size, points_per_task)]
        res = runner.run(_task, [(loop.params, loop.options, loop.backend, limits, PP[c], DD[c], experiment,
                                  setup.amplitude, seconds, seed, rtol, stable[c].astype(float)) for c in chunks],
                         f"regions --nonlinear: {seconds:g} s runs")
        return [np.concatenate([r[i] for r in res]) for i in range(4)]
    try:
        everything = np.arange(PP.size)
        kind, ts, amp, freq = simulate_points(everything, setup.duration)
        kind = kind.astype(object)          # a later run's kind may be a longer string
        cls = classify(kind, ts, stable, always, saturating_fraction, forced)
        run_s = np.full(PP.size, setup.duration)
        seconds, rounds = setup.duration, 0
        while seconds < max_duration:
            again = np.flatnonzero((cls == CLASSES.index("growing")) | (cls == CLASSES.index("undecided")))
            if not again.size:
                break
            seconds = min(seconds * EXTEND_FACTOR, max_duration)
            rounds += 1
            k2, t2, a2, f2 = simulate_points(again, seconds)
            kind[again], ts[again], amp[again], freq[again] = k2, t2, a2, f2
            run_s[again] = seconds
            cls[again] = classify(kind[again], ts[again], stable[again], always, saturating_fraction, forced)
    finally:
        runner.close()
    shape = (P.size, D.size)
    meta = loop.provenance(
        analysis="nonlinear_map", classes=list(CLASSES), experiment=experiment, amplitude=setup.amplitude,
        duration=setup.duration, max_duration=max_duration, extend_factor=EXTEND_FACTOR, longer_rounds=rounds,
        seed=seed, rtol=rtol, limits=limits.active, limits_act_every_step=always,
        saturating_fraction=saturating_fraction, samples_per_run=setup.n,
        samples_simulated=simulated[0],
        scheduler="in-process" if scheduler is None else "dask.distributed",
        rules="docs/simulate.md, Nonlinear maps", P_gain_unit="Nm/rad", D_gain_unit="Nms/rad",
        cycle_amplitude_unit="Nm", cycle_frequency_unit="Hz")
    m = NonlinearMap(P, D, cls.reshape(shape), stable.reshape(shape), amp.reshape(shape), freq.reshape(shape),
                     ts.reshape(shape), run_s.reshape(shape), meta)
    meta["counts"] = m.counts()
    return m

