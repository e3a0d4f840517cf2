"""The explorer's view state (haa_sym.explore.state): the page validates exactly as the CLI does
(the same one-line messages), the query string reproduces the state, and what the page shows is
the library's result, checked against an independent computation (the reference closed loop's
eigenvalues)."""
import numpy as np
import pytest

from haa_sym.analysis.margins import margins
from haa_sym.analysis.regions import region_map
from haa_sym.check import reference
from haa_sym.errors import ParameterError
from haa_sym.explore.state import (ViewState, categories, compute_view, from_query, point_detail, resolve,
                                   to_query, view_summary)

SMALL = ViewState(P_gain="log:1:20000:40", D_gain="lin:1:50:20")


@pytest.mark.parametrize("state", [
    ViewState(),
    SMALL.with_set("beta", "2").with_set("velocity_filter", "lowpass1").with_set("f_c", "40")
    .with_option("delay", "1").replace(point="200,10", configuration="retracted"),
    ViewState(params="sea", blend_to="retracted", blend="0.25", schedule="a b&c=d.csv", measured="m.csv",
              robust="on").with_set("J_m", "5e-5"),
    ViewState(sets=(("J_L2", "nan"), ("Ts", "0")), P_gain="1,2,3", D_gain="  x y "),
])
def test_query_string_round_trip(state):
    q = to_query(state)
    assert from_query(q) == state
    assert from_query("?" + q) == state
    # a server hands the query as a mapping of lists of bytes
    from urllib.parse import parse_qs
    assert from_query({k: [v.encode() for v in vs] for k, vs in parse_qs(q, keep_blank_values=True).items()}) == state


def test_defaults_give_an_empty_query_and_overrides_replace():
    assert to_query(ViewState()) == ""
    s = ViewState().with_set("beta", "2").with_set("beta", "3")
    assert s.sets == (("beta", "3"),)
    assert s.with_set("beta", "").sets == ()


@pytest.mark.parametrize("query, match", [("nope=1", "query key 'nope': unknown"),
                                          ("set.beta=1&set.beta=2", "given twice")])
def test_bad_query_is_refused(query, match):
    with pytest.raises(ParameterError, match=match):
        from_query(query)


@pytest.mark.parametrize("state, argv", [
    (ViewState().with_set("J_L2", "nan"), ["--set", "J_L2=nan"]),
    (ViewState().with_set("J_L2", "-0.4"), ["--set", "J_L2=-0.4"]),
    (ViewState().with_set("Ts", "0"), ["--set", "Ts=0"]),
    (ViewState().with_set("velocity_filter", "lowpass1"), ["--set", "velocity_filter=lowpass1"]),
    (ViewState().with_set("N_av", "x"), ["--set", "N_av=x"]),
    (ViewState().with_option("delay", "2"), ["--option", "delay=2"]),
    (ViewState(configuration="sitting"), ["--configuration", "sitting"]),
    (ViewState(params="no_such_actuator"), ["--params", "no_such_actuator"]),
    (ViewState(P_gain="log:0:10:5"), ["--P-gain", "log:0:10:5"]),
    (ViewState(D_gain="-3"), ["--D-gain", "-3"]),
    # a huge grid: the memory budget refuses it before any work, with the map's own message
    (ViewState(P_gain="log:1:20000:100000", D_gain="lin:1:50:100000"),
     ["--P-gain", "log:1:20000:100000", "--D-gain", "lin:1:50:100000"]),
])
def test_refusals_are_the_clis_messages(state, argv, assert_refused):
    with pytest.raises(ParameterError) as page:
        resolve(state)
    line = assert_refused(["regions"] + argv, "")
    assert line.rstrip("\n") == f"haa-sym: error: {page.value}"


def test_page_limit_and_point_and_blend_are_checked():
    with pytest.raises(ParameterError, match="allowed: at most 1000000 on the page"):
        resolve(ViewState(P_gain="log:1:20000:2000", D_gain="lin:1:50:1000"))
    for point in ("1", "1,x", "-1,2", "nan,1"):
        with pytest.raises(ParameterError, match="point"):
            resolve(ViewState(point=point))
    for blend in ("1.5", "x", "nan"):
        with pytest.raises(ParameterError, match="blend = "):
            resolve(ViewState(blend_to="retracted", blend=blend))
    with pytest.raises(ParameterError, match="blend_to = 'sitting'"):
        resolve(ViewState(blend_to="sitting"))


def test_blend_interpolates_between_the_configurations():
    r = resolve(ViewState(configuration="retracted", blend_to="extended", blend="0.25"))
    ret, ext = (resolve(ViewState(configuration=c)).params.plant for c in ("retracted", "extended"))
    for key in ("J_L2", "K_L2"):
        a, b = getattr(ret, key), getattr(ext, key)
        assert getattr(r.params.plant, key) == pytest.approx(a + 0.25 * (b - a), rel=1e-12)
    assert resolve(ViewState(configuration="retracted", blend_to="extended", blend="1")).params.plant == ext


