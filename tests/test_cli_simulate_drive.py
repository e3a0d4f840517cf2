"""The drive ([drive]: tau_drive, delay_drive) through the commands that simulate: `simulate`
(its CSV, --log-out and --meta) and `regions --nonlinear` (docs/simulate.md, "The drive")."""
import json

import numpy as np

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate
from haa_sym.cli import main
from haa_sym.model.limits import Limits
from haa_sym.model.resources import data_dir

BASE = (data_dir("model") / "hyq_haa.toml").read_text()
DRIVE = ('\n[drive]\ntau_drive = { value = 4, unit = "ms", source = "-", description = "lag" }\n'
         'delay_drive = { value = 2.37, unit = "ms", source = "-", description = "dead time" }\n')
SUPPLY = '\n[limits]\nV_max = { value = 5, unit = "V", source = "-", description = "supply" }\n'


def test_simulate_log_out_and_meta_carry_the_drive(tmp_path, capsys):
    log, meta, csv = tmp_path / "run.csv", tmp_path / "m.json", tmp_path / "sim.csv"
    assert main(["simulate", "--P-gain", "200", "--D-gain", "5", "--set", "tau_drive=0.004", "--set",
                 "delay_drive=0.00237", "--experiment", "chirp", "--duration", "0.5", "--log-out", str(log),
                 "--meta", str(meta), "--out", str(csv)]) == 0
    assert "drive: lag 0.004 s, dead time 0.00237 s (2 samples + 0.00037 s)" in capsys.readouterr().out
    m = json.loads(meta.read_text())
    assert m["drive"]["delay_whole_samples"] == 2
    assert abs(m["drive"]["delay_fraction_s"] - 0.00037) < 1e-12
    # the log is the run with the drive: the API's run of the same loop
    p = load_params().with_values(tau_drive=0.004, delay_drive=0.00237)
    s = simulate(ClosedLoop(p), 200.0, 5.0, limits=Limits(), experiment="chirp", duration=0.5)
    lines = [ln for ln in log.read_text().splitlines() if not ln.startswith("#")]
    table = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    logged = dict(zip(lines[0].split(","), table.T))
    for c in ("voltage", "torque", "current"):
        assert np.allclose(logged[c], getattr(s, c), rtol=1e-9, atol=1e-12 * np.abs(getattr(s, c)).max()), c
    free = simulate(ClosedLoop(load_params()), 200.0, 5.0, limits=Limits(), experiment="chirp", duration=0.5)
    assert np.abs(free.torque - s.torque).max() > 1e-2 * np.abs(s.torque).max()


def test_regions_nonlinear_sees_the_drive(tmp_path, capsys):
    # HyQ P 5000, D 6.95: stable without the drive, unstable with it; a 5 V supply bounds it
    out = {}
    for name, text in (("free", BASE + SUPPLY), ("drive", BASE + SUPPLY + DRIVE)):
        f = tmp_path / f"{name}.toml"
        f.write_text(text)
        npz = tmp_path / f"{name}.npz"
        assert main(["regions", "--params", str(f), "--P-gain", "5000", "--D-gain", "6.95", "--nonlinear",
                     "--out", str(npz), "-q"]) == 0, capsys.readouterr().err
        out[name] = capsys.readouterr().out
    assert "1 converging" in out["free"] and "1 limit cycle" in out["drive"], out
