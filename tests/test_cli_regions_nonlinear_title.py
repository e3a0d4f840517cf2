"""regions --nonlinear says what was simulated (review of issue 19): the figure's title and the
summary line name the experiment with its unit, the runs' length and reruns, and the limits with
their units (the classes depend on all of them; the title named only the actuator)."""
from haa_sym.cli import main
from haa_sym.io import plots
from haa_sym.model.resources import data_dir

BASE = (data_dir("model") / "hyq_haa.toml").read_text()


def test_title_and_summary_name_the_runs_and_limits(tmp_path, monkeypatch, capsys):
    p = tmp_path / "v.toml"
    p.write_text(BASE + '\n[limits]\nV_max = { value = 24000, unit = "mV" }\nencoder_counts = 4096\n')
    seen = {}
    real = plots.plot_nonlinear_region

    def spy(*a, **k):
        seen["title"] = k["title"]
        return real(*a, **k)

    monkeypatch.setattr(plots, "plot_nonlinear_region", spy)
    rc = main(["regions", "--params", str(p), "--P-gain", "100,1000", "--D-gain", "1,10", "--nonlinear",
               "--experiment", "impedance-step", "--amplitude", "0.05", "--duration", "0.2", "--max-duration", "0.6",
               "--out", str(tmp_path / "m.npz"), "--plot", str(tmp_path / "m.png")])
    out = capsys.readouterr().out
    assert rc == 0 and (tmp_path / "m.png").stat().st_size > 10_000
    runs = "impedance-step, A = 0.05 rad, 0.2 s each (reruns up to 0.6 s)"
    assert seen["title"].split("\n", 1)[1].endswith(
        f"simulated: {runs}; limits: V_max = 24 V, encoder_counts = 4096")
    assert f"simulated with V_max = 24 V, encoder_counts = 4096 ({runs}): " in out
