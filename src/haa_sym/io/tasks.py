"""Lists of independent tasks run in-process (dask's threaded scheduler), on N local worker
processes (``--scheduler local:N``) or on a dask.distributed cluster (``--scheduler ADDRESS``),
with a progress bar (:mod:`haa_sym.io.progress`).

``--scheduler local:N`` starts a :class:`haa_sym.io.pool.LocalPool` of N one-thread worker
processes for the duration of one call (:func:`cluster`), and stops it, also on an error, Ctrl-C
or SIGTERM; the pool offers the part of a ``distributed.Client`` this runner uses, so the
cluster code below drives both.

A task is a module-level function of plain data (parameters, options, gain points): a worker
process builds what it needs itself (the compiled library is loaded per process, never shipped).
Used by the torque-gain scheduler (:mod:`haa_sym.design.schedule`) and the nonlinear maps
(:mod:`haa_sym.analysis.nonlinear_map`).

Example
-------
>>> r = TaskRunner(None, False)
>>> r.run(pow, [(2, 3), (3, 2)], "demo")
[8, 9]
"""
from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading

from haa_sym.errors import ParameterError
from haa_sym.io.pool import LocalPool, WorkerLost
from haa_sym.io.progress import progress as progress_bar

__all__ = ["TaskRunner", "connect", "cluster", "local_workers", "scheduler_kind", "DEFAULT_CONNECT_TIMEOUT", "THREADS"]

#: Seconds to connect to a --scheduler and finish dask's handshake.
DEFAULT_CONNECT_TIMEOUT = 5.0
#: Threads of the in-process scheduler (the machines this runs on have 2 cores).
THREADS = 2
#: Seconds a cluster may have no worker while tasks are pending before the command stops (a
#: worker that died mid-run, and no other: dask would wait for a new one for ever).
NO_WORKER_TIMEOUT = 30.0
#: Seconds between two looks at the cluster while waiting for results.
POLL_S = 0.5
#: None, or a list to which every task submitted to a cluster is appended as ``{"key": ...,
#: "after": [keys], "submitted": time.time()}``: the tasks it waited for (the previous
#: :meth:`TaskRunner.run` call's, a barrier; or the task whose result asked for it,
#: :meth:`TaskRunner.stream`) and when it was submitted. The chains of
#: this graph bound the speedup (benchmarks/bench_scale.py reads it).
TRACE: list | None = None


#: The form of a local cluster's --scheduler value: ``local:N``.
LOCAL = "local:"


#: ``local:N`` accepts at most this many worker processes per core: more only share the cores
#: (N above the cores is allowed, with a warning, to test the scheduling), and each is a process
#: of its own (about 50 MB resident): ``local:100000`` forked until the kernel killed processes
#: for memory, the command's and others' (2026-11-27).
LOCAL_MAX_PER_CORE = 8


def local_workers(spec) -> int | None:
    """N of a ``--scheduler local:N`` value, None for any other value (an address, a Client,
    None); ParameterError unless N is an integer from 1 to :data:`LOCAL_MAX_PER_CORE` times the
    cores."""
    if not isinstance(spec, str) or not spec.lower().startswith(LOCAL):   # LOCAL:2 too, not an address
        return None
    text = spec[len(LOCAL):]
    n = int(text) if text.isascii() and text.isdigit() and len(text) < 10 else 0
    most = LOCAL_MAX_PER_CORE * (os.cpu_count() or 1)
    if not 1 <= n <= most:
        raise ParameterError(f"--scheduler {spec!r}: the number of worker processes is not an integer from 1 "
                             f"to {most} ({LOCAL_MAX_PER_CORE} per core, {os.cpu_count() or 1} cores); allowed: "
                             f"local:N with 1 <= N <= {most} (e.g. local:{os.cpu_count() or 1}), or the address "
                             "of a running dask.distributed scheduler (tcp://127.0.0.1:8786)")
    return n


def scheduler_kind(spec) -> str:
    """What runs the tasks of a ``--scheduler`` value other than None, as results' metadata
    name it: "local worker processes" (``local:N``, a LocalPool) or "dask.distributed"."""
    return "local worker processes" if isinstance(spec, LocalPool) or local_workers(spec) else "dask.distributed"


