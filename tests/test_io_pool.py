"""The local worker processes of ``--scheduler local:N`` (:class:`haa_sym.io.pool.LocalPool`):
priorities, a worker's death (the task queued again for the others, given up after
ALLOWED_FAILURES deaths, the worker replaced by a spawned one, the command stopped with one line
when no worker is left), errors that keep their type, and a close that leaves no process and
does not wait for a running task."""
import contextlib
import os
import signal
import subprocess
import sys
import time

import psutil
import pytest

from haa_sym.errors import ParameterError
from haa_sym.io.pool import ALLOWED_FAILURES, REPLACEMENTS_PER_WORKER, LocalPool, WorkerLost
from haa_sym.io.tasks import TaskRunner

from test_io_tasks_local import ENV, _gone, _watch, start_schedule_on_local_2


def _nap(tag, seconds):
    time.sleep(seconds)
    return tag, os.getpid()


def _gate(tag, path):
    """Runs until ``path`` exists: the worker busy for as long as the test needs."""
    while not os.path.exists(path):
        time.sleep(0.002)
    return tag, os.getpid()


def _refuse_to_load():
    raise TypeError("refused")


class _Unloadable:
    """Pickles anywhere, does not load (e.g. an exception whose __init__ wants other arguments;
    not used here: tblib, which distributed installs, changes how exceptions pickle)."""

    def __reduce__(self):
        return _refuse_to_load, ()


def _return_unloadable():
    return _Unloadable()


def _die_if(tag, pid):
    """Kills its worker when run on ``pid``'s process, or when pid is 0 (every time)."""
    if pid in (0, os.getpid()):
        os.kill(os.getpid(), signal.SIGKILL)
    return tag


def _fail(x):
    raise ArithmeticError(f"task {x} failed")


def _unpicklable():
    return lambda: None


def _workers(pool) -> list[int]:
    return sorted(pool.nthreads())


def _until(pool, check, timeout=20.0) -> list[int]:
    """The pool's workers once ``check(workers)`` holds (a replacement is started by the pool's
    thread after it sees the death)."""
    deadline = time.monotonic() + timeout
    while not check(_workers(pool)):
        assert time.monotonic() < deadline, _workers(pool)
        time.sleep(0.01)
    return _workers(pool)


def test_results_in_order_and_errors_keep_their_type():
    with LocalPool(2) as pool:
        assert pool.gather([pool.submit(pow, k, 2) for k in range(50)]) == [k * k for k in range(50)]
        f = pool.submit(_fail, 7)
        with pytest.raises(ArithmeticError, match="task 7 failed"):
            f.result()
        assert f.status == "error"
        f = pool.submit(_unpicklable)
        with pytest.raises(RuntimeError, match="could not be sent back"):
            f.result()
        assert len(_workers(pool)) == 2             # neither error cost a worker
        assert pool.gather([pool.submit(pow, 3, 3)]) == [27]


def test_a_higher_priority_is_given_to_the_next_idle_worker_first(tmp_path):
    gate = tmp_path / "go"
    with LocalPool(1) as pool:
        first = pool.submit(_gate, "first", str(gate))     # the worker held while the rest is queued
        while not first.running():
            time.sleep(0.001)
        low = [pool.submit(_nap, f"low{k}", 0.0) for k in range(4)]
        high = [pool.submit(_nap, f"high{k}", 0.0, priority=1) for k in range(4)]
        gate.touch()
        pool.gather([first, *low, *high])
        order = [r["key"] for r in sorted(pool.get_task_stream(), key=lambda r: r["startstops"][0]["start"])]
    keys = [f.key for f in (first, *high, *low)]
    assert order == keys                            # first (already running), then by priority, then FIFO


def test_cancelled_queued_tasks_never_run(tmp_path):
    gate = tmp_path / "go"
    with LocalPool(1) as pool:
        busy = pool.submit(_gate, "busy", str(gate))
        while not busy.running():
            time.sleep(0.001)
        queued = [pool.submit(_nap, k, 0.0) for k in range(3)]
        pool.cancel(queued)
        gate.touch()
        assert busy.result()[0] == "busy"
        after = pool.submit(_nap, "after", 0.0)
        assert after.result()[0] == "after"
        ran = {r["key"] for r in pool.get_task_stream()}
    assert all(f.cancelled() for f in queued) and ran == {busy.key, after.key}


