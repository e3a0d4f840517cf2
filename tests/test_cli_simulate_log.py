"""haa-sym simulate --log-out (issue 26, item 17): a synthetic log in identify's CSV format from a
run driven by a chosen excitation (--excitation chirp / prbs / multisine, the torque reference
of --experiment chirp), with seeded output noise; identify recovers the file's values from it."""
import json

import numpy as np
import pytest

from haa_sym.analysis.excitation import excitation_signal, parse_excitation
from haa_sym.cli import main
from haa_sym.errors import ParameterError
from haa_sym.io.logs import read_log
from haa_sym.model.params import load_params

KEYS = ("J_link", "B_link", "K_hd", "D_hd")
START = ("--set", "J_link=0.42", "--set", "B_link=1.7", "--set", "K_hd=3.6e4", "--set", "D_hd=50")


def _simulate(tmp_path, excitation, *extra):
    log = tmp_path / "run.csv"
    assert main(["simulate", "--params", "harmonic_drive", "--P-gain", "0", "--D-gain", "0", "--experiment", "chirp",
                 "--excitation", excitation, "--amplitude", "20", "--duration", "6", "--log-out", str(log),
                 "--log-noise", "0.01", "--seed", "3", "-q", *extra]) == 0
    return log


@pytest.mark.parametrize("excitation", ["multisine:0.5:100:40",
                                        pytest.param("prbs:200", marks=pytest.mark.slow),
                                        pytest.param("chirp:0.5:100", marks=pytest.mark.slow)])
def test_identify_recovers_the_files_values_from_a_simulated_log(tmp_path, excitation):
    log = _simulate(tmp_path, excitation)
    rep = tmp_path / "fit.json"
    assert main(["identify", "--params", "harmonic_drive", "--log", str(log), "--input", "voltage", "--output",
                 "torque,theta", "--fit", ",".join(KEYS), *START, "--out", str(tmp_path / "f.toml"),
                 "--report", str(rep), "-q"]) == 0
    truth = load_params("harmonic_drive").plant
    for k, p in json.loads(rep.read_text())["parameters"].items():
        # started 12-24 % off; 1 % output noise
        assert abs(p["value"] / getattr(truth, k) - 1) < 0.01, (k, p)


def test_the_log_is_identifys_format_and_says_how_it_was_made(tmp_path):
    log = _simulate(tmp_path, "multisine:0.5:100:40")
    text = log.read_text()
    head = [ln for ln in text.splitlines() if ln.startswith("#")]
    assert len(head) == 3 and "multisine:0.5:100:40" in head[1] and "output noise 0.01 x std" in head[1]
    assert text.splitlines()[3] == "time,voltage,current,torque_ref,torque,theta,velocity"
    read = read_log(log, ("torque_ref",), ("torque", "theta", "velocity", "current"))
    assert read.samples == 6001
    rows = np.array([[float(x) for x in ln.split(",")] for ln in text.splitlines()[4:]])
    u = excitation_signal("multisine:0.5:100:40", 6001, 1e-3)
    np.testing.assert_allclose(rows[:, 3], 20 * u, atol=1e-9)              # the reference exact, peak 20 Nm


def test_seeded_noise(tmp_path):
    a = _simulate(tmp_path, "prbs:200").read_text()
    (tmp_path / "b").mkdir()
    b = _simulate(tmp_path / "b", "prbs:200").read_text()
    assert a == b
    (tmp_path / "c").mkdir()
    c = _simulate(tmp_path / "c", "prbs:200", "--seed", "4").read_text()
    assert c != a


def test_excitation_signals():
    Ts, n = 1e-3, 10000
    T = n * Ts
    u = excitation_signal("multisine:1:50:12", n, Ts)
    assert abs(np.abs(u).max() - 1) < 1e-12
    spectrum = np.abs(np.fft.rfft(u))
    lines = np.flatnonzero(spectrum > 1e-6 * spectrum.max()) / T
    assert lines.size == 12 and lines.min() >= 1 - 1e-9 and lines.max() <= 50 + 1e-9   # on the grid, in band
    p = excitation_signal("prbs:100", n, Ts, seed=5)
    assert set(np.unique(p)) == {-1.0, 1.0}
    edges = np.flatnonzero(np.diff(p))
    assert np.all((edges + 1) % 10 == 0)                     # levels held 1 / (100 Hz x 1 ms) = 10 samples
    assert not np.array_equal(p, excitation_signal("prbs:100", n, Ts, seed=6))
    c = excitation_signal("chirp:2:40", n, Ts)
    # a linear sweep from 2 to 40 Hz over T has (2 + 40) / 2 T cycles, two zero crossings each
    crossings = np.flatnonzero(np.diff(np.signbit(c[1:])))
    assert abs(crossings.size - 2 * (2 + 40) / 2 * (n - 1) * Ts) <= 2
    last = np.diff(crossings[-5:]).mean() * Ts * 2                  # the period at the end
    assert abs(1 / last - 40) < 1


@pytest.mark.parametrize("spec,match", [("sweep:1:2", "unknown kind 'sweep'"), ("chirp:5", "chirp takes 2 numbers"),
                                        ("chirp:5:1", "F0 must be below F1"), ("prbs:x", "not a number"),
                                        ("multisine:1:900", "at most Nyquist 500 Hz"),
                                        ("multisine:1:2:0", "N = 0 sines")])
def test_bad_excitation(spec, match):
    with pytest.raises(ParameterError, match=match) as e:
        parse_excitation(spec, 1e-3)
    assert "allowed: chirp:F0:F1" in str(e.value)


def test_bad_flags_refused(tmp_path, assert_refused):
    base = ["simulate", "--params", "harmonic_drive", "--P-gain", "0", "--D-gain", "0", "--duration", "1"]
    assert_refused(base + ["--experiment", "torque-step", "--excitation", "prbs:100"],
                   "--excitation prbs:100: a torque reference of the forced experiment; allowed: with --experiment chirp")
    assert_refused(base + ["--experiment", "chirp", "--log-noise", "0.01"], "--log-noise applies to the log")
    assert_refused(base + ["--experiment", "chirp", "--log-out", "x.csv", "--log-noise", "-1"], "--log-noise -1.0")
    assert_refused(base + ["--experiment", "chirp", "--log-out", "x.txt"], "--log-out 'x.txt'")
    assert_refused(base + ["--experiment", "chirp", "--excitation", "multisine:1:2:50", "--log-out", "x.csv"],
                   "50 sines between 1 and 2 Hz need a run of more than")


def test_too_many_sines_refused_before_any_work(capsys):
    """multisine:1:100:100000000 was refused after 42 s (a Python loop over the sines)."""
    import time
    t0 = time.perf_counter()
    assert main(["simulate", "--P-gain", "200", "--D-gain", "5", "--duration", "1", "--experiment", "chirp",
                 "--excitation", "multisine:1:100:100000000"]) == 2
    assert time.perf_counter() - t0 < 5
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "100000000 sines between 1 and 100 Hz need a run of more than" in err
