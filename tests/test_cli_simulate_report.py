"""haa-sym simulate, as a new user meets it (review of issue 19): a run beyond the memory budget
is refused before it starts (the library's arrays, and the CLI's CSV text), the [limits] jitter
refusals name the file like every other [limits] message, and the figure says what was run
(experiment, amplitude, gains, limits) with the describing-function note off the torque trace."""
import math
import re

import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate
from haa_sym.cli import main
from haa_sym.errors import ParameterError
from haa_sym.io import plots
from haa_sym.io.budget import BYTES_PER_SAMPLE, CSV_BYTES_PER_SAMPLE
from haa_sym.model.resources import data_dir

BASE = (data_dir("model") / "hyq_haa.toml").read_text()


def _params_file(tmp_path, limits):
    p = tmp_path / "lim.toml"
    p.write_text(BASE + "\n[limits]\n" + limits + "\n")
    return p


def _samples(duration, Ts=1e-3):
    return int(math.ceil(duration / Ts - 1e-9)) + 1


def test_library_refuses_a_run_beyond_the_memory_budget(monkeypatch):
    loop = ClosedLoop(load_params())
    n = _samples(2.0)
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", str(n * BYTES_PER_SAMPLE - 1))
    with pytest.raises(ParameterError, match=rf"duration = 2.0 s \({n} samples.*memory budget") as e:
        simulate(loop, 200.0, 5.0, duration=2.0)
    assert "\n" not in str(e.value)
    # one sample's worth below it the same run is allowed
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", str(n * BYTES_PER_SAMPLE))
    assert len(simulate(loop, 200.0, 5.0, duration=2.0).time) == n


def test_cli_refuses_a_csv_beyond_the_budget_and_writes_nothing(tmp_path, monkeypatch, capsys):
    p = _params_file(tmp_path, "V_max = 24")
    n = _samples(10.0)
    # (10 s: the describing function's frequency grid, 8 MB, fits too)
    # enough for the simulation's arrays, not for the CSV's text of the same run
    monkeypatch.setenv("HAA_SYM_MEMORY_BUDGET", str(n * CSV_BYTES_PER_SAMPLE - 1))
    assert n * BYTES_PER_SAMPLE < n * CSV_BYTES_PER_SAMPLE - 1
    out, fig = tmp_path / "s.csv", tmp_path / "s.png"
    args = ["simulate", "--params", str(p), "--P-gain", "200", "--D-gain", "5", "--experiment",
            "disturbance-step", "--duration", "10"]
    assert main(args + ["--out", str(out), "--plot", str(fig)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"--duration 10 ({n} samples at Ts = 0.001 s" in err and "memory" in err
    assert not out.exists() and not fig.exists()
    # without outputs only the simulation's own arrays count: it runs
    assert main(args) == 0


@pytest.mark.parametrize("limits, match", [
    ("jitter = 1e-3", r"jitter = 0.001 s rms; allowed: < Ts / 6"),
    ("jitter = 1e-6\nFc_L2 = 0.1", r"jitter together with Coulomb friction is not supported"),
])
def test_jitter_refusals_name_the_file(tmp_path, capsys, limits, match):
    p = _params_file(tmp_path, limits)
    out = tmp_path / "s.csv"
    rc = main(["simulate", "--params", str(p), "--P-gain", "200", "--D-gain", "5", "--experiment",
               "disturbance-step", "--duration", "0.05", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and not out.exists()
    assert err.startswith(f"haa-sym: error: {p} [limits]: ")
    assert re.search(match, err)


def test_figure_says_what_was_run_and_the_note_does_not_cover_the_trace(tmp_path, monkeypatch, capsys):
    p = _params_file(tmp_path, 'V_max = { value = 6000, unit = "mV" }\nencoder_counts = 4096')
    seen = {}
    real = plots.plot_simulation

    def spy(time, columns, saturated=None, title="", cycle="", command="voltage (V)"):
        seen["title"], seen["fig"] = title, real(time, columns, saturated, title, cycle, command)
        return seen["fig"]

    monkeypatch.setattr(plots, "plot_simulation", spy)
    rc = main(["simulate", "--params", str(p), "--P-gain", "300", "--D-gain", "4", "--experiment",
               "impedance-step", "--amplitude", "0.2", "--duration", "0.2", "--plot", str(tmp_path / "s.png")])
    text = capsys.readouterr().out
    assert rc == 0 and (tmp_path / "s.png").stat().st_size > 10_000
    line = seen["title"].splitlines()[-1]
    assert line == ("impedance-step, A = 0.2 rad; P_gain = 300 Nm/rad, D_gain = 4 Nms/rad; "
                    "limits: V_max = 6 V, encoder_counts = 4096")
    assert "impedance-step (A = 0.2 rad)" in text and "limits: V_max = 6 V, encoder_counts = 4096;" in text
    torque_ax = seen["fig"].axes[1]
    assert torque_ax.get_ylabel() == "torque (Nm)"
    assert torque_ax.get_legend().get_title().get_text() == ""
    assert torque_ax.get_title(loc="left").startswith("verdict: saturating; linear loop at this point: stable")
    assert "\ndescribing function, V_max = 6 V" in torque_ax.get_title(loc="left")
