"""haa_sym.io.plots.plot_identify, review of issue 17: the measured (H1) phase is drawn wherever
the coherence is >= 0.5, also after a low-coherence gap (np.unwrap over the NaN mask had made
every later point NaN, so the figure silently lost the measured phase)."""
from types import SimpleNamespace

import matplotlib
import numpy as np

matplotlib.use("Agg")

from haa_sym.io.plots import plot_identify  # noqa: E402


def test_h1_phase_drawn_after_a_low_coherence_gap():
    w = np.logspace(0, 3, 200)
    s = 1j * w
    model = 100 / (s * (s / 300 + 1) ** 3)            # phase from -90 to about -330 deg
    coherence = np.where(w < 3, 0.3, 0.95)             # low at the start, as in a real log
    H1 = model * np.exp(1j * np.radians(5.0))          # the measurement 5 deg ahead of the model
    t = np.arange(100) * 1e-3
    y = np.zeros((100, 1))
    result = SimpleNamespace(
        outputs=("theta",), inputs=("voltage",), rms_initial={"theta": 1.0}, rms_fitted={"theta": 0.1},
        traces=[{"name": "x.csv", "t": t, "u": y, "measured": y, "initial": y, "fitted": y}],
        bode=[{"name": "x.csv", "omega": w, "H1": [H1], "coherence": [coherence], "initial": [model],
               "fitted": [model]}])
    fig = plot_identify(result)
    phase_axis = fig.axes[2]
    h1_line = next(ln for ln in phase_axis.get_lines() if ln.get_label().startswith("H1"))
    fitted_line = next(ln for ln in phase_axis.get_lines() if ln.get_label() == "model, fitted")
    shown = np.isfinite(h1_line.get_ydata())
    assert np.array_equal(shown, coherence >= 0.5)
    # the independent reference: the model's own phase, unwrapped without gaps, plus 5 deg
    expected = np.degrees(np.unwrap(np.angle(model))) + 5.0
    assert np.allclose(h1_line.get_ydata()[shown], expected[shown], atol=1e-9)
    assert np.allclose(fitted_line.get_ydata(), expected - 5.0, atol=1e-9)
