"""haa_sym.io.plots: every plot function draws a figure whose title and axis labels say what is
drawn, and save_figure writes it (a PNG here) and closes it. Small data, so this stays fast:
a real region map and step response on coarse grids, plain stand-ins for the slower results."""
from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pytest

from haa_sym import ClosedLoop, region_map
from haa_sym.analysis.torque import step_response
from haa_sym.io import plots

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


def _saved(fig, tmp_path, name="fig.png"):
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
    assert ax.get_ylabel() == "spectral radius" and ax.get_xlabel() == "environment stiffness K_L2 (Nm/rad)"
    _saved(fig, tmp_path)
    excess = np.where(rho < 1, -0.5, np.nan)
    fig = plots.plot_contact(K, rho, unstable=[(70.0, 3400.0)], key="K_C", excess=excess,
                             not_passive=[(1.0, 70.0)], tol=0.01)
    top, bottom = fig.axes
    assert top.get_ylabel() == "spectral radius" and bottom.get_ylabel() == "phase excess of Z (deg)"
    assert bottom.get_xlabel() == "environment stiffness K_C (Nm/rad)" and bottom.get_yscale() == "symlog"
    _saved(fig, tmp_path, "excess.png")


def test_plot_torque_bandwidth(tmp_path):
    B, A = np.array([0.5, 1.0, 3.0]), np.array([0.0, 0.5, 0.94])
    bw = 20.0 * B[:, None] * (1 + A[None, :])
    fig = plots.plot_torque_bandwidth([("free leg", B, A, bw, bw < 60)], title="torque bandwidth")
    ax = fig.axes[0]
    assert _labels(ax) == ("free leg (dark: torque loop unstable)", "beta", "alpha")
    assert fig.axes[1].get_ylabel() == "log10 torque bandwidth (rad/s)"          # the colour bar
    assert fig._suptitle.get_text() == "torque bandwidth"
    _saved(fig, tmp_path)


def test_plot_schedule(tmp_path):
    feasible = np.ones((8, 6), bool)
    feasible[-2:, :2] = False
    beta = np.where(feasible, 1.0 + np.arange(8)[:, None] * 0.1 + np.zeros(6), np.nan)
    s = SimpleNamespace(P_gain=P, D_gain=D, feasible=feasible, beta=beta, beta_fixed_feasible=feasible & (beta < 1.5),
                        torque_bandwidth_rad_s=30 * beta, meta={"torque_bandwidth_beta_1_rad_s": 30.0})
    fig = plots.plot_schedule(s, title="schedule")
    left, right = fig.axes[:2]
    assert _labels(left) == ("largest robust beta (grey: none)", "P_gain (Nm/rad)", "D_gain (Nms/rad)")
    assert _labels(right) == ("bandwidth gained by the schedule", "P_gain (Nm/rad)", "D_gain (Nms/rad)")
    assert "beta = 1 unsafe for some leg" in [t.get_text() for t in right.get_legend().get_texts()]
    assert fig._suptitle.get_text() == "schedule"
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
