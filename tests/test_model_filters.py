"""The velocity estimate as a choice (issue 8): "average", "lowpass1", "butterworth2".

Each controller element is defined once (haa_sym.model.elements); the characteristic polynomial, the
frequency responses and the explicit state space (haa_sym.loop.statespace) all derive from it. The
reference (haa_sym.check.reference) builds the loop independently: scipy's bilinear map of the analog
prototype, tf2ss realisations and a block interconnection. More than 1,000 random gain points
per new filter, over sampling times, cut-offs, filter placements, delays and both legs.

The filters are a registry (haa_sym.model.filters); a toy filter registered at test time is validated,
listed and built like the built-in ones, and its loops agree with the explicit closed loop.
"""
import dataclasses
import itertools
import re

import numpy as np
import pytest
import scipy.signal

from haa_sym import ClosedLoop, LoopOptions, ParameterError, load_params
from haa_sym.model import filters
from haa_sym.check import reference as ref
from haa_sym.loop import statespace
from haa_sym.cli import main
from haa_sym.model.elements import backward_difference, delay, pi_integral
from haa_sym.model.filters import velocity_filter

from conftest import ROOT, decisions_against_reference

TSS = (20e-6, 100e-6, 1e-3, 4e-3)
CUTOFFS = (0.02, 0.1, 0.3)          # f_c as a fraction of the sampling frequency 1/Ts
PLACEMENTS = ("both", "impedance", "compensation")
POINTS = 12   # per case: 4 Ts x 3 f_c x 3 placements x 2 delays x 2 legs x 12 = 1,728 per filter


def _points(rng, n):
    return np.stack([10 ** rng.uniform(0, np.log10(50000), n), rng.uniform(0, 60, n),
                     rng.uniform(0.3, 8, n), rng.uniform(0, 1.2, n)])


@pytest.fixture(scope="module", params=("lowpass1", "butterworth2"))
def cases(request, params):
    rng = np.random.default_rng(11)
    out = []
    for Ts, frac, place, d, cfg in itertools.product(TSS, CUTOFFS, PLACEMENTS, (0, 1), ("extended", "retracted")):
        p = params.configuration(cfg).with_values(Ts=Ts, velocity_filter=request.param, f_c=frac / Ts)
        loop = ClosedLoop(p, LoopOptions(delay=d, filter=place, port="encoder_average" if d else "dtheta_L2"))
        pts = _points(rng, POINTS)
        out.append((loop, pts, ref.closed_loop_eigenvalues(loop, pts)))
    return request.param, out


def test_decisions_agree_with_the_independent_closed_loop(cases):
    kind, cases = cases
    bad, decided, unstable, refined, wrong_count = [], 0, 0, 0, 0
    for loop, pts, eig in cases:
        c = decisions_against_reference(loop, pts, 1e-6, eig=eig)     # certified (as the maps use it) and raw
        decided += c["decided"]
        unstable += c["unstable"]
        refined += c["refined"]
        bad += [(loop.params.controller.Ts, loop.params.controller.f_c, loop.options.filter, pts[:, i], c["rho"][i])
                for i in c["bad"]]
        wrong_count += c["count_disagree"]
    assert not bad, (kind, bad[:5])
    assert wrong_count == 0, (kind, wrong_count)
    assert decided >= 1000 and decided > 0.98 * len(cases) * POINTS
    assert 0.05 * decided < unstable < 0.95 * decided      # both answers occur
    assert refined < 0.02 * decided


def test_library_state_space_has_the_reference_spectrum(cases):
    _, cases = cases
    for loop, pts, eig in cases[::7]:
        mine = np.abs(statespace.closed_loop_eigenvalues(loop, pts)).max(axis=1)
        np.testing.assert_allclose(mine, np.abs(eig).max(axis=1), rtol=0, atol=1e-9)


