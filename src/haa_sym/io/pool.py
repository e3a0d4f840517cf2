"""``--scheduler local:N``: N worker processes of this machine fed from a priority queue in the
command's process (issue 27, item 3, sixth round).

A worker is a process forked from the command (on Linux; started with ``spawn`` elsewhere, where
fork is unsafe or missing) that receives ``(key, fn, args)`` on a pipe, runs ``fn(*args)`` and
sends back the result with the time it started and stopped. Nothing listens on any port: the
pipes are the only channel. The command keeps every task not yet given to a worker in a heap
(higher ``priority`` first, then submission order) and gives one task at a time to an idle worker,
so a task list submitted later with a higher priority overtakes the queue at once (dask's
priorities on a cluster, :meth:`haa_sym.io.tasks.TaskRunner.start`).

Why not dask's ``LocalCluster`` (what ``local:N`` started until this round): on the 2-core
machines its start cost the command 0.45-0.55 s before the first task, serial on any machine
(importing ``distributed``, 0.27-0.41 s, then the scheduler, the nannies and the workers' 0.15 s),
and its scheduler, in the command's process, spends about 2.8 ms of it per task (473 tasks of the
nonlinear map sized for 16 workers: 1.34 s). Both bound what 16 workers can gain
(docs/schedule.md, "Measured after the sixth round"). A cluster given by address stays dask's.

A worker that dies (killed, out of memory) takes down only the task it was running: that task is
queued again for the others, as dask resubmits it, up to :data:`ALLOWED_FAILURES` deaths (dask's
``distributed.scheduler.allowed-failures``), then its future raises :class:`WorkerLost`; with no
worker left every queued task raises it. A dead worker is not replaced (a fork from the
dispatcher thread while the command's thread runs is not safe): the command finishes on the
others.

The interface is the part of a ``distributed.Client`` that :class:`haa_sym.io.tasks.TaskRunner`
uses (``submit``, ``gather``, ``cancel``, ``nthreads``, ``scheduler_info``, ``get_task_stream``),
so that one runner drives both.
"""
from __future__ import annotations

import concurrent.futures
import heapq
import itertools
import os
import signal
import sys
import threading
import time

__all__ = ["LocalPool", "WorkerLost", "ALLOWED_FAILURES", "START_METHOD"]

#: Deaths of the worker running a task before the task is given up (dask's default
#: ``distributed.scheduler.allowed-failures``: a task that kills every worker it runs on).
ALLOWED_FAILURES = 3
#: How workers are started: "fork" on Linux (a worker inherits the command's imported haa_sym,
#: numpy and compiled library and is up in milliseconds); "spawn" elsewhere (a new interpreter
#: that imports them again: fork is unsafe on macOS and missing on Windows).
START_METHOD = "fork" if sys.platform == "linux" else "spawn"
#: Seconds a worker has to end after it is asked to, before it is terminated.
STOP_TIMEOUT = 2.0


class WorkerLost(RuntimeError):
    """A task's worker died each time it ran it (:data:`ALLOWED_FAILURES`), or no worker is left."""


class PoolFuture(concurrent.futures.Future):
    """A task's future: ``key`` names it (the trace of :data:`haa_sym.io.tasks.TRACE`),
    ``status`` is dask's word for its state."""

    def __init__(self, key: str):
        super().__init__()
        self.key = key

    @property
    def status(self) -> str:
        if not self.done():
            return "pending"
        if self.cancelled():
            return "cancelled"
        return "error" if self.exception() is not None else "finished"


def _worker(conn) -> None:
    """A worker process's loop: ``(key, fn, args)`` in, ``(key, ok, result, start, stop)`` out,
    until ``None`` or the pipe closes."""
    # SIGINT (Ctrl-C reaches the whole process group) is the command's to handle: it stops the
    # workers itself. SIGTERM ends a worker (the command's own handler, inherited by a fork,
    # would raise haa_sym.errors.Terminated mid-task).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        key, fn, args = msg
        start = time.time()                  # the clock of the task stream (dask's too)
        try:
            out, ok = fn(*args), True
        except BaseException as exc:         # noqa: BLE001 - the task's error, raised by its future
            out, ok = exc, False
        stop = time.time()
        try:
            conn.send((key, ok, out, start, stop))
        except Exception as exc:             # noqa: BLE001 - a result or error that does not pickle
            conn.send((key, False, RuntimeError(f"the result of task {key} could not be sent back "
                                                f"({type(exc).__name__}: {exc})"), start, stop))


