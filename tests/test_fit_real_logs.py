"""identify on real measured logs (issue 23): the ITregear SEA (RMD X8 + torsion spring, output
locked on an ATI sensor), tests/data/real-logs/itregear-sea/ (README.txt: source, licence
statement, rig). The 3 Nm chirp run 3 is fitted before t = 28 s on its own jittered, gapped stamps
(median period 2.0 ms, 8 segments); its last 12 s and the repeat run 2 validate.

NRMSE = rms(y - y_model) / rms(y - mean y); VAF = 100 (1 - var(y - y_model) / var(y)) %. The
issue's reference numbers (NRMSE 0.32 <-> VAF 91 %) follow these definitions."""
import dataclasses
import json
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from haa_sym.fit.identify import Experiment, simulate_log
from haa_sym.io.logs import read_log
from haa_sym.model.params import load_params

DATA = Path(__file__).parent / "data" / "real-logs" / "itregear-sea"
FILE = DATA / "rmdx8_sea.toml"
N = 9                                       # the gear ratio of the file
J_OUT_ESTIMATE = 0.028                      # kg m^2, the rotor's estimate at the output (the file's J_m N^2)


def nrmse_vaf(y, yp):
    e = y - yp
    return float(np.sqrt(np.mean(e ** 2)) / np.std(y)), float(100 * (1 - np.var(e) / np.var(y)))


def _friction(params, fc, v_s=0.01):
    """``params`` with Coulomb friction ``fc`` (Nm) on the rotor ([limits] Fc_m)."""
    return dataclasses.replace(params, limits=dataclasses.replace(params.limits, friction={"m": fc},
                                                                  friction_velocity=v_s))


def _validate(params):
    """NRMSE of run 3's held-out part (t >= 28 s, its initial state estimated) and VAF of run 2."""
    held = read_log(DATA / "sweep3Nm_run3_stamped.csv", ("current",), ("torque",), window=(28.0, np.inf))
    run2 = read_log(DATA / "sweep3Nm_run2_stamped.csv", ("current",), ("torque",))
    out = []
    for log in (held, run2):
        yp = simulate_log(Experiment(log, params), ("current",), ("torque",))[0][:, 0]
        out.append(nrmse_vaf(log.signals["torque"], yp))
    return out


def test_the_drive_model_predicts_held_out_data_the_plain_model_does_not():
    """The values the fit below reaches (docs/identify.md), simulated on data it did not see:
    with the drive's lag and delay the held-out NRMSE is below 0.35 and run 2's VAF above 95 %;
    without them (the same mechanical values) neither holds."""
    fitted = {"k_t": 0.15171, "J_m": 3.5230e-4, "B_m": 0.012524}
    p = load_params(FILE).with_values(**fitted, tau_drive=0.034857, delay_drive=0.0034969)
    (held_nrmse, _), (_, run2_vaf) = _validate(p)
    assert held_nrmse <= 0.35 and run2_vaf >= 95.0
    (plain_nrmse, _), (_, plain_vaf) = _validate(p.with_values(tau_drive=0.0, delay_drive=0.0))
    assert plain_nrmse > 0.35 and plain_vaf < 95.0


@pytest.mark.slow
def test_chirp_fit_with_lag_and_delay_on_the_logs_own_stamps(tmp_path, capsys):
    """The acceptance check of issue 23: fit k_t, J_m, B_m, tau_drive, delay_drive to run 3 before
    28 s (input the current command, output the ATI torque) in under 10 s; held-out NRMSE <= 0.35,
    VAF on run 2 >= 95 %, J_m N^2 within a factor 2 of 0.028 kg m^2, the lag and the delay written
    into [drive] with their intervals."""
    from haa_sym.cli import main
    out, report = tmp_path / "fitted.toml", tmp_path / "fit.json"
    start = time.perf_counter()
    assert main(["identify", "--params", str(FILE), "--log", str(DATA / "sweep3Nm_run3_stamped.csv"),
                 "--window", "0:28", "--input", "current", "--output", "torque",
                 "--fit", "k_t,J_m,B_m,tau_drive,delay_drive", "--out", str(out), "--report", str(report)]) == 0
    elapsed = time.perf_counter() - start
    assert elapsed < 10.0, elapsed
    text = capsys.readouterr().out
    assert "simulated on its own intervals; 8 segments" in text
    fit = json.loads(report.read_text())["parameters"]
    assert 0.5 < fit["J_m"]["value"] * N ** 2 / J_OUT_ESTIMATE < 2.0
    for k in ("tau_drive", "delay_drive"):
        lo, hi = fit[k]["ci95"]
        assert 0 < lo < fit[k]["value"] < hi < np.inf
    drive = tomllib.loads(out.read_text())["drive"]
    for k in ("tau_drive", "delay_drive"):
        assert drive[k]["value"] == fit[k]["value"] and drive[k]["ci95"] == fit[k]["ci95"]
        assert drive[k]["source"].startswith("identify_")
    (held_nrmse, _), (_, run2_vaf) = _validate(load_params(out))
    assert held_nrmse <= 0.35 and run2_vaf >= 95.0


