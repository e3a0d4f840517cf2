"""haa_sym.io.plots: every plot function draws a figure whose title and axis labels say what is
drawn (every axis label and colour bar with its unit), and save_figure writes it (a PNG here) and
closes it; the CLI's figures are titled with the actuator and what differs from its file. Small
data, so this stays fast: a real region map and step response on coarse grids, plain stand-ins
for the slower results."""
import re
from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.collections import QuadMesh
from matplotlib.colors import to_hex

from haa_sym import ClosedLoop, LoopOptions, region_map
from haa_sym.analysis.torque import step_response
from haa_sym.cli import main
from haa_sym.cli.common import differences, figure_title, measured_torque
from haa_sym.io import plots
from haa_sym.model.params import actuator_path, load_params

P, D = np.geomspace(1.0, 20000.0, 8), np.linspace(1.0, 50.0, 6)


@pytest.fixture(scope="module")
def region(params):
    return region_map(ClosedLoop(params), P, D, progress=False)


def _boundary():
    """Curves of every kind plot_boundary styles (the fields it reads of a Boundaries)."""
    def curve(kind, shift):
        return SimpleNamespace(P_gain=np.geomspace(2.0, 10000.0, 20), D_gain=np.linspace(1 + shift, 40 + shift, 20),
                               kind=kind)
    kinds = ("complex", "z=1", "z=-1", "pm=30", "passivity")
    return SimpleNamespace(curves=[curve(k, i) for i, k in enumerate(kinds)],
                           meta={"P_range": (1.0, 20000.0), "D_range": (0.0, 50.0)})


def _labels(ax):
    return ax.get_title(), ax.get_xlabel(), ax.get_ylabel()


UNIT = re.compile(r"[(\[][^()\[\]]+[)\]]")


def _check_units(fig):
    """Every axis label of every axes (colour bars included) names a unit in brackets or
    parentheses: the generic check over every figure these tests draw."""
    labels = [lab for ax in fig.axes for lab in (ax.get_xlabel(), ax.get_ylabel()) if lab]
    assert labels
    for lab in labels:
        assert UNIT.search(lab), f"axis label without a unit: {lab!r}"


def _saved(fig, tmp_path, name="fig.png"):
    _check_units(fig)
    path = plots.save_figure(fig, tmp_path / name)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 1000
    assert fig.number not in plt.get_fignums()                  # closed after saving
    return path


def test_plot_region(region, tmp_path):
    fig = plots.plot_region(region, title="nominal map")
    (ax,) = fig.axes
    assert _labels(ax) == ("nominal map", "P_gain (Nm/rad)", "D_gain (Nms/rad)") and ax.get_xscale() == "log"
    assert "stable, PM < 30 deg" in [t.get_text() for t in fig.legends[0].get_texts()]
    _saved(fig, tmp_path)
    fig = plots.plot_region(region, title="with curves", boundary=_boundary())
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "phase margin 30 deg" in texts and "stability boundary (z=-1)" in texts
    _saved(fig, tmp_path, "curves.png")


def test_plot_region_panels(region, tmp_path):
    fig = plots.plot_region_panels([region, region], ["beta = 1", "beta = 2"], "Fig. 8: varying beta")
    assert [ax.get_title() for ax in fig.axes] == ["beta = 1", "beta = 2"]
    assert fig._suptitle.get_text() == "Fig. 8: varying beta"
    assert all(_labels(ax)[1:] == ("P_gain (Nm/rad)", "D_gain (Nms/rad)") for ax in fig.axes)
    _saved(fig, tmp_path)


def test_plot_boundary(tmp_path):
    fig = plots.plot_boundary(_boundary(), title="exact curves")
    (ax,) = fig.axes
    assert _labels(ax) == ("exact curves", "P_gain (Nm/rad)", "D_gain (Nms/rad)")
    assert ax.get_xlim() == pytest.approx((1.0, 20000.0)) and len(ax.lines) == 5
    assert "passivity boundary (|phase Z| = 90 deg)" in [t.get_text() for t in ax.get_legend().get_texts()]
    assert len(plots.curve_legend(_boundary())) == 5
    _saved(fig, tmp_path)