def test_what_does_not_load_fails_its_task_and_keeps_the_worker():
    with LocalPool(1) as pool:
        pid = _workers(pool)

        def late():                          # defined after the fork: the worker cannot load it
            return 1
        late.__qualname__ = late.__name__ = "_late_fn"
        globals()["_late_fn"] = late
        try:
            with pytest.raises(AttributeError, match="_late_fn"):
                pool.submit(late).result(timeout=30)
        finally:
            del globals()["_late_fn"]
        # a result that pickles in the worker and does not load here
        with pytest.raises(RuntimeError, match="could not be loaded"):
            pool.submit(_return_unloadable).result(timeout=30)
        assert _workers(pool) == pid and pool.gather([pool.submit(pow, 2, 3)]) == [8]


def test_an_idle_worker_that_died_costs_nothing(tmp_path):
    with LocalPool(2) as pool:
        first = _workers(pool)
        victim = first[0]
        os.kill(victim, signal.SIGKILL)
        # submitted at once, before or after the pool sees the death: every task finishes
        got = pool.gather([pool.submit(pow, k, 2) for k in range(40)])
        assert got == [k * k for k in range(40)]
        now = _until(pool, lambda w: victim not in w and len(w) == 2)
        assert first[1] in now                       # replaced, the other kept


def _nap_noting(tag, seconds, path):
    with open(path, "a") as f:
        f.write(f"{os.getpid()}\n")
    return _nap(tag, seconds)


def test_a_killed_worker_costs_its_task_a_rerun_on_the_others(tmp_path):
    note = tmp_path / "pids"
    with LocalPool(3) as pool:
        long = pool.submit(_nap_noting, "long", 1.0, str(note))
        while not note.exists() or not note.read_text().endswith("\n"):
            time.sleep(0.005)
        victim = int(note.read_text())
        others = [pool.submit(_nap, k, 0.05) for k in range(12)]
        os.kill(victim, signal.SIGKILL)
        assert [g[0] for g in pool.gather(others)] == list(range(12))
        tag, pid = long.result(timeout=30)
        assert tag == "long" and pid != victim
        assert victim not in _until(pool, lambda w: len(w) == 3)
    assert [int(p) for p in note.read_text().split()] == [victim, pid]     # run twice, finished once


def test_a_task_that_kills_every_worker_is_given_up_after_the_allowed_failures():
    deaths = ALLOWED_FAILURES + 1                   # dask's rule: given up when they exceed it
    with LocalPool(deaths + 1) as pool:
        bad = pool.submit(_die_if, "bad", 0)
        with pytest.raises(WorkerLost, match=f"died {deaths} times"):
            bad.result(timeout=30)
        assert len(_until(pool, lambda w: len(w) == deaths + 1)) == deaths + 1     # each replaced
        assert pool.gather([pool.submit(pow, 2, 5)]) == [32]     # the rest still runs


@pytest.mark.parametrize("how", ["zygote", "spawned"])
def test_one_worker_survives_its_death_on_a_replacement(how, monkeypatch):
    """local:1: the task that was running when its worker was killed runs again on the
    replacement, with one BLAS thread as the first workers: on Linux a fork of the pool's zygote
    (a child of it, not of the command), elsewhere a spawned process (as without pidfd_open)."""
    from haa_sym.io.tasks import one_blas_thread
    from test_io_tasks_local import _blas_threads
    if how == "spawned":
        monkeypatch.delattr(os, "pidfd_open", raising=False)
    elif not hasattr(os, "pidfd_open"):
        pytest.skip("the zygote needs os.pidfd_open (Linux)")
    with LocalPool(1, initializer=one_blas_thread) as pool:
        (first,) = _workers(pool)
        victim = pool.submit(_die_if, "victim", first)
        assert victim.result(timeout=60) == "victim"
        (second,) = _workers(pool)
        assert second != first
        pid, threads = pool.gather([pool.submit(_blas_threads)])[0]
        assert pid == second and threads == [1]
        parent = psutil.Process(second).parent()
        if how == "zygote":
            assert parent.pid != os.getpid() and parent.parent().pid == os.getpid()
            assert parent.name() == "haa_sym-zygote" and psutil.Process(second).name() == "haa_sym-worker"
            proc, conn = pool._workers[second]
            # the fds it came with are this process's alone (a later exec does not inherit them)
            assert not os.get_inheritable(conn.fileno()) and not os.get_inheritable(proc.sentinel)
        else:
            assert parent.pid == os.getpid()
    assert _gone({first, second} | ({parent.pid} if how == "zygote" else set())) == []