def test_a_log_that_does_not_start_at_rest_is_refused_or_its_state_estimated(tmp_path):
    """Run 3 cut at 10 s, written as a log of its own: from rest it is refused in one line (it gave
    k_t 30 % high without a word, issue 23); with --initial-state estimate its state is fitted and
    the prediction holds."""
    from haa_sym.errors import ParameterError
    from haa_sym.fit.identify import FitOptions, identify
    src = np.loadtxt(DATA / "sweep3Nm_run3_stamped.csv", delimiter=",", skiprows=2)
    cut = src[(src[:, 0] >= 10.0) & (src[:, 0] < 16.0)]
    path = tmp_path / "mid.csv"
    np.savetxt(path, cut, delimiter=",", header="time,current,torque", comments="")
    log = read_log(path, ("current",), ("torque",))
    p = load_params(FILE).with_values(k_t=0.15171, J_m=3.5230e-4, B_m=0.012524, tau_drive=0.034857,
                                      delay_drive=0.0034969)
    with pytest.raises(ParameterError, match="torque starts at .*not at rest; allowed: --initial-state estimate"):
        identify([Experiment(log, p)], ("k_t",), ("current",), ("torque",))
    yp = simulate_log(Experiment(log, p), ("current",), ("torque",), options=FitOptions(initial_state="estimate"))[0][:, 0]
    assert nrmse_vaf(log.signals["torque"], yp)[0] < 0.35


# the fit below with friction (docs/identify.md, the worked example; values of 2026-11-26)
FRICTION_FIT = {"k_t": 0.15092, "J_m": 3.4582e-4, "tau_drive": 0.034059, "delay_drive": 0.0030115}
FRICTION_FC = 0.0079350


def test_the_friction_model_predicts_held_out_data():
    """The values the friction fit reaches, simulated (with Fc_m on the rotor) on data it did not
    see: held-out NRMSE below 0.35 and run 2's VAF above 95 %; the same values without the
    friction do worse on both (the friction is not a free decoration)."""
    p = load_params(FILE).with_values(**FRICTION_FIT)
    (held, _), (_, vaf) = _validate(_friction(p, FRICTION_FC))
    assert held <= 0.35 and vaf >= 95.0
    (held0, _), (_, vaf0) = _validate(p)
    assert held0 > held and vaf0 < vaf


@pytest.mark.slow
def test_chirp_fit_with_lag_delay_and_friction():
    """The acceptance check of issue 23 with friction: k_t, J_m, tau_drive, delay_drive and Fc_m
    fitted to run 3 before 28 s on its own stamps (8 segments); scored on run 3 from 28 s on
    (simulated on from the fitted part) and on run 2: NRMSE <= 0.35, VAF >= 95 %; J_m N^2 within
    2x of 0.028 kg m^2; the lag's and the delay's HAC intervals finite and around their values."""
    from haa_sym.fit.identify import identify, validate
    p = _friction(load_params(FILE), 0.02)
    log = read_log(DATA / "sweep3Nm_run3_stamped.csv", ("current",), ("torque",), window=(0.0, 28.0))
    full = read_log(DATA / "sweep3Nm_run3_stamped.csv", ("current",), ("torque",))
    run2 = read_log(DATA / "sweep3Nm_run2_stamped.csv", ("current",), ("torque",))
    keys = ("k_t", "J_m", "tau_drive", "delay_drive", "Fc_m")
    r = identify([Experiment(log, p)], keys, ("current",), ("torque",))
    assert r.meta["converged"]
    n28 = int(np.searchsorted(full.t, 28.0))
    q, _ = validate(r, [("held", Experiment(full, p), n28, full.samples), ("run2", Experiment(run2, p), 0,
                                                                            run2.samples)])
    assert q["held"]["torque"]["nrmse"] <= 0.35 and q["run2"]["torque"]["vaf_percent"] >= 95.0
    got = dict(zip(r.keys, r.value))
    assert 0.5 < got["J_m"] * N ** 2 / J_OUT_ESTIMATE < 2.0
    for k in ("tau_drive", "delay_drive", "Fc_m"):
        lo, hi = r.ci95[r.keys.index(k)]
        assert 0 < lo < got[k] < hi < np.inf