@contextlib.contextmanager
def cluster(spec):
    """What :class:`TaskRunner` takes for ``spec``: ``spec`` itself, except for ``local:N``: a
    :class:`haa_sym.io.pool.LocalPool` of N one-thread worker processes started here (nothing
    listens on a port) and stopped on leaving, whatever ends the block (an error,
    KeyboardInterrupt, or :class:`haa_sym.errors.Terminated` on SIGTERM).

    One thread per process: a point's Python part holds the GIL (see
    :data:`haa_sym.analysis.nonlinear_map.IN_PROCESS_THREADS`), so cores are used by processes.
    """
    n = local_workers(spec)
    if n is None:
        yield spec
        return
    cores = os.cpu_count() or 1
    if n > cores:
        # allowed (a test of the scheduling), but more processes than cores share them
        print(f"haa-sym: warning: --scheduler {spec}: {n} worker processes on {cores} cores; they share the "
              f"cores (no faster than local:{cores})", file=sys.stderr)
    import threadpoolctl  # noqa: F401 - imported once here, before the forks, not by every worker
    pool = None
    try:
        try:
            pool = LocalPool(n, initializer=one_blas_thread)
        except OSError as e:             # a fork refused (process or memory limits): the started ones are stopped
            raise ParameterError(f"--scheduler {spec!r}: the worker processes could not be started "
                                 f"({type(e).__name__}: {e}); allowed: fewer workers (local:N with a "
                                 "smaller N) or no --scheduler") from None
        yield pool
    finally:
        if pool is not None:
            pool.close()


def one_blas_thread() -> None:
    """A local worker's initializer: one BLAS thread. A worker is one thread (:func:`cluster`);
    a *forked* worker inherits the command's OpenBLAS, initialised with a thread per core, so
    each worker of local:2 would run two BLAS threads on a 2-core machine, and local:1's one
    worker could use both cores, which a one-worker baseline must not. ``threadpool_limits``
    reaches the libraries loaded already (a fork's, or a spawned worker's that its main module
    imported); the environment those loaded later (a spawned worker's numpy, with its first
    task): OpenBLAS reads OPENBLAS_NUM_THREADS before OMP_NUM_THREADS, MKL its own."""
    from threadpoolctl import threadpool_limits
    for key in BLAS_THREADS_ENV:
        os.environ[key] = "1"
    threadpool_limits(limits=1, user_api="blas")


#: The variables by which a BLAS loaded later learns its threads (:func:`one_blas_thread`).
BLAS_THREADS_ENV = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def connect(Client, address: str, timeout: float = DEFAULT_CONNECT_TIMEOUT):
    """A dask.distributed Client of ``address``, or one ParameterError within ``timeout`` s.

    Client's own ``timeout`` bounds the TCP connection only: a service that accepts and never
    answers (an HTTP server waiting for a request) blocks the handshake for ever, and one that
    greets first has its greeting read as a frame length (an allocation of exabytes). So the
    client is made in a daemon thread, waited for with a deadline, and any failure it raises
    (MemoryError included) is the address's fault.
    """
    out: dict = {}

    def make():
        try:
            out["client"] = Client(address, timeout=f"{timeout:g}s")
        except BaseException as exc:       # noqa: BLE001 - reported below, in the caller's thread
            out["error"] = exc
    worker = threading.Thread(target=make, name="haa_sym-scheduler-connect", daemon=True)
    worker.start()
    worker.join(timeout + 1)
    allowed = "allowed: the address of a running dask.distributed scheduler, e.g. tcp://127.0.0.1:8786"
    if "client" in out:
        return out["client"]
    if worker.is_alive():
        why = f"no dask handshake within {timeout:g} s (a service that is not a dask scheduler?)"
    else:
        e = out.get("error")
        first = str(e).splitlines()[0] if e is not None and str(e) else "no answer"
        if isinstance(e, MemoryError):
            first = "its answer is not dask's protocol"
        why = f"no dask scheduler answers there ({type(e).__name__}: {first})"
    raise ParameterError(f"--scheduler {address!r}: {why}; {allowed}")


