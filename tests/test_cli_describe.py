"""haa-sym describe: the predictions written and printed, the figure, and one-line refusals."""
import json

import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.describing import linear_part
from haa_sym.cli import main


def test_describe_writes_json_and_plot(tmp_path, capsys):
    out, png = tmp_path / "df.json", tmp_path / "df.png"
    rc = main(["describe", "--P-gain", "3000", "--D-gain", "1", "--limit", "V_max=24", "--limit", "Fc_L2=0.1",
               "--out", str(out), "--plot", str(png)])
    assert rc == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    data = json.loads(out.read_text())
    assert [p["nonlinearity"] for p in data["predictions"]] == ["V_max", "Fc_L2"]
    (cycle,) = data["predictions"][0]["limit_cycles"]
    assert f"A = {cycle['amplitude']:.6g} V" in printed and "stable (Loeb)" in printed
    # the written cycle satisfies the harmonic balance with the saturation's DF, G from the loop
    a = 24.0 / cycle["amplitude"]
    N = 2 / np.pi * (np.arcsin(a) + a * np.sqrt(1 - a * a))
    G = linear_part(ClosedLoop(load_params()), 3000.0, 1.0, "V_max", np.array([cycle["omega_rad_s"]]))[0]
    assert abs(1 + N * G) < 1e-8
    assert cycle["frequency_hz"] == pytest.approx(cycle["omega_rad_s"] / (2 * np.pi), rel=1e-15)
    assert data["predictions"][0]["meta"]["P_gain"] == 3000.0
    assert png.stat().st_size > 1000


def test_describe_says_when_nothing_is_predicted(capsys):
    # the torque loop alone at the file's gains: |G| < 1 at every phase crossover
    assert main(["describe", "--limit", "V_max=24"]) == 0
    assert capsys.readouterr().out.startswith("V_max = 24 V on the voltage command V_k (PI output + velocity "
                                              "compensation, before the hold): no limit cycle predicted")


@pytest.mark.parametrize("args,msg", [
    ([], "--limit missing"),
    (["--limit", "V_max"], "--limit 'V_max'"),
    (["--limit", "V_max=abc"], "--limit 'V_max=abc'"),
    (["--limit", "V_max=0"], "V_max = 0.0; allowed: a number from 1e-100 to 1e+100 (V)"),
    (["--limit", "I_max=3"], "I_max: structure = 'paper' commands a voltage, and the current limit"),
    (["--limit", "Fc_L3=1"], "no body 'L3'"),
    (["--P-gain", "1,2", "--limit", "V_max=24"], "allowed: one point"),
])
def test_describe_refuses_bad_input_and_writes_nothing(tmp_path, assert_refused, args, msg):
    assert_refused(["describe", *args, "--out", "df.json", "--plot", "df.png"], msg)


def test_describe_refuses_bad_output_suffix(assert_refused):
    assert_refused(["describe", "--limit", "V_max=24", "--out", "df.csv"], "allowed: ['.json']")
