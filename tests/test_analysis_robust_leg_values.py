"""Leg ranges say what they analyse (issue 16.2): the configurations of the range replace the
parameters' own values (an edited [bodies.*] J, a --set), so the analysed ends and values are
said on stderr, in meta and in the plot title, with a warning when the own values lie outside."""
import json

import numpy as np

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.robust import leg_text, leg_values, robust_region
from haa_sym.cli import main
from haa_sym.design.schedule import schedule
from haa_sym.io.plots import plot_robust, plot_schedule

from conftest import ROOT


def test_leg_values_of_an_edit_outside_the_range():
    p = load_params().with_values(J_L2=2.0)
    lv = leg_values(p)
    assert lv["leg"] == ["retracted", "extended"]
    assert lv["ends"] == {"retracted": {"J_L2": 0.129, "K_L2": 7.17}, "extended": {"J_L2": 0.439, "K_L2": 11.2}}
    assert lv["own"] == {"J_L2": 2.0, "K_L2": 11.2} and lv["outside"] == {"J_L2": 2.0}
    line, warning = leg_text(lv)
    assert line == ("leg range retracted (J_L2 = 0.129, K_L2 = 7.17) .. extended (J_L2 = 0.439, K_L2 = 11.2), "
                    "segment; it replaces the parameters' own J_L2 = 2, K_L2 = 11.2")
    assert warning.startswith("the parameters' own J_L2 = 2 (range 0.129..0.439) lie outside the leg range")
    # inside the range, or the file as it is: said, no warning
    assert leg_text(leg_values(load_params().with_values(J_L2=0.3)))[1] is None
    assert leg_text(leg_values(load_params()))[1] is None
    # "nominal" as an end analyses the own values: nothing outside
    assert leg_values(p, ("nominal", "retracted"))["outside"] == {}


def test_robust_and_schedule_meta_and_titles():
    loop = ClosedLoop(load_params().with_values(J_L2=2.0))
    P, D = np.geomspace(10, 2000, 3), np.array([5.0, 30.0])
    r = robust_region(loop, P, D, max_per_axis=2)
    assert r.meta["leg_values"] == leg_values(loop.params)
    title = plot_robust(r).axes[0].get_title()
    assert "retracted (J_L2 0.129, K_L2 7.17) .. extended (J_L2 0.439, K_L2 11.2)" in title
    assert "instead of the parameters' J_L2 2, K_L2 11.2 (outside the range)" in title
    s = schedule(loop, P, D, beta_range=(0.5, 2.0), beta_tol=0.25, progress=False)
    assert s.meta["leg_values"]["outside"] == {"J_L2": 2.0}
    sup = plot_schedule(s)._suptitle.get_text()
    assert "instead of the parameters' J_L2 2, K_L2 11.2 (outside the range)" in sup


def test_cli_says_and_warns(tmp_path, capsys):
    text = (ROOT / "model" / "sea.toml").read_text()
    edited = text.replace('J = { value = 0.0867, unit = "kg m^2"', 'J = { value = 2.5, unit = "kg m^2"', 1)
    assert edited != text
    path = tmp_path / "sea_edit.toml"
    path.write_text(edited)
    out = tmp_path / "r.npz"
    rc = main(["regions", "--robust", "--params", str(path), "--P-gain", "10,100", "--D-gain", "1,10",
               "--out", str(out)])
    err = capsys.readouterr().err.splitlines()
    assert rc == 0
    # the warning before the work, the line saying what was analysed once it is done
    assert err[0].startswith("haa-sym: warning: the parameters' own J_link = 2.5 (range 0.0867..0.867) lie outside")
    assert err[1] == ("leg range light (J_link = 0.0867, K_link = 4.25) .. heavy (J_link = 0.867, K_link = 28.3), "
                      "segment; it replaces the parameters' own J_link = 2.5, K_link = 4.25")
    with np.load(out) as z:
        meta = json.loads(str(z["meta"]))
    assert meta["leg_values"]["own"] == {"J_link": 2.5, "K_link": 4.25}
    assert meta["leg_values"]["outside"] == {"J_link": 2.5}
    # --quiet silences the progress line, not the warning
    rc = main(["-q", "regions", "--robust", "--params", str(path), "--P-gain", "10,100", "--D-gain", "1,10"])
    err = capsys.readouterr().err.splitlines()
    assert rc == 0 and len(err) == 1 and err[0].startswith("haa-sym: warning: ")
