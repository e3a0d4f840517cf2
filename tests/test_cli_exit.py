"""How ``haa-sym`` ends (haa_sym.cli.end, docs/startup.md "The end of a command"): the atexit
handlers run and the streams are flushed, then the process ends without the interpreter's
teardown (0.13-0.23 s of every command); Python's own exit while a non-daemon thread runs."""
import os
import subprocess
import sys
import threading
import tomllib

from conftest import ROOT
from haa_sym.cli import main
from haa_sym.io.tasks import TaskRunner


def _python(code: str, *args: str, **kw) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, *(["-c", code] if code else []), *args], capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=120, **kw)


def test_the_console_script_and_python_m_end_through_entry():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["haa-sym"] == "haa_sym.cli:entry"
    assert "entry()" in (ROOT / "src" / "haa_sym" / "cli" / "__main__.py").read_text()


def test_a_long_output_through_a_pipe_is_whole_and_the_status_is_the_commands(capsys):
    # 'options' prints every --set key of an actuator: flushed before the quick exit, byte for byte
    assert main(["options", "--params", "sea"]) == 0
    expected = capsys.readouterr().out
    done = _python("", "-m", "haa_sym.cli", "options", "--params", "sea")
    assert done.returncode == 0 and done.stdout == expected and len(expected) > 2000
    bad = _python("", "-m", "haa_sym.cli", "stability", "--P-gain", "-1", "--D-gain", "10")
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.startswith("haa-sym: error: ") and bad.stderr.count("\n") == 1
    usage = _python("", "-m", "haa_sym.cli", "no-such-command")
    assert usage.returncode == 2 and "invalid choice" in usage.stderr


def test_atexit_handlers_run_and_the_teardown_is_skipped():
    # an object whose finalizer would run in the interpreter's teardown: not run (the teardown is
    # what the quick exit skips), while the atexit handler is
    code = ("import atexit, sys\n"
            "class Teardown:\n    def __del__(self):\n        print('teardown ran', flush=True)\n"
            "keep = Teardown()\n"
            "atexit.register(print, 'atexit ran')\n"
            "sys.argv = ['haa-sym', '--version']\n"
            "from haa_sym.cli import entry\nentry()\n")
    done = _python(code)
    assert done.returncode == 0
    assert done.stdout.startswith("haa-sym ") and "atexit ran" in done.stdout
    assert "teardown ran" not in done.stdout


def test_the_statuses_of_sys_exit():
    for arg, status, err in (("None", 0, ""), ("3", 3, ""), ("258", 2, ""), ("'no such file'", 1, "no such file\n")):
        done = _python(f"from haa_sym.cli import end\nend({arg})\n")
        assert (done.returncode, done.stderr) == (status, err), arg


def test_a_running_non_daemon_thread_is_waited_for(tmp_path):
    # Python's own exit joins it; the quick exit would kill it mid-work
    out = tmp_path / "thread.txt"
    code = ("import threading, time\nfrom haa_sym.cli import end\n"
            f"def work():\n    time.sleep(0.3)\n    open({str(out)!r}, 'w').write('done')\n"
            "threading.Thread(target=work).start()\nend(0)\n")
    done = _python(code)
    assert done.returncode == 0 and out.read_text() == "done"


def test_an_in_process_task_list_leaves_no_thread_behind():
    # dask's default pool for num_workers kept two idle non-daemon threads until the end, and
    # every command that ran tasks in-process then took Python's slow exit
    before = set(threading.enumerate())
    assert TaskRunner(None, False).run(pow, [(2, 3), (3, 2), (4, 2)], "test") == [8, 9, 16]
    left = [t for t in threading.enumerate() if t not in before and t.is_alive() and not t.daemon]
    assert left == []
