"""identify fits logs with different outputs jointly (issue 23, item 3): a torque-only log and a
torque-and-angle log of one drive (``--log a.csv --output torque --log b.csv --output torque,theta``),
both from the independent simulation of tests/identify_synthetic.py. What is checked: the fit
recovers the keys; it uses log b's angle (an encoder mis-scaled by 5 % in b moves the values far
outside their intervals) and not a column of log a that its --output does not name (a's file carries
a wrong angle column, 50 % off, and the values are those of the correct one bit for bit); the
report and the fitted file name both logs."""
import json
import tomllib

import numpy as np
import pytest

from haa_sym.cli import main
from haa_sym.model.params import load_params
from identify_synthetic import HD_TRUTH, experiment, two_mass, write_csv

START = ["--set", "J_link=0.42", "--set", "B_link=2.6", "--set", "K_hd=2.5e4", "--set", "D_hd=50"]


def _logs(tmp_path, theta_scale_a, theta_scale_b):
    plant = load_params("harmonic_drive").plant
    p = {k: getattr(plant, k) for k in plant.topology.parameter_keys} | HD_TRUTH
    paths = []
    for name, seed, scale in (("chirp_torque.csv", 1, theta_scale_a), ("ramp_torque_theta.csv", 2, theta_scale_b)):
        t, u, y, _ = experiment(two_mass, p, seed=seed, duration=6.0)
        path = tmp_path / f"{scale}_{name}"
        write_csv(path, t, {"voltage": u, "torque": y[:, 0], "theta": scale * y[:, 1]})
        paths.append(path)
    return paths


def _fit(tmp_path, a, b, tag):
    out, report = tmp_path / f"{tag}.toml", tmp_path / f"{tag}.json"
    assert main(["identify", "--params", "harmonic_drive", "--log", str(a), "--output", "torque",
                 "--log", str(b), "--output", "torque,theta", "--input", "voltage",
                 "--fit", "J_link,B_link,K_hd,D_hd", *START, "--out", str(out), "--report", str(report)]) == 0
    return json.loads(report.read_text()), out.read_text()


@pytest.mark.slow
def test_a_torque_log_and_a_torque_and_angle_log_fitted_jointly(tmp_path):
    a, b = _logs(tmp_path, 1.0, 1.0)
    rep, text = _fit(tmp_path, a, b, "joint")
    par = rep["parameters"]
    for key, truth in HD_TRUTH.items():
        lo, hi = par[key]["ci95"]
        assert abs(par[key]["value"] / truth - 1) < 0.01 and lo <= truth <= hi, (key, par[key])
    assert set(rep["rms_error"]) == {"torque", "theta"}
    assert rep["samples"] == 2 * 6000                                     # rows of both logs
    for section in ("sampling", ):
        assert set(rep[section]) == {a.name, b.name}
    assert set(rep["meta"]["logs"]) == {a.name, b.name}
    refs = tomllib.loads(text)["about"]["references"]
    ident = [v for k, v in refs.items() if k.startswith("identify_")]
    assert len(ident) == 1 and a.name in ident[0] and b.name in ident[0]

    # a's wrong angle column is not read: the same values to the last bit
    a_bad, _ = _logs(tmp_path, 1.5, 1.0)
    rep_a_bad, _ = _fit(tmp_path, a_bad, b, "a_bad")
    assert all(rep_a_bad["parameters"][k]["value"] == par[k]["value"] for k in HD_TRUTH)
    # b's angle is: mis-scaled by 5 %, the inertia and stiffness move far outside their intervals
    _, b_bad = _logs(tmp_path, 1.0, 1.05)
    rep_b_bad, _ = _fit(tmp_path, a, b_bad, "b_bad")
    moved = [k for k in HD_TRUTH if not par[k]["ci95"][0] <= rep_b_bad["parameters"][k]["value"] <= par[k]["ci95"][1]]
    assert moved, rep_b_bad["parameters"]
