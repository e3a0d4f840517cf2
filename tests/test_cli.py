"""haa-sym command line: one point, and clear errors for bad --set input."""
from haa_sym.cli import main


def test_stability_point(capsys):
    assert main(["stability", "--P-gain", "200", "--D-gain", "10", "--set", "N_av=10"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("stable: ") and "spectral radius: " in out


def test_bad_set_key_and_value(capsys):
    assert main(["stability", "--P-gain", "200", "--D-gain", "10", "--set", "Nav=10"]) == 2
    assert "unknown parameter key(s) ['Nav']" in capsys.readouterr().err
    assert main(["stability", "--P-gain", "200", "--D-gain", "10", "--set", "Ts=-1"]) == 2
    assert "Ts = -1.0 is out of range" in capsys.readouterr().err
    assert main(["stability", "--P-gain", "200", "--D-gain", "10", "--set", "Ts"]) == 2
    assert "expected KEY=VALUE" in capsys.readouterr().err
