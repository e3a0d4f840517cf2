"""Nonlinear maps without barriers (issue 27, item 1): a point still growing or undecided is run
again as soon as its task's result arrives, not after a whole pass; the classes are those of
running every point on its own by the rules (run, and while growing or undecided, run again
EXTEND_FACTOR times longer up to max_duration); warm processes build the loop once; tasks are
sized to the workers."""
import threading
import time

import numpy as np

import haa_sym.analysis.nonlinear_map as nm
from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.nonlinear_map import CLASSES, EXTEND_FACTOR, classify, nonlinear_map, task_size
from haa_sym.analysis.simulate import limits_act_every_step, simulate_batch
from haa_sym.io.tasks import TaskRunner
from haa_sym.model.limits import Limits

LIM = Limits(V_max=24.0)


def _loop():
    return ClosedLoop(load_params().with_values(beta=3.0))


def _one_by_one(loop, P, D, duration, max_duration):
    """The rules point by point, each point's runs one after the other: the reference."""
    out = []
    for p in P:
        for d in D:
            stable = float(loop.stability([p], [d]).stable[0])
            seconds = duration
            while True:
                b = simulate_batch(loop, [p], [d], limits=LIM, duration=seconds, linear_stable=[stable])
                c = int(classify(b.oscillation.astype(object), b.tail_saturation, np.array([bool(stable)]),
                                 limits_act_every_step(LIM), nm.SATURATING_FRACTION, False)[0])
                if CLASSES[c] not in ("growing", "undecided") or seconds >= max_duration:
                    break
                seconds = min(seconds * EXTEND_FACTOR, max_duration)
            out.append((c, seconds, b.cycle_amplitude[0], b.cycle_frequency[0], b.tail_saturation[0]))
    return out


def test_the_classes_are_those_of_each_point_run_on_its_own():
    loop = _loop()
    P, D = [3000.0, 20000.0], [1.0, 10.0]
    m = nonlinear_map(loop, P, D, limits=LIM, duration=0.4, max_duration=1.2, progress=False, points_per_task=3)
    ref = _one_by_one(loop, P, D, 0.4, 1.2)
    assert m.run_duration.max() > 0.4                          # some point was run again
    assert m.nonlinear_class.ravel().tolist() == [r[0] for r in ref]
    assert m.run_duration.ravel().tolist() == [r[1] for r in ref]
    for got, k in ((m.cycle_amplitude, 2), (m.cycle_frequency, 3), (m.saturation_fraction, 4)):
        assert got.ravel().tobytes() == np.array([r[k] for r in ref]).tobytes()


def test_a_growing_point_is_run_again_before_the_other_first_runs(monkeypatch):
    calls = []
    task = nm._task

    def recording(*a):
        calls.append(a[8])                                     # the run's duration
        return task(*a)
    monkeypatch.setattr(nm, "_task", recording)
    # (20000, 10) grows over a 0.4 s run; it is the first point, in the first task of one point
    m = nonlinear_map(_loop(), [20000.0, 300.0, 500.0, 800.0], [10.0], limits=LIM, duration=0.4,
                      progress=False, points_per_task=1)
    assert m.class_names[0, 0] == "limit cycle" and m.run_duration[0, 0] > 0.4
    first_reruns = calls.index(next(c for c in calls if c > 0.4))
    # before: every first run (0.4 s) came before any longer run
    assert first_reruns == 1 and calls[-1] == 0.4, calls


def test_stream_follow_ups_do_not_wait_for_the_slowest_task():
    """Two threads: a follow-up of a fast task runs while a slow first task still runs."""
    r = TaskRunner(None, False, threads=2)
    log, lock = [], threading.Lock()

    def work(name, seconds):
        time.sleep(seconds)
        with lock:
            log.append(name)
        return name

    def then(a, result):
        return [(("follow-up", 0.0), 1)] if result == "fast" else []
    r.stream(work, [("slow", 0.6), ("fast", 0.0)], then, "demo")
    assert log == ["fast", "follow-up", "slow"]
    # one thread: the follow-up (priority 1) before the remaining first tasks
    r1, log[:] = TaskRunner(None, False, threads=1), []
    r1.stream(work, [("fast", 0.0), ("slow", 0.0), ("slow2", 0.0)], then, "demo")
    assert log == ["fast", "follow-up", "slow", "slow2"]


def test_a_process_builds_the_loop_and_the_setup_once(monkeypatch):
    built = []
    real = nm.ClosedLoop

    def counting(*a, **kw):
        built.append(1)
        return real(*a, **kw)
    monkeypatch.setattr(nm, "ClosedLoop", counting)
    nm._LOOPS.clear()
    nm._SETUPS.clear()
    loop = _loop()
    args = (loop.params, loop.options, loop.backend, LIM)
    for P in ([300.0], [500.0], [800.0]):
        nm._task(*args, np.array(P), np.array([5.0]), "disturbance-step", 1.0, 0.2, 0, 1e-6, np.array([1.0]))
    nm._task(*args, np.array([300.0]), np.array([5.0]), "disturbance-step", 1.0, 0.6, 0, 1e-6, np.array([1.0]))
    assert len(built) == 1 and len(nm._SETUPS) == 2


def test_tasks_are_sized_to_the_workers():
    assert task_size(2400, 2) == 150                 # 8 tasks a worker
    assert task_size(2400, 16) == 19
    assert task_size(2400, 1) == nm.POINTS_PER_TASK  # at most 250
    assert task_size(40, 16) == nm.MIN_POINTS_PER_TASK
    assert task_size(2400, 16, 7) == 7               # given: kept