def test_plot_corrected_phase(tmp_path):
    w = np.logspace(-1, 3, 50)
    fig = plots.plot_corrected_phase([(w, 60 * np.sin(np.log(w)), "torque loop"), (w, 0 * w, "P 200, D 10")],
                                     title="Fig. 12")
    (ax,) = fig.axes
    assert _labels(ax) == ("Fig. 12", "omega (rad/s)", "corrected phase of Z (deg)")
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["torque loop", "P 200, D 10"]
    _saved(fig, tmp_path)


def test_plot_steps(params, tmp_path):
    s = step_response(ClosedLoop(params.with_values(K_L2=0.0)), duration=0.05)
    fig = plots.plot_steps([("free leg", [(s, "alpha = 0.94", "-")]), ("contact", [(s, "same", "--")])],
                           title="Fig. 7")
    assert [ax.get_title() for ax in fig.axes] == ["free leg", "contact"]
    assert all(ax.get_ylabel() == "T_l (Nm)" for ax in fig.axes) and fig.axes[-1].get_xlabel() == "t (s)"
    assert fig._suptitle.get_text() == "Fig. 7"
    _saved(fig, tmp_path)


def test_plot_contact(tmp_path):
    K = np.geomspace(1.0, 1e5, 40)
    rho = 1 + 0.1 * np.sin(np.log(K))
    fig = plots.plot_contact(K, rho, paper_range=(72, 3500), unstable=[(70.0, 3400.0)])
    (ax,) = fig.axes
    assert ax.get_ylabel() == "spectral radius (-)" and ax.get_xlabel() == "environment stiffness K_L2 (Nm/rad)"
    _saved(fig, tmp_path)
    excess = np.where(rho < 1, -0.5, np.nan)
    fig = plots.plot_contact(K, rho, unstable=[(70.0, 3400.0)], key="K_C", excess=excess,
                             not_passive=[(1.0, 70.0)], tol=0.01)
    top, bottom = fig.axes
    assert top.get_ylabel() == "spectral radius (-)" and bottom.get_ylabel() == "phase excess of Z (deg)"
    assert bottom.get_xlabel() == "environment stiffness K_C (Nm/rad)" and bottom.get_yscale() == "symlog"
    _saved(fig, tmp_path, "excess.png")


def test_plot_torque_bandwidth(tmp_path):
    B, A = np.array([0.5, 1.0, 3.0]), np.array([0.0, 0.5, 0.94])
    bw = 20.0 * B[:, None] * (1 + A[None, :])
    fig = plots.plot_torque_bandwidth([("free leg", B, A, bw, bw < 60)], title="torque bandwidth")
    ax = fig.axes[0]
    assert _labels(ax) == ("free leg", "beta, torque-gain scale (-)", "alpha, velocity compensation (-)")
    assert fig.axes[1].get_ylabel() == "torque bandwidth (rad/s, log scale)"          # the colour bar
    fig.canvas.draw()
    ticks = [t.get_text() for t in fig.axes[1].get_yticklabels() if t.get_text()]
    assert ticks and all(re.fullmatch(r"[0-9.]+", t) for t in ticks)                # bandwidths, not log10
    # the unstable cells are hatched and the legend says so, and nothing else (the colour bar says
    # dark is low bandwidth)
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert texts == ["torque loop unstable (bandwidth meaningless)"]
    assert any(list(getattr(c, "hatches", None) or []) == ["xxx"] for c in ax.collections)
    assert fig._suptitle.get_text() == "torque bandwidth"
    _saved(fig, tmp_path)


