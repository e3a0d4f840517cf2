"""haa_sym.analysis.torque: step responses with python-control's step_info metrics, the torque
bandwidth, and the zeros of the torque transfer function (p1 of Eq. 4)."""
import numpy as np
import pytest

from haa_sym import ClosedLoop
from haa_sym.cli import main
from haa_sym.analysis.torque import STEP_CONVENTION, step_info, step_response


# --- step metrics: the python-control step_info convention ----------------------------------------
@pytest.mark.parametrize("K_L2, alpha", [(0.0, 0.94), (11.2, 0.94), (11.2, 0.0)])
def test_step_metrics_match_python_control_step_info(params, K_L2, alpha):
    control = pytest.importorskip("control")
    # 3 s: long enough for these steps to settle, so every step_info number is defined
    s = step_response(ClosedLoop(params.with_values(K_L2=K_L2)), duration=3.0, alpha=alpha)
    ref = control.step_info(s.T, s.t, yfinal=s.final_value)
    ours = s.info
    assert np.isfinite(ours["SettlingTime"])
    for key, value in ref.items():
        assert ours[key] == pytest.approx(value, rel=1e-12, abs=1e-15), key


def test_step_info_with_the_last_sample_as_final_value_is_python_controls_default(params):
    control = pytest.importorskip("control")
    s = step_response(ClosedLoop(params.with_values(K_L2=0.0)), duration=0.3)
    ref = control.step_info(s.T, s.t)
    ours = step_info(s.t, s.T)
    for key, value in ref.items():
        assert ours[key] == pytest.approx(value, rel=1e-12, abs=1e-15), key


def test_unsettled_step_reports_nan_not_a_number(params):
    """Fig. 7's 0.3 s window: the free leg with alpha = 0.94 rises but has not settled within 2 %
    of its final value; with alpha = 0 it does not even reach 90 %."""
    p = params.with_values(K_L2=0.0)
    on = step_response(ClosedLoop(p), duration=0.3, alpha=0.94)
    off = step_response(ClosedLoop(p), duration=0.3, alpha=0.0)
    # the final value is where the step goes: the long response ends within 2 % of it
    assert abs(step_response(ClosedLoop(p), duration=3.0).T[-1] / on.final_value - 1) < 0.02
    assert np.isfinite(on.rise_time) and abs(on.T[-1] / on.final_value - 1) > 0.02
    assert np.isnan(on.settling_time) and np.isnan(on.overshoot_pct)
    assert off.T.max() < 0.9 * off.final_value and np.isnan(off.rise_time)


def test_step_cli_states_the_convention_and_never_a_negative_overshoot(capsys, params):
    assert main(["step", "--set", "K_L2=0"]) == 0
    out = capsys.readouterr().out
    s = step_response(ClosedLoop(params.with_values(K_L2=0.0)), duration=0.3)
    assert f"rise time (10-90 %) {s.rise_time * 1e3:.1f} ms" in out
    assert "settling time (2 %) not settled within 0.3 s" in out
    assert STEP_CONVENTION in out and "overshoot -" not in out


def test_torque_bandwidth_map_matches_the_pointwise_bandwidth(params):
    from haa_sym.analysis.torque import torque_bandwidth, torque_bandwidth_map
    p = params.with_values(K_L2=0.0)
    B, A = np.array([0.5, 1.0, 3.0]), np.array([0.0, 0.94])
    bw, stable = torque_bandwidth_map(ClosedLoop(p), B, A)
    assert stable.all()
    for i, b in enumerate(B):
        for j, a in enumerate(A):
            assert bw[i, j] == torque_bandwidth(ClosedLoop(p), beta=b, alpha=a)
    # more torque gain, more bandwidth (Sec. 3.3), with and without velocity compensation
    assert (np.diff(bw, axis=0) > 0).all()


def test_numeric_p1_roots_match_the_paper_polynomial(params):
    """haa_sym.analysis.torque.p1_roots (zeros of the generated plant, no sympy) against the roots of p1
    as printed in Eq. (4) (sympy, exact parameters), both legs, K_L2 = 0 and the configured K_L2."""
    import sympy as sp

    from haa_sym.symbolic import eom
    from haa_sym.symbolic import torque_tf as tt
    from haa_sym.analysis.torque import p1_roots
    syms = eom.plant_symbols()
    for cfg in sorted(params.configurations):
        for K in (0.0, params.configuration(cfg).plant.K_L2):
            pc = params.configuration(cfg).with_values(K_L2=K)
            sub = {syms[k]: sp.nsimplify(v, rational=True) for k, v in pc.plant.as_dict().items()}
            exact = np.sort_complex(np.array(
                [complex(z) for z in sp.Poly(tt.paper_polynomials(syms)["p1"].subs(sub), eom.s).nroots(n=30)]))
            num = p1_roots(pc)
            assert num.size == exact.size == 4
            np.testing.assert_allclose(num, exact, rtol=1e-6, atol=1e-9)


def test_describe_step_overshoot_undefined_only_when_none_to_define():
    """Issue 26, item 16: "overshoot undefined (not settled)" was printed for HyQ's step, whose
    torque had passed its final value by 3.1 % within the window: an unsettled response past its
    final value has an overshoot of at least that peak; "undefined" only below the final value."""
    from haa_sym.analysis.torque import StepResponse, describe_step
    t = np.linspace(0.0, 0.3, 301)
    rising_past = StepResponse(t, 1.08 * (1 - np.exp(-t / 0.03)))         # 1.08 at the end: not settled
    assert "overshoot at least 8.0 % (the peak within 0.3 s; not settled)" in describe_step(rising_past)
    below = StepResponse(t, 0.5 * (1 - np.exp(-t / 0.03)))
    assert "overshoot undefined (below the final value until 0.3 s; not settled)" in describe_step(below)
    settled = StepResponse(t, 1 - np.exp(-t / 0.01) * np.cos(t / 0.01))
    line = describe_step(settled)
    assert "overshoot " in line and "undefined" not in line and "at least" not in line
