"""numpy's floating-point warnings never reach the user as Python's two-line warnings with a
source line from inside the library (issue 26, item 11): a failed command prints its one error
line only; a command that succeeds through an overflow says so in one warning line."""
from haa_sym.cli import main


def test_refused_overflow_is_one_line(capsys):
    assert main(["stability", "--P-gain", "1e308", "--D-gain", "1e308"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("haa-sym: error: the closed loop at P_gain = 1e+308")


def test_overflow_in_a_result_is_one_warning(capsys):
    assert main(["boundary", "--P-gain", "log:1:1e300:3", "--D-gain", "lin:1:1e300:3", "-q"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("haa-sym: warning: floating-point overflow") and "check the result" in err[0]
    assert "RuntimeWarning" not in err[0]
