"""haa-sym identify, issue 23 items 4 and 5: --validate / --validate-window / --holdout (NRMSE and VAF
in the summary, fit.json's ``validation`` and the figure), keys the logs cannot tell apart and a fit
stopped at its iteration limit refused (exit 2, one line, nothing written) unless
--allow-unconverged, which marks the file. Logs from tests/identify_synthetic.py (independent
simulation)."""
import json

import pytest

import haa_sym.cli.identify as cli_identify
from haa_sym.cli import main
from haa_sym.fit.identify import FitOptions
from haa_sym.model.params import actuator_path, load_params

from identify_synthetic import experiment, two_mass, write_csv

KEYS = "J_link,B_link,K_hd,D_hd"
START = ("--set", "J_link=0.42", "--set", "B_link=1.7", "--set", "K_hd=3.6e4", "--set", "D_hd=50")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("logs")
    p = load_params(actuator_path("harmonic_drive")).plant.as_dict()
    out = []
    for seed, name in ((7, "hd.csv"), (8, "val.csv")):
        t, u, y, _ = experiment(two_mass, p, seed=seed, duration=6.0)
        out.append(write_csv(d / name, t, {"voltage": u, "torque": y[:, 0], "theta": y[:, 1]}))
    return out


def _argv(log, *extra):
    return ["identify", "--params", "harmonic_drive", "--log", str(log), "--input", "voltage", "--output",
            "torque,theta", "--fit", KEYS, *START, *extra]


def test_validation_and_holdout_in_summary_and_report(tmp_path, logs, capsys):
    fit, val = logs
    rep, out = tmp_path / "fit.json", tmp_path / "f.toml"
    assert main(_argv(fit, "--holdout", "0.25", "--validate", str(val), "--validate-window", "1:5",
                      "--out", str(out), "--report", str(rep))) == 0
    printed = capsys.readouterr().out
    assert "the last 1500 held out (--holdout)" in printed
    for label in ("hd.csv", "hd.csv:holdout", "val.csv"):
        assert f"validation {label}: torque NRMSE" in printed, printed
    report = json.loads(rep.read_text())
    v = report["validation"]
    assert set(v) == {"hd.csv", "hd.csv:holdout", "val.csv"}
    assert [v[k]["torque"]["samples"] for k in ("hd.csv", "hd.csv:holdout", "val.csv")] == [4500, 1500, 4000]
    assert report["samples"] == 4500
    for q in v.values():
        for o in ("torque", "theta"):
            # 1 % white sensor noise on a correct model: NRMSE about 0.01, VAF about 99.99 %
            assert set(q[o]) == {"nrmse", "vaf_percent", "samples"}
            assert 0.005 < q[o]["nrmse"] < 0.05 and 99.7 < q[o]["vaf_percent"] <= 100, q
    assert report["converged"] is True and "HAC" in report["ci95_method"]
    assert set(report["residuals"]["hd.csv"]) == {"torque", "theta"}
    assert "sandwich (HAC)" in out.read_text()


def _locked_log(tmp_path):
    """The harmonic drive's link held (K_link 1e9), current in, torque out: the outputs see J_m, B_m,
    K_hd and D_hd only through their ratios (scaling all four by one factor changes nothing)."""
    p = load_params(actuator_path("harmonic_drive")).plant.as_dict()
    t, u, y, _ = experiment(two_mass, dict(p, K_link=1e9), seed=0, duration=2.0, current=True, outputs=("torque",))
    return write_csv(tmp_path / "locked.csv", t, {"current": u, "torque": y[:, 0]})


def test_indistinguishable_keys_are_refused(tmp_path, assert_refused):
    log = _locked_log(tmp_path)
    assert_refused(["identify", "--params", "harmonic_drive", "--log", str(log), "--input", "current", "--output",
                    "torque", "--fit", "J_m,B_m,K_hd,D_hd", "--set", "K_link=1e9", "--set", "J_m=6e-5",
                    "--out", "f.toml", "--report", "fit.json"],
                   ("cannot tell D_hd, K_hd, J_m, B_m apart", "condition number", "above 1e+10"))


def test_unconverged_fit_refused_unless_allowed_then_marked(tmp_path, logs, assert_refused, monkeypatch, capsys):
    monkeypatch.setattr(cli_identify, "FitOptions", lambda **kw: FitOptions(**kw, max_iterations=1))
    argv = _argv(logs[0], "--out", "f.toml", "--report", "fit.json")
    assert_refused(argv, ("stopped at its iteration limit (1 per pass)", "--allow-unconverged"))
    monkeypatch.chdir(tmp_path)
    assert main(argv + ["--allow-unconverged"]) == 0
    assert "iteration limit" in capsys.readouterr().err
    text = (tmp_path / "f.toml").read_text()
    assert text.startswith("# haa-sym identify (identify_") and "NOT CONVERGED" in text.splitlines()[0]
    assert json.loads((tmp_path / "fit.json").read_text())["converged"] is False


@pytest.mark.parametrize("extra,match", [
    (("--holdout", "1.5"), "--holdout 1.5; allowed: a fraction 0 < F < 1"),
    (("--validate-window", "1:2"), "--validate-window given 1 times for 0 --validate logs"),
    (("--validate", "VAL", "--validate-window", "7:9"), "--validate-window 7:9 holds 0 samples"),
    (("--validate", "VAL", "--validate-window", "3:1"), "--validate-window '3:1': START must be below STOP"),
    (("--validate", "VAL", "--validate-window", "1-3"), "--validate-window '1-3'; allowed: START:STOP"),
    (("--validate", "FIT"), "--validate FIT: the same file as --log"),
])
def test_bad_validation_flags_one_line_exit_2(tmp_path, logs, assert_refused, extra, match):
    extra = tuple(str(logs[1]) if x == "VAL" else str(logs[0]) if x == "FIT" else x for x in extra)
    assert_refused(_argv(logs[0], "--out", "f.toml", *extra), match.replace("FIT", str(logs[0])))
