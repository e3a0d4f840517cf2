"""haa_sym.io.inputs: a user's input file is read only when it is a regular file of bounded size
(never blocking on a FIFO, never reading a device whole), only from the allowed roots when
reads are restricted, and no command writes over one of its own inputs, through any link."""
import os
import shutil
import threading
import time

import pytest

from haa_sym.cli import main
from haa_sym.errors import OutputError, ParameterError
from haa_sym.io import inputs
from haa_sym.io.outputs import Transaction, check_directory, check_file
from haa_sym.model.params import actuator_path


def test_regular_file_read_and_recorded(tmp_path):
    f = tmp_path / "a.csv"
    f.write_text("x\n")
    with inputs.command_scope():
        assert inputs.read_text(f, "--log") == "x\n"
        assert inputs.recorded_inputs() == [str(f)]
    assert inputs.recorded_inputs() == []


@pytest.mark.parametrize("path", ["/dev/zero", "/dev/null"])
def test_devices_refused_at_once(path):
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=r"^--params '/dev/\w+': a character device; allowed: a regular file$"):
        inputs.read_bytes(path, "--params")
    assert time.perf_counter() - t0 < 0.5


def test_fifo_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    done = []
    t = threading.Thread(target=lambda: done.append(pytest.raises(ParameterError, inputs.read_bytes, fifo, "--log")))
    t.start()
    t.join(2.0)
    assert not t.is_alive(), "reading a FIFO with no writer blocked"
    assert "a FIFO (named pipe); allowed: a regular file" in str(done[0].value)


def test_directory_missing_and_too_large(tmp_path):
    with pytest.raises(ParameterError, match="a directory; allowed: a regular file"):
        inputs.read_bytes(tmp_path, "--measured")
    with pytest.raises(ParameterError, match="no such file"):
        inputs.read_bytes(tmp_path / "nope.csv", "--measured")
    big = tmp_path / "big.csv"
    big.write_bytes(b"0" * 2048)
    with pytest.raises(ParameterError, match=r"'big.csv'?.*2 KiB; allowed: a file of at most 1 KiB|2 KiB; allowed"):
        inputs.read_bytes(big, "--log", limit=1024)


def test_restrict_reads(tmp_path):
    inside, outside = tmp_path / "in", tmp_path / "out"
    inside.mkdir(), outside.mkdir()
    (inside / "a.csv").write_text("a")
    (outside / "b.csv").write_text("b")
    (inside / "link.csv").symlink_to(outside / "b.csv")       # a link out of the root is outside
    with inputs.restrict_reads([inside]):
        assert inputs.read_text(inside / "a.csv", "schedule") == "a"
        for p in (outside / "b.csv", inside / "link.csv", "/etc/passwd"):
            with pytest.raises(ParameterError, match="outside the files this server may read"):
                inputs.read_bytes(p, "schedule")
    assert inputs.read_text(outside / "b.csv", "schedule") == "b"          # lifted after the block


@pytest.mark.parametrize("how", ["same", "symlink", "hardlink"])
def test_output_over_input_refused(tmp_path, how):
    src = tmp_path / "log.csv"
    src.write_text("keep me\n")
    target = tmp_path / "out.csv"
    if how == "same":
        target = src
    elif how == "symlink":
        target.symlink_to(src)
    else:
        os.link(src, target)
    with inputs.command_scope():
        inputs.read_text(src, "--log")
        with pytest.raises(OutputError, match="is one of this command's inputs"):
            check_file(target, "--out")
    with inputs.command_scope():
        with pytest.raises(OutputError, match="is one of this command's inputs"):
            with Transaction() as tx:
                tx.write_text(target, "new")            # staged before the input is read:
                inputs.read_text(src, "--log")          # the commit's check refuses it
    assert src.read_text() == "keep me\n"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]     # no temporary left


def test_directory_output_holding_an_input_refused(tmp_path):
    d = tmp_path / "results"
    d.mkdir()
    (d / "params.toml").write_text("x")
    with inputs.command_scope():
        inputs.read_text(d / "params.toml", "--params")
        with pytest.raises(OutputError, match="holds .*params.toml', one of this command's inputs"):
            check_directory(d, "--out")


def test_tune_out_is_its_params_file(tmp_path, capsys):
    f = tmp_path / "sea.toml"
    shutil.copy(actuator_path("sea"), f)
    before = f.read_bytes()
    link = tmp_path / "link.toml"
    link.symlink_to(f)
    for out in (f, link):
        assert main(["tune", "--params", str(f), "--out", str(out), "-q"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(f"haa-sym: error: --out {str(out)!r}") and "one of this command's inputs" in err
        assert len(err.splitlines()) == 1
    assert f.read_bytes() == before and link.is_symlink()


def test_params_from_dev_zero_and_fifo(tmp_path, capsys):
    fifo = tmp_path / "p.toml"
    os.mkfifo(fifo)
    for p in ("/dev/zero", str(fifo)):
        t0 = time.perf_counter()
        assert main(["stability", "--params", p, "--P-gain", "200", "--D-gain", "10"]) == 2
        assert time.perf_counter() - t0 < 2
        err = capsys.readouterr().err.strip()
        assert "allowed: a regular file" in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("kind", ["fifo", "fifo-link"])
def test_output_that_is_not_a_regular_file_is_refused(tmp_path, kind):
    """--out naming a FIFO or a device (or a link to one) replaced it with a regular file (as
    root, /dev/full became a 96 KB file)."""
    fifo = tmp_path / "ff.csv"
    os.mkfifo(fifo)
    target = fifo
    if kind == "fifo-link":
        target = tmp_path / "link.csv"
        target.symlink_to(fifo)
    with pytest.raises(OutputError, match="is not a regular file .*allowed: a new path or an existing regular file"):
        check_file(target, "--out")
    assert stat_is_fifo(fifo)


def stat_is_fifo(p):
    import stat
    return stat.S_ISFIFO(os.lstat(p).st_mode)


def test_two_outputs_in_one_file_refused(tmp_path):
    """simulate --out same.csv --log-out same.csv kept only the log."""
    a = tmp_path / "same.csv"
    link = tmp_path / "link.csv"
    link.symlink_to(a)
    for second in (a, link):
        with pytest.raises(OutputError, match="the same file as another output of this command"):
            with Transaction() as tx:
                tx.write_text(a, "one", "--out")
                tx.write_text(second, "two", "--log-out")
        assert not a.exists()
    a.write_text("old")
    hard = tmp_path / "hard.csv"
    os.link(a, hard)
    with pytest.raises(OutputError, match="the same file as another output"):
        with Transaction() as tx:
            tx.write_text(a, "one", "--out")
            tx.write_text(hard, "two", "--log-out")
    assert a.read_text() == "old"


def test_schedule_c_out_holding_its_params_refused_before_work(tmp_path, capsys):
    """--params DIR/haa_schedule.c --c-out DIR was refused only at commit, after the work."""
    d = tmp_path / "c"
    d.mkdir()
    src = d / "haa_schedule.c"
    shutil.copy(actuator_path("hyq_haa"), src)
    t0 = time.perf_counter()
    assert main(["schedule", "--params", str(src), "--P-gain", "log:10:2000:5", "--D-gain", "lin:1:30:4",
                 "--c-out", str(d), "-q"]) == 2
    assert time.perf_counter() - t0 < 3
    assert "is one of this command's inputs" in capsys.readouterr().err
    assert src.read_bytes() == actuator_path("hyq_haa").read_bytes()
