"""haa_sym.cli: the commands' output, their options and arguments, and clear errors for bad
--set input (the one-error contract for every user-caused condition is test_cli_errors.py)."""
import json
import subprocess
import sys

import numpy as np
import pytest

from haa_sym.cli import main


def test_stability_point(capsys):
    assert main(["stability", "--P-gain", "200", "--D-gain", "10", "--set", "N_av=10"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("stable: ") and "spectral radius: " in out


def test_bad_set_key_and_value(assert_refused):
    point = ["stability", "--P-gain", "200", "--D-gain", "10"]
    assert_refused([*point, "--set", "Nav=10"], "unknown parameter key(s) ['Nav']")
    assert_refused([*point, "--set", "Ts=-1"], "--set Ts=-1: Ts = -1 is out of range")
    assert_refused([*point, "--set", "Ts"], "expected KEY=VALUE")


# --- haa-sym regions and friends (issue 3) -------------------------------------------------------

def test_regions_writes_npz_and_plot(tmp_path, capsys):
    out, png = tmp_path / "map.npz", tmp_path / "map.png"
    rc = main(["regions", "--set", "beta=2", "--set", "N_av=10", "--P-gain", "log:1:20000:12",
               "--D-gain", "lin:1:50:5", "--option", "pm_rule=worst", "--out", str(out),
               "--plot", str(png)])
    assert rc == 0, capsys.readouterr().err
    with np.load(out) as f:
        assert f["stable"].shape == (12, 5) and f["P_gain"].shape == (12,)
        assert f["phase_margin_deg"].shape == (12, 5) and f["passive"].dtype == bool
        meta = json.loads(str(f["meta"]))
    assert meta["params"]["controller"]["beta"] == 2.0 and meta["params"]["controller"]["N_av"] == 10
    assert meta["options"]["pm_rule"] == "worst"
    assert png.stat().st_size > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.npz", "map.png"]


@pytest.mark.parametrize("args,msg", [
    (["--P-gain", "log:0:20000:10"], "--P-gain = 'log:0:20000:10'"),
    (["--D-gain", "lin:1:50:x"], "--D-gain = 'lin:1:50:x'"),
    (["--set", "J_L3=0.1"], "unknown parameter key(s) ['J_L3']"),
    (["--set", "J_L2=-0.1"], "J_L2"),
    (["--set", "N_av=0"], "N_av"),
    (["--set", "Ts=nan"], "Ts"),
    (["--option", "port=foot"], "--option port = 'foot'"),
    (["--option", "bogus=1"], "unknown option 'bogus'"),
    (["--configuration", "folded"], "unknown configuration 'folded'"),
])
def test_regions_rejects_bad_input_and_writes_nothing(tmp_path, assert_refused, args, msg):
    out = tmp_path / "map.npz"
    assert_refused(["regions", "--P-gain", "log:1:20000:5", "--D-gain", "lin:1:50:3", *args,
                    "--out", str(out), "--plot", str(tmp_path / "map.png")], msg)
    assert list(tmp_path.iterdir()) == []


def test_regions_rejects_bad_output_suffix(tmp_path, assert_refused):
    assert_refused(["regions", "--P-gain", "1,2", "--D-gain", "1", "--out", str(tmp_path / "m.csv")],
                   "allowed: ['.npz']")


def test_passivity_step_margins(tmp_path, capsys, assert_refused):
    assert main(["passivity", "--out", str(tmp_path / "p.csv")]) == 0
    out = capsys.readouterr().out
    assert "P_gain 0  D_gain 0: No" in out and "P_gain 200  D_gain 10: Yes" in out
    assert (tmp_path / "p.csv").read_text().startswith("P_gain,D_gain,status")
    assert_refused(["passivity", "--P-gain", "1,2", "--D-gain", "1,2,3"], "same number")
    assert main(["step", "--set", "K_L2=0", "--out", str(tmp_path / "s.csv")]) == 0
    assert "rise time" in capsys.readouterr().out
    assert main(["margins", "--P-gain", "200", "--D-gain", "10"]) == 0
    assert "impedance loop (opened at T_lref):\n  PM +30.79 deg @ 21.8862 rad/s" in capsys.readouterr().out


def test_regions_rejects_unwritable_output(tmp_path, assert_refused):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    out = blocker / "m.npz"
    assert_refused(["regions", "--P-gain", "1", "--D-gain", "1", "--out", str(out)],
                   "a_file' is not a directory; allowed: a path whose existing part is directories")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


@pytest.mark.parametrize("argv,msg", [
    (["step", "--duration", "abc"], "argument --duration: invalid float value: 'abc'"),
    (["margins", "--P-gain", "1;2"], "--P-gain = '1;2': '1;2' is not a number; allowed: 'log:START"),
    (["regions", "--option", "n_omega=abc"], "'abc' is not a valid int; allowed: an integer"),
])
def test_argument_errors_are_one_line(assert_refused, argv, msg):
    assert_refused(argv, msg)            # argparse's own errors leave through SystemExit 2


@pytest.mark.parametrize("value, expected", [("false", False), ("True", True), ("none", None)])
def test_torque_damping_option_from_the_command_line(value, expected, capsys):
    from haa_sym.cli.common import _parse_options
    assert _parse_options([f"torque_damping={value}"]).structure.torque_damping is expected
    assert main(["stability", "--P-gain", "200", "--D-gain", "10", "--option", f"torque_damping={value}"]) == 0


def test_unknown_set_key_is_named_before_its_value(assert_refused):
    assert_refused(["stability", "--P-gain", "1", "--D-gain", "1", "--set", "port=L1"],
                   "unknown parameter key(s) ['port']")


def test_a_closed_pipe_is_not_an_error():
    cmd = [sys.executable, "-c", "from haa_sym.cli import main; import sys; sys.exit(main(['passivity', "
           "'--P-gain', '0,200,20000,1,2,3', '--D-gain', '0,10,50,1,2,3']))"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.read(1)
    proc.stdout.close()                                # the reader goes away, as `| head -c1`
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) in (0, 1) and "Traceback" not in err and "error" not in err


@pytest.mark.parametrize("argv, message", [
    (["regions", "--leg", "retracted:extended"], "--leg applies to the leg range; allowed: with --robust"),
    (["regions", "--require", "stable"], "--require applies to the leg range"),
    (["regions", "--robust", "--radius"], "--radius with --robust"),
    (["regions", "--robust", "--method", "grid"], "--method grid with --robust"),
])
def test_robust_only_and_plain_only_arguments_are_not_silently_ignored(tmp_path, assert_refused, argv, message):
    out = tmp_path / "m.npz"
    assert_refused(argv + ["--P-gain", "log:1:100:3", "--D-gain", "lin:1:5:2", "--out", str(out), "-q"], message)
    assert not out.exists()
