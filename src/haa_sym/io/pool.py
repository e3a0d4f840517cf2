"""``--scheduler local:N``: N worker processes of this machine fed from a priority queue in the
command's process (issue 27, item 3, sixth round).

A worker is a process forked from the command (on Linux; started with ``spawn`` elsewhere, where
fork is unsafe or missing) that receives a task (its key, and its function and arguments
pickled) on a pipe, runs it and sends back the result with the time it started and stopped. Nothing listens on any port: the
pipes are the only channel. The command keeps every task not yet given to a worker in a heap
(higher ``priority`` first, then submission order) and gives one task at a time to an idle worker,
so a task list submitted later with a higher priority overtakes the queue at once (dask's
priorities on a cluster, :meth:`haa_sym.io.tasks.TaskRunner.start`).

Why not dask's ``LocalCluster`` (what ``local:N`` started until this round): on the 2-core
machines its start cost the command 0.45-0.55 s before the first task, serial on any machine
(importing ``distributed``, 0.27-0.41 s, then the scheduler, the nannies and the workers' 0.15 s),
and a task's trip from the command to a worker and back took about 2.8 ms (473 tasks of the
nonlinear map sized for 16 workers: 1.34 s). Both bound what 16 workers can gain
(docs/schedule.md, "Measured after the sixth round"). A cluster given by address stays dask's.

A worker that dies (killed, out of memory) takes down only the task it was running: that task is
queued again for the others, as dask resubmits it, until its deaths exceed
:data:`ALLOWED_FAILURES` (dask's rule and default for ``distributed.scheduler.allowed-failures``:
given up at the fourth), then its future raises :class:`WorkerLost`. A dead worker is replaced,
as a dask nanny restarts its worker, so that ``local:1`` survives its worker's death too. On
Linux by a fork of a *zygote*: a process forked from the command with the first workers, one
thread, that forks a worker on request and passes its pipe end (and a pidfd, the handle by which
the command sees it end) back over its own pipe. A fork from the pool's thread while the
command's thread runs could copy a lock another thread holds; a spawned process re-runs the
user's ``__main__`` (a script without a ``__main__`` guard would run again, a function defined
in a notebook would not load) and starts cold. The zygote's worker has the command's imports
at the pool's start and takes a task within milliseconds. Elsewhere (spawned workers, and Linux
without ``os.pidfd_open``) a replacement is spawned like the first workers. A pool of N replaces
at most N x :data:`REPLACEMENTS_PER_WORKER` workers: a machine that keeps killing them ends the
command. With no worker left and none starting, every queued task raises :class:`WorkerLost`.

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

__all__ = ["LocalPool", "WorkerLost", "ALLOWED_FAILURES", "REPLACEMENTS_PER_WORKER", "START_METHOD"]

#: A task is given up when the workers that died running it exceed this many (dask's default
#: ``distributed.scheduler.allowed-failures`` and its rule: a task that kills every worker it runs on).
ALLOWED_FAILURES = 3
#: How workers are started: "fork" on Linux (a worker inherits the command's imported haa_sym,
#: numpy and compiled library and is up in milliseconds); "spawn" elsewhere (a new interpreter
#: that imports them again: fork is unsafe on macOS and missing on Windows).
START_METHOD = "fork" if sys.platform == "linux" else "spawn"
#: A pool of N workers replaces at most N times this many dead workers, counted over the pool
#: (so that a task that kills every worker still meets :data:`ALLOWED_FAILURES` on one worker,
#: and a machine that kills every worker it is given does not get new ones for ever).
REPLACEMENTS_PER_WORKER = ALLOWED_FAILURES + 1
#: Seconds a worker has to end after it is asked to, before it is terminated; and the zygote has
#: to answer a request for a worker.
STOP_TIMEOUT = 2.0


class WorkerLost(RuntimeError):
    """A task's worker died each time it ran it (more than :data:`ALLOWED_FAILURES` times), no
    worker is left, or the pool was stopped with the task unfinished."""


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


def _named(name: str) -> None:
    """Linux: the process's name (``ps``, ``top``, ``psutil``'s name) says what it is: the
    command's name otherwise, like the command's."""
    if sys.platform != "linux":
        return
    try:
        import ctypes
        ctypes.CDLL(None).prctl(15, name.encode()[:15], 0, 0, 0)      # PR_SET_NAME
    except (OSError, AttributeError):        # pragma: no cover - the name only
        pass


def _die_with_parent(parent: int) -> None:
    """Linux: the kernel sends this process SIGKILL when the command's process (pid ``parent``)
    dies (killed, out of memory), busy or not; strictly, when the thread that started it ends
    (the pool's thread for a spawned replacement: it stops every worker before it ends; the
    zygote for its workers). Elsewhere a worker ends at its next read of the closed pipe."""
    if sys.platform != "linux":
        return
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)          # PR_SET_PDEATHSIG
    except (OSError, AttributeError):        # pragma: no cover - no prctl: the pipe's end still ends it
        pass
    if os.getppid() != parent:               # it died before the call: nobody will send the signal
        os._exit(0)


def _started(name: str, parent_ends, parent: int | None) -> None:
    """What a worker and the zygote do first: their name, their signals, the command's pipe ends
    they hold closed, their parent's death theirs."""
    _named(name)
    # SIGINT (Ctrl-C reaches the whole process group) is the command's to handle: it stops the
    # workers itself. SIGTERM ends a worker (the command's own handler, inherited by a fork,
    # would raise haa_sym.errors.Terminated mid-task).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    # a fork holds copies of the command's ends of its own pipe and of the workers forked before
    # it: closed, so that the command's death closes its pipe (EOF) and ends it
    for c in parent_ends:
        c.close()
    if parent is not None:
        _die_with_parent(parent)


