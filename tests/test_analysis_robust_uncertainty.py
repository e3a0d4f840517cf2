"""Robust regions over an identification's confidence box (issue 17.2): the box of the fitted
keys is sampled like the leg's box (n points per axis, doubling) and combined with the leg
range; the map is the intersection of independent per-configuration maps, shrinks as the box
widens, and agrees with explicit closed-loop eigenvalues sampled inside the box."""
from itertools import product

import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.regions import region_map
from haa_sym.analysis.robust import (check_uncertainty, leg_configurations, leg_values, robust_region,
                                     uncertainty_text)
from haa_sym.check import reference as ref
from haa_sym.errors import ParameterError

P = np.geomspace(5.0, 5000.0, 10)
D = np.linspace(1.0, 50.0, 6)
BETA = 3.0


def _box(params, rel: float, keys=("K_hd", "D_hd")) -> dict:
    """A relative box around the file's values of ``keys`` (what an identification reports)."""
    return {k: ((1 - rel) * getattr(params.plant, k), (1 + rel) * getattr(params.plant, k)) for k in keys}


def test_configurations_are_the_leg_times_the_box():
    p = load_params()
    box = _box(p, 0.1)
    c2 = leg_configurations(p, 2, uncertainty=box)
    assert len(c2) == 2 * 2 * 2
    corners = {(c["J_L2"], c["K_L2"], c["K_hd"], c["D_hd"]) for c in c2}
    assert corners == {(j, k, kh, dh) for (j, k) in ((0.129, 7.17), (0.439, 11.2))
                       for kh in box["K_hd"] for dh in box["D_hd"]}
    c3 = leg_configurations(p, 3, uncertainty=box)
    assert len(c3) == 27 and {tuple(sorted(c.items())) for c in c2} <= {tuple(sorted(c.items())) for c in c3}
    # a degenerate interval is a fixed value, not an axis
    fixed = leg_configurations(p, 3, uncertainty={"K_hd": (8000.0, 8000.0)})
    assert len(fixed) == 3 and all(c["K_hd"] == 8000.0 for c in fixed)


def test_robust_map_is_the_intersection_of_independent_maps():
    p = load_params()
    box = _box(p, 0.3, ("R", "K_hd"))         # the coil resistance matters on this grid, K_hd a little
    P, D = np.geomspace(5.0, 5000.0, 8), np.linspace(1.0, 50.0, 5)
    r = robust_region(ClosedLoop(p), P, D, beta=BETA, uncertainty=box)
    assert r.converged and r.meta["uncertainty"] == {k: list(v) for k, v in sorted(box.items())}
    assert r.meta["leg_values"]["uncertainty"] == r.meta["uncertainty"]
    # the configurations rebuilt here from the box and the leg's ends, each map on its own
    n = r.n_per_axis
    t = np.linspace(0.0, 1.0, n)
    expect = np.ones((P.size, D.size), bool)
    count = 0
    for s, u, v in product(t, t, t):
        c = {"J_L2": 0.129 + s * (0.439 - 0.129), "K_L2": 7.17 + s * (11.2 - 7.17),
             "R": box["R"][0] + u * (box["R"][1] - box["R"][0]),
             "K_hd": box["K_hd"][0] + v * (box["K_hd"][1] - box["K_hd"][0])}
        m = region_map(ClosedLoop(p.with_values(**c)), P, D, beta=BETA, passivity=False, progress=False)
        expect &= m.stable & ~m.low_pm
        count += 1
    assert count == r.n_configurations
    np.testing.assert_array_equal(r.feasible, expect)
    # the box matters here: the leg range alone admits more gains
    plain = robust_region(ClosedLoop(p), P, D, beta=BETA)
    assert not (r.feasible & ~plain.feasible).any() and r.feasible.sum() < plain.feasible.sum()


def test_a_wider_box_never_has_more_feasible_points():
    p = load_params()
    feasible = [robust_region(ClosedLoop(p), P, D, beta=BETA, uncertainty=_box(p, rel, ("R",))).feasible
                for rel in (0.1, 0.3, 0.5)]
    for narrow, wide in zip(feasible, feasible[1:]):
        assert not (wide & ~narrow).any()
    assert feasible[2].sum() < feasible[0].sum()


