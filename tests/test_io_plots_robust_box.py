"""The robust map's title with an uncertainty box (review of issue 17): like the leg range, the box
replaces the file's own values of its keys, and the figure says which (the stderr line did, the
figure alone did not); measured points agree when SOME configuration predicts them, and the
legend says so."""
import matplotlib.pyplot as plt
import numpy as np

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.robust import robust_region
from haa_sym.io import plots


def test_the_title_names_the_values_the_box_replaces():
    p = load_params().with_values(R=3.0)
    r = robust_region(ClosedLoop(p), np.array([10.0, 100.0]), np.array([5.0, 20.0]), beta=1.0,
                      requirements=("stable",), uncertainty={"R": (2.3, 4.3)})
    fig = plots.plot_robust(r)
    try:
        title = fig.axes[0].get_title().replace("\n", " ")
        assert "uncertainty box R 2.3..4.3 (instead of R 3)" in title
    finally:
        plt.close(fig)


def test_the_legend_says_agreement_is_at_some_configuration():
    loop = ClosedLoop(load_params().with_values(beta=3.0))
    P, D = np.geomspace(10, 5000, 6), np.linspace(1, 50, 4)
    r = robust_region(loop, P, D, max_per_axis=2, requirements=("stable",))
    drawn = {"P_gain": np.array([100.0, 3000.0]), "D_gain": np.array([20.0, 3.0]),
             "outcome": np.array(["stable", "unstable"]), "agrees": np.array([True, False]),
             "configurations": r.n_configurations}
    fig = plots.plot_robust(r, measured=drawn)
    try:
        labels = {t.get_text() for t in fig.legends[0].get_texts()}
        assert {"agrees with the model at some configuration (marker colour)",
                "disagrees with the model at every configuration (marker colour)"} <= labels
    finally:
        plt.close(fig)
    # one configuration: the plain words
    fig = plots.plot_robust(r, measured={**drawn, "configurations": 1})
    try:
        assert "agrees with the model (marker colour)" in {t.get_text() for t in fig.legends[0].get_texts()}
    finally:
        plt.close(fig)