def _requests(conn):
    """The messages on ``conn`` until ``None`` or its end."""
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        yield msg


def _worker(conn, parent_ends=(), parent: int | None = None, initializer=None) -> None:
    """A worker process's loop: ``(key, payload)`` in, ``payload`` the pickled ``(fn, args)``;
    ``(key, ok, result, start, stop)`` out; until ``None`` or the pipe closes. The payload is
    unpickled here, apart from the key, so that a task whose function or arguments do not load
    in the worker (a function defined after the fork) fails as that task's error, not as a dead
    worker."""
    import pickle
    _started("haa_sym-worker", parent_ends, parent)
    if initializer is not None:
        initializer()
    for key, payload in _requests(conn):
        start = time.time()                  # the clock of the task stream (dask's too)
        try:
            fn, args = pickle.loads(payload)
            out, ok = fn(*args), True
        except BaseException as exc:         # noqa: BLE001 - the task's error, raised by its future
            out, ok = exc, False
        stop = time.time()
        try:
            conn.send((key, ok, out, start, stop))
        except Exception as exc:             # noqa: BLE001 - a result or error that does not pickle
            conn.send((key, False, RuntimeError(f"the result of task {key} could not be sent back "
                                                f"({type(exc).__name__}: {exc})"), start, stop))


def _zygote(conn, parent_ends, parent: int, initializer) -> None:
    """The zygote's loop (Linux): on each request a worker forked from this one-thread process,
    its pid sent back, then its pipe end and a pidfd of it as file descriptors (SCM_RIGHTS); until
    ``None`` or the pipe closes. Its children are reaped here (SIGCHLD); the command watches each
    through its pidfd, which a reap does not close."""
    from multiprocessing import reduction
    _started("haa_sym-zygote", parent_ends, parent)
    signal.signal(signal.SIGCHLD, _reap)
    me = os.getpid()
    for _ in _requests(conn):
        try:
            pid, mine, pidfd = _fork_worker(conn, me, initializer)
        except Exception as exc:             # noqa: BLE001 - this request's failure, told; the zygote goes on
            try:
                conn.send(("failed", f"{type(exc).__name__}: {exc}"))
            except OSError:
                return
            continue
        try:
            conn.send(("forked", pid))
            reduction.send_handle(conn, mine.fileno(), parent)
            reduction.send_handle(conn, pidfd, parent)
        except OSError:
            return
        finally:
            mine.close()
            os.close(pidfd)


