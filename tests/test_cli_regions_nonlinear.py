"""haa-sym regions --nonlinear (the classes and their meta in the npz, over the linear map) and
haa-sym simulate's describing-function prediction next to the simulated cycle; bad input exit 2."""
import json
import re

import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.describing import limit_cycles
from haa_sym.cli import main
from haa_sym.model.resources import data_dir

BASE = (data_dir("model") / "hyq_haa.toml").read_text()
SUPPLY = 'V_max = { value = 24, unit = "V", source = "-", description = "supply" }'


def _params_file(tmp_path, limits):
    p = tmp_path / "lim.toml"
    p.write_text(BASE + ("\n[limits]\n" + limits + "\n" if limits else ""))
    return p


def test_regions_nonlinear_writes_classes_next_to_the_linear_map(tmp_path, capsys):
    p = _params_file(tmp_path, SUPPLY)
    out = tmp_path / "map.npz"
    rc = main(["regions", "--params", str(p), "--set", "beta=3", "--P-gain", "log:300:20000:6",
               "--D-gain", "lin:1:40:3", "--nonlinear", "--duration", "1", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    text = capsys.readouterr().out
    z = np.load(out)
    assert z["nonlinear_class"].shape == (6, 3) and z["stable"].shape == (6, 3)
    meta = json.loads(str(z["meta"]))
    nl = meta["nonlinear"]
    assert nl["classes"][:3] == ["converging", "limit cycle", "saturating"]
    assert nl["limits"] == {"V_max": 24.0} and nl["duration"] == 1.0
    # the linear map's stable points in the linear regime are converging; (20000, 1..40) unstable
    assert np.array_equal(z["linear_stable"], z["stable"])
    names = np.asarray(nl["classes"])[z["nonlinear_class"]]
    assert "limit cycle" in names[-1] and not z["stable"][-1].any()
    assert f"{(names == 'limit cycle').sum()} limit cycle" in text


def test_no_continue_runs_reaches_the_map(tmp_path, capsys):
    # issue 27: the longer runs continue the shorter ones unless --no-continue-runs; one point at
    # the 24 V cycle, still settling at 0.1 s (growing), so run again to 0.3 s
    p = _params_file(tmp_path, SUPPLY)
    nl = {}
    for flag in ((), ("--no-continue-runs",)):
        out = tmp_path / f"map{len(flag)}.npz"
        rc = main(["regions", "--params", str(p), "--set", "beta=3", "--P-gain", "20000", "--D-gain", "10",
                   "--nonlinear", "--duration", "0.1", "--max-duration", "0.3", "--out", str(out), *flag])
        assert rc == 0, capsys.readouterr().err
        z = np.load(out)
        assert float(z["run_duration"][0, 0]) == pytest.approx(0.3)
        nl[bool(flag)] = json.loads(str(z["meta"]))["nonlinear"]
    assert nl[False]["longer_runs_continue"] and not nl[True]["longer_runs_continue"]
    # 101 + the 200 samples of the continuation, or 101 + 301 from t = 0
    assert (nl[False]["samples_simulated"], nl[True]["samples_simulated"]) == (301, 402)
    assert nl[False]["counts"] == nl[True]["counts"]


@pytest.mark.parametrize("argv, message", [
    (["--nonlinear"], "limits: the parameter file has no [limits] section"),
    (["--duration", "2"], "--duration applies to the nonlinear map; allowed: with --nonlinear"),
    (["--scheduler", "tcp://127.0.0.1:1"], "--scheduler applies to the nonlinear map and the robust region"),
    (["--max-duration", "5"], "--max-duration applies to the nonlinear map"),
    (["--no-continue-runs"], "--no-continue-runs applies to the nonlinear map; allowed: with --nonlinear"),
    (["--nonlinear", "--duration", "2", "--max-duration", "1"], "limits: the parameter file has no [limits]"),
    (["--nonlinear", "--robust"], "--nonlinear with --robust; allowed: one of them"),
])
def test_regions_nonlinear_bad_input_exit_2_writes_nothing(tmp_path, capsys, argv, message):
    p = _params_file(tmp_path, None)
    out = tmp_path / "map.npz"
    rc = main(["regions", "--params", str(p), "--P-gain", "log:300:20000:3", "--D-gain", "lin:1:40:2",
               "--out", str(out), *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and message in err[0]
    assert not out.exists()


def test_bad_limits_entry_exit_2(tmp_path, capsys):
    p = _params_file(tmp_path, 'V_max = { value = -3, unit = "V", source = "-", description = "supply" }')
    rc = main(["regions", "--params", str(p), "--P-gain", "100", "--D-gain", "1", "--nonlinear"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "V_max" in err[0]


def test_simulate_prints_the_describing_function_next_to_the_simulated_cycle(tmp_path, capsys):
    p = _params_file(tmp_path, SUPPLY)
    rc = main(["simulate", "--params", str(p), "--set", "beta=3", "--P-gain", "20000", "--D-gain", "10",
               "--experiment", "disturbance-step", "--duration", "1"])
    assert rc == 0, capsys.readouterr().err
    text = capsys.readouterr().out
    line = next(s for s in text.splitlines() if s.startswith("describing function, V_max = 24 V"))
    df = limit_cycles(ClosedLoop(load_params(p).with_values(beta=3.0)), 20000.0, 10.0,
                      nonlinearity={"V_max": 24.0})
    assert f"A = {df.amplitude[0]:.4g} V at {df.frequency_hz[0]:.4g} Hz" in line
    fund_pred, fund_sim, f_sim = (float(x) for x in re.search(
        r"N\(A\) A = ([\d.]+) V\); simulated voltage: fundamental ([\d.]+) V \(error [\d.]+ %\) at ([\d.]+) Hz", line).groups())
    # the harmonic balance and the simulation agree within a few per cent here (distortion 4 %)
    assert fund_sim == pytest.approx(fund_pred, rel=0.03)
    assert f_sim == pytest.approx(df.frequency_hz[0], rel=0.01)
