"""Faults found by probes (issue 16, items 14-19): every one is now exit status 2 and one line,
refused before the work (and the memory) it would cost, or handled as documented."""
import os
import shutil
import signal
import socket
import stat
import subprocess
import sys
import threading
import time
import tracemalloc
from fractions import Fraction

import numpy as np
import pytest

from haa_sym import ClosedLoop, ParameterError, load_params
from haa_sym.cli import main
from haa_sym.compiled.generated import Compiler
from haa_sym.design import schedule as schedule_module
from haa_sym.errors import CompilerError, OutputError
from haa_sym.io.gridspec import grid
from haa_sym.io.outputs import Transaction, check_file
from haa_sym.loop import closed_loop as closed_loop_module
from haa_sym.loop.exact import charpoly_adjugate, transfer_polynomials

from conftest import ROOT

PY = sys.executable
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
HUGE = "1000000000"


def one_error(err: str) -> str:
    """The single error line of a command's stderr (no traceback)."""
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("MAXRSS ")]
    assert "Traceback" not in err
    assert len(lines) == 1 and lines[0].startswith("haa-sym: error: "), err
    return lines[0]


# --- item 14: one budget gate before every command allocates --------------------------------

@pytest.mark.parametrize("argv, expected", [
    (["contact", "--n-scan", HUGE], "n_scan = 1000000000: a contact scan of 1000000000 stiffnesses would need"),
    (["contact", "--option", f"n_omega={HUGE}"], "n_omega = 1000000000: a frequency grid"),
    (["boundary", "--option", f"n_omega={HUGE}"], "n_omega = 1000000000: a frequency grid"),
    (["margins", "--option", f"n_omega={HUGE}"], "n_omega = 1000000000: a frequency grid"),
    (["passivity", "--option", f"n_omega={HUGE}"], "n_omega = 1000000000: a frequency grid"),
    (["stability", "--P-gain", "1", "--D-gain", "1", "--option", f"n_omega={HUGE}"], "n_omega = 1000000000"),
    (["regions", "--robust", "--P-gain", "lin:1:2:100000", "--D-gain", "lin:1:2:100000"],
     "a robust region of 100000 x 100000 (P_gain x D_gain) points over 2 leg configurations"),
    (["schedule", "--P-gain", "lin:1:2:100000", "--D-gain", "lin:1:2:100000"], "100000 x 100000"),
    (["step", "--duration", "1e9"], "duration = 1000000000.0 s: a step response"),
    (["reproduce", "--option", f"n_omega={HUGE}"], "n_omega = 1000000000: a frequency grid"),
])
def test_budget_refuses_before_allocating(argv, expected, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", "64M")
    if argv[0] == "reproduce":
        argv = argv + ["--out", str(tmp_path / "res")]
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        rc = main(argv)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    out, err = capsys.readouterr()
    assert rc == 2
    line = one_error(err)
    assert expected in line and "allowed: at most 64 MiB (the memory budget" in line
    assert peak < 32 * 2**20, f"{peak / 2**20:.0f} MiB traced before refusing"
    assert time.perf_counter() - t0 < 20
    assert out == ""                   # margins printed its first line before refusing
    assert list(tmp_path.iterdir()) == []


def test_stability_refuses_huge_N_av_at_once(capsys):
    """N_av = 10**6 built a million-coefficient filter and its common denominator for minutes;
    the generated capacity is checked from the counts first."""
    t0 = time.perf_counter()
    rc = main(["stability", "--P-gain", "1", "--D-gain", "1", "--set", "N_av=1000000"])
    line = one_error(capsys.readouterr().err)
    assert rc == 2 and time.perf_counter() - t0 < 10
    assert "N_av = 1000000 is out of range; allowed: an integer >= 1 and <= 10000" in line
    # within the file format's range, beyond the generated capacity: refused from the counts
    t0 = time.perf_counter()
    rc = main(["stability", "--P-gain", "1", "--D-gain", "1", "--set", "N_av=10000"])
    line = one_error(capsys.readouterr().err)
    assert rc == 2 and time.perf_counter() - t0 < 10
    assert "N_av = 10000 gives a closed loop of order 10008" in line and "allowed: N_av <= 56" in line
    assert main(["stability", "--P-gain", "1", "--D-gain", "1", "--set", "N_av=56"]) == 0   # the edge


@pytest.mark.parametrize("argv", [["contact", "--option", f"n_omega={HUGE}"],
                                  ["regions", "--robust", "--P-gain", "lin:1:2:100000", "--D-gain",
                                   "lin:1:2:100000"]])
def test_budget_peak_rss_of_the_process(argv):
    """The two probes that grew to 22 GB and 9.6 GB: the whole process stays at its import size."""
    code = ("import atexit, resource, sys\n"
            "atexit.register(lambda: sys.stderr.write("
            "f'MAXRSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}\\n'))\n"
            "from haa_sym.cli import main\nsys.exit(main(sys.argv[1:]))\n")
    p = subprocess.run([PY, "-c", code, *argv], capture_output=True, text=True, timeout=120,
                       env={**ENV, "HAA_SYM_MEMORY_BUDGET": "64M"})
    assert p.returncode == 2
    one_error(p.stderr)
    rss_kib = int(p.stderr.split("MAXRSS ")[1].split()[0])
    assert rss_kib < 600 * 1024, f"peak RSS {rss_kib / 1024:.0f} MiB"


# --- item 15: --scheduler at a service that is not dask -------------------------------------

@pytest.fixture
def tcp_server():
    """start(reply): a local TCP server on a free port that accepts, sends ``reply`` (maybe
    nothing) and then holds the connection silently; returns its tcp:// address."""
    sockets, stop = [], threading.Event()

    def start(reply: bytes) -> str:
        srv = socket.socket()
        srv.bind(("127.0.0.1", 0))
        srv.listen(8)
        srv.settimeout(0.2)
        sockets.append(srv)

        def serve():
            while not stop.is_set():
                try:
                    conn, _ = srv.accept()
                except OSError:
                    continue
                sockets.append(conn)
                if reply:
                    conn.sendall(reply)
        threading.Thread(target=serve, daemon=True).start()
        return f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    yield start
    stop.set()
    for s in sockets:
        s.close()


@pytest.mark.parametrize("reply, why", [
    (b"", "no dask handshake within 1 s"),
    (b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n\r\nhi", "its answer is not dask's protocol"),
    (b"220 mail.example ESMTP ready\r\n", "its answer is not dask's protocol"),
])
def test_scheduler_that_is_not_dask(reply, why, tcp_server, monkeypatch, capsys):
    pytest.importorskip("distributed")
    monkeypatch.setattr(schedule_module, "CONNECT_TIMEOUT", 1.0)
    address = tcp_server(reply)
    t0 = time.perf_counter()
    rc = main(["schedule", "--P-gain", "log:1:100:3", "--D-gain", "lin:1:5:2", "--scheduler", address])
    line = one_error(capsys.readouterr().err)
    assert rc == 2 and time.perf_counter() - t0 < 15
    assert f"--scheduler '{address}': " in line and why in line
    assert "allowed: the address of a running dask.distributed scheduler" in line


# --- item 16: replacing an output keeps what the user set on it -------------------------------

def test_replace_keeps_the_file_mode(tmp_path):
    f = tmp_path / "out.csv"
    f.write_text("old\n")
    f.chmod(0o600)
    with Transaction() as tx:
        tx.write_text(f, "new\n")
    assert f.read_text() == "new\n" and stat.S_IMODE(f.stat().st_mode) == 0o600


def test_replace_keeps_the_directory_mode(tmp_path):
    d = tmp_path / "res"
    d.mkdir()
    (d / "old.txt").write_text("old")
    d.chmod(0o700)
    with Transaction() as tx:
        (tx.directory(d) / "new.txt").write_text("new")
    assert sorted(p.name for p in d.iterdir()) == ["new.txt"] and stat.S_IMODE(d.stat().st_mode) == 0o700


def test_symlinked_output_writes_its_target(tmp_path):
    real = tmp_path / "real.csv"
    real.write_text("old\n")
    real.chmod(0o640)
    link = tmp_path / "link.csv"
    link.symlink_to(real)
    with Transaction() as tx:
        tx.write_text(link, "new\n")
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert real.read_text() == "new\n" and stat.S_IMODE(real.stat().st_mode) == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.csv", "real.csv"]


def test_read_only_output_is_refused_before_work(tmp_path, capsys):
    f = tmp_path / "cells.csv"
    f.write_text("keep\n")
    f.chmod(0o444)
    with pytest.raises(OutputError, match=r"the existing file is read-only \(mode 0444\); allowed: a "
                                          r"writable file \(chmod u\+w it\) or a new path"):
        check_file(f, "--out")
    rc = main(["passivity", "--P-gain", "0", "--D-gain", "0", "--out", str(f)])
    line = one_error(capsys.readouterr().err)
    assert rc == 2 and f"--out '{f}': the existing file is read-only" in line
    assert f.read_text() == "keep\n" and stat.S_IMODE(f.stat().st_mode) == 0o444


# --- item 17: the compiled cache records only a library that loads ---------------------------

@pytest.fixture
def c_file(tmp_path):
    c = tmp_path / "probe.c"
    c.write_text("int haa_probe(void) { return 42; }\n")
    return c


@pytest.mark.parametrize("cc", ["true", "gcc -c"])
def test_compiler_that_links_nothing_is_not_recorded(cc, c_file, tmp_path):
    if shutil.which(cc.split()[0]) is None:
        pytest.skip(f"{cc.split()[0]} not installed")
    comp = Compiler(cc, cache_dir=tmp_path / "cache")
    with pytest.raises(CompilerError, match=rf"with CC = '{cc}' exited 0 but it is not a loadable shared "
                                            "library .*allowed: a CC that compiles and links"):
        comp.build(c_file, ("haa_probe",))
    assert list((tmp_path / "cache").rglob("*.sha256")) == [] and list((tmp_path / "cache").rglob("*.so")) == []


def test_library_without_the_function_is_refused(c_file, tmp_path):
    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    comp = Compiler("gcc", cache_dir=tmp_path / "cache")
    with pytest.raises(CompilerError, match=r"it does not export \['haa_missing'\]"):
        comp.build(c_file, ("haa_missing",))
    lib = comp.build(c_file, ("haa_probe",))
    assert comp.verified(lib)


def test_directory_in_place_of_the_library_is_rebuilt(c_file, tmp_path):
    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    comp = Compiler("gcc", cache_dir=tmp_path / "cache")
    lib = comp.build(c_file, ("haa_probe",))
    lib.unlink()
    lib.mkdir()
    (lib / "stray").write_text("x")
    assert comp.build(c_file, ("haa_probe",)) == lib
    assert lib.is_file() and comp.verified(lib)


def test_cli_with_a_compiler_that_links_nothing(tmp_path):
    p = subprocess.run([PY, "-m", "haa_sym.cli", "stability", "--P-gain", "1", "--D-gain", "1"],
                       capture_output=True, text=True, timeout=120,
                       env={**ENV, "CC": "true", "HAA_SYM_CACHE": str(tmp_path)})
    assert p.returncode == 2
    assert "with CC = 'true' exited 0 but it is not a loadable shared library" in one_error(p.stderr)
    assert list(tmp_path.rglob("*.sha256")) == []


# --- item 18: tracebacks that became one line --------------------------------------------------

def test_grid_count_with_a_non_ascii_digit():
    with pytest.raises(ParameterError, match=r"N = '²' is not an integer >= 1"):
        grid("lin:1:2:²", "--P-gain")


def test_deeply_nested_toml(tmp_path, capsys):
    f = tmp_path / "deep.toml"
    f.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    rc = main(["stability", "--P-gain", "1", "--D-gain", "1", "--params", str(f)])
    line = one_error(capsys.readouterr().err)
    assert rc == 2 and f"{f}: not a parameter file (arrays or tables nested too deeply" in line


def test_title_that_mathtext_cannot_parse(tmp_path, capsys):
    t0 = time.perf_counter()
    rc = main(["regions", "--P-gain", "lin:1:200:3", "--D-gain", "lin:1:5:2", "--out", str(tmp_path / "m.npz"),
               "--plot", str(tmp_path / "m.png"), "--title", "$\\frac{$"])
    line = one_error(capsys.readouterr().err)
    assert rc == 2 and time.perf_counter() - t0 < 20
    assert "--title '$\\\\frac{$': matplotlib cannot draw it" in line and "allowed: text, math between $" in line
    assert list(tmp_path.iterdir()) == []
    assert main(["regions", "--P-gain", "lin:1:200:3", "--D-gain", "lin:1:5:2", "--plot",
                 str(tmp_path / "m.png"), "--title", "HyQ, $N_{av} = 4$, cost \\$5"]) == 0


@pytest.mark.slow
def test_sigterm_rolls_back_like_sigint(tmp_path):
    out = tmp_path / "res"
    p = subprocess.Popen([PY, "-m", "haa_sym.cli", "reproduce", "--quick", "--out", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        deadline = time.monotonic() + 90
        # wait until the staged directory exists: the command is writing
        while not any(q.name.startswith(".res.") for q in tmp_path.iterdir()):
            assert p.poll() is None and time.monotonic() < deadline, "reproduce ended before staging"
            time.sleep(0.1)
        time.sleep(2)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 143
    assert "haa-sym: terminated (SIGTERM); no output written" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


# --- item 19: chains beyond the generated capacity ------------------------------------------

def chain_toml(n: int) -> str:
    """An actuator file (docs/model.md, "Actuator files"): rotor, then n bodies in a row."""
    lines = ["[about]", f'name = "{n}-body test chain"', 'description = "a long chain"',
             "[about.references]", 'mine = "haa_sym tests"', "",
             "[motor]", "L = 1e-3", "R = 1.0", "k_t = 0.1", "k_w = 0.1", "J_m = 2e-5", "B_m = 1e-4", "N = 50", ""]
    for i in range(n):
        lines += [f"[bodies.b{i}]", "J = 0.01", "B = 0.01"] + (["K = 5.0"] if i == n - 1 else []) + [""]
    for i in range(n):
        lines += [f"[couplings.c{i}]", f'between = ["{"rotor" if i == 0 else f"b{i - 1}"}", "b{i}"]',
                  "K = 5000.0", "D = 1.0", ""]
    lines += ["[sensors]", 'torque = "c0"', "torque_damping = false", 'encoder = "b0"', f'port = "b{n - 1}"', "",
              "[controller]", "Ts = 1e-3", "N_av = 4", "alpha = 0.9", "beta = 1.0", "P_t0 = 0.3", "I_t0 = 10.0", ""]
    return "\n".join(lines)


@pytest.mark.parametrize("n_bodies", [30, 50])
def test_chain_beyond_capacity_refused_before_compiling(n_bodies, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HAA_SYM_CACHE", str(tmp_path / "cache"))
    f = tmp_path / f"chain{n_bodies}.toml"
    f.write_text(chain_toml(n_bodies))
    t0 = time.perf_counter()
    rc = main(["stability", "--P-gain", "1", "--D-gain", "1", "--params", str(f)])
    line = one_error(capsys.readouterr().err)
    assert rc == 2 and time.perf_counter() - t0 < 10
    n_x = 3 + 2 * n_bodies
    assert (f"{f}: the chain has too many states for the generated code: {n_bodies} bodies give {n_x} plant "
            f"states (3 of the motor, 2 per body), a closed loop of order >= {n_x + 2}, above the largest "
            "generated capacity 64; allowed: at most 29 bodies") in line
    assert "N_av <=" not in line
    assert not (tmp_path / "cache").exists()           # nothing compiled


def test_exact_step_in_integers_equals_the_adjugate():
    """transfer_polynomials' integer recursion gives exactly charpoly_adjugate's Fractions."""
    rng = np.random.default_rng(3)
    Phi = rng.normal(size=(9, 9)) * np.logspace(-12, 0, 9)
    Gamma, C = rng.normal(size=(9, 2)), rng.normal(size=(4, 9))
    d, nums = transfer_polynomials(Phi, Gamma, C)
    d_ref, Ms = charpoly_adjugate(Phi)
    assert d == d_ref
    G = [[Fraction(float(v)) for v in row] for row in Gamma]
    for o, row in enumerate(C):
        c = [Fraction(float(v)) for v in row]
        for i in range(2):
            ref = [sum(c[a] * sum(M[a][b] * G[b][i] for b in range(9)) for a in range(9)) for M in Ms]
            assert nums[o][i] == ref


def test_exact_step_states_its_cost_for_large_plants(params, monkeypatch, capsys):
    monkeypatch.setattr(closed_loop_module, "SLOW_EXACT_STATES", 7)
    monkeypatch.setattr(closed_loop_module, "_PLANT_POLYS", closed_loop_module.BoundedCache())
    monkeypatch.setattr(closed_loop_module, "_BASES", closed_loop_module.BoundedCache())
    ClosedLoop(params)
    err = capsys.readouterr().err
    assert f"haa_sym: exact characteristic polynomial of the 7-state plant of {params.source}: about 0 s" in err
    monkeypatch.setattr(closed_loop_module, "SLOW_EXACT_STATES", 8)
    monkeypatch.setattr(closed_loop_module, "_PLANT_POLYS", closed_loop_module.BoundedCache())
    monkeypatch.setattr(closed_loop_module, "_BASES", closed_loop_module.BoundedCache())
    ClosedLoop(params)
    assert capsys.readouterr().err == ""


def test_deeply_nested_toml_runs_no_finalizer_at_the_recursion_limit(tmp_path):
    """Reading a file nested 5000 levels deep pauses the garbage collector: garbage waiting to be
    collected (cycles with finalizers) is not finalized deep in the parser, where the finalizer
    itself would hit the recursion limit (seen once in CI as "Exception ignored in ..." on stderr)."""
    import gc
    import sys
    f = tmp_path / "deep.toml"
    f.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    depth = []

    class Cycle:
        def __init__(self):
            self.me = self

        def __del__(self):
            depth.append(len(_frames()))

    def _frames():
        frame, out = sys._getframe(), []
        while frame is not None:
            out.append(frame)
            frame = frame.f_back
        return out
    threshold = gc.get_threshold()
    gc.disable()
    try:
        gc.collect()                             # the allocation count starts at 0
        for _ in range(100):
            Cycle()                              # garbage only the cyclic collector frees
        # the next collection after about 1000 allocations: inside the parser, about 800 frames
        # down (measured), near the recursion limit where the parse fails
        gc.set_threshold(1000)
        gc.enable()
        with pytest.raises(ParameterError, match="nested too deeply"):
            load_params(f)
    finally:
        gc.set_threshold(*threshold)
        gc.enable()
        gc.collect()
    assert depth and max(depth) < 200            # finalized after the parse, not deep inside it