class LocalPool:
    """N worker processes of one thread each, with a priority queue in this process.

    Parameters
    ----------
    n : int
        Worker processes (>= 1), started now.
    start_method : str
        ``multiprocessing``'s start method (default :data:`START_METHOD`).
    """

    def __init__(self, n: int, start_method: str = START_METHOD):
        import multiprocessing               # here: a command that runs in-process never needs it
        ctx = multiprocessing.get_context(start_method)
        self._lock = threading.Lock()
        self._queue: list = []               # (-priority, order, key, fn, args, future)
        self._order = itertools.count()
        self._names = itertools.count()
        self._workers: dict = {}             # pid -> (process, connection)
        self._idle: list = []                # pids
        self._running: dict = {}             # pid -> (queue entry)
        self._failures: dict = {}            # key -> deaths of the workers that ran it
        self._stream: list = []              # dask's task-stream records of finished tasks
        self._closed = False
        try:
            for _ in range(n):
                mine, theirs = ctx.Pipe(duplex=True)
                proc = ctx.Process(target=_worker, args=(theirs,), daemon=True, name="haa_sym-worker")
                proc.start()
                theirs.close()
                self._workers[proc.pid] = (proc, mine)
                self._idle.append(proc.pid)
        except BaseException:
            self._stop_workers()
            raise
        self._wake_r, self._wake_w = multiprocessing.Pipe(duplex=False)
        self._thread = threading.Thread(target=self._dispatch, name="haa_sym-pool", daemon=True)
        self._thread.start()

    # -- the part of distributed.Client that TaskRunner uses ------------------------------------
    def submit(self, fn, *args, priority: int = 0, pure: bool = False, key: str | None = None) -> PoolFuture:
        """``fn(*args)`` on a worker; a higher ``priority`` is given to a worker first."""
        del pure                             # every task runs (no result cache), as dask's pure=False
        name = key if key is not None else f"{getattr(fn, '__name__', 'task')}-{next(self._names)}"
        fut = PoolFuture(name)
        with self._lock:
            if self._closed:
                raise RuntimeError("the local pool is closed")
            if not self._workers:
                fut.set_exception(WorkerLost("no worker is left"))
                return fut
            heapq.heappush(self._queue, (-priority, next(self._order), name, fn, args, fut))
        self._wake_w.send_bytes(b"")
        return fut

    def gather(self, futures) -> list:
        return [f.result() for f in futures]

    def cancel(self, futures) -> None:
        for f in futures:
            f.cancel()                       # a queued task is skipped; a running one finishes

    def nthreads(self) -> dict:
        with self._lock:
            return {pid: 1 for pid in self._workers}

    def scheduler_info(self) -> dict:
        return {"workers": self.nthreads()}

    def get_task_stream(self, start: float | None = None) -> list:
        """The finished tasks as dask's task stream records ``{"key", "worker", "startstops":
        [{"action": "compute", "start", "stop"}]}``, those that stopped after ``start``."""
        with self._lock:
            return [r for r in self._stream if start is None or r["startstops"][0]["stop"] >= start]

    def close(self) -> None:
        """Stop the workers (a running task is abandoned) and the dispatcher."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            queued, self._queue = self._queue, []
        for entry in queued:
            entry[-1].cancel()
        try:
            self._wake_w.send_bytes(b"")
        except OSError:
            pass
        self._thread.join(STOP_TIMEOUT)
        self._stop_workers()
        for c in (self._wake_r, self._wake_w):
            c.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- the dispatcher thread -------------------------------------------------------------------
    def _dispatch(self) -> None:
        from multiprocessing.connection import wait
        while True:
            with self._lock:
                if self._closed:
                    return
                self._feed()
                conns = {c: pid for pid, (_, c) in self._workers.items()}
                sentinels = {p.sentinel: pid for pid, (p, _) in self._workers.items()}
            ready = wait([self._wake_r, *conns, *sentinels])
            for r in ready:
                if r is self._wake_r:
                    while self._wake_r.poll():
                        self._wake_r.recv_bytes()
                elif r in conns:
                    self._finished(conns[r])
            for r in ready:
                if r in sentinels and sentinels[r] in self._workers:
                    self._died(sentinels[r])

    def _feed(self) -> None:
        """Give queued tasks to idle workers (under the lock)."""
        while self._idle and self._queue:
            entry = heapq.heappop(self._queue)
            fut = entry[-1]
            # a task queued again after its worker died is running already (a future does not go
            # back to pending); any other is started here, or skipped if cancelled while queued
            if not fut.running() and not fut.set_running_or_notify_cancel():
                continue
            pid = self._idle.pop()
            try:
                self._workers[pid][1].send((entry[2], entry[3], entry[4]))
            except Exception as exc:         # noqa: BLE001 - the task's arguments do not pickle
                self._idle.append(pid)
                fut.set_exception(exc)
                continue
            self._running[pid] = entry

    def _finished(self, pid: int) -> None:
        conn = self._workers[pid][1]
        try:
            key, ok, out, start, stop = conn.recv()
        except (EOFError, OSError):
            return                           # the worker died: its sentinel says so
        with self._lock:
            entry = self._running.pop(pid)
            self._idle.append(pid)
            self._failures.pop(key, None)
            self._stream.append({"key": key, "worker": f"local-{pid}",
                                 "startstops": [{"action": "compute", "start": start, "stop": stop}]})
            # the worker's next task before the result is handed over: the result wakes the
            # command's thread, whose work on it (a stream's follow-up, the progress bar) holds
            # the GIL, and this thread waited for it to send the next task (2.8 ms between two
            # tasks of the nonlinear map on one worker, median, against about 1 ms of pickling)
            self._feed()
        fut = entry[-1]
        if ok:
            fut.set_result(out)
        else:
            fut.set_exception(out)

    def _died(self, pid: int) -> None:
        """A worker's process ended: its task queued again, or given up."""
        lost = []
        with self._lock:
            proc, conn = self._workers.pop(pid)
            if pid in self._idle:
                self._idle.remove(pid)
            entry = self._running.pop(pid, None)
            if entry is not None:
                key = entry[2]
                self._failures[key] = self._failures.get(key, 0) + 1
                if self._failures[key] >= ALLOWED_FAILURES:
                    lost.append((entry[-1], f"the worker processes running task {key} died "
                                            f"{ALLOWED_FAILURES} times (exit code {proc.exitcode})"))
                else:
                    # a new future state cannot go back to pending: the entry keeps its future,
                    # already running, and is given to the next idle worker as it is
                    heapq.heappush(self._queue, entry)
            if not self._workers:
                lost += [(e[-1], "no worker is left") for e in self._queue]
                self._queue = []
        conn.close()
        for fut, why in lost:
            if not fut.done():
                fut.set_exception(WorkerLost(why))

    def _stop_workers(self) -> None:
        for pid, (proc, conn) in list(self._workers.items()):
            if pid in self._running:
                proc.terminate()             # its task abandoned (an error, Ctrl-C): no wait for it
                continue
            try:
                conn.send(None)
            except OSError:
                pass
        deadline = time.monotonic() + STOP_TIMEOUT
        for proc, conn in list(self._workers.values()):
            proc.join(max(0.0, deadline - time.monotonic()))
            if proc.is_alive():
                proc.terminate()             # SIGTERM: a worker's default action (see _worker)
                proc.join(STOP_TIMEOUT)
            if proc.is_alive():
                proc.kill()
                proc.join()
            conn.close()
        self._workers.clear()
