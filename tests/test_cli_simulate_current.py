"""The command line on a current-commanded structure (impedance_current; docs/simulate.md, "A
current command"): simulate's CSV names the held command a current, --log-out writes identify's
`current` input, regions --nonlinear and describe run on it."""
import json

import numpy as np

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate
from haa_sym.cli import main
from haa_sym.model import resources

LIMITS = """
[limits]
I_max = { value = 3, unit = "A", source = "-", description = "the amplifier's current limit" }
Fc_m = { value = 0.005, unit = "Nm", source = "-", description = "brush friction" }
"""


def _file(tmp_path, name="haptic_wall", extra=LIMITS):
    f = tmp_path / f"{name}.toml"
    f.write_text((resources.data_dir("model") / f"{name}.toml").read_text() + extra)
    return f


def _csv(path):
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    table = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    return dict(zip(lines[0].split(","), table.T))


def test_simulate_writes_the_current_command_and_a_current_log(tmp_path, capsys):
    f = _file(tmp_path)
    out, log, meta = tmp_path / "s.csv", tmp_path / "log.csv", tmp_path / "m.json"
    assert main(["simulate", "--params", str(f), "--P-gain", "20", "--D-gain", "0.001", "--experiment", "deflection",
                 "--duration", "0.5", "--out", str(out), "--log-out", str(log), "--meta", str(meta)]) == 0
    text = capsys.readouterr().out
    assert "describing function, I_max = 3 A" in text and "simulated current command" in text
    s = simulate(ClosedLoop(load_params(str(f))), 20.0, 0.001, experiment="deflection", duration=0.5)
    csv = _csv(out)
    assert "voltage" not in csv
    assert np.allclose(csv["current_command"], s.voltage, rtol=1e-11) and np.abs(s.voltage).max() == 3.0
    lg = _csv(log)
    assert list(lg) == ["time", "current", "torque_ref", "torque", "theta", "velocity"]
    assert np.allclose(lg["current"], s.voltage, rtol=1e-11)
    assert json.loads(meta.read_text())["drive"]["command"] == "current"


def test_regions_nonlinear_and_describe_run_on_the_qdd_leg(tmp_path, capsys):
    f = _file(tmp_path, "qdd_leg", '\n[limits]\nI_max = { value = 5, unit = "A", source = "-", description = "x" }\n')
    npz = tmp_path / "m.npz"
    # P 60 / D 0.6 linearly stable (converging), P 300 / D 0 unstable, bounded by the current limit
    assert main(["regions", "--params", str(f), "--P-gain", "60,300", "--D-gain", "0,0.6", "--nonlinear",
                 "--experiment", "deflection", "--out", str(npz), "-q"]) == 0, capsys.readouterr().err
    z = np.load(npz, allow_pickle=False)
    meta = json.loads(str(z["meta"]))
    classes = [meta["nonlinear"]["classes"][c] for c in z["nonlinear_class"].ravel()]
    assert classes[1] == "converging" and classes[2] == "limit cycle", classes      # (60, 0.6), (300, 0)
    capsys.readouterr()
    assert main(["describe", "--params", str(f), "--P-gain", "300", "--D-gain", "0"]) == 0
    text = capsys.readouterr().out
    assert "I_max = 5 A on the current command" in text and "agrees" in text
