"""All or nothing: no command deletes or overwrites a user's file unless it succeeds (issue 7.4)."""
import errno
import os

import matplotlib.figure
import pytest

from haa_sym.io import outputs
from haa_sym.cli import main
from haa_sym.errors import OutputError
from haa_sym.io.outputs import Transaction

from conftest import snapshot

SMALL = ["--P-gain", "log:1:100:3", "--D-gain", "1,2"]


def test_regions_keeps_old_out_when_plot_is_a_directory(tmp_path, assert_refused):
    (tmp_path / "old.npz").write_bytes(b"the user's old map")
    (tmp_path / "dir.png").mkdir()
    err = assert_refused(["regions", *SMALL, "--out", str(tmp_path / "old.npz"), "--plot", str(tmp_path / "dir.png")],
                         "dir.png' is a directory; allowed: a file path")
    assert err.startswith("haa-sym: error: --plot ")


@pytest.mark.parametrize("cmd,out,args", [
    ("regions", "old.npz", SMALL),
    ("passivity", "old.csv", ["--P-gain", "200", "--D-gain", "10"]),
    ("step", "old.csv", ["--duration", "0.05"]),
])
def test_late_plot_failure_keeps_old_out(tmp_path, assert_refused, monkeypatch, cmd, out, args):
    """The disk fills up while the figure is written: --out keeps its old bytes, no temporaries."""
    def full(self, fh, **kw):
        fh.write(b"partial")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full)
    (tmp_path / out).write_bytes(b"the user's old result")
    (tmp_path / "fig.png").write_bytes(b"the user's old figure")
    err = assert_refused([cmd, *args, "--out", str(tmp_path / out), "--plot", str(tmp_path / "fig.png")],
                         "cannot write (No space left on device)", printed=cmd != "regions")
    assert err == f"haa-sym: error: --plot '{tmp_path / 'fig.png'}': cannot write (No space left on device)\n"


def test_outputs_follow_the_umask(tmp_path, capsys):
    old = os.umask(0o027)
    try:
        assert main(["step", "--duration", "0.05", "--out", str(tmp_path / "s.csv"),
                     "--plot", str(tmp_path / "s.png")]) == 0
    finally:
        os.umask(old)
    assert {p.name: p.stat().st_mode & 0o777 for p in tmp_path.iterdir()} == {"s.csv": 0o640, "s.png": 0o640}


@pytest.mark.parametrize("cmd,name", [("step", "x.csv"), ("regions", "x.npz"), ("reproduce", "results")])
def test_parent_that_is_a_file_is_an_error(tmp_path, assert_refused, cmd, name):
    # missing parents are created (tests/test_io_outputs_dirs.py); a file in the way is refused
    (tmp_path / "afile").write_text("x")
    target = tmp_path / "afile" / "sub" / name
    assert_refused([cmd, *(SMALL if cmd == "regions" else []), "--out", str(target)],
                   f"--out '{target}': '{tmp_path / 'afile'}' is not a directory")
    assert [p.name for p in tmp_path.iterdir()] == ["afile"]


def test_commit_failure_puts_back_the_files_already_replaced(tmp_path, monkeypatch):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text("old a")
    b.write_text("old b")
    before = snapshot(tmp_path)
    real_replace = os.replace
    calls = []

    def replace(src, dst):
        calls.append(dst)
        if len(calls) == 2:                    # the second output cannot be moved into place
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        return real_replace(src, dst)
    monkeypatch.setattr(outputs.os, "replace", replace)
    with pytest.raises(OutputError, match=r"'.*b\.csv': cannot write \(Input/output error\)"):
        with Transaction() as tx:
            tx.write_text(a, "new a")
            tx.write_text(b, "new b")
    assert a.read_text() == "old a" and b.read_text() == "old b"
    assert sorted(snapshot(tmp_path)) == sorted(before)


