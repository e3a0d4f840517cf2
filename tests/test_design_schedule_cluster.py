"""The README's cluster recipe (issue 16.11): a real `dask scheduler` and `dask worker` pair on
127.0.0.1, started as the README says, and the README's `haa-sym schedule --scheduler` command
run against it give the bytes of the in-process run."""
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

import haa_sym
from haa_sym.cli import main

from conftest import ROOT

# a small grid of the README's command, so the test takes seconds
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


def test_readme_documents_the_cluster_and_the_extra():
    readme = (ROOT / "README.md").read_text()
    assert "dask scheduler --host 127.0.0.1 --port 8786" in readme
    assert "dask worker tcp://127.0.0.1:8786 --nworkers 1 --nthreads 1" in readme
    assert "haa-sym schedule --P-gain log:1:2000:60 --D-gain lin:1:50:40 --scheduler tcp://127.0.0.1:8786" in readme
    assert "pip install 'haa_sym[control]'" in readme


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
        # the README's commands, on a free port and without the dashboards (ports of their own)
        procs.append(subprocess.Popen(
            dask_cli() + ["scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
            stdout=open(log / "scheduler.log", "w"), stderr=subprocess.STDOUT, env=env, cwd=tmp_path,
            start_new_session=True))
        procs.append(subprocess.Popen(
            dask_cli() + ["worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
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
    assert local.read_text().startswith("P_gain,D_gain,beta,alpha,torque_bandwidth_rad_s,feasible,beta_at_limit\n")
