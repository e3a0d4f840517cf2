"""Every simulated run ends in one verdict with the linear verdict beside it (issue 26, item 4):
a growing oscillation is not "no limit cycle", a run that overflows is "diverged" and stops at
its first non-finite sample, a forced run (the chirp) is never a limit cycle."""
import csv
import json

import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate
from haa_sym.cli import main
from haa_sym.cli import simulate as cli_simulate
from haa_sym.model.limits import Limits
from haa_sym.model.resources import data_dir

BASE = (data_dir("model") / "hyq_haa.toml").read_text()


def _run(tmp_path, capsys, args, monkeypatch=None):
    notes = []
    if monkeypatch is not None:          # the figure's note (its text), not its pixels
        real = cli_simulate._plots

        class _P:
            def __getattr__(self, name):
                return getattr(real(), name)

            def plot_simulation(self, *a):
                notes.append(a[4])
                return real().plot_simulation(*a)
        monkeypatch.setattr(cli_simulate, "_plots", lambda: _P())
    rc = main(["simulate"] + args)
    out = capsys.readouterr()
    assert rc == 0, out.err
    return out.out, notes


def test_a_growing_oscillation_is_growing_with_the_linear_verdict(tmp_path, capsys, monkeypatch):
    # HyQ at P 2000, D 10: linearly unstable (spectral radius 1.00065 a sample, +9.6 % a cycle);
    # before: "no limit cycle" in the summary and the figure
    meta = tmp_path / "m.json"
    text, notes = _run(tmp_path, capsys, ["--P-gain", "2000", "--D-gain", "10", "--experiment", "disturbance-step",
                                          "--duration", "5", "--meta", str(meta), "--plot", str(tmp_path / "f.png")],
                       monkeypatch)
    line = "verdict: growing"
    assert line in text and "linear loop at this point: UNSTABLE (spectral radius 1.00" in text
    assert "no limit cycle" not in text
    assert notes and notes[0].startswith(line) and "UNSTABLE" in notes[0]
    m = json.loads(meta.read_text())
    assert m["verdict"] == "growing" and m["linear"]["stable"] is False
    assert m["linear"]["spectral_radius"] == pytest.approx(1.00065, abs=1e-5)


@pytest.mark.slow
def test_an_overflowing_run_is_diverged_and_stops_at_its_first_non_finite_sample(tmp_path, capsys):
    # beta 3, P 20000, D 10, no limits: grows 1.0126 a sample and overflows after 56.92 s; before:
    # 3,081 NaN/inf rows and "time in saturation", exit 0
    out, meta = tmp_path / "b.csv", tmp_path / "b.json"
    text, _ = _run(tmp_path, capsys, ["--set", "beta=3", "--P-gain", "20000", "--D-gain", "10", "--experiment",
                                      "disturbance-step", "--duration", "60", "--out", str(out), "--meta", str(meta)])
    rows = list(csv.reader(out.open()))
    data = np.array(rows[1:], float)
    assert np.all(np.isfinite(data)) and 50_000 < data.shape[0] < 60_001
    m = json.loads(meta.read_text())
    assert m["verdict"] == "diverged" and m["samples_written"] == data.shape[0]
    assert m["diverged_at_s"] == pytest.approx(data[-1, 0] + 1e-3, abs=1e-9)
    assert f"verdict: diverged (a state overflowed at t = {m['diverged_at_s']:.6g} s" in text


@pytest.mark.parametrize("args", [["--amplitude", "1e308"], ["--params", "FC"]])
def test_absurd_inputs_diverge_with_exit_zero(tmp_path, capsys, args):
    if args[1] == "FC":
        p = tmp_path / "fc.toml"
        p.write_text(BASE + "\n[limits]\nFc_m = 1e50\n")
        args = ["--params", str(p), "--duration", "0.05"]
    else:
        args += ["--duration", "1"]
    text, _ = _run(tmp_path, capsys, ["--P-gain", "1000", "--D-gain", "5", "--experiment", "disturbance-step",
                                      "--out", str(tmp_path / "c.csv")] + args)
    assert "verdict: diverged (a state overflowed at t = " in text
    data = np.genfromtxt(tmp_path / "c.csv", delimiter=",", names=True)
    assert np.all(np.isfinite(data["torque"]))


def test_a_chirp_is_never_a_limit_cycle():
    # the 24 V cycle of beta 3, P 20000, D 10 under a chirp: the oscillation is forced
    loop = ClosedLoop(load_params().with_values(beta=3.0))
    s = simulate(loop, 20000.0, 10.0, limits=Limits(V_max=24.0), experiment="chirp", duration=1.5)
    assert not s.limit_cycle
    assert s.verdict == "forced response"
    free = simulate(loop, 20000.0, 10.0, limits=Limits(V_max=24.0), experiment="disturbance-step", duration=1.5)
    assert free.verdict == "limit cycle"


def test_the_harmonic_drive_spiky_cycle():
    # issue 26 item 5: V_max 2 V, P 1000, D 5, 0.1 rad deflection, 30 s: the torque cycles at
    # 1.314 Hz (761-762 samples a period), 17.9 Nm half peak-to-peak; before: 3.99 Hz, 9.6 Nm
    loop = ClosedLoop(load_params("harmonic_drive"))
    s = simulate(loop, 1000.0, 5.0, limits=Limits(V_max=2.0), experiment="deflection", duration=30.0)
    assert s.cycle_frequency == pytest.approx(1.314, rel=3e-3)
    # half peak-to-peak over whole periods of the last half, against the plain extremes of the trace
    tail = s.torque[15000:]
    assert s.cycle_amplitude == pytest.approx(0.5 * np.ptp(tail), rel=0.01)
    assert s.verdict == "limit cycle"


def test_short_run_is_not_diverged(capsys):
    """A 6-sample run of a stable loop was "diverged (a state overflowed at t = nan s)"."""
    assert main(["simulate", "--P-gain", "200", "--D-gain", "5", "--experiment", "deflection", "--duration", "0.005"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("verdict: converging;") and "nan" not in last


def test_long_growing_run_keeps_its_rate_and_frequency(capsys):
    """150 s of HyQ at P 2000, D 10 read "+1.7e+03 % a cycle at nan Hz": the trace's mean
    (1e39) absorbed its early cycles' swing (1e21) when subtracted; the rate is 9.61 % a cycle
    at 7.07 Hz at every length (checked against a synthetic trace in test_analysis_oscillation_period)."""
    assert main(["simulate", "--P-gain", "2000", "--D-gain", "10", "--experiment", "deflection", "--duration", "150"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert "growing (torque oscillation growing, +9.61 % a cycle at 7.06" in last, last


def test_no_nan_hz_on_a_chirp(capsys):
    assert main(["simulate", "--P-gain", "200", "--D-gain", "5", "--duration", "1", "--experiment", "chirp"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("verdict: forced response") and "nan" not in last