def test_replacements_end_when_every_worker_they_get_is_killed():
    """A machine that kills each worker it is given: at most REPLACEMENTS_PER_WORKER per worker,
    then every queued task raises WorkerLost (no wait for ever)."""
    with LocalPool(1) as pool:
        futs = [pool.submit(_die_if, f"t{k}", 0) for k in range(REPLACEMENTS_PER_WORKER + 2)]
        for f in futs:
            with pytest.raises(WorkerLost):
                f.result(timeout=120)
        assert _until(pool, lambda w: not w) == []
        with pytest.raises(WorkerLost, match="no worker is left"):
            pool.submit(pow, 2, 2).result(timeout=5)


def test_the_runner_stops_with_one_line_when_a_task_kills_every_worker():
    with LocalPool(1) as pool:
        runner = TaskRunner(pool, False)
        t0 = time.monotonic()
        with pytest.raises(ParameterError) as e:
            runner.run(_die_if, [("x", 0)] + [("y", -1)] * 5, "dying")
        assert time.monotonic() - t0 < 10
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("the local worker processes: a task ended WorkerLost")
    assert "allowed: workers that stay up" in msg


def test_close_abandons_a_running_task_and_leaves_no_process(tmp_path):
    note = tmp_path / "pids"
    pool = LocalPool(2)
    pids = set(_workers(pool))
    long = pool.submit(_nap_noting, "long", 60.0, str(note))
    queued = [pool.submit(_nap, k, 60.0) for k in range(3)]
    while not note.exists():                         # running
        time.sleep(0.005)
    t0 = time.monotonic()
    pool.close()
    # a busy worker is terminated, not waited for (STOP_TIMEOUT = 2 s an idle one is given)
    assert time.monotonic() - t0 < 1.5
    assert _gone(pids, timeout=5) == []
    for f in (long, *queued):                        # nobody waits for ever on them
        with pytest.raises(WorkerLost, match="stopped"):
            f.result(timeout=5)
    with pytest.raises(RuntimeError, match="closed"):
        pool.submit(pow, 1, 1)


@pytest.mark.slow
def test_schedule_on_local_2_finishes_on_the_other_worker_when_one_is_killed(tmp_path):
    """Issue 27's check: a worker killed mid-run, the command finishes on the others, with the
    bytes of an undisturbed run."""
    out = tmp_path / "s.csv"
    proc = start_schedule_on_local_2(out, tmp_path)
    try:
        seen, _ = _watch(proc, until=lambda pids, s: len(pids) >= 4)
        # each names itself once it runs (under load, maybe not at once)
        deadline = time.monotonic() + 20
        while True:
            children = psutil.Process(proc.pid).children()
            workers = [c for c in children if c.name() == "haa_sym-worker"]
            if len(workers) == 2 and {c.name() for c in children} == {"haa_sym-worker", "haa_sym-zygote"}:
                break
            assert time.monotonic() < deadline and proc.poll() is None, children
            time.sleep(0.05)
        # killed while computing (its CPU time grows), not idle between task lists
        busy = sum(workers[0].cpu_times()[:2])
        deadline = time.monotonic() + 20
        while sum(workers[0].cpu_times()[:2]) - busy < 0.05:
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
        workers[0].kill()
        stdout, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, err
    ref = tmp_path / "ref.csv"
    undisturbed = subprocess.run([sys.executable, "-m", "haa_sym.cli", "schedule", "-q", "--scheduler", "local:2",
                                  "--out", str(ref)], capture_output=True, text=True, env=ENV, cwd=tmp_path,
                                 timeout=300)
    assert undisturbed.returncode == 0, undisturbed.stderr
    # the same messages (the schedule's own warning, nothing of the lost worker) and bytes
    assert (stdout, err) == (undisturbed.stdout.replace("ref.csv", "s.csv"), undisturbed.stderr)
    assert out.read_bytes() == ref.read_bytes()
    assert _gone(seen) == []


#: A command holding a pool of two idle workers: prints their pids, then waits to be killed.
HOLDER = """
import sys, time
from haa_sym.io import pool
if sys.argv[1] == "pipe-only":
    pool._die_with_parent = lambda parent: None      # the pipe's end alone must end them
p = pool.LocalPool(2)
print(" ".join(map(str, sorted(p.nthreads()))), flush=True)
time.sleep(600)
"""


