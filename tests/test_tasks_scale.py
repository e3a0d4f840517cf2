"""The schedule's work on the task runner, in cluster-sized tasks (issue 27, items 1 and 2): the
point check and the torque bandwidths run as tasks (not in the command's own thread, where they
were the serial part on a cluster), a cluster's ``run`` groups small calls into a few tasks per
worker, and the task graph is recorded for benchmarks/bench_scale.py."""
import contextlib
import threading
import time

import pytest

import haa_sym.design.schedule as sch
from haa_sym import ClosedLoop, load_params
from haa_sym.io import tasks
from haa_sym.io.tasks import TaskRunner


#: What the runner's cluster code drives: a dask cluster (``--scheduler ADDRESS``, here in-process)
#: and the local worker processes of ``--scheduler local:N`` (:class:`haa_sym.io.pool.LocalPool`).
BACKENDS = ["dask", "pool"]


@contextlib.contextmanager
def traced_cluster(n_workers=2, backend="dask"):
    """(client, trace) of ``n_workers`` one-thread workers (an in-process dask cluster, or a
    LocalPool), with every task submitted in the block recorded in ``trace``
    (:data:`haa_sym.io.tasks.TRACE`)."""
    with contextlib.ExitStack() as stack:
        if backend == "pool":
            from haa_sym.io.pool import LocalPool
            client = stack.enter_context(LocalPool(n_workers))
        else:
            distributed = pytest.importorskip("distributed")
            # the scheduler's HTTP server (started even without a dashboard) on a free port, not
            # 8787, which a test beside this one may hold (dask warned)
            cl = stack.enter_context(distributed.LocalCluster(
                n_workers=n_workers, threads_per_worker=1, processes=False, dashboard_address=None,
                scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"}))
            client = stack.enter_context(distributed.Client(cl))
        trace = tasks.TRACE = []
        try:
            yield client, trace
        finally:
            tasks.TRACE = None


def test_the_point_check_and_the_bandwidths_run_as_tasks(monkeypatch):
    threads = {"decide": set(), "bandwidth": set()}
    decide, bandwidth = sch.decide_points, sch.torque_bandwidth

    def decide_where(*a, **kw):
        threads["decide"].add(threading.current_thread() is threading.main_thread())
        return decide(*a, **kw)

    def bandwidth_where(*a, **kw):
        threads["bandwidth"].add(threading.current_thread() is threading.main_thread())
        return bandwidth(*a, **kw)
    monkeypatch.setattr(sch, "decide_points", decide_where)
    monkeypatch.setattr(sch, "torque_bandwidth", bandwidth_where)
    s = sch.schedule(ClosedLoop(load_params()), [5.0, 300.0], [1.0, 20.0], beta_range=(0.5, 4.0), beta_tol=0.25,
                     progress=False)
    assert s.feasible.any()
    # every call on the runner's threads, none in the command's own (before: _verify and the
    # bandwidths ran in the main thread, one after the other)
    assert threads == {"decide": {False}, "bandwidth": {False}}


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_cluster_run_groups_small_calls_and_keeps_their_order(backend):
    with traced_cluster(backend=backend) as (client, trace):
        r = TaskRunner(client, False)
        out = r.run(pow, [(k, 2) for k in range(100)], "squares")
        again = r.run(pow, [(k, 3) for k in range(5)], "cubes")
    assert out == [k ** 2 for k in range(100)] and again == [k ** 3 for k in range(5)]
    first = tasks.CHUNKS_PER_WORKER * 2
    assert len(trace) == first + 5                  # 100 calls in 8 tasks; 5 calls in 5
    # the second run waited for every task of the first (a barrier), the first for nothing
    assert all(t["after"] == [] for t in trace[:first])
    assert all(sorted(t["after"]) == sorted(x["key"] for x in trace[:first]) for t in trace[first:])


@pytest.mark.parametrize("backend", BACKENDS)
def test_stream_records_which_task_asked_for_which(backend):
    seen = []
    with traced_cluster(1, backend) as (client, trace):
        r = TaskRunner(client, False)
        r.stream(pow, [(2, 1), (3, 1)], lambda a, res: (seen.append(res) or [((res, 2), 1)] if a[1] == 1 else []),
                 "powers")
    assert sorted(seen) == [2, 3] and len(trace) == 4
    firsts = {t["key"] for t in trace[:2]}
    assert all(t["after"] == [] for t in trace[:2])
    assert all(len(t["after"]) == 1 and t["after"][0] in firsts for t in trace[2:])


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_robust_region_maps_each_configuration_as_a_task_once(backend):
    # issue 27, item 2: regions --robust on the task runner; the doubling (2, 3, ... configurations)
    # maps only the configurations it has not mapped yet, and the result is the in-process one
    from haa_sym.analysis.robust import robust_region
    loop = ClosedLoop(load_params())
    P, D = [5.0, 50.0, 300.0, 2000.0], [1.0, 10.0, 40.0]
    local = robust_region(loop, P, D)
    with traced_cluster(backend=backend) as (client, trace):
        remote = robust_region(loop, P, D, scheduler=client)
    assert remote.feasible.tobytes() == local.feasible.tobytes() and remote.history == local.history
    assert 0 < remote.feasible.sum() < remote.feasible.size
    # one task per configuration: the ends, then one midpoint per doubling
    assert len(trace) == remote.n_configurations == local.n_configurations


@pytest.mark.parametrize("backend", BACKENDS)
def test_start_submits_without_a_barrier_and_collects_in_order(backend):
    with traced_cluster(backend=backend) as (client, trace):
        r = TaskRunner(client, False)
        first = r.run(pow, [(k, 2) for k in range(3)], "squares")
        later = r.start(pow, [(k, 3) for k in range(20)], "cubes")
        then = r.run(pow, [(k, 4) for k in range(3)], "fourth powers")
        assert later() == [k ** 3 for k in range(20)] and first == [0, 1, 4] and then == [0, 1, 16]
    squares, cubes = {t["key"] for t in trace[:3]}, {t["key"] for t in trace[3:-3]}
    assert len(cubes) == 2 * tasks.CHUNKS_PER_WORKER
    # the started tasks waited for the run before them; the next run waited for that run too,
    # not for the started ones
    assert all(set(t["after"]) == squares for t in trace[3:])
    # in-process, the calls run when their results are asked for
    calls = []
    r = TaskRunner(None, False)
    later = r.start(lambda x: calls.append(x) or x, [(1,), (2,)], "later")
    assert calls == []
    assert later() == [1, 2] and sorted(calls) == [1, 2]


def _stamp(tag, seconds):
    time.sleep(seconds)
    return tag, time.monotonic()


@pytest.mark.parametrize("backend", BACKENDS)
def test_background_tasks_give_way_to_every_later_task_list(backend):
    """start(background=True): the later lists' tasks go first (they would otherwise wait behind
    every started call), the started calls run in what idle time is left, one call a task."""
    with traced_cluster(1, backend) as (client, trace):
        r = TaskRunner(client, False)
        later = r.start(_stamp, [("background", 0.05)] * 10, "background", background=True)
        first = r.run(_stamp, [("list", 0.01)] * 4, "a later task list")
        done = max(t for _, t in first)
        got = later()
        assert [tag for tag, _ in got] == ["background"] * 10
        # at most the calls the worker had begun or been given (dask gives a one-thread worker
        # two tasks at a time, the pool one) before the later list arrived; in submission
        # order, all ten
        assert sum(t < done for _, t in got) <= 2
        assert len(trace) == 10 + 4
        # the same without background: the later list waits behind the started calls
        later = r.start(_stamp, [("started", 0.02)] * 10, "started")
        first = r.run(_stamp, [("list", 0.01)] * 4, "a later task list")
        assert sum(t < max(t for _, t in first) for _, t in later()) >= 8


def _depth(trace) -> int:
    """Task lists that waited for one another: the longest chain of the trace, in tasks."""
    depth: dict = {}
    for t in trace:
        depth[t["key"]] = 1 + max((depth[k] for k in t["after"]), default=0)
    return max(depth.values())


GRID = ([5.0, 300.0], [1.0, 20.0, 40.0])
SMALL = dict(beta_range=(0.5, 4.0), beta_tol=0.25, cell_subdivisions=2)


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_schedule_waits_for_few_task_lists_and_its_point_check_for_none(backend):
    # issue 27: the first task lists compute what the next leg level and the point check will ask
    # for, and the bandwidths run beside the cell check: maps, refinement and the cell check's
    # passes (on the default grid 5 task lists, where there were 11)
    labels = []
    run = TaskRunner.run

    def counting(self, fn, args_list, label, unit="task"):
        labels.append((label, len(args_list)))
        return run(self, fn, args_list, label, unit)
    with traced_cluster(backend=backend) as (client, trace):
        TaskRunner.run = counting
        try:
            s = sch.schedule(ClosedLoop(load_params()), *GRID, scheduler=client, progress=False, **SMALL)
        finally:
            TaskRunner.run = run
    local = sch.schedule(ClosedLoop(load_params()), *GRID, progress=False, **SMALL)
    assert s.csv_text() == local.csv_text() and s.feasible.any()
    assert [n for label, n in labels if label == "schedule: point check"] == [0]
    passes = s.meta["cell_check_passes"]
    assert passes >= 1
    # the bandwidths (started after the refinement) beside the first pass: no list of their own
    assert _depth(trace) == 2 + passes, (labels, passes)
