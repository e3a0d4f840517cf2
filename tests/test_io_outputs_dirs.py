"""One rule for every output path (issue 16.9): missing parent directories are created, and a
failed command leaves no new directory behind (haa_sym.io.outputs)."""
import os

import pytest

from haa_sym.cli import main
from haa_sym.design.schedule_c import HEADER, SOURCE, write_c
from haa_sym.errors import OutputError
from haa_sym.io.outputs import Transaction, check_directory, check_file

SMALL = ["--P-gain", "log:1:100:3", "--D-gain", "1,2"]


def tree(directory):
    return sorted(os.path.relpath(os.path.join(r, n), directory)
                  for r, ds, fs in os.walk(directory) for n in ds + fs)


def test_transaction_creates_missing_parents_and_keeps_them_on_commit(tmp_path):
    target = tmp_path / "a" / "b" / "c.txt"
    check_file(target, "--out")                       # no error, and nothing created yet
    assert list(tmp_path.iterdir()) == []
    with Transaction() as tx:
        tx.write_text(target, "x", "--out")
        assert (tmp_path / "a" / "b").is_dir()         # staged next to the target
    assert target.read_text() == "x"
    assert tree(tmp_path) == ["a", "a/b", "a/b/c.txt"]


def test_rollback_removes_only_the_directories_it_created(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "keep").write_text("the user's")
    with pytest.raises(RuntimeError):
        with Transaction() as tx:
            tx.write_text(tmp_path / "a" / "new" / "deeper" / "x.csv", "1")
            tx.write_text(tmp_path / "other" / "y.csv", "2")
            raise RuntimeError("the computation failed after staging")
    assert tree(tmp_path) == ["a", "a/keep"]


def test_rollback_keeps_a_created_directory_someone_else_wrote_into(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with Transaction() as tx:
            tx.write_text(tmp_path / "new" / "x.csv", "1")
            (tmp_path / "new" / "theirs.txt").write_text("another process")
            raise KeyboardInterrupt
    assert tree(tmp_path) == ["new", "new/theirs.txt"]


def test_commit_failure_removes_the_created_directories(tmp_path, monkeypatch):
    real = os.replace

    def failing(src, dst):
        if str(dst).endswith("second.csv"):
            raise OSError(28, "No space left on device")
        return real(src, dst)
    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OutputError, match="second.csv'.*cannot write"):
        with Transaction() as tx:
            tx.write_text(tmp_path / "d1" / "first.csv", "1")
            tx.write_text(tmp_path / "d2" / "sub" / "second.csv", "2")
    assert tree(tmp_path) == []


def test_a_file_in_the_way_or_an_unwritable_ancestor_is_refused_before_work(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputError, match=r"--out '.*f/a/b.csv': '.*f' is not a directory"):
        check_file(tmp_path / "f" / "a" / "b.csv", "--out")
    with pytest.raises(OutputError, match=r"--out '.*f/new': '.*f' is not a directory"):
        check_directory(tmp_path / "f" / "new", "--out")
    if os.geteuid() != 0:                               # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o555)
        with pytest.raises(OutputError, match=r"cannot create directory '.*ro/a': directory '.*ro' is not "
                                              "writable"):
            check_file(ro / "a" / "b.csv", "--plot")
    assert tree(tmp_path) == ["f", "ro"] or tree(tmp_path) == ["f"]


def test_cli_out_and_plot_create_their_directories(tmp_path, capsys):
    out, plot = tmp_path / "maps" / "m.npz", tmp_path / "figs" / "2026" / "m.png"
    assert main(["regions", "-q", *SMALL, "--out", str(out), "--plot", str(plot)]) == 0
    assert out.stat().st_size > 0 and plot.stat().st_size > 0


def test_cli_failure_leaves_no_new_directory(tmp_path, capsys):
    # the plot target is a directory: refused before any work, nothing created for --out either
    (tmp_path / "fig.png").mkdir()
    rc = main(["regions", "-q", *SMALL, "--out", str(tmp_path / "new" / "m.npz"),
               "--plot", str(tmp_path / "fig.png")])
    assert rc == 2 and capsys.readouterr().err.count("\n") == 1
    assert tree(tmp_path) == ["fig.png"]


def test_write_c_creates_the_directory_and_rolls_it_back(tmp_path):
    from test_design_schedule_c import synthetic
    d = tmp_path / "ctrl" / "gen"
    write_c(synthetic(), d)
    assert sorted(p.name for p in d.iterdir()) == [SOURCE, HEADER]
    d2 = tmp_path / "ctrl2" / "gen"
    with pytest.raises(RuntimeError):
        with Transaction() as tx:
            write_c(synthetic(), d2, tx)
            raise RuntimeError("a later output failed")
    assert not (tmp_path / "ctrl2").exists()


def test_reproduce_creates_its_parents_and_removes_them_on_failure(tmp_path, capsys, monkeypatch):
    # the first section fails after the directory was staged: the created parent goes again
    from haa_sym.errors import ParameterError
    from haa_sym.paper import reproduce as rp
    staged = []

    def fail(job):
        staged.append(job.out.parent.is_dir())
        raise ParameterError("stop here")
    monkeypatch.setattr(rp, "_regions", fail)
    rc = main(["reproduce", "-q", "--quick", "--out", str(tmp_path / "a" / "b" / "results")])
    assert rc == 2 and "stop here" in capsys.readouterr().err
    assert staged == [True]
    assert tree(tmp_path) == []
