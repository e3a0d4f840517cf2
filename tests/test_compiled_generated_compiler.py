"""The compiled-library cache checks itself; compiler faults are one message, exit 2 (issue 7).

Every test uses its own cache directory (never the user's). A library is never loaded into this
process before it is damaged: truncating a mapped library would crash the test process itself.
"""
import os
import shutil
import subprocess
import sys

import pytest

from haa_sym.errors import CompilerError, NoCompiler
from haa_sym.compiled.generated import Compiler

pytestmark = pytest.mark.skipif(not (shutil.which("cc") or shutil.which("gcc")),
                                reason="needs a C compiler")
GCC = shutil.which("gcc") or shutil.which("cc")

TINY = "double haa_twice(double x) { return 2.0 * x + 0.25; }\n"


@pytest.fixture
def tiny(tmp_path):
    c = tmp_path / "tiny.c"
    c.write_text(TINY)
    return c


def _call(lib):
    """haa_twice(1.5) from ``lib``, in a fresh process."""
    code = ("import ctypes, sys\nf = ctypes.CDLL(sys.argv[1]).haa_twice\n"
            "f.restype = ctypes.c_double\nf.argtypes = [ctypes.c_double]\nprint(repr(f(1.5)))")
    return subprocess.run([sys.executable, "-c", code, str(lib)], capture_output=True, text=True,
                          check=True).stdout