def test_frequency_responses_agree_with_the_reference(cases):
    _, cases = cases
    worst = 0.0
    for loop, pts, _ in cases[::5]:
        Ts = loop.params.controller.Ts
        w = np.logspace(-1, np.log10(np.pi / Ts * 0.99), 40)
        fr = loop.frequency_response(w, *pts[:, :2])
        for j in range(2):
            r = ref.frequency_response(loop, w, *pts[:, j])
            for k in r:
                # Tustin puts the low-pass filters' zeros at z = -1: near Nyquist some responses
                # fall 10-12 orders below their low-frequency size, where every evaluation (the
                # reference's and the library state space's too) keeps only an absolute accuracy
                # relative to that size; so the error is measured against |ref| + 1e-6 max |ref|.
                scale = np.abs(r[k]) + 1e-6 * np.abs(r[k]).max()
                worst = max(worst, float(np.max(np.abs(fr[k][j] - r[k]) / scale)))
    assert worst < 1e-7, worst


@pytest.mark.parametrize("element", [
    velocity_filter("average", 1e-3, N_av=7), velocity_filter("lowpass1", 1e-4, f_c=300.0),
    velocity_filter("butterworth2", 1e-3, f_c=80.0), backward_difference(2e-4), pi_integral(1e-3),
    delay(2)])
def test_every_view_of_an_element_is_the_same_transfer_function(element):
    Ts = 1e-3
    w = np.logspace(-1, np.log10(np.pi / Ts * 0.999), 50)
    num = [float(c) for c in element.numerator]
    den = [float(c) for c in element.denominator]
    num = [0.0] * (len(den) - len(num)) + num                   # freqz: powers of z^-1
    _, h = scipy.signal.freqz(num, den, worN=w * Ts)
    A, B, C, D = element.realization()
    z = np.exp(1j * w * Ts)
    hs = np.array([(C @ np.linalg.solve(zz * np.eye(A.shape[0]) - A, B) + D)[0, 0] if A.size else D[0, 0]
                   for zz in z])
    np.testing.assert_allclose(element.frequency_response(w, Ts), h, rtol=1e-9)
    np.testing.assert_allclose(hs, h, rtol=1e-9)


def test_lowpass_filters_follow_their_analog_prototype_at_low_frequency():
    Ts, f_c = 1e-5, 100.0
    w_c, w = 2 * np.pi * f_c, np.array([0.1, 10.0, 600.0])
    s = 1j * w
    for kind, analog in (("lowpass1", w_c / (s + w_c)),
                         ("butterworth2", w_c ** 2 / (s ** 2 + np.sqrt(2) * w_c * s + w_c ** 2))):
        F = velocity_filter(kind, Ts, f_c=f_c).frequency_response(w, Ts)
        # backward difference and Tustin differ from s and the prototype by O(w Ts)
        np.testing.assert_allclose(F / (s * analog), 1, atol=5 * w.max() * Ts)


def test_to_statespace_names_its_signals_and_has_the_closed_loop_poles(params):
    control = pytest.importorskip("control")
    loop = ClosedLoop(params.with_values(velocity_filter="butterworth2", f_c=60.0))
    sys = loop.to_statespace(300.0, 12.0, cut="T_ref")
    assert isinstance(sys, control.StateSpace) and sys.dt == params.controller.Ts
    assert sys.input_labels == ["T_dist", "r"]
    assert sys.output_labels == ["T_meas", "theta_encoder", "port_velocity", "y"]
    closed = loop.to_statespace(300.0, 12.0)
    rho = np.abs(control.poles(closed)).max()
    assert np.isclose(rho, ref.spectral_radius(loop, 300.0, 12.0), rtol=0, atol=1e-10)


def test_cli_runs_a_map_with_a_lowpass_velocity_estimate(tmp_path):
    out = tmp_path / "m.npz"
    assert main(["regions", "--P-gain", "log:1:5000:6", "--D-gain", "lin:1:40:5", "--set",
                 "velocity_filter=butterworth2", "--set", "f_c=40", "--out", str(out), "-q"]) == 0
    with np.load(out, allow_pickle=False) as m:
        assert m["stable"].shape == (6, 5)


def test_cli_rejects_a_cutoff_above_nyquist(assert_refused):
    assert_refused(["stability", "--P-gain", "100", "--D-gain", "5", "--set", "velocity_filter=lowpass1",
                    "--set", "f_c=600"], "f_c = 600.0 is at or above Nyquist 1/(2 Ts) = 500 Hz; allowed: 0 < f_c < 500")


# --- the registry (haa_sym.model.filters): one entry per filter, everything else derives from it ----