#: Tasks a :meth:`TaskRunner.run` call gives each worker of a cluster at most: the calls are
#: grouped (:func:`_call_each`) so that a map of many small calls does not pay a cluster task's
#: milliseconds for each.
CHUNKS_PER_WORKER = 4
#: dask priority of :meth:`TaskRunner.start`'s background tasks (the others' is 0: higher first).
BACKGROUND_PRIORITY = -1


def _call_each(fn, args_list: list) -> list:
    """``[fn(*a) for a in args_list]``: a group of calls as one cluster task."""
    return [fn(*a) for a in args_list]


class TaskRunner:
    """Runs task lists on dask (threaded, in-process) or on a dask.distributed cluster.

    Parameters
    ----------
    scheduler : None, str or distributed.Client
        None: dask's threaded scheduler in this process (:data:`THREADS` threads); an address
        ("tcp://host:port"): connect to it (closed by :meth:`close`); ``"local:N"``: N local
        worker processes (:func:`cluster`; stopped by :meth:`close`); a Client or a
        :class:`haa_sym.io.pool.LocalPool`: use it.
    progress : bool or None
        The progress bar's setting (:func:`haa_sym.io.progress.progress`).
    connect_timeout : float
        Seconds for the connection and dask's handshake.
    threads : int
        Threads of the in-process run (default :data:`THREADS`); 1 runs the tasks one after
        the other in this thread (for tasks whose Python part holds the GIL most of the time).
    """

    def __init__(self, scheduler, progress, connect_timeout: float = DEFAULT_CONNECT_TIMEOUT,
                 threads: int = THREADS, no_worker_timeout: float = NO_WORKER_TIMEOUT):
        self.client, self.own, self._local = None, False, None
        self._before: list = []                 # keys of the last barrier's tasks (TRACE)
        self.progress, self.threads = progress, threads
        self.no_worker_timeout = no_worker_timeout
        self.address = scheduler if isinstance(scheduler, str) else None
        if scheduler is None:
            return
        if local_workers(scheduler) is not None:
            self._local = contextlib.ExitStack()
            self.client = self._local.enter_context(cluster(scheduler))
            return
        if isinstance(scheduler, LocalPool):
            self.client = scheduler
            return
        try:
            from distributed import Client
        except ImportError as e:               # pragma: no cover - a dependency
            raise ParameterError(f"--scheduler {scheduler!r}: dask.distributed is not installed ({e})")
        if isinstance(scheduler, Client):
            self.client = scheduler
            return
        self.client = connect(Client, str(scheduler), connect_timeout)
        self.own = True

    def close(self):
        if self.own and self.client is not None:
            self.client.close()
        if self._local is not None:
            self._local.close()
            self._local = None

    def run(self, fn, args_list: list, label: str, unit: str = "task") -> list:
        """``[fn(*a) for a in args_list]``, in that order, the tasks run concurrently."""
        if not args_list:
            return []
        with progress_bar(len(args_list), label, unit, self.progress) as bar:
            if self.client is not None:
                submitted = self._submit(fn, args_list)
                self._before = [f.key for f in submitted[0]]
                return self._gather(*submitted, bar)
            if self.threads == 1:
                out = []
                for a in args_list:
                    out.append(fn(*a))
                    bar.update(1)
                return out
            import dask
            from dask.callbacks import Callback

            class _Bar(Callback):
                def _posttask(self, key, result, dsk, state, worker_id):
                    if str(key[0] if isinstance(key, tuple) else key).startswith("task-"):
                        bar.update(1)
            tasks = [dask.delayed(fn, pure=False)(*a, dask_key_name=f"task-{k}") for k, a in enumerate(args_list)]
            # a pool of this call's own, shut down when it returns: dask's default pool for
            # num_workers stays alive with its idle non-daemon threads until the interpreter
            # ends, and the CLI's quick exit (haa_sym.cli.end) waits for no such thread
            from concurrent.futures import ThreadPoolExecutor
            with _Bar(), ThreadPoolExecutor(self.threads, thread_name_prefix="haa_sym-task") as pool:
                return list(dask.compute(*tasks, scheduler="threads", pool=pool))

    def start(self, fn, args_list: list, label: str, unit: str = "task", background: bool = False):
        """:meth:`run` without the wait: returns a function of no argument that returns the
        results. On a cluster the tasks are submitted now and run while the command goes on, so
        the task lists that follow do not wait for them (no barrier); in-process they run when
        the results are asked for.

        ``background``: on a cluster, every task submitted later (by :meth:`run`, :meth:`start`
        or :meth:`stream`) goes first (dask's priority), so these fill the workers' idle time at
        the end of each later task list (one worker still busy with the list's last group, the
        others waiting for the next list) instead of delaying the lists; in groups of one call
        each: a worker idle at a list's end takes one short call, not a group of them."""
        if self.client is None or not args_list:
            return lambda: self.run(fn, args_list, label, unit)
        submitted = self._submit(fn, args_list, BACKGROUND_PRIORITY if background else 0,
                                 len(args_list) if background else None)

        def collect():
            with progress_bar(len(args_list), label, unit, self.progress) as bar:
                return self._gather(*submitted, bar)
        return collect

    def _submit(self, fn, args_list: list, priority: int = 0, n: int | None = None):
        """A cluster's tasks of ``args_list``: small calls go in groups, CHUNKS_PER_WORKER a
        worker (a cluster task costs milliseconds of scheduling and transfer), or ``n`` groups;
        every n-th call to a group (neighbouring calls cost alike, e.g. one leg configuration's
        maps), so the groups take about the same time and the slowest decides little. Returns
        (futures, groups, n)."""
        n = max(1, min(len(args_list), CHUNKS_PER_WORKER * self.workers() if n is None else n))
        groups = [args_list[g::n] for g in range(n)]
        futures = [self.client.submit(_call_each, fn, g, pure=False, priority=priority) for g in groups]
        self._trace(futures, self._before)
        return futures, groups, n

    def _gather(self, futures, groups, n, bar) -> list:
        try:
            self._wait(futures, bar, sizes={f: len(g) for f, g in zip(futures, groups)})
            out = [None] * sum(len(g) for g in groups)
            for g, rs in enumerate(self.client.gather(futures)):
                out[g::n] = rs
            return out
        finally:
            self.client.cancel([f for f in futures if not f.done()])

    def workers(self) -> int:
        """How many tasks run at once: the cluster's worker threads, else the in-process threads."""
        if self.client is None:
            return max(1, self.threads)
        return max(1, sum(self.client.nthreads().values()))

    def stream(self, fn, first: list, then, label: str, unit: str = "task") -> None:
        """Run ``fn(*a)`` for every ``a`` of ``first``, and what the results ask for, with no
        barrier between rounds: as each task finishes, ``then(a, result)`` is called (in this
        thread) and returns ``(args, priority)`` pairs of further tasks, submitted at once
        while the others run (a higher ``priority`` is started first by a cluster). ``then``
        must not depend on the order results arrive in: it is the completion order."""
        with progress_bar(len(first), label, unit, self.progress) as bar:
            def more(a, result):
                new = list(then(a, result))
                if new:
                    bar.total += len(new)
                    bar.refresh()
                return new
            if self.client is not None:
                futures = {}

                keys: list = []

                def submit(items, after):
                    new = [self.client.submit(fn, *a, pure=False, priority=prio) for a, prio in items]
                    futures.update(zip(new, (a for a, _ in items)))
                    self._trace(new, after)
                    keys.extend(f.key for f in new)
                    return new

                def on_done(f):
                    a = futures.pop(f)
                    return submit(more(a, f.result()), [f.key])
                submit([(a, 0) for a in first], self._before)
                self._before = keys
                try:
                    self._wait(list(futures), bar, on_done)
                finally:
                    self.client.cancel([f for f in futures if not f.done()])
                return
            if self.threads == 1:
                import heapq
                import itertools
                order = itertools.count()
                queue = [(0, next(order), a) for a in first]
                heapq.heapify(queue)
                while queue:
                    _, _, a = heapq.heappop(queue)
                    r = fn(*a)
                    bar.update(1)
                    for b, prio in more(a, r):
                        heapq.heappush(queue, (-prio, next(order), b))
                return
            from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
            with ThreadPoolExecutor(self.threads, thread_name_prefix="haa_sym-task") as pool:
                running = {pool.submit(fn, *a): a for a in first}
                try:
                    while running:
                        done, _ = wait(running, return_when=FIRST_COMPLETED)
                        for f in done:
                            a = running.pop(f)
                            bar.update(1)
                            for b, _prio in more(a, f.result()):
                                running[pool.submit(fn, *b)] = b
                finally:
                    for f in running:
                        f.cancel()

    @staticmethod
    def _trace(futures, after) -> None:
        if TRACE is not None:
            import time
            now = time.time()                  # the clock of dask's task stream
            TRACE.extend({"key": f.key, "after": list(after), "submitted": now} for f in futures)

    def _wait(self, futures, bar, on_done=None, sizes=None) -> None:
        """Wait for ``futures``, updating ``bar``; ``on_done(future)`` (if given) is called on
        each finished one and returns new futures to wait for too. Stop with one line when the
        cluster has had no worker for :attr:`no_worker_timeout` s, or when a task killed the
        workers it ran on (dask's ``KilledWorker``, after its allowed failures): never wait for ever."""
        import queue
        import time

        if isinstance(self.client, LocalPool):      # no import of distributed for local:N
            lost: tuple = (WorkerLost,)
            where = f"--scheduler {self.address!r}" if self.address else "the local worker processes"
        else:
            from distributed.scheduler import KilledWorker
            lost = (KilledWorker,)
            where = f"--scheduler {self.address!r}" if self.address else "the dask cluster"
        sizes = {} if sizes is None else sizes             # calls per cluster task (run's groups)
        # finished futures arrive on a queue (each future's done callback, in the pool's or the
        # client's thread): a wait per finished task over every pending future (wait(...,
        # FIRST_COMPLETED)) costs this thread time in the number pending, 473 of the nonlinear
        # map's tasks on 16 workers, while it holds the GIL the pool's dispatcher needs
        finished: queue.SimpleQueue = queue.SimpleQueue()

        def track(fs):
            for f in fs:
                f.add_done_callback(finished.put)
        pending, idle_since = set(futures), None
        total = sum(sizes.get(f, 1) for f in futures)
        track(futures)
        while pending:
            done = set()
            try:
                done.add(finished.get(timeout=POLL_S))
                while True:
                    done.add(finished.get_nowait())
            except queue.Empty:
                pass
            done &= pending                  # (a future is put once; cancelled ones are not pending)
            pending -= done
            bar.update(sum(sizes.get(f, 1) for f in done))
            for f in done:
                if f.status == "error":
                    exc = f.exception()
                    if isinstance(exc, lost):
                        raise ParameterError(f"{where}: a task ended {exc.__class__.__name__} (the worker "
                                             "process running it died, each time it was retried, or no "
                                             "worker was left: out of memory, or killed); allowed: workers "
                                             "that stay up (check their memory and logs)") from None
                if on_done is not None:
                    new = on_done(f)             # raises the task's own error, if any
                    pending |= set(new)
                    total += len(new)
                    track(new)
            if not pending:
                return
            if done:
                # a task finished: the cluster has a worker. The cluster is asked only after a
                # wait in which none did: each ask is a round trip to the scheduler (its whole
                # identity, every worker's metrics): after every finished task, 36 of them on the
                # default schedule on local:2, 0.08 s of the command's own thread
                idle_since = None
                continue
            workers = len(self.client.scheduler_info().get("workers", {}))
            now = time.monotonic()
            if workers:
                idle_since = None
            elif idle_since is None:
                idle_since = now
            elif now - idle_since > self.no_worker_timeout:
                left = sum(sizes.get(f, 1) for f in pending)
                raise ParameterError(f"{where}: no worker for {self.no_worker_timeout:g} s with {left} "
                                     f"of {total} tasks pending (did the last worker die?); allowed: a "
                                     "cluster with at least one running worker")