def test_compute_view_is_region_map_and_matches_eigenvalues():
    s = SMALL.with_set("beta", "2")
    v = compute_view(s)
    r = resolve(s)
    m = region_map(r.loop, r.P_gain, r.D_gain)
    for name in ("stable", "low_pm", "passive"):
        np.testing.assert_array_equal(getattr(v, name), getattr(m, name))
    assert r.params.controller.beta == 2.0
    # independent: the reference closed loop's eigenvalues, points off the unit circle
    PP, DD = np.meshgrid(r.P_gain, r.D_gain, indexing="ij")
    rho = np.abs(reference.closed_loop_eigenvalues(r.loop, np.stack([PP.ravel(), DD.ravel(),
                                                                     np.full(PP.size, 2.0),
                                                                     np.full(PP.size, r.params.controller.alpha)]))
                 ).max(axis=1).reshape(PP.shape)
    far = np.abs(rho - 1) > 1e-6
    assert far.sum() > 0.9 * far.size and v.stable.any() and (~v.stable).any()
    np.testing.assert_array_equal(v.stable[far], rho[far] < 1)
    # the exposed categories decode to the decisions
    cat = np.array([int(c) for c in view_summary(v)["category"]]).reshape(v.stable.shape)
    np.testing.assert_array_equal(cat == 4, ~v.stable)
    np.testing.assert_array_equal(np.isin(cat, (2, 3)), v.low_pm)
    np.testing.assert_array_equal(np.isin(cat, (0, 2)), v.passive & v.stable)
    assert {c["family"] for c in v.curves} >= {"stability", "pm"}
    np.testing.assert_array_equal(categories([True, True, False], [False, True, False], [True, False, True]),
                                  [0, 3, 4])


def test_point_detail_against_the_reference():
    s = ViewState().with_set("beta", "3")
    r = resolve(s)
    d = point_detail(s, 300.0, 5.0)
    ref = np.sort_complex(reference.closed_loop_eigenvalues(
        r.loop, np.array([[300.0], [5.0], [3.0], [r.params.controller.alpha]]))[0])
    np.testing.assert_allclose(np.sort_complex(d.poles), ref, atol=1e-9)
    assert d.stable == bool(np.abs(ref).max() < 1)
    assert d.spectral_radius == pytest.approx(np.abs(ref).max(), rel=1e-9)
    m = margins(r.loop, 300.0, 5.0, which="L_imp")
    np.testing.assert_allclose(d.margins["impedance"]["phase_margins_deg"], m.phase_margins_deg)
    # the impedance step: the closed loop from the reference's matrices, simulated here
    A, B, C, D = reference.closed_loop_matrices(r.loop, 300.0, 5.0)
    x, theta = np.zeros(A.shape[0]), []
    for _ in range(d.impedance_step["t_s"].size):
        theta.append(C[1] @ x + D[1, 0])
        x = A @ x + B[:, 0]
    np.testing.assert_allclose(d.impedance_step["theta_rad"], theta, rtol=1e-7, atol=1e-12)
    dc = C[1] @ np.linalg.solve(np.eye(A.shape[0]) - A, B[:, 0]) + D[1, 0]
    assert d.impedance_step["final_value_rad_per_Nm"] == pytest.approx(dc, rel=1e-8)
    js = d.to_dict()
    assert js["P_gain"] == 300.0 and len(js["poles"]) == d.poles.size


def test_overlays(tmp_path):
    from haa_sym.design.schedule import CSV_COLUMNS
    sched = tmp_path / "schedule.csv"
    sched.write_text(",".join(CSV_COLUMNS) + "\n10,5,2.5,0.94,100,true,false\n20,5,,,,false,false\n")
    meas = tmp_path / "measured.csv"
    meas.write_text("P_gain,D_gain,outcome\n200,10,stable\n19000,1,unstable\n")
    s = ViewState(P_gain="log:1:20000:12", D_gain="lin:1:50:6", schedule=str(sched), measured=str(meas))
    v = compute_view(s)
    sc, me = v.overlays["schedule"], v.overlays["measured"]
    np.testing.assert_array_equal(sc["feasible"], [True, False])
    assert sc["beta"][0] == 2.5 and np.isnan(sc["beta"][1])
    assert me["outcome"] == ["stable", "unstable"]
    # the model's prediction at the measured points: the reference's eigenvalues
    loop = resolve(s).loop
    rho = np.abs(reference.closed_loop_eigenvalues(loop, np.array([[200.0, 19000.0], [10.0, 1.0], [1.0, 1.0],
                                                                   [loop.params.controller.alpha] * 2]))).max(axis=1)
    np.testing.assert_array_equal(me["predicted_stable"], rho < 1)
    bad = tmp_path / "bad.csv"
    bad.write_text("P_gain,D_gain,outcome\n1,x,stable\n")
    with pytest.raises(ParameterError, match="row 2: D_gain = 'x' is not a number"):
        compute_view(s.replace(measured=str(bad), robust="", schedule=""))
    with pytest.raises(ParameterError, match="missing column"):
        compute_view(s.replace(schedule=str(meas), robust="", measured=""))
    with pytest.raises(ParameterError, match="robust = 'x'"):
        compute_view(s.replace(robust="x", schedule="", measured=""))


def test_robust_overlay():
    s = ViewState(P_gain="log:1:20000:12", D_gain="lin:1:50:6", robust="retracted:extended")
    rb = compute_view(s).overlays["robust"]
    # feasible only where both ends of the leg range are stable with PM >= 30 deg
    for end in ("retracted", "extended"):
        e = compute_view(s.replace(configuration=end, robust=""))
        assert not (rb["feasible"] & ~(e.stable & ~e.low_pm)).any()
    assert rb["feasible"].any() and rb["leg"] == ["retracted", "extended"]
