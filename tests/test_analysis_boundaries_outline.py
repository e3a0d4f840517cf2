"""The drawn 30 deg curves are the outline of the low-phase-margin region (the "distance" rule):
every kept point is a stable loop whose nearest crossover to -1 is exactly 30 deg away, checked
with the independent exact crossovers; the loci's other pieces are dropped."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params, region_map
from haa_sym.analysis.boundaries import phase_margin_curves
from haa_sym.check.reference_margins import closed_loop_spectral_radius, reference_crossovers

from conftest import ROOT


@pytest.mark.parametrize("path,beta", [(ROOT / "model" / "hyq_haa.toml", 1.0), (ROOT / "model" / "sea.toml", 3.0)],
                         ids=["hyq", "sea-3"])
def test_kept_points_bound_the_low_pm_region(path, beta):
    loop = ClosedLoop(load_params(path))
    outline = phase_margin_curves(loop, beta, P_range=(1.0, 2e4), D_range=(0.0, 50.0))
    loci = phase_margin_curves(loop, beta, P_range=(1.0, 2e4), D_range=(0.0, 50.0), outline=False)
    assert outline and {c.kind for c in outline} <= {"pm=+30", "pm=-30"}
    ref_loop = ClosedLoop(loop.params, loop.options, basis=False)
    for c in outline:
        idx = np.unique(np.linspace(0, c.P_gain.size - 1, 6).astype(int))
        rho = closed_loop_spectral_radius(ref_loop, c.P_gain[idx], c.D_gain[idx], beta)
        assert (rho < 1).all()
        for r, w in zip(reference_crossovers(ref_loop, c.P_gain[idx], c.D_gain[idx], beta), c.omega[idx]):
            assert r.distance_deg == pytest.approx(30.0, abs=1e-6)          # nothing nearer to -1
            assert np.min(np.abs(r.omega_c - w) / w) < 1e-6                 # the crossover drawn
    n_out = sum(c.P_gain.size for c in outline)
    n_all = sum(c.P_gain.size for c in loci)
    assert n_out <= n_all


def test_dropped_locus_points_are_inside_or_unstable(params):
    """On HyQ nominal some +-30 deg locus points lie in the unstable region or beside a crossover
    nearer to -1 (measured in the issue: 30 of 100): those are the points the outline drops."""
    loop = ClosedLoop(params)
    loci = phase_margin_curves(loop, P_range=(1.0, 2e4), D_range=(0.0, 50.0), outline=False)
    P = np.concatenate([c.P_gain for c in loci])
    D = np.concatenate([c.D_gain for c in loci])
    sel = np.unique(np.linspace(0, P.size - 1, 60).astype(int))
    ref_loop = ClosedLoop(params, basis=False)
    rho = closed_loop_spectral_radius(ref_loop, P[sel], D[sel])
    dist = np.array([r.distance_deg for r in reference_crossovers(ref_loop, P[sel], D[sel])])
    inside = (rho >= 1) | (dist < 30 - 1e-6)
    assert inside.any() and (~inside).any()
    outline = phase_margin_curves(loop, P_range=(1.0, 2e4), D_range=(0.0, 50.0))
    kept = {(p, d) for c in outline for p, d in zip(c.P_gain, c.D_gain)}
    for k in np.flatnonzero(inside):
        assert (P[sel][k], D[sel][k]) not in kept


@pytest.mark.parametrize("name,changes,beta", [
    ("hyq_haa", {"velocity_filter": "butterworth2", "f_c": 40.0}, 1.0),
    ("hyq_haa", {"velocity_filter": "lowpass1", "f_c": 60.0, "Ts": 1e-5}, 1.0),
    ("sea", {"P_t0": 0.01954, "I_t0": 0.01954}, 7.6), ("harmonic_drive", {}, 7.6),
    ("sea", {"Ts": 8e-3, "N_av": 1}, 1.0)],
    ids=["butterworth2", "lowpass1-Ts10us", "sea-7.6-first-PI", "hd-7.6", "sea-Ts8ms"])
def test_maps_from_the_curves_equal_the_grid_for_filters_and_light_modes(name, changes, beta):
    """The curves' maps and the point-by-point maps agree on every point for the other velocity
    filters, the fastest and slowest sampling, and the lightly damped modes of beta 7.6. The SEA
    keeps its first PI (P_t0 = I_t0 = 0.01954) there: with the tuned one beta 7.6 lies above its
    torque loop's stability limit (3.98, model/sea.toml's header) and 16 of this grid's 1,500
    points would be stable, against 949; the harmonic drive's tuned PI keeps 84 % stable."""
    loop = ClosedLoop(load_params(ROOT / "model" / f"{name}.toml").with_values(**changes))
    P, D = np.geomspace(1.0, 20000.0, 50), np.linspace(0.0, 50.0, 30)
    a = region_map(loop, P, D, beta=beta)
    b = region_map(loop, P, D, beta=beta, method="grid")
    for key in ("stable", "low_pm", "passive"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)
    known = np.isfinite(a.phase_margin_deg)                   # the points the curves decided one by one
    np.testing.assert_allclose(a.phase_margin_deg[known], b.phase_margin_deg[known], atol=1e-9)