def _toy_filters():
    """Two filters not built in: a fixed two-sample average, which reads no key (so N_av is
    not required), and an exponential smoothing of the backward difference, which reads f_c
    (so the Nyquist rule applies): each with its exact transfer function and, separately, the
    reference's own realisation."""
    from fractions import Fraction

    from haa_sym.model.elements import Element

    def average2(Ts):
        return Element("average2", (Fraction(1), Fraction(0), Fraction(-1)),
                       (2 * Fraction(float(Ts)), Fraction(0), Fraction(0)))

    def ema1(Ts, f_c):
        a = Fraction(float(np.exp(-2 * np.pi * f_c * Ts)))
        return backward_difference(Ts) * Element("ema1", (1 - a, Fraction(0)), (Fraction(1), -a))

    def ref_average2(ctrl):                   # FIR in powers of z^-1, as the reference's average
        return [ref._tf_block(np.array([1.0, 0.0, -1.0]) / (2 * ctrl.Ts), [1.0, 0.0, 0.0])]

    def ref_ema1(ctrl):                       # difference equation v[k] = a v[k-1] + (1 - a) d[k]
        a = np.exp(-2 * np.pi * ctrl.f_c * ctrl.Ts)
        return [ref._tf_block([1 / ctrl.Ts, -1 / ctrl.Ts], [1.0]),
                (np.array([[a]]), np.array([[1.0]]), np.array([[a * (1 - a)]]), np.array([[1 - a]]))]

    return [(filters.VelocityFilter("average2", "the average of two first differences",
                                    "(1 - z^-2)/(2 Ts)", (), average2), ref_average2),
            (filters.VelocityFilter("ema1", "backward difference and exponential smoothing",
                                    "(1 - z^-1)/Ts * (1 - a)/(1 - a z^-1), a = exp(-2 pi f_c Ts)",
                                    (filters.F_C,), ema1), ref_ema1)]


@pytest.fixture
def toys():
    """The toy filters registered in both tables for one test, removed afterwards."""
    added = []
    try:
        for entry, realise in _toy_filters():
            filters.register(entry)
            ref.register_velocity_estimate(entry.name, realise)
            added.append(entry.name)
        yield added
    finally:
        for name in added:
            filters.unregister(name)
            ref.VELOCITY_ESTIMATES.pop(name, None)


BUILT_IN = ["average", "lowpass1", "butterworth2"]


def test_the_reference_realises_exactly_the_registered_filters():
    # the reference keeps its own table (its algebra stays independent of the registry's)
    assert filters.names() == tuple(BUILT_IN)
    assert set(ref.VELOCITY_ESTIMATES) == set(filters.names())


def test_filter_keys_are_controller_fields_with_the_registry_domains():
    from haa_sym.model.params import _CONTROLLER_DOMAIN, Controller
    fields = {f.name for f in dataclasses.fields(Controller)}
    assert set(filters.PARAMETERS) <= fields
    for name, p in filters.PARAMETERS.items():
        assert _CONTROLLER_DOMAIN[name] == p.domain


def test_docs_list_the_registered_filters():
    model = (ROOT / "docs" / "model.md").read_text()
    assert filters.markdown_rows() in model          # the element table is the registry's rows
    controller_row = next(line for line in model.splitlines() if line.startswith("| `[controller]`"))
    guide = (ROOT / "docs" / "python.md").read_text()      # "Actuators are data" (the README's before issue 26)
    for name in filters.names():
        assert f'"{name}"' in controller_row and f'"{name}"' in guide, name


def test_register_refuses_a_taken_name_and_an_unknown_key():
    with pytest.raises(ValueError, match="'average' is already registered"):
        filters.register(filters.get("average"))
    tau = filters.FilterParameter("tau", ">0", "s", "time constant")
    with pytest.raises(ValueError, match=r"parameter 'tau' is not one of haa_sym.model.filters.PARAMETERS "
                                         r"\['N_av', 'f_c'\] \(a new key needs .* haa_sym.model.params.Controller\)"):
        filters.register(filters.VelocityFilter("lag", "", "", (tau,), lambda Ts, tau: None))
    assert filters.names() == tuple(BUILT_IN)


