"""The describing-function figure (review of issue 19): every predicted cycle sits on the drawn
locus -1/N(A), and several cycles at one crossover (a quantiser) get one readable label."""
import matplotlib.pyplot as plt
import numpy as np

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.describing import limit_cycles
from haa_sym.analysis.sweep import blas_limits
from haa_sym.io import plots


def test_the_relay_locus_reaches_every_predicted_cycle():
    # docs/describing.md's friction case: the crossing is at G = -0.08, where -1/N = -pi A/(4 F)
    # lies for A = 0.01 rad/s; the locus used to stop at -0.39 (A from F/2 up), short of it
    F = 0.1
    loop = ClosedLoop(load_params().with_values(alpha=1.2, beta=3.0))
    with blas_limits(1):
        r = limit_cycles(loop, 5000.0, 0.0, nonlinearity={"Fc_L2": F})
    assert r.amplitude.size >= 1
    # the locus is -1/N of its amplitudes (N recomputed in closed form here: 4 F/(pi A))
    np.testing.assert_allclose(r.minus_inv_N, -np.pi * r.amplitude_curve / (4 * F), rtol=1e-12)
    for g in r.G_crossing:
        assert r.minus_inv_N.min() < g < r.minus_inv_N.max()


def _texts(ax):
    return [t.get_text() for t in ax.texts]


def test_several_cycles_at_one_crossover_share_one_label():
    G = np.exp(1j * np.linspace(0.1, 3.0, 50)) * -1.2
    pts = [(-1.02, A, 210.0, s) for A, s in ((0.055, True), (0.117, False), (0.155, True))]
    one = [(-2.0, 61.8, 40.4, True)]
    fig = plots.plot_describing([dict(label="T_res", G=G, minus_inv_N=-np.geomspace(0.8, 5, 50), unit="Nm", points=pts),
                                 dict(label="V_max", G=G, minus_inv_N=-np.geomspace(1, 5, 50), unit="V", points=one)])
    try:
        ax_q, ax_v = fig.axes[:2]
        (text,), = [_texts(ax_q)]
        assert "3 cycles" in text and "0.055 .. 0.155 Nm" in text and "2 stable, 1 unstable" in text
        markers = [ln for ln in ax_q.get_lines() if ln.get_marker() == "o"]
        assert len(markers) == 1 and markers[0].get_fillstyle() == "left"
        (text,), = [_texts(ax_v)]
        assert text.startswith("A = 61.8 V") and "stable" in text
        markers = [ln for ln in ax_v.get_lines() if ln.get_marker() == "o"]
        assert len(markers) == 1 and markers[0].get_fillstyle() == "full"
    finally:
        plt.close(fig)


def test_the_legend_says_what_the_markers_mean():
    G = np.exp(1j * np.linspace(0.1, 3.0, 50)) * -1.2
    fig = plots.plot_describing([dict(label="V_max", G=G, minus_inv_N=-np.geomspace(1, 5, 50), unit="V",
                                      points=[(-2.0, 61.8, 40.4, True)])])
    try:
        labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert {"-1 (N = 1)", "limit cycle, stable (Loeb)", "limit cycle, unstable (Loeb)", "-1/N(A)"} <= set(labels)
    finally:
        plt.close(fig)
