"""haa-sym identify with Coulomb friction and output offsets from the command line (issue 23,
item 2): ``--set Fc_m=...`` / ``friction_velocity=...`` (the [limits] friction identify fits),
``--fit ...,Fc_m``, ``--offsets``; the fitted file's [limits] and fit.json's offsets; the refusals
(one line, exit 2, nothing written). The log: the friction simulation of the RMD X8 SEA file (its
drive off), written to a CSV with a tare added to each output."""
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from haa_sym.cli import main
from haa_sym.fit.friction import friction_entries, simulate_friction
from haa_sym.fit.model import open_loop_model
from haa_sym.model.params import load_params

from identify_synthetic import write_csv

FILE = Path(__file__).parent / "data" / "real-logs" / "itregear-sea" / "rmdx8_sea.toml"
FC, VS, TARE = 0.03, 0.01, {"torque": 0.05, "theta": -2e-4}
NO_DRIVE = ("--set", "tau_drive=0", "--set", "delay_drive=0")


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    p = load_params(FILE).with_values(tau_drive=0.0, delay_drive=0.0)
    m = open_loop_model(p.plant, (), ("current",), ("torque", "theta"))
    fr = friction_entries(p.plant, (), ("current",), m.A.shape[0], {"m": FC}, VS)
    rng = np.random.default_rng(3)
    n = 1500
    t = np.arange(n) * 2e-3
    u = 4 * np.sin(2 * np.pi * 2 * t) + 1.5 * np.sin(2 * np.pi * 13 * t) + 0.5 * rng.standard_normal(n)
    y, _ = simulate_friction(m, fr, np.full(n - 1, 2e-3), u[:, None], sensitivities=False)
    y = y + 0.005 * y.std(axis=0) * rng.standard_normal(y.shape)
    path = tmp_path_factory.mktemp("fr") / "fr.csv"
    return write_csv(path, t, {"current": u, "torque": y[:, 0] + TARE["torque"], "theta": y[:, 1] + TARE["theta"]})


def _argv(log, tmp_path, *extra):
    return ["identify", "--params", str(FILE), "--log", str(log), "--input", "current", "--output", "torque,theta",
            *NO_DRIVE, "--out", str(tmp_path / "f.toml"), "--report", str(tmp_path / "fit.json"), *extra]


def test_friction_and_offsets_fitted_from_the_command_line(log, tmp_path, capsys):
    assert main(_argv(log, tmp_path, "--fit", "k_t,Fc_m", "--set", "Fc_m=0.02", "--set", "k_t=0.17",
                      "--set", f"friction_velocity={VS}", "--offsets", "torque,theta")) == 0
    text = capsys.readouterr().out
    report = json.loads((tmp_path / "fit.json").read_text())
    fc = report["parameters"]["Fc_m"]
    assert abs(fc["value"] / FC - 1) < 0.01 and fc["ci95"][0] < FC < fc["ci95"][1]
    assert abs(report["parameters"]["k_t"]["value"] / 0.15478 - 1) < 0.01
    off = report["offsets"]["fr.csv"]
    assert abs(off["torque"] - TARE["torque"]) < 2e-3 and abs(off["theta"] - TARE["theta"]) < 2e-5
    assert "fr.csv: offsets torque 0.05" in text
    limits = tomllib.loads((tmp_path / "f.toml").read_text())["limits"]
    assert limits["Fc_m"]["value"] == fc["value"] and limits["Fc_m"]["ci95"] == fc["ci95"]
    assert limits["friction_velocity"]["value"] == VS


@pytest.mark.parametrize("extra, message", [
    (("--fit", "k_t,Fc_m"), "--fit Fc_m: initial value 0.0; allowed: a positive start"),
    (("--fit", "k_t", "--set", "Fc_q=0.01"), "--set Fc_q=0.01: not a friction entry; allowed: ['Fc_m'"),
    (("--fit", "k_t", "--set", "Fc_m=-1"), "--set Fc_m=-1: Fc_m = -1 is out of range; allowed: a number >= 0"),
    (("--fit", "k_t", "--set", "friction_velocity=0"), "friction_velocity = 0 is out of range; allowed: a number > 0"),
    (("--fit", "k_t", "--offsets", "velocity"), "--offsets velocity; allowed: distinct names of --output"),
])
def test_bad_friction_and_offset_flags_refused(log, tmp_path, capsys, extra, message):
    assert main(_argv(log, tmp_path, *extra)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("haa-sym: error: ") and message in err[0], err
    assert not (tmp_path / "f.toml").exists() and not (tmp_path / "fit.json").exists()