def _truncate(lib):
    with open(lib, "r+b") as f:
        f.truncate(lib.stat().st_size // 2)


def _flip_byte(lib):
    data = bytearray(lib.read_bytes())
    data[len(data) // 2] ^= 0x40
    lib.write_bytes(bytes(data))


def _replace(path, how):
    path.unlink()
    if how == "fifo":
        os.mkfifo(path)
    elif how == "dir":
        path.mkdir()
    else:
        path.write_bytes(bytes(range(256)) + b"\xab" * 44)     # not UTF-8, not a digest


@pytest.mark.parametrize("damage", [_truncate, _flip_byte, lambda lib: lib.unlink(),
                                    lambda lib: Compiler.digest_path(lib).unlink(),
                                    # what lies in the cache may not be a file (issue 26's prober): a FIFO blocked
                                    # the process for ever, binary bytes were a UnicodeDecodeError, a directory a
                                    # message naming a temporary file left behind
                                    lambda lib: _replace(lib, "fifo"),
                                    lambda lib: _replace(Compiler.digest_path(lib), "fifo"),
                                    lambda lib: _replace(Compiler.digest_path(lib), "binary"),
                                    lambda lib: _replace(Compiler.digest_path(lib), "dir")],
                         ids=["truncated", "flipped", "no-library", "no-digest", "library-fifo", "digest-fifo",
                              "digest-binary", "digest-dir"])
def test_damaged_library_is_rebuilt(tmp_path, tiny, damage):
    comp = Compiler(cc=GCC, cache_dir=tmp_path / "cache")
    lib = comp.build(tiny)
    good, result = lib.read_bytes(), _call(lib)
    assert comp.verified(lib) and result == "3.25\n"
    damage(lib)
    assert not comp.verified(lib)
    assert comp.build(tiny) == lib
    assert comp.verified(lib) and lib.read_bytes() == good and _call(lib) == result
    # only the library and its digest: no temporary files left behind
    assert sorted(p.name for p in lib.parent.iterdir()) == ["tiny.so", "tiny.so.sha256"]


def test_verified_library_is_not_rebuilt(tmp_path, tiny):
    comp = Compiler(cc=GCC, cache_dir=tmp_path / "cache")
    lib = comp.build(tiny)
    mtime = lib.stat().st_mtime_ns
    assert comp.build(tiny) == lib and lib.stat().st_mtime_ns == mtime


def test_cc_with_flags_is_honoured(tmp_path, tiny):
    plain = Compiler(cc=GCC, cache_dir=tmp_path / "cache").build(tiny)
    flagged = Compiler(cc=f"{GCC} -O0", cache_dir=tmp_path / "cache").build(tiny)
    assert flagged != plain  # the command is part of the cache key
    assert _call(flagged) == _call(plain) == "3.25\n"


def test_failing_compiler_is_named_with_its_output(tmp_path, tiny):
    cache = tmp_path / "cache"
    with pytest.raises(CompilerError, match=r"CC = '/bin/false' failed \(exit status 1\)"):
        Compiler(cc="/bin/false", cache_dir=cache).build(tiny)
    tiny.write_text("double broken(double x) { return x +; }\n")
    with pytest.raises(CompilerError, match=r"(?s)CC = .* failed.*tiny.c.*error"):
        Compiler(cc=GCC, cache_dir=cache).build(tiny)
    assert not [p for p in cache.rglob("*") if p.is_file()]  # no partial library left


def test_missing_compiler_command_is_no_compiler(tmp_path):
    with pytest.raises(NoCompiler, match="no C compiler found .CC = '/nonexistent/cc -O0'"):
        Compiler(cc="/nonexistent/cc -O0", cache_dir=tmp_path)
    with pytest.raises(CompilerError, match="cannot be split"):
        Compiler(cc="gcc '-O0", cache_dir=tmp_path)


@pytest.mark.parametrize("command", [["-m", "haa_sym.cli", "stability", "--P-gain", "200",
                                      "--D-gain", "10"], ["-m", "haa_sym.check.verify"]])
def test_failing_compiler_exits_2(tmp_path, command):
    env = dict(os.environ, CC="/bin/false", HAA_SYM_CACHE=str(tmp_path / "cache"))
    proc = subprocess.run([sys.executable, *command], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("haa-sym: error: compiling ")
    assert "CC = '/bin/false' failed" in proc.stderr and "Traceback" not in proc.stderr
    assert proc.stdout == ""



def test_unwritable_cache_names_the_variable(tmp_path):
    (tmp_path / "file").write_text("not a directory")
    env = dict(os.environ, HAA_SYM_CACHE=str(tmp_path / "file" / "cache"))
    proc = subprocess.run([sys.executable, "-m", "haa_sym.cli", "stability", "--P-gain", "200",
                           "--D-gain", "10"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr == (f"haa-sym: error: the compiled-code cache {tmp_path / 'file' / 'cache'} "
                           "(HAA_SYM_CACHE, default ~/.cache/haa_sym) cannot be created: Not a "
                           "directory; allowed: a writable directory\n")


SLOW_CC = """#!/bin/sh
# a compiler whose child (cc1's stand-in) runs long and leaves a temporary in $TMPDIR
[ "$1" = --version ] && { echo slowcc 1.0; exit 0; }
touch "$TMPDIR/ccTEMP.s"
sleep 60 &
echo $! > "$PROBE_PIDFILE"
wait
"""


def test_sigterm_during_compile_stops_the_compiler_group(tmp_path, tiny):
    """SIGTERM during the first compile left cc1 running and its temporaries behind (issue 26):
    the compiler's whole process group is stopped and its TMPDIR removed."""
    import signal
    import time
    cc = tmp_path / "slowcc"
    cc.write_text(SLOW_CC)
    cc.chmod(0o755)
    pidfile, cache = tmp_path / "child.pid", tmp_path / "cache"
    code = ("import signal, sys\nfrom haa_sym.errors import Terminated\n"
            "def term(*a): raise Terminated()\nsignal.signal(signal.SIGTERM, term)\n"
            "from haa_sym.compiled.generated import Compiler\n"
            "try:\n    Compiler(cc=sys.argv[1], cache_dir=sys.argv[2]).build(__import__('pathlib').Path(sys.argv[3]))\n"
            "except Terminated:\n    sys.exit(143)\n")
    p = subprocess.Popen([sys.executable, "-c", code, str(cc), str(cache), str(tiny)],
                         env={**os.environ, "PROBE_PIDFILE": str(pidfile)})
    try:
        deadline = time.monotonic() + 30
        while not (pidfile.exists() and pidfile.read_text().strip()):
            assert p.poll() is None and time.monotonic() < deadline, "the compiler never started"
            time.sleep(0.05)
        child = int(pidfile.read_text())
        p.send_signal(signal.SIGTERM)
        assert p.wait(10) == 143
    finally:
        if p.poll() is None:
            p.kill()
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        os.kill(child, 9)
        pytest.fail("the compiler's child kept running after SIGTERM")
    left = [q.name for q in cache.rglob("*")] if cache.exists() else []
    assert not [n for n in left if n.startswith("cc-tmp") or n.endswith((".s", ".so"))], left