def test_torque_bandwidth_no_overlapping_labels_no_legend_for_what_is_not_drawn(tmp_path):
    """Issue 26, item 16: torque_bandwidth.png had its contour labels piled on each other where
    the contours bunch (the stability cliff) and a legend entry "torque loop stable everywhere"
    (a red patch drawn nowhere) with "dark"/"bright" swatches repeating the colour bar. Now the
    contours are marked on the colour bar (no text on the map) and a panel without unstable
    cells says so in its title; no legend."""
    B, A = np.linspace(0.1, 8, 25), np.linspace(0, 1.2, 13)
    # a cliff: the bandwidth jumps from 2 to 300 rad/s across a line, every contour level on it
    bw = np.where(B[:, None] + 4 * A[None, :] > 5, 300.0, 2.0) * (1 + 0.1 * A[None, :])
    fig = plots.plot_torque_bandwidth([("extended leg", B, A, bw, np.ones_like(bw, bool)),
                                       ("retracted leg", B, A, bw, np.ones_like(bw, bool))], title="t")
    panels = [ax for ax in fig.axes if ax.get_xlabel().startswith("beta")]
    assert [ax.get_title() for ax in panels] == ["extended leg (torque loop stable in every cell)",
                                                 "retracted leg (torque loop stable in every cell)"]
    assert not fig.legends
    for ax in panels:
        assert not ax.texts                                  # no contour labels to overlap
        assert not any("xxx" in (getattr(c, "hatches", None) or []) for c in ax.collections)
    bars = [ax for ax in fig.axes if ax.get_ylabel() == "torque bandwidth (rad/s, log scale)"]
    assert len(bars) == 2 and all(len(b.collections) + len(b.lines) > 1 for b in bars)   # the contour levels
    _saved(fig, tmp_path)


def test_contact_titled_with_its_gains(tmp_path, monkeypatch):
    """Issue 26, item 16: contact.png did not say at which gains the environment was scanned."""
    assert plots.gains_text(200, 10, 1.0, 0.94) == "P_gain = 200 Nm/rad, D_gain = 10 Nms/rad, beta = 1, alpha = 0.94"
    assert plots.gains_text(0, 0, 2.0).startswith("torque loop alone (P_gain = 0 Nm/rad, D_gain = 0 Nms/rad")
    titles = []
    save = plots.save_figure

    def keep(fig, *a, **k):
        titles.append(fig._suptitle.get_text() if fig._suptitle else "")
        return save(fig, *a, **k)
    monkeypatch.setattr(plots, "save_figure", keep)
    assert main(["contact", "--P-gain", "200", "--D-gain", "10", "--set", "beta=2", "--n-scan", "12",
                 "--plot", str(tmp_path / "contact.png"), "-q"]) == 0
    (title,) = titles
    assert title.splitlines()[-1] == "gains: P_gain = 200 Nm/rad, D_gain = 10 Nms/rad, beta = 2, alpha = 0.94"


def test_plot_schedule(tmp_path):
    feasible = np.ones((8, 6), bool)
    feasible[-2:, :2] = False
    beta = np.where(feasible, 1.0 + np.arange(8)[:, None] * 0.1 + np.zeros(6), np.nan)
    s = SimpleNamespace(P_gain=P, D_gain=D, feasible=feasible, beta=beta, beta_fixed_feasible=feasible & (beta < 1.5),
                        torque_bandwidth_rad_s=30 * beta, meta={"torque_bandwidth_beta_1_rad_s": 30.0})
    s.beta[0, 0] = 8.0                       # a log colour bar spanning 1..8: plain tick labels
    fig = plots.plot_schedule(s, title="schedule")
    left, right = fig.axes[:2]
    assert _labels(left) == ("largest robust beta", "P_gain (Nm/rad)", "D_gain (Nms/rad)")
    assert _labels(right) == ("bandwidth gained by the schedule", "P_gain (Nm/rad)", "D_gain (Nms/rad)")
    assert "beta = 1 unsafe for some leg" in [t.get_text() for t in right.get_legend().get_texts()]
    assert fig._suptitle.get_text() == "schedule"
    # one colour for "no robust beta": the same drawn colour at an infeasible cell of both panels
    # (the data layers above are masked there), and the same in both legends
    cell = 0 * P.size + (P.size - 1)                         # D index 0, P index -1 (C order of .T)
    shown = []
    for ax in (left, right):
        base, data = [c for c in ax.collections if isinstance(c, QuadMesh)][:2]
        base.update_scalarmappable()
        assert np.ma.getmaskarray(data.get_array()).ravel()[cell]
        shown.append(to_hex(base.get_facecolor()[cell]))
        (patch,) = [h for h in ax.get_legend().legend_handles if h.get_label() == "no robust beta in the range"]
        shown.append(to_hex(patch.get_facecolor()))
    assert shown == [plots.INFEASIBLE_COLOR] * 4
    fig.canvas.draw()
    ticks = [t.get_text() for cb in fig.axes[2:] for t in cb.get_yticklabels(which="both") if t.get_text()]
    assert ticks and not any("times" in t or "^" in t for t in ticks)                  # no 8x10^0
    _saved(fig, tmp_path)


