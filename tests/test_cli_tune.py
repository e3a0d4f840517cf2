"""``haa-sym tune``: bad input is one line and exit 2 with nothing written; the written file loads
and gives the new gains, its report agrees with it, and every other line of the input is kept."""
import json
import tomllib

import numpy as np
import pytest

from haa_sym import load_params
from haa_sym.cli import main

from conftest import ROOT

HD = ROOT / "model" / "harmonic_drive.toml"
# a small search: the round trip, not the optimum, is what these tests check
SMALL = ["--n-lead", "2", "--n-integral", "3", "--rtol", "0.2", "--step-duration", "0.2"]


@pytest.mark.parametrize("argv, match", [
    (["--out", "x.txt"], ("--out 'x.txt': unsupported file type", ".toml")),
    (["--out", "x.toml", "--report", "r.csv"], ("--report 'r.csv'", ".json")),
    (["--out", "x.toml", "--plot", "p.gif"], ("--plot 'p.gif'",)),
    (["--out", "x.toml", "--pm", "-5"], ("--pm: pm_deg = -5.0", "allowed")),
    (["--out", "x.toml", "--gm", "nan"], ("--gm: gm_db = nan", "allowed")),
    (["--out", "x.toml", "--stable-alpha", "1"], ("--stable-alpha '1': not LO:HI",)),
    (["--out", "x.toml", "--stable-alpha", "1:0"], ("--stable-alpha: stable_alpha = (1.0, 0.0)",)),
    (["--out", "x.toml", "--lead-range", "0:1"], ("--lead-range: lead_range = (0.0, 1.0)",)),
    (["--out", "x.toml", "--n-integral", "1"], ("--n-integral: n_integral = 1",)),
    (["--out", "x.toml", "--objective", "best"], ("--objective", "invalid choice")),
    (["--out", "x.toml", "--option", "delay=x"], ("--option",)),
    (["--out", "x.toml", "--params", "no_such_actuator"], ("no_such_actuator",)),
    (["--out", "x.toml", "--passive-at", "100"], ("--passive-at '100'", "P_GAIN:D_GAIN")),
    (["--out", "x.toml", "--passive-at", "100:-1"], ("--passive-at: passive_at",)),
    (["--out", "x.toml", "--params", "harmonic_drive", "--passive-at", "100:10", "--passive-configurations",
      "nominal,retracted"], ("--passive-configurations", "['retracted']", "low_damping")),
    # issue 26: without --passive-at the configurations were ignored silently
    (["--out", "x.toml", "--params", "harmonic_drive", "--passive-configurations", "nominal,heavy"],
     ("--passive-configurations 'nominal,heavy' without --passive-at", "allowed: --passive-at")),
])
def test_bad_input_is_one_line_exit_2_nothing_written(assert_refused, argv, match):
    assert_refused(["tune", *argv], match)


def test_out_is_required(assert_refused):
    assert_refused(["tune", "--params", "harmonic_drive"], "--out")


def test_targets_no_pi_meets_are_refused_before_writing(assert_refused):
    assert_refused(["tune", "--params", str(HD), "--out", "x.toml", "--report", "r.json", "--stable-alpha", "2:3",
                    "--n-lead", "2", "--n-integral", "3"],
                   ("no PI of the search grid meets the targets", "stability over alpha"))


@pytest.mark.slow
def test_the_written_file_round_trips(tmp_path, capsys):
    out, report, plot = tmp_path / "tuned.toml", tmp_path / "tune.json", tmp_path / "tune.png"
    rc = main(["tune", "--params", str(HD), "--out", str(out), "--report", str(report), "--plot", str(plot), *SMALL])
    assert rc == 0
    printed = capsys.readouterr().out
    r = json.loads(report.read_text())
    tuned = load_params(out)
    assert tuned.controller.P_t0 == r["after"]["P_t0_V_per_Nm"]
    assert tuned.controller.I_t0 == r["after"]["I_t0_V_per_Nm_s"]
    original = load_params(HD)
    assert tuned.plant == original.plant and tuned.configurations == original.configurations
    back = tuned.with_values(P_t0=original.controller.P_t0, I_t0=original.controller.I_t0).to_dict()
    assert {k: v for k, v in back.items() if k != "source"} == {k: v for k, v in original.to_dict().items()
                                                                 if k != "source"}
    old, new = HD.read_text().splitlines(), out.read_text().splitlines()
    assert len(old) == len(new) and sum(a != b for a, b in zip(old, new)) == 2
    entry = tomllib.loads(out.read_text())["controller"]["P_t0"]
    assert entry["unit"] == "V/Nm" and "GM >= 12 dB" in entry["description"] and "was " in entry["description"]
    assert list(r["after"]["configurations"]) == ["nominal", *original.configurations]
    assert all(c["meets_targets"] for c in r["after"]["configurations"].values())
    assert plot.stat().st_size > 10_000
    assert "active constraint:" in printed and f"wrote {out}" in printed
    # tuning the tuned file again from its own gains: they are the before of the new run
    out2, report2 = tmp_path / "again.toml", tmp_path / "again.json"
    assert main(["tune", "--params", str(out), "--out", str(out2), "--report", str(report2), *SMALL]) == 0
    again = capsys.readouterr().out
    assert f"before: P_t0 = {tuned.controller.P_t0:.6g}" in again
    # issue 26: the same search finds the same PI, and says so instead of printing before = after
    assert "already at the optimum (no change)" in again and "after: P_t0" not in again
    assert json.loads(report2.read_text())["unchanged"] is True and r["unchanged"] is False
    # the figures are the engineer's, named in the report
    assert r["bandwidth_definition"]["name"] == "tracking"
    assert all("settling_time_5pct_s" in c and "load_mode" in c for c in r["after"]["configurations"].values())
    assert np.isfinite(load_params(out2).controller.I_t0)


@pytest.mark.slow
def test_a_pm_target_met_only_below_the_band_is_not_met(assert_refused):
    """issue 26: `--pm 179` on HyQ wrote a PI whose crossover lay at 0.0999 rad/s, just below the
    analysed band, and reported "PM n/a" with the targets met; the crossover is found now, and
    no PI of the grid has PM >= 179 deg."""
    assert_refused(["tune", "--pm", "179", "--out", "x.toml"],
                   ("no PI of the search grid meets the targets", "pm_deg = 179", "most often missed: pm"))
