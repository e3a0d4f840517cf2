"""Stability boundaries by the parameter-space method (issue 9, first step): every returned point
is on the unit circle by the eigenvalues of the independent closed loop, and a grid classified
from the curves equals the certified point-by-point decision."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.check import reference as ref
from haa_sym.analysis.boundaries.classify import classify_grid
from haa_sym.analysis.boundaries.stability import crossings, stability_boundary
from haa_sym.io.gridspec import grid

from conftest import ROOT

CASES = {
    "nominal": lambda p: p,
    "N_av=50": lambda p: p.with_values(N_av=50),
    "Ts=10us": lambda p: p.with_values(Ts=1e-5),
    "butterworth2": lambda p: p.with_values(velocity_filter="butterworth2", f_c=30.0),
    "retracted beta=3": lambda p: p.configuration("retracted").with_values(beta=3.0),
}


@pytest.fixture(scope="module", params=list(CASES) + ["sea"])
def case(request, params):
    p = load_params(ROOT / "model" / "sea.toml") if request.param == "sea" else CASES[request.param](params)
    loop = ClosedLoop(p)
    return request.param, loop, stability_boundary(loop)


def test_every_boundary_point_has_a_pole_on_the_unit_circle(case):
    name, loop, b = case
    assert b.curves, name
    pts = np.concatenate([np.stack([c.P_gain, c.D_gain]) for c in b.curves], axis=1)
    pts = pts[:, np.linspace(0, pts.shape[1] - 1, min(300, pts.shape[1])).astype(int)]
    k = pts.shape[1]
    rho = np.abs(ref.closed_loop_eigenvalues(loop, np.vstack([pts, np.full(k, b.beta), np.full(k, b.alpha)]))).max(axis=1)
    assert np.abs(rho - 1).max() < 1e-9, (name, np.abs(rho - 1).max())


def test_grid_classified_from_the_curves_equals_the_pointwise_decision(case):
    name, loop, b = case
    P, D = grid("log:1:20000:120"), grid("lin:0:50:80")
    st = classify_grid(loop, b, P, D)
    PP, DD = np.meshgrid(P, D, indexing="ij")
    direct = loop.stability(PP, DD, b.beta, b.alpha).stable
    assert (st != direct).sum() == 0, name
    assert 0.02 < direct.mean() < 0.98 or name == "Ts=10us"     # a boundary crosses the map


def test_crossings_are_exact_to_rounding(case):
    name, loop, b = case
    d = np.array([5.0, 25.0, 45.0])
    for dj, cuts in zip(d, crossings(b, d)):
        for P in cuts[(cuts > 1) & (cuts < 2e4)]:
            # the decision changes within a relative 1e-9 of the crossing
            lo, hi = loop.stability([P * (1 - 1e-9), P * (1 + 1e-9)], [dj, dj], b.beta, b.alpha).stable
            assert lo != hi, (name, dj, P)


def test_cli_boundary_writes_json_and_plot(tmp_path, capsys):
    import json

    from haa_sym.cli import main
    out, plot = tmp_path / "b.json", tmp_path / "b.png"
    assert main(["boundary", "--set", "N_av=10", "--out", str(out), "--plot", str(plot), "-q"]) == 0
    data = json.loads(out.read_text())
    assert data["beta"] == 1.0 and data["pm_deg"] == 30.0
    for key in ("stability", "phase_margin", "passivity"):
        assert data[key], key
        assert all(len(c["P_gain"]) == len(c["D_gain"]) == len(c["omega"]) for c in data[key]), key
        assert max(len(c["P_gain"]) for c in data[key]) > 3, key
    assert {c["kind"] for c in data["passivity"]} <= {"passivity", "passivity (omega_min)", "passivity (Nyquist)"}
    assert plot.stat().st_size > 1000
    assert "passivity" in capsys.readouterr().out


def test_cli_boundary_refuses_a_bad_output_and_writes_nothing(tmp_path, assert_refused):
    assert_refused(["boundary", "--out", str(tmp_path / "b.csv")], "--out")
    assert not list(tmp_path.iterdir())


def test_phase_margin_curves_are_crossovers_with_exactly_that_margin(params):
    from haa_sym.analysis.boundaries.stability import phase_margin_curves
    loop = ClosedLoop(params)
    curves = phase_margin_curves(loop)
    assert curves
    for c in curves:
        idx = np.linspace(0, c.P_gain.size - 1, 12).astype(int)
        for i in idx:
            L = ref.frequency_response(loop, c.omega[i:i + 1], c.P_gain[i], c.D_gain[i])["L_imp"][0]
            assert abs(abs(L) - 1) < 1e-9 and abs(180 + np.degrees(np.angle(L)) - 30) < 1e-6


@pytest.mark.parametrize("changes", [{}, {"alpha": 0.0}, {"beta": 6.0}, {"N_av": 50}, {"Ts": 1e-4},
                                     {"Ts": 1e-5}, {"Ts": 8e-3, "N_av": 1}])
def test_regions_classified_from_the_curves_equal_the_map(params, changes):
    from haa_sym.analysis.boundaries.classify import classify_regions
    from haa_sym.analysis.regions import region_map
    p = params.with_values(**changes)
    loop = ClosedLoop(p)
    P, D = grid("log:1:20000:90"), grid("lin:1:50:60")
    r = classify_regions(loop, stability_boundary(loop), P, D)
    m = region_map(loop, P, D, progress=False, method="grid")
    assert (r.stable != m.stable).sum() == 0 and (r.low_pm != m.low_pm).sum() == 0
    assert (r.passive != m.passive).sum() == 0
    assert m.low_pm.any() or "Ts" in changes
    assert (m.stable & ~m.passive).any() and m.passive.any()


@pytest.mark.parametrize("name", ["sea", "harmonic_drive"])
def test_maps_of_the_other_actuators_from_the_curves_equal_the_grid(name):
    from haa_sym.analysis.regions import region_map
    p = load_params(ROOT / "model" / f"{name}.toml")
    loop = ClosedLoop(p)
    P, D = grid("log:1:20000:70"), grid("lin:0:50:40")
    a = region_map(loop, P, D, progress=False)
    b = region_map(loop, P, D, progress=False, method="grid")
    for key in ("stable", "low_pm", "passive"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=f"{name} {key}")
    assert 0 < b.stable.mean() < 1 and b.low_pm.any()


PASSIVITY_CASES = {**{k: v for k, v in CASES.items() if k != "N_av=50"},   # N_av = 50: in the map tests
                   "Ts=8ms": lambda p: p.with_values(Ts=8e-3, N_av=1)}


@pytest.fixture(scope="module", params=list(PASSIVITY_CASES) + ["harmonic_drive"])
def passivity_curves(request, params):
    from haa_sym.analysis.boundaries.passivity import passivity_boundary
    name = request.param
    p = load_params(ROOT / "model" / "harmonic_drive.toml") if name == "harmonic_drive" \
        else PASSIVITY_CASES[name](params)
    loop = ClosedLoop(p)
    c = p.controller
    return name, loop, passivity_boundary(loop, c.beta, c.alpha, P_range=(1.0, 2e4), D_range=(0.0, 50.0),
                                          n_lines=41)


def _corrected_phase(loop, omega, P, D):
    from haa_sym.analysis.sweep import colgate_factor
    c = loop.params.controller
    Z = ref.frequency_response(loop, omega, P, D, c.beta, c.alpha, which=("Z",))["Z"]
    return np.degrees(np.angle(Z * colgate_factor(omega, c.Ts, loop.options.conventions.colgate)))


def _spread(curves, per_curve, total):
    pts = [(c, i) for c in curves for i in np.unique(np.linspace(0, c.P_gain.size - 1, per_curve).astype(int))]
    return [pts[k] for k in np.unique(np.linspace(0, len(pts) - 1, min(total, len(pts))).astype(int))]


def test_every_passivity_point_has_a_corrected_phase_of_90_deg(passivity_curves):
    """By the state-space frequency response of the independent closed loop, at the point's own
    frequency (25 points spread over the curves); and no frequency of a dense grid puts a point's phase beyond 90 deg
    (a sample of points: the point is on the envelope, not inside the non-passive set)."""
    name, loop, curves = passivity_curves
    assert curves, name
    for c, i in _spread(curves, 10 ** 6, 25):
        ph = _corrected_phase(loop, c.omega[i:i + 1], c.P_gain[i], c.D_gain[i])[0]
        assert abs(abs(ph) - 90) < 1e-6, (name, c.kind, c.P_gain[i], c.D_gain[i], ph)
    Ts = loop.params.controller.Ts
    dense = np.geomspace(loop.options.numerics.omega_min, np.pi / Ts * (1 - 1e-9), 1500)
    for c, i in _spread(curves, 3, 8):
        worst = np.abs(_corrected_phase(loop, np.sort(np.append(dense, c.omega[i])), c.P_gain[i], c.D_gain[i])).max()
        assert worst - 90 < 1e-6, (name, c.kind, c.P_gain[i], c.D_gain[i], worst)


def test_passivity_curves_separate_passive_from_not_passive(passivity_curves):
    """Across a tangency point (kind "passivity") along its line, passivity changes: the phase
    near the point's frequency goes beyond 90 deg on one side only."""
    name, loop, curves = passivity_curves
    tangency = [c for c in curves if c.kind == "passivity"]
    assert tangency, name
    Ts = loop.params.controller.Ts
    for c, i in _spread(tangency, 2, 5):
        w = c.omega[i]
        band = np.geomspace(w / 1.2, min(w * 1.2, np.pi / Ts * (1 - 1e-9)), 401)
        # a step of 1e-4 in P_gain or in D_gain (whichever crosses the curve; a curve parallel
        # to one axis is not crossed by steps along it)
        P, D = c.P_gain[i], c.D_gain[i]
        ex = {(dP, dD): np.abs(_corrected_phase(loop, band, P * (1 + dP), D * (1 + dD))).max() - 90
              for dP, dD in ((-1e-4, 0), (1e-4, 0), (0, -1e-4), (0, 1e-4))}
        changes = [(ex[(-d, 0)] > 0) != (ex[(d, 0)] > 0) for d in (1e-4,)] + \
            [(ex[(0, -d)] > 0) != (ex[(0, d)] > 0) for d in (1e-4,)]
        assert any(changes), (name, P, D, ex)