def test_interrupt_while_staging_leaves_nothing(tmp_path):
    (tmp_path / "a.csv").write_text("old a")
    before = snapshot(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        with Transaction() as tx:
            tx.write_text(tmp_path / "a.csv", "new a")
            tx.write_text(tmp_path / "b.csv", "new b")
            raise KeyboardInterrupt
    assert snapshot(tmp_path) == before


# --- reproduce --out DIR ------------------------------------------------------------------------
def old_results(directory):
    (directory / "regions").mkdir(parents=True)
    (directory / "regions" / "fig08a.npz").write_bytes(b"old map")
    (directory / "REPORT.md").write_text("# old report\n")
    (directory / "fig08.png").write_bytes(b"old figure")


def test_interrupted_reproduce_keeps_the_old_results(tmp_path, capsys, monkeypatch):
    import haa_sym.paper.reproduce as rp
    old_results(tmp_path / "results")
    before = snapshot(tmp_path)

    def interrupted(job):                     # the first section has written, then Ctrl-C
        (job.out / "fig08.png").write_bytes(b"new figure")
        (job.out / "regions" / "fig08a.npz").write_bytes(b"new map")
        raise KeyboardInterrupt
    monkeypatch.setattr(rp, "_regions", interrupted)
    assert main(["reproduce", "--quick", "--out", str(tmp_path / "results")]) == 130
    assert capsys.readouterr().err.endswith("haa-sym: interrupted; no output written\n")
    assert snapshot(tmp_path) == before


def test_reproduce_refuses_a_directory_with_other_files(tmp_path, assert_refused):
    old_results(tmp_path / "results")
    (tmp_path / "results" / "notes.txt").write_text("mine")
    err = assert_refused(["reproduce", "--quick", "--out", str(tmp_path / "results")], "(notes.txt)")
    assert err.startswith(f"haa-sym: error: --out '{tmp_path / 'results'}': holds files reproduce does "
                          "not write (notes.txt)")
    (tmp_path / "file").write_text("a file")
    assert_refused(["reproduce", "--quick", "--out", str(tmp_path / "file")], "file' is not a directory")


def test_directory_swap(tmp_path):
    """A staged directory replaces the old one at commit; the old one stays until then."""
    old_results(tmp_path / "results")
    with Transaction() as tx:
        stage = tx.directory(tmp_path / "results")
        (stage / "REPORT.md").write_text("# new report\n")
        assert (tmp_path / "results" / "REPORT.md").read_text() == "# old report\n"
    assert sorted(os.listdir(tmp_path)) == ["results"]
    assert os.listdir(tmp_path / "results") == ["REPORT.md"]
    assert (tmp_path / "results" / "REPORT.md").read_text() == "# new report\n"


def test_a_failed_write_is_never_committed(tmp_path):
    (tmp_path / "a.csv").write_text("old a")
    with Transaction() as tx:
        with pytest.raises(ValueError):
            with tx.open(tmp_path / "a.csv", "w") as fh:
                fh.write("half")
                raise ValueError("the writer failed")
        tx.write_text(tmp_path / "b.csv", "new b")
    assert sorted(os.listdir(tmp_path)) == ["a.csv", "b.csv"]
    assert (tmp_path / "a.csv").read_text() == "old a"


def test_interrupt_is_one_line_and_writes_nothing(tmp_path, capsys, monkeypatch):
    """Ctrl-C during a command: exit 130, one line, no traceback, existing output untouched."""
    import haa_sym.cli.analyses as cli
    out = tmp_path / "old.npz"
    out.write_bytes(b"the user's file")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(cli, "region_map", interrupted)
    from haa_sym.cli import main
    assert main(["regions", "--P-gain", "1,2", "--D-gain", "1,2", "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert err == "haa-sym: interrupted; no output written\n"
    assert out.read_bytes() == b"the user's file" and [p.name for p in tmp_path.iterdir()] == ["old.npz"]