def _fork_worker(conn, me: int, initializer):
    """(pid, the command's pipe end, a pidfd) of a worker forked from the zygote."""
    from multiprocessing.connection import Pipe
    mine, theirs = Pipe(duplex=True)
    # not reaped before its pidfd is open (a reaped pid may be another process's)
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGCHLD})
    try:
        pid = os.fork()
        if pid == 0:                         # the worker
            code = 0
            try:
                signal.signal(signal.SIGCHLD, signal.SIG_DFL)
                signal.pthread_sigmask(signal.SIG_SETMASK, old)
                _worker(theirs, (conn, mine), me, initializer)
            except BaseException:            # noqa: BLE001 - a worker's end, not the zygote's
                code = 1
            finally:
                for f in (sys.stdout, sys.stderr):   # a task's prints (os._exit does not flush)
                    try:
                        f.flush()
                    except Exception:        # noqa: BLE001 - closed streams
                        pass
                os._exit(code)
        try:
            pidfd = os.pidfd_open(pid)
        except OSError:
            os.kill(pid, signal.SIGKILL)     # not watchable: not left running
            raise
    except BaseException:
        mine.close()
        raise
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
        theirs.close()
    return pid, mine, pidfd


def _reap(signum, frame) -> None:
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return


def _pidfd_works() -> bool:
    """os.pidfd_open exists and the kernel (and a seccomp profile) allow it."""
    try:
        os.close(os.pidfd_open(os.getpid()))
    except (AttributeError, OSError):
        return False
    return True


class _Forked:
    """A worker the zygote forked (not this process's child): the part of
    ``multiprocessing.Process`` the pool uses, on a pidfd (no pid reuse can mislead it). Its exit
    code is its parent's to read: None."""

    exitcode = None

    def __init__(self, pid: int, pidfd: int):
        self.pid, self.sentinel = pid, pidfd

    def is_alive(self) -> bool:
        from multiprocessing.connection import wait          # poll(): any fd number, not select's < 1024
        return not wait([self.sentinel], 0)

    def join(self, timeout: float | None = None) -> None:
        from multiprocessing.connection import wait
        wait([self.sentinel], timeout)

    def terminate(self) -> None:
        self._signal(signal.SIGTERM)

    def kill(self) -> None:
        self._signal(signal.SIGKILL)

    def _signal(self, sig) -> None:
        try:
            signal.pidfd_send_signal(self.sentinel, sig)
        except ProcessLookupError:
            pass

    def close(self) -> None:
        os.close(self.sentinel)


