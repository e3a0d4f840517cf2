"""haa-sym identify, review of issue 17: ``--configuration nominal`` names the file's own values
(as tune does), so a nominal log and a configuration's log can be fitted jointly; a key the logs
do not determine (here: a log whose time column is in ms, read as 1 s periods) is refused with one
line, exit 2, nothing written, instead of a fitted file with an interval of 1e-47 .. 1e45."""
import json

import numpy as np

from haa_sym.cli import main
from haa_sym.model.params import actuator_path, load_params

from identify_synthetic import experiment, two_mass, write_csv

TRUTH = {"K_hd": 2.5e4, "D_hd": 50.0}


def test_nominal_and_heavy_logs_fitted_jointly(tmp_path, capsys):
    params = load_params(actuator_path("harmonic_drive"))
    logs = []
    for seed, conf in ((1, None), (2, "heavy")):
        p = params.configuration(conf) if conf else params
        t, u, y, _ = experiment(two_mass, dict(p.plant.as_dict(), **TRUTH), seed=seed, duration=2.0)
        logs += ["--log", str(write_csv(tmp_path / f"{conf}.csv", t, {"voltage": u, "torque": y[:, 0],
                                                                     "theta": y[:, 1]}))]
    out, rep = tmp_path / "fitted.toml", tmp_path / "fit.json"
    assert main(["identify", "--params", "harmonic_drive", *logs, "--configuration", "nominal", "--configuration",
                 "heavy", "--input", "voltage", "--output", "torque,theta", "--fit", "K_hd,D_hd", "--out", str(out),
                 "--report", str(rep), "-q"]) == 0
    report = json.loads(rep.read_text())
    assert [v["configuration"] for v in report["meta"]["logs"].values()] == [None, "heavy"]
    for k, truth in TRUTH.items():
        p = report["parameters"][k]
        assert abs(p["value"] / truth - 1) < 0.03 and p["ci95"][0] <= truth <= p["ci95"][1], (k, p)


def test_undetermined_keys_refused_in_one_line(tmp_path, capsys):
    params = load_params(actuator_path("harmonic_drive"))
    t, u, y, _ = experiment(two_mass, params.plant.as_dict(), seed=5, duration=3.0)
    log = write_csv(tmp_path / "ms.csv", 1000 * t, {"voltage": u, "torque": y[:, 0], "theta": y[:, 1]})
    out, rep = tmp_path / "fitted.toml", tmp_path / "fit.json"
    code = main(["identify", "--params", "harmonic_drive", "--log", str(log), "--input", "voltage", "--output",
                 "torque,theta", "--fit", "J_link,B_link,K_hd,D_hd", "--out", str(out), "--report", str(rep), "-q"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--fit" in err and "do not determine" in err, err
    assert not out.exists() and not rep.exists() and not list(tmp_path.glob("*.tmp*"))
    assert np.allclose(np.diff(1000 * t), 1.0)          # the log is uniform: only its unit is wrong
