"""Stability boundaries by the parameter-space method (issue 9, first step): every returned point
is on the unit circle by the eigenvalues of the independent closed loop, and a grid classified
from the curves equals the certified point-by-point decision."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym import reference as ref
from haa_sym.boundary import classify_grid, crossings, stability_boundary
from haa_sym.regions import grid

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
    return request.param, loop, stability_boundary(p, loop=loop)


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
    assert data["boundary"] == "stability" and data["beta"] == 1.0 and data["curves"]
    c = data["curves"][0]
    assert len(c["P_gain"]) == len(c["D_gain"]) == len(c["omega"]) > 10
    assert plot.stat().st_size > 1000
    assert "curve(s)" in capsys.readouterr().out


def test_cli_boundary_refuses_a_bad_output_and_writes_nothing(tmp_path, capsys):
    from haa_sym.cli import main
    assert main(["boundary", "--out", str(tmp_path / "b.csv")]) == 2
    assert "--out" in capsys.readouterr().err and not list(tmp_path.iterdir())


def test_phase_margin_curves_are_crossovers_with_exactly_that_margin(params):
    from haa_sym.boundary import phase_margin_curves
    loop = ClosedLoop(params)
    curves = phase_margin_curves(params, loop=loop)
    assert curves
    for c in curves:
        idx = np.linspace(0, c.P_gain.size - 1, 12).astype(int)
        for i in idx:
            L = ref.frequency_response(loop, c.omega[i:i + 1], c.P_gain[i], c.D_gain[i])["L_imp"][0]
            assert abs(abs(L) - 1) < 1e-9 and abs(180 + np.degrees(np.angle(L)) - 30) < 1e-6


@pytest.mark.parametrize("changes", [{}, {"alpha": 0.0}, {"beta": 6.0}, {"N_av": 50}, {"Ts": 1e-4}])
def test_regions_classified_from_the_curves_equal_the_map(params, changes):
    from haa_sym.boundary import classify_regions
    from haa_sym.regions import region_map
    p = params.with_values(**changes)
    loop = ClosedLoop(p)
    P, D = grid("log:1:20000:90"), grid("lin:1:50:60")
    stable, low_pm = classify_regions(loop, stability_boundary(p, loop=loop), P, D)
    m = region_map(p, P, D, loop=loop, passivity=False, progress=False)
    assert (stable != m.stable).sum() == 0 and (low_pm != m.low_pm).sum() == 0
    assert m.low_pm.any() or changes == {"Ts": 1e-4}
