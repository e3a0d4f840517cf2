"""``--scheduler local:N`` (issue 27, item 3): N worker processes (:class:`haa_sym.io.pool.LocalPool`),
started and stopped by the command. Refused values are one line; nothing the command starts
listens on any port (the pool's channels are pipes); the results are the in-process bytes; no
process is left behind, also when the command is ended by SIGTERM."""
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

import haa_sym
from haa_sym.cli import main
from haa_sym.errors import ParameterError
from haa_sym.io import tasks

from conftest import ROOT

SMALL = ["--P-gain", "log:5:2000:4", "--D-gain", "lin:1:50:3", "--beta-tol", "0.1"]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(
    [str(Path(haa_sym.__file__).parents[1])] + [p for p in [os.environ.get("PYTHONPATH")] if p])}


@pytest.mark.parametrize("cmd", [["schedule"], ["regions", "--nonlinear"]])
@pytest.mark.parametrize("value", ["local:0", "local:x", "local:", "local:1.5", "local:-2", "local: 2",
                                   "local:100000", "local:99999999999999999999"])
def test_a_bad_worker_count_is_one_line(cmd, value, capsys, tmp_path):
    out = tmp_path / ("s.csv" if cmd[0] == "schedule" else "m.npz")
    assert main([*cmd, "--scheduler", value, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"haa-sym: error: --scheduler {value!r}: ")
    assert "allowed: local:N with 1 <= N <= " in err
    assert not out.exists()


def test_more_workers_than_cores_warns_in_one_line(monkeypatch, capsys):
    started = []

    class Refuse(Exception):
        pass

    class FakePool:                        # records the arguments, starts nothing
        def __init__(self, n, initializer=None):
            started.append((n, initializer))
            raise Refuse()
    from haa_sym.io import pool
    monkeypatch.setattr(tasks.os, "cpu_count", lambda: 2)
    monkeypatch.setattr(tasks, "LocalPool", FakePool)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    with pytest.raises(Refuse):
        with tasks.cluster("local:3"):
            pass
    err = capsys.readouterr().err
    assert err == "haa-sym: warning: --scheduler local:3: 3 worker processes on 2 cores; they share the cores " \
                  "(no faster than local:2)\n"
    with pytest.raises(Refuse):
        with tasks.cluster("local:2"):
            pass
    assert capsys.readouterr().err == ""      # N = the cores: no warning
    # every worker (forked, spawned, a replacement) limits its own BLAS; the command's
    # environment is left as it was
    assert started == [(3, tasks.one_blas_thread), (2, tasks.one_blas_thread)]
    assert "OMP_NUM_THREADS" not in os.environ
    # on Linux the workers are forked from the command (its imports inherited: a start in
    # milliseconds); spawn elsewhere
    assert pool.START_METHOD == ("fork" if sys.platform == "linux" else "spawn")


def _blas_threads():
    import threadpoolctl
    time.sleep(0.2)                        # both workers busy at once: one answer each
    return os.getpid(), sorted({d["num_threads"] for d in threadpoolctl.threadpool_info() if d["user_api"] == "blas"})


def test_local_workers_run_one_blas_thread():
    """A worker is one thread: a forked worker inherits the command's OpenBLAS with a thread per
    core, so local:N limits it to one before the forks."""
    import numpy  # noqa: F401 - OpenBLAS loaded in the command before the fork, as in a command
    from threadpoolctl import threadpool_limits
    # the command's OpenBLAS on two threads when it forks: an xdist worker runs on one
    # (tests/conftest.py), which the forked workers would inherit unless local:N limits it first
    with threadpool_limits(limits=2, user_api="blas"):
        assert _blas_threads()[1] == [2]
        with tasks.cluster("local:2") as pool:
            got = dict(pool.gather([pool.submit(_blas_threads) for _ in range(2)]))
        assert _blas_threads()[1] == [2]          # the command's own limit restored
    assert len(got) == 2 and all(v == [1] for v in got.values()), got


def test_at_most_eight_worker_processes_per_core(monkeypatch):
    # a large N forked until the kernel killed processes for memory (the command's and others')
    monkeypatch.setattr(tasks.os, "cpu_count", lambda: 2)
    assert tasks.local_workers("local:16") == 16
    with pytest.raises(ParameterError, match=r"'local:17': .* from 1 to 16 \(8 per core, 2 cores\)"):
        tasks.local_workers("local:17")
    monkeypatch.setattr(tasks.os, "cpu_count", lambda: 16)
    assert tasks.local_workers("local:128") == 128


def test_a_refused_fork_is_one_line_and_leaves_no_worker(monkeypatch):
    import multiprocessing.context
    from haa_sym.io import pool
    started = []
    real = multiprocessing.context.ForkProcess.start

    def start(self):
        if started:
            raise BlockingIOError(11, "Resource temporarily unavailable")
        real(self)
        started.append(self)
    monkeypatch.setattr(multiprocessing.context.ForkProcess, "start", start)
    monkeypatch.setattr(pool, "START_METHOD", "fork")
    monkeypatch.setattr(pool.LocalPool.__init__, "__defaults__", ("fork", None))
    with pytest.raises(ParameterError, match=r"'local:2': the worker processes could not be started "
                                             r"\(BlockingIOError: .*\); allowed: fewer workers"):
        with tasks.cluster("local:2"):
            pass
    assert len(started) == 1 and _gone({started[0].pid}) == []


def test_other_values_pass_through():
    for spec in (None, "tcp://127.0.0.1:8786"):
        with tasks.cluster(spec) as s:
            assert s == spec
        assert tasks.local_workers(spec) is None
    assert tasks.local_workers("local:4") == 4 and tasks.local_workers("LOCAL:2") == 2
    with pytest.raises(ParameterError, match="local:0"):
        tasks.local_workers("local:0")


def _tree(root: psutil.Process) -> set[int]:
    try:
        return {root.pid} | {c.pid for c in root.children(recursive=True)}
    except psutil.NoSuchProcess:
        return set()


def _listening(pids: set[int]) -> set[tuple[int, str, int]]:
    # (pid, ip, port) of every listening TCP socket of the processes (UDP and unix sockets: the
    # pool opens none either)
    return {(c.pid, c.laddr.ip, c.laddr.port) for c in psutil.net_connections("tcp")
            if c.status == psutil.CONN_LISTEN and c.pid in pids}


def _watch(proc: subprocess.Popen, until=None):
    """Every process of ``proc``'s tree and every listening socket of it, seen while it runs;
    ``until(pids)`` True ends the watch early (the process keeps running)."""
    root, seen, sockets = psutil.Process(proc.pid), set(), set()
    while proc.poll() is None:
        pids = _tree(root)
        seen |= pids
        sockets |= _listening(pids)
        if until is not None and until(pids, sockets):
            break
        time.sleep(0.1)
    return seen, sockets


def _gone(pids: set[int], timeout: float = 10.0) -> list[int]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        alive = [p for p in pids if psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]
        if not alive:
            return []
        time.sleep(0.2)
    return alive


def _run_on_local_2(argv, out: Path, cwd: Path):
    """``haa-sym ARGV --scheduler local:2 --out OUT`` in a new process of its own session, watched
    to its end (killed with its tree if the test fails first): (returncode, stdout, stderr, every
    pid of its tree, every listening socket of it)."""
    proc = subprocess.Popen([sys.executable, "-m", "haa_sym.cli", *argv, "--scheduler", "local:2",
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=ENV, cwd=cwd, start_new_session=True)
    try:
        seen, sockets = _watch(proc)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    return proc.returncode, stdout, stderr, seen, sockets


def _params_file(tmp_path) -> Path:
    p = tmp_path / "hyq_limits.toml"
    p.write_text((ROOT / "model" / "hyq_haa.toml").read_text() + "\n[limits]\nV_max = 24.0\n")
    return p


@pytest.mark.slow
def test_regions_nonlinear_on_local_2_listens_nowhere_gives_the_bytes_and_leaves_nothing(tmp_path):
    p = _params_file(tmp_path)
    argv = ["regions", "--params", str(p), "--set", "beta=3", "--P-gain", "log:300:20000:6",
            "--D-gain", "lin:1:40:4", "--nonlinear", "--duration", "0.4", "--max-duration", "1.2", "-q"]
    remote = tmp_path / "remote.npz"
    rc, _, err, seen, sockets = _run_on_local_2(argv, remote, tmp_path)
    assert rc == 0, err
    assert err == ""                                  # no log lines of the pool
    # the command and its two worker processes; no listening socket (a fortiori none beyond
    # 127.0.0.1, issue 27's check: the pool's channels are pipes)
    assert len(seen) >= 3, seen
    assert sockets == set(), sockets
    assert _gone(seen) == []
    local = tmp_path / "local.npz"
    assert main([*argv, "--out", str(local)]) == 0
    a, b = np.load(local), np.load(remote)
    assert set(a.files) == set(b.files)
    for k in a.files:
        if k != "meta":
            assert a[k].tobytes() == b[k].tobytes(), k
    ma, mb = json.loads(str(a["meta"])), json.loads(str(b["meta"]))
    assert mb["nonlinear"].pop("scheduler") == "local worker processes"
    assert ma["nonlinear"].pop("scheduler") == "in-process"
    assert ma == mb
    assert len(set(a["nonlinear_class"].ravel())) >= 2


def start_schedule_on_local_2(out: Path, cwd: Path) -> subprocess.Popen:
    """``haa-sym schedule -q --scheduler local:2 --out OUT`` on the default grid (long enough to
    act on while it runs), started in a new process of its own session."""
    return subprocess.Popen([sys.executable, "-m", "haa_sym.cli", "schedule", "-q", "--scheduler", "local:2",
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=ENV, cwd=cwd, start_new_session=True)


@pytest.mark.slow
def test_sigterm_stops_the_local_cluster(tmp_path):
    out = tmp_path / "s.csv"
    proc = start_schedule_on_local_2(out, tmp_path)
    try:
        # until both workers run (the pool is up and the command is computing)
        seen, sockets = _watch(proc, until=lambda pids, s: len(pids) >= 3)
        assert proc.poll() is None, proc.communicate()
        time.sleep(1.0)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "haa-sym: terminated (SIGTERM); no output written"
    assert time.monotonic() - t0 < 30
    assert sockets == set(), sockets
    assert _gone(seen) == [], "worker processes left behind"
    assert not out.exists()


@pytest.mark.slow
def test_regions_robust_on_local_2_listens_nowhere_and_writes_the_in_process_bytes(tmp_path):
    # issue 27, item 2: the leg range's (and an uncertainty box's) maps on the cluster's workers
    argv = ["regions", "--robust", "--leg-mode", "box", "--P-gain", "log:1:2000:40", "--D-gain", "lin:1:50:20",
            "-q"]
    remote = tmp_path / "remote.npz"
    # dask's default port of the scheduler's HTTP server held (as a cluster of the two-terminal
    # recipe holds it): the command neither needs it nor warns
    held = socket.socket()
    try:
        held.bind(("127.0.0.1", 8787))
        held.listen()
    except OSError:
        pass                                     # another program holds it: the same test
    try:
        rc, _, err, seen, sockets = _run_on_local_2(argv, remote, tmp_path)
    finally:
        held.close()
    assert rc == 0, err
    assert err == ""
    assert sockets == set(), sockets
    assert _gone(seen) == []
    local = tmp_path / "local.npz"
    assert main([*argv, "--out", str(local)]) == 0
    assert remote.read_bytes() == local.read_bytes()      # the whole file, its meta included
    z = np.load(local)
    assert 0 < z["feasible"].sum() < z["feasible"].size