def test_unknown_names_list_the_registry(params, toys, tmp_path, assert_refused):
    allowed = f"allowed: one of {BUILT_IN + toys}"
    with pytest.raises(ParameterError, match=re.escape(f"velocity_filter = 'median'; {allowed}")):
        params.with_values(velocity_filter="median")
    with pytest.raises(ParameterError, match=re.escape(f"velocity_filter = 'median'; {allowed}")):
        filters.velocity_filter("median", 1e-3)
    toml = (ROOT / "model" / "hyq_haa.toml").read_text()
    line = next(x for x in toml.splitlines() if x.startswith("Ts "))
    f = tmp_path / "p.toml"
    f.write_text(toml.replace(line, line + '\nvelocity_filter = "median"', 1))
    with pytest.raises(ParameterError, match=re.escape(f"[controller]: velocity_filter = 'median'; {allowed}")):
        load_params(f)
    assert_refused(["stability", "--P-gain", "100", "--D-gain", "5", "--set", "velocity_filter=median"], allowed)


def test_a_registered_filter_is_validated_like_the_built_in_ones(params, toys, capsys):
    # average2 reads no key: N_av may be absent; ema1 reads f_c, with the cut-off's Nyquist rule
    ctrl = dataclasses.replace(params.controller, velocity_filter="average2", N_av=None)
    assert ctrl.velocity_filter == "average2" and ctrl.N_av is None
    with pytest.raises(ParameterError, match=re.escape("N_av is missing; allowed: an integer >= 1, required "
                                                       "by velocity_filter = 'average'")):
        ctrl.replace(velocity_filter="average")
    with pytest.raises(ParameterError, match=re.escape("f_c is missing; allowed: a cut-off frequency in Hz, "
                                                       "0 < f_c < 500 (Nyquist), required by velocity_filter = 'ema1'")):
        params.with_values(velocity_filter="ema1")
    with pytest.raises(ParameterError, match=re.escape("f_c = 600.0 is at or above Nyquist 1/(2 Ts) = 500 Hz")):
        params.with_values(velocity_filter="ema1", f_c=600.0)
    assert params.with_values(velocity_filter="ema1", f_c=40.0).controller.f_c == 40.0
    # the command line: its help lists the filters, --set takes them
    with pytest.raises(SystemExit):
        main(["stability", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "average2, ema1 (f_c in Hz)" in help_text
    assert main(["stability", "--P-gain", "100", "--D-gain", "5", "--set", "velocity_filter=ema1",
                 "--set", "f_c=40"]) == 0


def test_a_registered_filter_builds_loops_that_agree_with_the_explicit_closed_loop(params, toys):
    rng = np.random.default_rng(5)
    n, disagree, unstable = 0, 0, 0
    for kind, Ts, place, d, cfg in itertools.product(toys, (100e-6, 1e-3), PLACEMENTS, (0, 1),
                                                     ("extended", "retracted")):
        extra = {"f_c": 0.1 / Ts} if kind == "ema1" else {}
        p = params.configuration(cfg).with_values(Ts=Ts, velocity_filter=kind, **extra)
        loop = ClosedLoop(p, LoopOptions(delay=d, filter=place, port="encoder_average" if d else "dtheta_L2"))
        pts = _points(rng, 25)
        eig = ref.closed_loop_eigenvalues(loop, pts)          # the reference's own realisation
        rho = np.abs(eig).max(axis=1)
        mine = np.abs(statespace.closed_loop_eigenvalues(loop, pts)).max(axis=1)   # the Element's
        np.testing.assert_allclose(mine, rho, rtol=0, atol=1e-9)
        away = np.abs(rho - 1) > 1e-6
        c = decisions_against_reference(loop, pts, 1e-6, eig=eig)
        disagree += c["disagree"]
        n += c["decided"]
        unstable += int((rho > 1)[away].sum())
        if kind == "average2":        # the same transfer function as the built-in average of 2
            same = ClosedLoop(p.with_values(velocity_filter="average", N_av=2), loop.options)
            np.testing.assert_array_equal(same.stability(*pts).stable, loop.stability(*pts).stable)
    assert disagree == 0 and n > 0.98 * len(toys) * 2 * 3 * 2 * 2 * 25
    assert 0.05 * n < unstable < 0.95 * n                    # both answers occur