@pytest.mark.parametrize("how", ["pdeathsig", "pipe-only"])
def test_workers_end_when_the_command_is_killed(how):
    """SIGKILL (or the kernel's out-of-memory killer) gives the command no time to stop its
    workers: they end by themselves (Linux's parent-death signal; the closed pipe elsewhere,
    which a fork's copies of the command's pipe ends kept open)."""
    if how == "pdeathsig" and sys.platform != "linux":
        pytest.skip("PR_SET_PDEATHSIG is Linux's")
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, how], stdout=subprocess.PIPE, text=True, env=ENV,
                            start_new_session=True)
    pids: set = set()
    try:
        pids = {int(p) for p in proc.stdout.readline().split()}
        assert len(pids) == 2
        proc.kill()
        proc.wait(timeout=10)
        assert _gone(pids, timeout=10) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        for pid in pids:                             # whatever the test found left, not left here
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


#: local:1 whose worker is killed; the replacement (spawned: its multiprocessing locks are named
#: semaphores, which it removes when it ends normally) creates one, then the pool is closed.
REPLACED = """
import os, signal
from haa_sym.io.pool import LocalPool

def lock_in_worker(victim):
    import multiprocessing
    if os.getpid() == victim:
        os.kill(victim, signal.SIGKILL)
    global LOCK
    LOCK = multiprocessing.Lock()
    return os.getpid()

if __name__ == "__main__":
    with LocalPool(1) as pool:
        (victim,) = pool.nthreads()
        print(victim != pool.submit(lock_in_worker, victim).result(timeout=60), flush=True)
"""


def test_a_replacement_ends_normally_when_the_pool_closes(tmp_path):
    """Linux's parent-death signal of a replacement is tied to the pool's thread that started it:
    when that thread ended before the workers were stopped, the replacement was SIGKILLed at
    every close (its named semaphore left behind, the resource tracker's warning on stderr)."""
    script = tmp_path / "replaced.py"
    script.write_text(REPLACED)
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=ENV, timeout=120)
    assert (run.returncode, run.stdout, run.stderr) == (0, "True\n", "")


@pytest.mark.parametrize("how", ["zygote", "spawned"])
def test_no_worker_is_left_when_a_replacement_cannot_be_started(how, monkeypatch):
    import multiprocessing.context

    def refuse(self):
        raise BlockingIOError(11, "Resource temporarily unavailable")
    if how == "spawned":
        monkeypatch.delattr(os, "pidfd_open", raising=False)
    elif not hasattr(os, "pidfd_open"):
        pytest.skip("the zygote needs os.pidfd_open (Linux)")
    with LocalPool(1) as pool:
        if how == "zygote":                          # the zygote gone: no fork to ask for
            # by its pid: its name is its own to set once it runs, maybe not yet under load
            zygote = psutil.Process(pool._zygote[0].pid)
            zygote.kill()
            zygote.wait(10)
        monkeypatch.setattr(multiprocessing.context.SpawnProcess, "start", refuse)
        (victim,) = _workers(pool)
        futs = [pool.submit(_die_if, "a", victim), pool.submit(pow, 2, 3)]
        for f in futs:
            with pytest.raises(WorkerLost, match="no worker is left"):
                f.result(timeout=30)
        assert _workers(pool) == []


#: A script without a ``__main__`` guard, whose task function is defined in it (run with -c: no
#: file), its one worker killed: the replacement must not run the script again (a spawned one
#: does, and cannot load the function of a __main__ without a file).
UNGUARDED = """
import os, signal, sys
from haa_sym.io.pool import LocalPool
print("top level", flush=True)

def where(victim):
    if os.getpid() == victim:
        os.kill(victim, signal.SIGKILL)
    print("from the replacement")             # buffered (stdout a pipe): flushed at its end
    return os.getpid()

if len(sys.argv) > 1:                         # its fds numbered above select()'s 1024
    import resource
    resource.setrlimit(resource.RLIMIT_NOFILE, (4096, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
    held = [os.open(os.devnull, os.O_RDONLY) for _ in range(1100)]
with LocalPool(1) as pool:
    (victim,) = pool.nthreads()
    print(victim != pool.submit(where, victim).result(timeout=60), flush=True)
"""


@pytest.mark.skipif(not hasattr(os, "pidfd_open"), reason="the zygote needs os.pidfd_open (Linux)")
@pytest.mark.parametrize("fds", ["few", "over 1024"])
def test_a_replacement_does_not_run_the_main_script_again(fds):
    """Nor loses what a task printed; and its pidfd may be numbered above 1024 (no select())."""
    env = {k: v for k, v in ENV.items() if k != "PYTHONUNBUFFERED"}
    run = subprocess.run([sys.executable, "-c", UNGUARDED, *(["many"] if fds != "few" else [])],
                         capture_output=True, text=True, env=env, timeout=120)
    assert (run.returncode, sorted(run.stdout.splitlines()), run.stderr) == \
        (0, ["True", "from the replacement", "top level"], "")