def test_map_from_the_curves_on_unsorted_grids_equals_the_grid_method(params):
    from haa_sym.analysis.regions import region_map
    rng = np.random.default_rng(1)
    P, D = rng.permutation(grid("log:1:20000:50")), rng.permutation(grid("lin:1:50:30"))
    a = region_map(ClosedLoop(params), P, D, progress=False)
    b = region_map(ClosedLoop(params), P, D, progress=False, method="grid")
    assert a.meta["method"] == "curves" and b.meta["method"] == "grid"
    for key in ("stable", "low_pm", "passive"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)


def test_curves_reach_the_edge_of_the_box_and_small_boxes_are_drawn_finely(params):
    """A curve leaving the box ends on its edge (located by bisection), and a small box gets as
    many points as a large one (the runs are resampled)."""
    loop = ClosedLoop(params)
    b = stability_boundary(loop)
    ends = np.concatenate([[c.D_gain[0], c.D_gain[-1]] for c in b.curves if c.kind == "complex"])
    assert np.abs(ends).min() < 1e-6                     # the D_gain = 0 edge, to bisection accuracy
    small = stability_boundary(loop, P_range=(2000.0, 20000.0), D_range=(0.0, 2.0))
    pts = sum(c.P_gain.size for c in small.curves if c.kind == "complex")
    assert pts >= 200
    P = np.concatenate([c.P_gain for c in small.curves if c.kind == "complex"])
    D = np.concatenate([c.D_gain for c in small.curves if c.kind == "complex"])
    rho = np.abs(ref.closed_loop_eigenvalues(loop, np.vstack([P[::20], D[::20], np.full(P[::20].size, small.beta),
                                                              np.full(P[::20].size, small.alpha)]))).max(axis=1)
    assert np.abs(rho - 1).max() < 1e-9