def test_plot_robust(tmp_path):
    r = SimpleNamespace(P_gain=P, D_gain=D, feasible=np.arange(48).reshape(8, 6) % 3 > 0, n_configurations=5,
                        meta={"leg": ["retracted", "extended"], "requirements": ["stable", "pm"], "leg_mode": "segment"})
    fig = plots.plot_robust(r)
    (ax,) = fig.axes
    title, xl, yl = _labels(ax)
    assert title.startswith("stable+pm for every leg configuration\nretracted..extended (segment, 5 configurations")
    assert (xl, yl) == ("P_gain (Nm/rad)", "D_gain (Nms/rad)")
    _saved(fig, tmp_path)


# --- the CLI's figures: titled with the actuator and what differs from its file ---------------

@pytest.fixture
def drawn(monkeypatch):
    """The figures the CLI saves (checked for units, then saved as usual): their titles."""
    seen = []
    save = plots.save_figure

    def capture(fig, path, *args, **kwargs):
        _check_units(fig)
        seen.append({"title": "\n".join([fig._suptitle.get_text() if fig._suptitle else ""]
                                        + [ax.get_title() for ax in fig.axes]),
                     "ylabels": [ax.get_ylabel() for ax in fig.axes], "legends": [
                         t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]})
        return save(fig, path, *args, **kwargs)
    monkeypatch.setattr(plots, "save_figure", capture)
    return seen


SMALL = ["--P-gain", "lin:1:200:3", "--D-gain", "lin:1:5:2"]
CLI_PLOTS = {
    "regions": (["regions", *SMALL, "--set", "beta=2"], "HyQ HAA joint", "beta = 2"),
    "boundary": (["boundary", "--params", "sea", *SMALL, "--set", "N_av=10", "--option", "delay=1"],
                 "WALK-MAN big series elastic actuator", "N_av = 10; option delay = 1"),
    "contact": (["contact", "--K-range", "10:10000", "--n-scan", "20", "--set", "K_hd=9000"],
                "HyQ HAA joint", "K_hd = 9000 Nm/rad"),
    "step": (["step", "--duration", "0.05", "--set", "K_L2=0"], "HyQ HAA joint", "K_L2 = 0 Nm/rad"),
    "passivity": (["passivity", "--P-gain", "200", "--D-gain", "10", "--set", "Ts=0.002"], "HyQ HAA joint",
                  "Ts = 0.002 s"),
}


@pytest.mark.parametrize("cmd", sorted(CLI_PLOTS))
def test_cli_plot_title_names_actuator_and_set_values(cmd, drawn, tmp_path, capsys):
    argv, name, differs = CLI_PLOTS[cmd]
    assert main(["--quiet", *argv, "--plot", str(tmp_path / "f.png")]) == 0
    (fig,) = drawn
    assert name in fig["title"] and differs in fig["title"], fig["title"]


def test_cli_user_title_goes_above_the_automatic_one(drawn, tmp_path, capsys):
    assert main(["--quiet", "regions", *SMALL, "--set", "alpha=0.5", "--title", "my run",
                 "--plot", str(tmp_path / "f.png")]) == 0
    assert drawn[0]["title"].startswith("\nmy run\nHyQ HAA joint\nalpha = 0.5")        # no suptitle: ""