class LocalPool:
    """N worker processes of one thread each, with a priority queue in this process.

    Parameters
    ----------
    n : int
        Worker processes (>= 1), started now.
    start_method : str
        ``multiprocessing``'s start method of the first N (default :data:`START_METHOD`);
        replacements are forked by the zygote after a fork (where pidfds work), else spawned.
    initializer : callable, optional
        Called by every worker (those started now and replacements) before its first task, as
        ``concurrent.futures``' initializer; a module-level function (a spawned worker loads it).
    """

    def __init__(self, n: int, start_method: str = START_METHOD, initializer=None):
        import multiprocessing               # here: a command that runs in-process never needs it
        from multiprocessing.reduction import ForkingPickler
        self._dumps = ForkingPickler.dumps
        ctx = multiprocessing.get_context(start_method)
        self._spawn = multiprocessing.get_context("spawn")
        if initializer is not None:
            self._dumps(initializer)         # a spawned replacement loads it: refused now, not then
        self._init = initializer
        self._replacements = n * REPLACEMENTS_PER_WORKER
        self._starting = 0                   # replacements being started (the pool is not empty)
        self._zygote = None                  # (process, connection): forks replacements (Linux)
        self._spawn_replacements = False
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
        self._broken: BaseException | None = None    # the dispatcher's own failure
        self._thread = None
        try:
            for _ in range(n):
                mine, theirs = ctx.Pipe(duplex=True)
                # the command's ends that a fork copies into the worker (a spawned worker gets
                # only what it is given)
                ends = [mine, *(c for _, c in self._workers.values())] if start_method == "fork" else []
                proc = ctx.Process(target=_worker, args=(theirs, ends, os.getpid(), self._init), daemon=True,
                                   name="haa_sym-worker")
                proc.start()
                theirs.close()
                self._workers[proc.pid] = (proc, mine)
                self._idle.append(proc.pid)
            if start_method == "fork" and _pidfd_works():
                mine, theirs = ctx.Pipe(duplex=True)
                ends = [mine, *(c for _, c in self._workers.values())]
                zygote = ctx.Process(target=_zygote, args=(theirs, ends, os.getpid(), self._init), daemon=True,
                                     name="haa_sym-zygote")
                try:
                    zygote.start()
                except BaseException:
                    mine.close()
                    raise
                finally:
                    theirs.close()
                self._zygote = (zygote, mine)
            # no zygote (spawned workers, or no pidfd): replacements are spawned, as such workers
            self._spawn_replacements = self._zygote is None
            self._wake_r, self._wake_w = multiprocessing.Pipe(duplex=False)
            self._thread = threading.Thread(target=self._dispatch, name="haa_sym-pool", daemon=True)
            self._thread.start()
        except BaseException:                # Ctrl-C, SIGTERM or a failed fork: nothing left running
            self._closed = True
            self._stop_workers()
            raise

    # -- the part of distributed.Client that TaskRunner uses ------------------------------------
    def submit(self, fn, *args, priority: int = 0, pure: bool = False, key: str | None = None) -> PoolFuture:
        """``fn(*args)`` on a worker; a higher ``priority`` is given to a worker first."""
        del pure                             # every task runs (no result cache), as dask's pure=False
        name = key if key is not None else f"{getattr(fn, '__name__', 'task')}-{next(self._names)}"
        fut = PoolFuture(name)
        with self._lock:
            if self._closed:
                raise RuntimeError("the local pool is closed")
            lost = self._lost_why()
            if lost is None:
                heapq.heappush(self._queue, (-priority, next(self._order), name, fn, args, fut))
        if lost is not None:
            fut.set_exception(WorkerLost(lost))
            return fut
        self._wake_w.send_bytes(b"")
        return fut

    def gather(self, futures) -> list:
        return [f.result() for f in futures]

    def cancel(self, futures) -> None:
        for f in futures:
            f.cancel()                       # a queued task is skipped; a running one finishes

    def nthreads(self) -> dict:
        with self._lock:
            return {} if self._broken is not None else {pid: 1 for pid in self._workers}

    def scheduler_info(self) -> dict:
        return {"workers": self.nthreads()}

    def get_task_stream(self, start: float | None = None) -> list:
        """The finished tasks as dask's task stream records ``{"key", "worker", "startstops":
        [{"action": "compute", "start", "stop"}]}``, those that stopped after ``start``."""
        with self._lock:
            return [r for r in self._stream if start is None or r["startstops"][0]["stop"] >= start]

    def close(self) -> None:
        """Stop the dispatcher and the workers: a running task is abandoned (its worker
        terminated) and its future, as every queued one, raises WorkerLost."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        try:
            self._wake_w.send_bytes(b"")
        except OSError:
            pass
        self._thread.join(STOP_TIMEOUT)
        self._stop(self._abandoned_now())
        for c in (self._wake_r, self._wake_w):
            c.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- the dispatcher thread -------------------------------------------------------------------
    def _lost_why(self) -> str | None:
        """Why no task can run any more (under the lock), or None."""
        if self._broken is not None:
            return f"the local pool's dispatcher failed ({type(self._broken).__name__}: {self._broken})"
        return None if self._workers or self._starting else "no worker is left"

    def _dispatch(self) -> None:
        try:
            self._serve()
        except BaseException as exc:         # noqa: BLE001 - every waiting future is told, none hangs
            with self._lock:
                self._broken = exc
                left = self._abandoned()
                try:
                    self._stop_workers()     # before this thread ends (its replacements' parent-death signal)
                except Exception:            # noqa: BLE001 - close() tries again; the futures are told below
                    pass
            for fut in left:
                if not fut.done():
                    fut.set_exception(WorkerLost(self._lost_why()))

    def _serve(self) -> None:
        from multiprocessing.connection import wait
        while True:
            with self._lock:
                closed = self._closed
                if closed:
                    left = self._abandoned()
                else:
                    failed = self._feed()
                    conns = {c: pid for pid, (_, c) in self._workers.items()}
                    sentinels = {p.sentinel: pid for pid, (p, _) in self._workers.items()}
            if closed:
                # stopped by this thread: Linux's parent-death signal of a spawned replacement
                # is tied to the thread that started it, this one (one still winding down when
                # it ended was killed: its semaphores leaked)
                self._stop(left)
                return
            _fail(failed)
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

    def _feed(self) -> list:
        """Give queued tasks to idle workers (under the lock); returns the (future, error) pairs
        of tasks that could not be sent, to be set after the lock is released (a future's
        callbacks may call this pool)."""
        failed = []
        while self._idle and self._queue:
            entry = heapq.heappop(self._queue)
            fut = entry[-1]
            # a task queued again after its worker died is running already (a future does not go
            # back to pending); any other is started here, or skipped if cancelled while queued
            if not fut.running() and not fut.set_running_or_notify_cancel():
                continue
            try:
                payload = self._dumps((entry[3], entry[4]))
            except Exception as exc:         # noqa: BLE001 - the task's function or arguments do not pickle
                failed.append((fut, exc))
                continue
            pid = self._idle.pop()
            try:
                self._workers[pid][1].send((entry[2], bytes(payload)))
            except OSError:
                # the worker has died (its sentinel says so next): the task waits for another,
                # and the dead worker is not idle any more
                heapq.heappush(self._queue, entry)
                continue
            self._running[pid] = entry
        return failed

    def _finished(self, pid: int) -> None:
        import pickle
        if pid not in self._workers:
            return
        conn = self._workers[pid][1]
        try:
            data = conn.recv_bytes()
        except (EOFError, OSError):
            return                           # the worker died: its sentinel says so
        try:
            key, ok, out, start, stop = pickle.loads(data)
        except Exception as exc:             # noqa: BLE001 - a result that pickles but does not load here
            key, ok, start, stop = None, False, time.time(), time.time()
            out = RuntimeError(f"a task's result could not be loaded ({type(exc).__name__}: {exc})")
        with self._lock:
            entry = self._running.pop(pid, None)
            if entry is None:                # stopped meanwhile (close)
                return
            key = entry[2] if key is None else key
            self._idle.append(pid)
            self._failures.pop(key, None)
            self._stream.append({"key": key, "worker": f"local-{pid}",
                                 "startstops": [{"action": "compute", "start": start, "stop": stop}]})
            # the worker's next task before the result is handed over: the result wakes the
            # command's thread, whose work on it (a stream's follow-up, the progress bar) holds
            # the GIL, and this thread waited for it to send the next task (2.8 ms between two
            # tasks of the nonlinear map on one worker, median, against about 1 ms of pickling)
            failed = self._feed()
        _fail(failed)
        fut = entry[-1]
        if ok:
            fut.set_result(out)
        else:
            fut.set_exception(out)

    def _died(self, pid: int) -> None:
        """A worker's process ended: its task queued again, or given up; the worker replaced."""
        lost = []
        with self._lock:
            if pid not in self._workers:     # stopped meanwhile (close)
                return
            proc, conn = self._workers.pop(pid)
            if pid in self._idle:
                self._idle.remove(pid)
            entry = self._running.pop(pid, None)
            if entry is not None:
                key = entry[2]
                self._failures[key] = self._failures.get(key, 0) + 1
                # dask's rule: given up when its deaths exceed allowed-failures
                if self._failures[key] > ALLOWED_FAILURES:
                    code = "" if proc.exitcode is None else f" (exit code {proc.exitcode})"
                    lost.append((entry[-1], WorkerLost(f"the worker processes running task {key} died "
                                                       f"{self._failures[key]} times{code}")))
                else:
                    # a new future state cannot go back to pending: the entry keeps its future,
                    # already running, and is given to the next idle worker as it is
                    heapq.heappush(self._queue, entry)
            replace = not self._closed and self._replacements > 0
            if replace:
                self._replacements -= 1
                self._starting += 1
        conn.close()
        if isinstance(proc, _Forked):
            proc.close()
        _fail(lost)
        if replace:
            self._replace()
        self._fail_all_if_none_left()

    def _replace(self) -> None:
        """A new worker: the zygote's fork where workers are forked, else spawned (module
        docstring); none if that fails (the others go on, or the pool is left with none)."""
        proc = mine = None
        try:
            if self._spawn_replacements:
                proc, mine = self._spawned()
            elif self._zygote is not None:
                proc, mine = self._from_zygote()
        except Exception:                    # noqa: BLE001 - none started (limits, the zygote's failure)
            proc = mine = None
        with self._lock:
            self._starting -= 1
            if proc is not None and not self._closed:
                self._workers[proc.pid] = (proc, mine)
                self._idle.append(proc.pid)
                return
        if proc is not None:                 # closed meanwhile: not left running
            proc.terminate()
            _end([(proc, mine)], ask=False)

    def _from_zygote(self):
        """(process, connection) of a worker forked by the zygote. An answer not in time or out
        of step ends the zygote (its late answer would be read as the next one's)."""
        from multiprocessing import reduction
        from multiprocessing.connection import Connection
        conn = self._zygote[1]
        try:
            conn.send(True)
            if not conn.poll(STOP_TIMEOUT):
                raise TimeoutError(f"the zygote did not answer within {STOP_TIMEOUT:g} s")
            what, value = conn.recv()
            if what != "forked":
                raise RuntimeError(f"the zygote could not fork a worker ({value})")
            fds = [reduction.recv_handle(conn), reduction.recv_handle(conn)]
        except RuntimeError:
            raise
        except BaseException:
            with self._lock:
                zygote, self._zygote = self._zygote, None
            if zygote is not None:
                zygote[0].kill()
                _end([zygote], ask=False)
            raise
        for fd in fds:                       # not inherited by a later exec of the command's
            os.set_inheritable(fd, False)
        return _Forked(value, fds[1]), Connection(fds[0])

    def _spawned(self):
        """(process, connection) of a spawned worker (a new interpreter)."""
        mine, theirs = self._spawn.Pipe(duplex=True)
        proc = self._spawn.Process(target=_worker, args=(theirs, (), os.getpid(), self._init), daemon=True,
                                   name="haa_sym-worker")
        try:
            proc.start()
        except BaseException:
            mine.close()
            raise
        finally:
            theirs.close()
        return proc, mine

    def _fail_all_if_none_left(self) -> None:
        with self._lock:
            if self._workers or self._starting:
                return
            lost = [(e[-1], WorkerLost("no worker is left")) for e in self._queue]
            self._queue = []
        _fail(lost)

    def _stop_workers(self) -> None:
        """Every worker stopped: a busy one terminated, an idle one asked to end; then the zygote
        (its workers would get its parent-death signal) (under the lock or before the
        dispatcher runs)."""
        for pid, (proc, conn) in list(self._workers.items()):
            if pid not in self._idle:        # running a task (self._running may be abandoned already)
                proc.terminate()             # its task abandoned (an error, Ctrl-C): no wait for it
                continue
            try:
                conn.send(None)
            except OSError:
                pass
        members = list(self._workers.values())
        self._workers.clear()
        self._idle.clear()
        _end(members, ask=False)
        if self._zygote is not None:
            zygote, self._zygote = self._zygote, None
            _end([zygote], ask=True)

    def _abandoned_now(self) -> list:
        with self._lock:
            return self._abandoned()

    def _stop(self, left: list) -> None:
        """The workers stopped, then ``left``'s futures failed (outside the lock: their
        callbacks may call this pool), whatever the stop raises."""
        try:
            with self._lock:
                self._stop_workers()
        finally:
            _fail([(f, WorkerLost("the local worker processes were stopped")) for f in left])

    def _abandoned(self) -> list:
        """The futures of every queued and running task, taken from the pool (under the lock)."""
        left = [e[-1] for e in self._queue] + [e[-1] for e in self._running.values()]
        self._queue, self._running = [], {}
        return left


def _end(members, ask: bool) -> None:
    """Wait for (process, connection) pairs to end, terminated then killed past STOP_TIMEOUT;
    ``ask``: sent ``None`` first."""
    for _, conn in members if ask else ():
        try:
            conn.send(None)
        except OSError:
            pass
    deadline = time.monotonic() + STOP_TIMEOUT
    for proc, conn in members:
        proc.join(max(0.0, deadline - time.monotonic()))
        if proc.is_alive():
            proc.terminate()                 # SIGTERM: a worker's default action (see _worker)
            proc.join(STOP_TIMEOUT)
        if proc.is_alive():
            proc.kill()
            proc.join()
        conn.close()
        if isinstance(proc, _Forked):
            proc.close()                     # its pidfd


def _fail(pairs) -> None:
    for fut, exc in pairs:
        if not fut.done():
            fut.set_exception(exc)
