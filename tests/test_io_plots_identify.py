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
    (phase_axis,) = [ax for ax in fig.axes if ax.get_ylabel() == "phase (deg)"]
    h1_line = next(ln for ln in phase_axis.get_lines() if ln.get_label().startswith("H1"))
    fitted_line = next(ln for ln in phase_axis.get_lines() if ln.get_label() == "model, fitted")
    shown = np.isfinite(h1_line.get_ydata())
    assert np.array_equal(shown, coherence >= 0.5)
    # the independent reference: the model's own phase, unwrapped without gaps, plus 5 deg
    expected = np.degrees(np.unwrap(np.angle(model))) + 5.0
    assert np.allclose(h1_line.get_ydata()[shown], expected[shown], atol=1e-9)
    assert np.allclose(fitted_line.get_ydata(), expected - 5.0, atol=1e-9)


def test_time_panels_whole_log_and_a_readable_zoom():
    """Issue 26, item 16: fit.png's time panel showed the last 2 s of a broadband log (a solid
    band of 250 oscillations). Now a row with the whole log and a row zoomed on its last
    ZOOM_CROSSINGS crossings of the mean, every sample drawn there; one legend below."""
    from haa_sym.io.plots import ZOOM_CROSSINGS
    t = np.arange(6000) * 1e-3
    y = np.sin(2 * np.pi * 60 * t)[:, None]             # 120 mean crossings a second
    w = np.logspace(0, 3, 50)
    result = SimpleNamespace(
        outputs=("torque",), inputs=("voltage",), rms_initial={"torque": 1.0}, rms_fitted={"torque": 0.1},
        traces=[{"name": "x.csv", "t": t, "u": y, "measured": y, "initial": 1.1 * y, "fitted": y}],
        bode=[{"name": "x.csv", "omega": w, "H1": [1 / (1j * w)], "coherence": [np.ones_like(w)],
               "initial": [1 / (1j * w)], "fitted": [1 / (1j * w)]}])
    fig = plot_identify(result)
    whole, zoom = fig.axes[0], fig.axes[1]
    assert whole.get_xlim() == (0.0, t[-1]) and whole.get_xlabel() == "t (s), the whole log"
    lo, hi = zoom.get_xlim()
    assert hi == t[-1]
    # ZOOM_CROSSINGS crossings of a 60 Hz sine: ZOOM_CROSSINGS / 120 s, to a sample
    assert abs((hi - lo) - ZOOM_CROSSINGS / 120) <= 1.5e-3
    zoomed = next(ln for ln in zoom.get_lines() if ln.get_label() == "measured")
    assert np.array_equal(zoomed.get_xdata(), t[t >= lo])               # every sample of the window
    assert not any(ax.get_legend() for ax in fig.axes)
    labels = [x.get_text() for x in fig.legends[0].get_texts()]
    assert labels == ["measured; Bode: H1 (Welch) where the coherence >= 0.5", "model, initial", "model, fitted",
                      "the zoomed window"]


def test_validation_rows_measured_against_fitted_with_nrmse_and_vaf():
    """Issue 23, item 5: a row per data set not fitted (held-out part, --validate log), zoomed as
    the fit data's second row, measured against the fitted model, titled with NRMSE and VAF; the
    fitted log's own NRMSE and VAF in its title. No row for a fitted log."""
    t = np.arange(3000) * 1e-3
    y = np.sin(2 * np.pi * 60 * t)[:, None]
    result = SimpleNamespace(
        outputs=("torque",), inputs=("voltage",), rms_initial={"torque": 1.0}, rms_fitted={"torque": 0.1},
        traces=[{"name": "x.csv", "t": t, "u": y, "measured": y, "initial": 1.1 * y, "fitted": y}], bode=[])
    tv = 3 + t[:1000]
    yv = np.sin(2 * np.pi * 60 * tv)[:, None]
    traces = [{"name": "x.csv", "t": t, "measured": y, "fitted": y},
              {"name": "x.csv:holdout", "t": tv, "measured": yv, "fitted": 0.9 * yv}]
    quality = {"x.csv": {"torque": {"nrmse": 0.01, "vaf_percent": 99.99, "samples": 3000}},
               "x.csv:holdout": {"torque": {"nrmse": 0.1, "vaf_percent": 99.0, "samples": 1000}}}
    fig = plot_identify(result, validation=(traces, quality))
    assert len(fig.axes) == 3
    assert "fit data NRMSE 0.01, VAF 99.99 %" in fig.axes[0].get_title()
    val = fig.axes[2]
    assert val.get_title() == "validation x.csv:holdout: torque, NRMSE 0.1, VAF 99 %"
    fitted = next(ln for ln in val.get_lines() if ln.get_label() == "model, fitted")
    lo, hi = val.get_xlim()
    assert hi == tv[-1] and lo > tv[0]
    assert np.allclose(fitted.get_ydata(), 0.9 * yv[tv >= lo, 0])