def test_cli_schedule_plot_title(drawn, tmp_path, capsys):
    assert main(["--quiet", "schedule", "--set", "beta=2", "--P-gain", "10,100", "--D-gain", "5,10",
                 "--beta-range", "0.5:2", "--beta-tol", "0.25", "--plot", str(tmp_path / "s.png")]) == 0
    assert drawn[0]["title"].startswith("HyQ HAA joint\nbeta = 2\n")


def test_cli_step_axis_names_the_measured_torque(drawn, tmp_path, capsys):
    assert main(["--quiet", "step", "--duration", "0.05", "--plot", str(tmp_path / "s.png")]) == 0
    assert drawn[0]["ylabels"] == ["sensed torque T_hd (Nm)"]
    assert drawn[0]["legends"] == ["T_hd: torque sensor on coupling hd (spring and damper)"]


@pytest.mark.parametrize("name, label", [("hyq_haa", "sensed torque T_hd (Nm)"), ("sea", "sensed torque T_bar (Nm)"),
                                         ("qdd_leg", "torque estimate k_t N I_m (Nm)")])
def test_measured_torque_follows_the_sensors_table(name, label):
    assert measured_torque(load_params(actuator_path(name, "--params")).plant.topology)[0] == label


def test_figure_title_says_what_differs(params):
    assert differences({"a": 1, "b": 2, "c": 3}, {"a": 1, "b": 5}) == {"b": 2, "c": 3}
    loop = ClosedLoop(params.with_values(J_L2=0.2, N_av=10), LoopOptions(delay=1, pm_rule="min_abs"))
    assert figure_title(loop, params) == ("HyQ HAA joint\nJ_L2 = 0.2 kg m^2, N_av = 10; "
                                          "options delay = 1, pm_rule = min_abs")
    # the file's own options (port, torque_damping resolved from [sensors]) are not differences
    assert figure_title(ClosedLoop(params, LoopOptions(port="dtheta_L2")), params, "retracted") == \
        "HyQ HAA joint, retracted configuration\nthe file's values, default options"


def test_range_edge_drawn_and_named_as_what_it_is(region):
    """A passivity set bounded by the edge of the judged frequency range (kinds "passivity
    (omega_min)", "passivity (Nyquist)" of analysis.boundaries.passivity) was drawn and named as
    the |phase Z| = 90 deg boundary (issue 26, item 9): now its own line style and name, in every
    figure that draws curves; a kind without a point to draw gets no legend entry."""
    b = _boundary()
    edge = SimpleNamespace(P_gain=np.geomspace(2.0, 100.0, 10), D_gain=np.linspace(0.5, 6, 10),
                           kind="passivity (omega_min)")
    empty = SimpleNamespace(P_gain=np.array([]), D_gain=np.array([]), kind="passivity (Nyquist)")
    b.curves += [edge, empty]
    tangency = "passivity boundary (|phase Z| = 90 deg)"
    named = "edge of the judged frequency range (omega_min)"
    fig = plots.plot_boundary(b)
    (ax,) = fig.axes
    by_label = {ln.get_label(): ln for ln in ax.lines}
    assert named in by_label and tangency in by_label
    assert "edge of the judged frequency range (Nyquist)" not in by_label and len(ax.lines) == 6
    assert by_label[named].get_linestyle() != by_label[tangency].get_linestyle()
    np.testing.assert_array_equal(by_label[named].get_xdata(), edge.P_gain)
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend.count(tangency) == 1 and named in legend and not any("Nyquist" in t for t in legend)
    plt.close(fig)
    for fig in (plots.plot_region(region, boundary=b),
                plots.plot_region_panels([region, region], ["a", "b"], boundaries=[b, b]),
                plots.plot_nonlinear_region(region, P, D, np.full((P.size, D.size), "converging"), boundary=b)):
        texts = [t.get_text() for t in fig.legends[0].get_texts()]
        assert texts.count(named) == 1 and texts.count(tangency) == 1 and not any("Nyquist" in t for t in texts)
        plt.close(fig)
