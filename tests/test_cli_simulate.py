"""haa-sym simulate: the CSV's columns exactly as issue 19 names them, the report of saturation
and limit cycles, and bad input refused (exit 2, nothing written)."""
import csv

import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate
from haa_sym.cli import main
from haa_sym.model.resources import data_dir

BASE = (data_dir("model") / "hyq_haa.toml").read_text()


def _params_file(tmp_path, limits):
    p = tmp_path.parent / f"{tmp_path.name}-lim.toml"
    p.write_text(BASE + "\n[limits]\n" + limits + "\n")
    return p


def test_simulate_writes_the_issue_columns(tmp_path, capsys):
    p = _params_file(tmp_path, 'V_max = { value = 6, unit = "V", source = "-", description = "supply" }')
    out = tmp_path / "sim.csv"
    rc = main(["simulate", "--params", str(p), "--P-gain", "300", "--D-gain", "4", "--experiment", "impedance-step",
               "--amplitude", "0.2", "--duration", "0.3", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    text = capsys.readouterr().out
    rows = list(csv.reader(out.open()))
    assert rows[0] == ["time", "theta", "velocity", "torque", "torque_ref", "voltage", "current"]
    data = np.array(rows[1:], float)
    assert data.shape == (301, 7)
    assert np.allclose(data[:, 0], np.arange(301) * 1e-3, rtol=0, atol=1e-15)
    assert np.abs(data[:, 5]).max() == 6.0
    # the same run through the API, to the CSV's 12 digits
    s = simulate(ClosedLoop(load_params(p), basis=False), 300.0, 4.0, experiment="impedance-step", amplitude=0.2,
                 duration=0.3)
    assert np.allclose(data[:, 3], s.torque, rtol=1e-11, atol=1e-12)
    assert f"time in saturation: {s.saturation_time:.6g} s" in text
    assert "limits: V_max = 6" in text and "\nverdict: " in text


def test_simulate_reports_a_limit_cycle_and_plots(tmp_path, capsys):
    p = _params_file(tmp_path, "V_max = 24")
    rc = main(["simulate", "--params", str(p), "--set", "beta=3", "--P-gain", "20000", "--D-gain", "10",
               "--experiment", "disturbance-step", "--duration", "1.5", "--out", str(tmp_path / "s.csv"),
               "--plot", str(tmp_path / "s.png")])
    assert rc == 0
    text = capsys.readouterr().out
    assert "verdict: limit cycle (torque: amplitude" in text and " Hz" in text
    assert (tmp_path / "s.png").stat().st_size > 10_000


@pytest.mark.parametrize("extra, match", [
    (["--experiment", "ramp"], "argument --experiment: invalid choice: 'ramp'"),
    (["--duration", "0"], "duration = 0.0; allowed: a finite number of seconds > 0"),
    (["--duration", "nan"], "duration = nan"),
    (["--out", "sim.npz"], "--out 'sim.npz': unsupported file type; allowed: ['.csv']"),
    (["--P-gain", "1,2"], "gives 2 points; allowed: one point (simulate)"),
    (["--amplitude", "inf"], "amplitude = inf"),
])
def test_bad_input_is_refused(tmp_path, assert_refused, extra, match):
    argv = {"--experiment": "deflection", "--duration": "0.1", "--out": "sim.csv", "--P-gain": "100",
            "--D-gain": "1"}
    for k, v in zip(extra[::2], extra[1::2]):
        argv[k] = v
    assert_refused(["simulate"] + [x for kv in argv.items() for x in kv], match)
