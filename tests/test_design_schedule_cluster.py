"""The cluster recipe of docs/schedule.md (issues 16.11, 26.3): a real `dask scheduler` and `dask
worker` pair, started with the page's own commands, listens on 127.0.0.1 only (every service: the
scheduler, its HTTP server, the nanny, the worker and its HTTP server), and the page's `haa-sym
schedule --scheduler` command run against it gives the bytes of the in-process run."""
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import threading
import sys
import time
from pathlib import Path

import psutil                 # a dependency of distributed
import pytest

import haa_sym
from haa_sym.cli import main

from conftest import ROOT

# a small grid of the page's command, so the test takes seconds
SMALL = ["--P-gain", "log:5:2000:4", "--D-gain", "lin:1:50:3", "--beta-tol", "0.1"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def dask_cli() -> list[str]:
    """The `dask` command of this interpreter's environment (distributed is a dependency)."""
    exe = Path(sys.executable).with_name("dask")
    if exe.exists():
        return [str(exe)]
    found = shutil.which("dask")
    if found is None:
        pytest.skip("the dask command is not installed")
    return [found]


def stop(proc: subprocess.Popen) -> None:
    """End a process this test started and its children (its own session), by its id."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
        except ProcessLookupError:
            pass


DOC = ROOT / "docs" / "schedule.md"


def recipe() -> tuple[list[str], list[str]]:
    """The page's `dask scheduler` and `dask worker` commands (its sh blocks), as argument lists."""
    lines = [ln.split("#")[0].strip() for block in re.findall(r"```sh\n(.*?)```", DOC.read_text(), re.S)
             for ln in block.splitlines()]
    (sched,) = [shlex.split(ln) for ln in lines if ln.startswith("dask scheduler ")]
    (worker,) = [shlex.split(ln) for ln in lines if ln.startswith("dask worker ")]
    return sched[1:], worker[1:]


def flag(argv: list[str], name: str) -> str:
    return argv[argv.index(name) + 1]


def test_the_docs_document_the_loopback_cluster_and_the_extra():
    sched, worker = recipe()
    # every service bound to loopback: the comm ports and the HTTP servers (dashboards)
    assert flag(sched, "--host") == "127.0.0.1" and flag(worker, "--host") == "127.0.0.1"
    assert flag(sched, "--dashboard-address").startswith("127.0.0.1:")
    assert flag(worker, "--dashboard-address").startswith("127.0.0.1:")
    assert worker[1] == f"tcp://127.0.0.1:{flag(sched, '--port')}"
    assert "haa-sym schedule --P-gain log:1:2000:60 --D-gain lin:1:50:40 --scheduler tcp://127.0.0.1:8786" \
        in DOC.read_text()
    # the package is not on an index: the extra is installed from a checkout
    assert "pip install -e '.[control]'" in (ROOT / "docs" / "python.md").read_text()


def listening(pids: set[int]) -> list[tuple[int, str, int]]:
    """(pid, address, port) of every listening TCP socket of ``pids`` (psutil, as `ss -ltnp`)."""
    return sorted((c.pid, c.laddr.ip, c.laddr.port) for c in psutil.net_connections("tcp")
                  if c.status == psutil.CONN_LISTEN and c.pid in pids)


def process_tree(procs) -> set[int]:
    pids = set()
    for p in procs:
        try:
            root = psutil.Process(p.pid)
            pids |= {root.pid} | {c.pid for c in root.children(recursive=True)}
        except psutil.NoSuchProcess:
            pass
    return pids


@pytest.mark.slow
def test_schedule_on_a_real_scheduler_and_worker_gives_the_in_process_bytes(tmp_path, capsys):
    distributed = pytest.importorskip("distributed")
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    # the workers import haa_sym from the tree under test, as an installed package would be found
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(Path(haa_sym.__file__).parents[1])] + [p for p in [os.environ.get("PYTHONPATH")] if p])}
    log = tmp_path / "logs"
    log.mkdir()
    procs = []
    try:
        # the page's commands, on free ports (the scheduler's and its HTTP server's)
        sched, worker = recipe()
        doc_port = flag(sched, "--port")
        sched[sched.index("--port") + 1] = str(port)
        i = sched.index("--dashboard-address") + 1
        sched[i] = f"{sched[i].rsplit(':', 1)[0]}:{free_port()}"
        worker[1] = worker[1].replace(f":{doc_port}", f":{port}")
        assert worker[1] == address
        procs.append(subprocess.Popen(
            dask_cli() + sched,
            stdout=open(log / "scheduler.log", "w"), stderr=subprocess.STDOUT, env=env, cwd=tmp_path,
            start_new_session=True))
        procs.append(subprocess.Popen(
            dask_cli() + worker,
            stdout=open(log / "worker.log", "w"), stderr=subprocess.STDOUT, env=env, cwd=tmp_path,
            start_new_session=True))
        deadline = time.monotonic() + 60
        while True:                                    # the scheduler up, one worker connected
            try:
                with distributed.Client(address, timeout="2s") as c:
                    c.wait_for_workers(1, timeout=max(1.0, deadline - time.monotonic()))
                break
            except (OSError, TimeoutError):
                if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
                    pytest.fail("the dask scheduler and worker did not start:\n"
                                + "\n".join(f.read_text()[-2000:] for f in sorted(log.iterdir())))
                time.sleep(0.5)
        # every service of both commands: the scheduler's port and HTTP server, the nanny, the
        # worker process and its HTTP server -- all on loopback, none on 0.0.0.0 or [::]
        sockets = listening(process_tree(procs))
        assert len(sockets) >= 5, sockets
        assert {ip for _, ip, _ in sockets} == {"127.0.0.1"}, sockets
        remote = tmp_path / "remote.csv"
        proc = subprocess.run([sys.executable, "-m", "haa_sym.cli", "schedule", "-q", *SMALL,
                               "--scheduler", address, "--out", str(remote)],
                              capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
        assert proc.returncode == 0, proc.stderr
    finally:
        for p in reversed(procs):
            stop(p)
    assert all(p.poll() is not None for p in procs)
    local = tmp_path / "local.csv"
    assert main(["schedule", "-q", *SMALL, "--out", str(local)]) == 0
    assert "impedances" in proc.stdout and "12 impedances" in capsys.readouterr().out
    assert remote.read_bytes() == local.read_bytes()
    assert local.read_text().startswith("P_gain,D_gain,beta,alpha,torque_bandwidth_rad_s,feasible,beta_at_limit,"
                                      "table_beta,cell_safe,table_meta\n")


@pytest.mark.slow
def test_a_dead_worker_stops_the_run_with_one_line(tmp_path):
    """The last worker killed mid-run: the command waited for ever (issue 26, item 11); now it
    stops with one line once the cluster has had no worker for no_worker_timeout s."""
    from haa_sym.errors import ParameterError
    from haa_sym.io.tasks import TaskRunner
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    sched = subprocess.Popen(dask_cli() + ["scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard",
                                           "--dashboard-address", "127.0.0.1:0"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True, env=env)
    worker = None
    try:
        worker = subprocess.Popen(dask_cli() + ["worker", address, "--host", "127.0.0.1", "--no-nanny",
                                                "--no-dashboard", "--nthreads", "1"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                                  env=env)
        runner = TaskRunner(address, False, connect_timeout=20, no_worker_timeout=3)
        deadline = time.monotonic() + 30
        while not runner.client.scheduler_info().get("workers"):
            assert time.monotonic() < deadline, "the worker never joined"
            time.sleep(0.2)
        killer = threading.Timer(1.0, lambda: os.killpg(worker.pid, signal.SIGKILL))
        killer.start()
        t0 = time.monotonic()
        with pytest.raises(ParameterError, match=r"no worker for 3 s with \d+ of 8 tasks pending"):
            runner.run(time.sleep, [(1.0,)] * 8, "sleeping")
        assert time.monotonic() - t0 < 15
        runner.close()
    finally:
        for p in (worker, sched):
            if p is not None:
                stop(p)
