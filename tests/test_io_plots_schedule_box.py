"""The schedule with an uncertainty box (review of issue 17): where beta = 1 fails, the failing
configuration may be a value of the box, not a leg, and the figure's legend and the summary say so."""
import json
from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pytest

from haa_sym.cli import main
from haa_sym.io import plots


@pytest.mark.parametrize("meta,word", [({}, "leg"), ({"uncertainty": {"R": [2.3, 4.3]}}, "configuration")])
def test_beta_one_unsafe_names_what_fails(meta, word):
    P, D = np.geomspace(10, 1000, 4), np.linspace(1, 50, 3)
    feasible = np.ones((4, 3), bool)
    beta = 1.0 + np.arange(4)[:, None] * 0.5 + np.zeros(3)
    s = SimpleNamespace(P_gain=P, D_gain=D, feasible=feasible, beta=beta, beta_fixed_feasible=beta < 2.0,
                        torque_bandwidth_rad_s=30 * beta, meta={"torque_bandwidth_beta_1_rad_s": 30.0, **meta})
    fig = plots.plot_schedule(s)
    try:
        labels = [t.get_text() for t in fig.axes[1].get_legend().get_texts()]
        assert f"beta = 1 unsafe for some {word}" in labels
    finally:
        plt.close(fig)


def test_the_schedule_summary_says_configuration_with_a_box(tmp_path, capsys):
    # a degenerate box (lo = hi: a fixed value, no new axis) keeps this to the leg's 3 maps
    fit = {"parameters": {"R": {"value": 3.32, "initial": 3.0, "ci95": [3.32, 3.32]}},
           "rms_error": {}, "samples": 10, "sampling": {}, "meta": {}}
    (tmp_path / "fit.json").write_text(json.dumps(fit))
    argv = ["schedule", "--P-gain", "100,1000", "--D-gain", "10,30", "--beta-tol", "0.1", "--require", "stable", "-q"]
    assert main([*argv, "--uncertainty", str(tmp_path / "fit.json")]) == 0
    assert "beta = 1 fails for some configuration at" in capsys.readouterr().out