def test_agrees_with_eigenvalues_sampled_inside_the_box():
    """Brute force: the explicit closed loop (haa_sym.check.reference) at the box's corners, the
    leg's ends and middle, and random values inside; robust stability = stable at all of them."""
    p = load_params()
    box = _box(p, 0.5, ("R",))
    r = robust_region(ClosedLoop(p), P, D, beta=BETA, requirements=("stable",), uncertainty=box)
    plain = robust_region(ClosedLoop(p), P, D, beta=BETA, requirements=("stable",))
    assert r.feasible.sum() < plain.feasible.sum()            # the box changes the answer here
    rng = np.random.default_rng(17)
    samples = list(box["R"]) + [box["R"][0] + rng.random() * (box["R"][1] - box["R"][0]) for _ in range(3)]
    PP, DD = (x.ravel() for x in np.meshgrid(P, D, indexing="ij"))
    pts = np.stack([PP, DD, np.full(PP.size, BETA), np.full(PP.size, p.controller.alpha)])
    rho_max = np.zeros(PP.size)
    near = np.zeros(PP.size, bool)
    for leg in ("retracted", "extended", None):
        base = p.configuration(leg) if leg else p.with_values(J_L2=(0.129 + 0.439) / 2, K_L2=(7.17 + 11.2) / 2)
        for R in samples:
            loop = ClosedLoop(base.with_values(R=R))
            rho = np.abs(ref.closed_loop_eigenvalues(loop, pts)).max(axis=1)
            rho_max = np.maximum(rho_max, rho)
            near |= np.abs(rho - 1) < 1e-6
    brute = (rho_max < 1).reshape(P.size, D.size)
    decided = ~near.reshape(P.size, D.size)
    assert decided.sum() > 0.9 * decided.size
    assert brute.any() and (~brute).any()                   # the small grid crosses the boundary
    np.testing.assert_array_equal(r.feasible[decided], brute[decided])


def test_bad_uncertainty_is_one_line():
    p = load_params()
    cases = [({"K_xx": (1, 2)}, "uncertainty key 'K_xx' is not a plant key"),
             ({"K_L2": (7, 12)}, "uncertainty key 'K_L2' is set by the leg range retracted..extended"),
             ({"K_hd": (9000.0, 8000.0)}, "uncertainty K_hd = (9000, 8000); allowed: finite lo <= hi"),
             ({"K_hd": (-1.0, 8000.0)}, "K_hd = -1.0 is out of range"),
             ({"K_hd": "x"}, "allowed: two numbers (lo, hi)"),
             ({}, "allowed: a non-empty mapping")]
    for box, msg in cases:
        with pytest.raises(ParameterError) as e:
            check_uncertainty(p, box)
        assert msg in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(ParameterError, match="is not a plant key"):
        robust_region(ClosedLoop(p), P[:2], D[:2], uncertainty={"nope": (1, 2)})
    # with "nominal" as an end, the keys the other end sets are still the range's
    assert check_uncertainty(p, {"K_hd": (7000, 9000)}, ("nominal", "retracted")) == {"K_hd": (7000.0, 9000.0)}
    with pytest.raises(ParameterError, match="set by the leg range nominal..retracted"):
        check_uncertainty(p, {"J_L2": (0.1, 0.2)}, ("nominal", "retracted"))


def test_the_centre_is_the_fits_value_and_a_difference_is_said():
    p = load_params()
    box = {"K_hd": (7300.0, 8850.0)}
    line, warning = uncertainty_text(p, {"K_hd": 8077.0}, box)
    assert line == "uncertainty box K_hd 7300..8850; it replaces the parameters' own K_hd = 8077" and warning is None
    line, warning = uncertainty_text(p.with_values(K_hd=8000.0), {"K_hd": 8077.0}, box)
    assert warning.startswith("the parameters' own K_hd = 8000 (the fit's 8077) differ from the fit's values")
    lv = leg_values(p.with_values(K_hd=8000.0), uncertainty=box)
    assert lv["uncertainty"] == {"K_hd": [7300.0, 8850.0]} and lv["uncertainty_own"] == {"K_hd": 8000.0}
