"""haa_sym.io.plots.plot_schedule, review of issue 17: the panels' legends do not cover the
grid's markers (in the upper-left corner they hid the whole top row of the red triangles of a
schedule whose robust gains lie at low P_gain, as `schedule --uncertainty` produced)."""
from types import SimpleNamespace

import matplotlib
import numpy as np

matplotlib.use("Agg")

from haa_sym.io.plots import plot_schedule  # noqa: E402


def test_legends_leave_every_marker_visible():
    P, D = np.geomspace(10, 3000, 8), np.linspace(1, 30, 4)
    PP, DD = np.meshgrid(P, D, indexing="ij")
    feasible = PP < 200 * (1 + DD / 10)              # the robust region: low P_gain, wider at high D_gain
    beta = np.where(feasible, 8.0, np.nan)
    s = SimpleNamespace(P_gain=P, D_gain=D, feasible=feasible, beta=beta, beta_at_limit=feasible,
                        torque_bandwidth_rad_s=np.where(feasible, 77.6, np.nan), beta_fixed_feasible=~feasible,
                        meta={"torque_bandwidth_beta_1_rad_s": 4.3})
    # six title lines, as the leg range and the uncertainty box write them: the panels get short
    fig = plot_schedule(s, title="\n".join(["a line of the title"] * 6))
    fig.canvas.draw()
    for ax in fig.axes[:2]:                  # the two panels (the colour bars come after)
        legend = ax.get_legend().get_window_extent()
        for line in ax.get_lines():
            xy = ax.transData.transform(np.column_stack([line.get_xdata(), line.get_ydata()]))
            covered = [legend.contains(x, y) for x, y in xy]
            assert not any(covered), (line.get_label(), int(np.sum(covered)))
    assert fig.axes[0].get_lines() and len(fig.axes[0].get_lines()[0].get_xdata()) == feasible.sum()
