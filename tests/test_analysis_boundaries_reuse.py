"""What the explorer reuses and loosens, checked against the computation it replaces:

* ``region_map(boundary=...)`` with the stability boundary the page also draws gives the map
  computed without it, and a boundary of other gains is refused;
* ``boundaries(stability=...)`` takes that boundary as it is (the same curves), and refuses one
  of another box;
* the passivity boundary located to ``xtol`` 1e-6 (the page's drawing) has the same points as
  the exact 1e-10 ones to ~1e-9, each still on the boundary by the corrected phase of Z
  computed point by point (:func:`haa_sym.analysis.passivity.corrected_phase`);
* the crossing brackets found from the sorted rows are the pairs of the dense test.
"""
import numpy as np
import pytest

from haa_sym import ClosedLoop, grid, region_map
from haa_sym.analysis.boundaries import boundaries, stability_boundary
from haa_sym.analysis.boundaries.passivity import ON_BOUNDARY_DEG, passivity_boundary
from haa_sym.analysis.boundaries.stability import _brackets
from haa_sym.analysis.passivity import corrected_phase
from haa_sym.errors import ParameterError

P_AXIS, D_AXIS = grid("log:1:20000:60"), grid("lin:1:50:40")
BOX = {"P_range": (1.0, 2e4), "D_range": (1.0, 50.0)}


@pytest.fixture(scope="module")
def loop(params):
    return ClosedLoop(params.with_values(beta=2.0))


def test_region_map_with_the_drawn_boundary_is_the_same_map(loop):
    st = stability_boundary(loop, **BOX)
    a = region_map(loop, P_AXIS, D_AXIS, progress=False, boundary=st)
    b = region_map(loop, P_AXIS, D_AXIS, progress=False)
    for name in ("stable", "low_pm", "passive", "phase_margin_deg", "phase_excess_deg"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.stable.any() and (~a.stable).any() and a.passive.any()


def test_region_map_refuses_a_boundary_of_other_gains(loop):
    other = stability_boundary(loop, 3.0, **BOX)
    with pytest.raises(ParameterError, match=r"boundary of beta = 3.*allowed: the map's beta = 2"):
        region_map(loop, P_AXIS, D_AXIS, progress=False, boundary=other)
    with pytest.raises(ParameterError, match="StabilityBoundary"):
        region_map(loop, P_AXIS, D_AXIS, progress=False, boundary=[])


def test_boundaries_take_the_given_stability_boundary(loop):
    st = stability_boundary(loop, **BOX)
    a = boundaries(loop, **BOX, n_lines=11, stability=st)
    b = boundaries(loop, **BOX, n_lines=11)
    assert a.stability is st
    assert [c.kind for c in a.curves] == [c.kind for c in b.curves]
    for x, y in zip(a.curves, b.curves):
        np.testing.assert_array_equal(x.P_gain, y.P_gain)
        np.testing.assert_array_equal(x.D_gain, y.D_gain)
    with pytest.raises(ParameterError, match="stability: a boundary of"):
        boundaries(loop, P_range=(1.0, 1e4), D_range=(1.0, 50.0), stability=st)


def test_drawn_passivity_boundary_is_on_the_boundary(loop):
    exact = passivity_boundary(loop, **BOX, n_lines=21)
    drawn = passivity_boundary(loop, **BOX, n_lines=21, xtol=1e-6)
    assert exact and [c.kind for c in drawn] == [c.kind for c in exact]
    for c, e in zip(drawn, exact):
        assert c.P_gain.size == e.P_gain.size
        np.testing.assert_allclose(c.P_gain, e.P_gain, rtol=1e-7)
        np.testing.assert_allclose(c.D_gain, e.D_gain, rtol=1e-7, atol=1e-9)
    P = np.concatenate([c.P_gain for c in drawn])
    D = np.concatenate([c.D_gain for c in drawn])
    w = np.concatenate([c.omega for c in drawn])
    tangent = np.concatenate([[c.kind == "passivity"] * c.P_gain.size for c in drawn])
    # on the options' grid no frequency puts the phase beyond +-90 deg ...
    _, ph = corrected_phase(loop, P, D)
    assert (np.abs(ph).max(axis=1) - 90.0 <= ON_BOUNDARY_DEG).all()
    # ... and at its own frequency a tangency point's phase is +-90 deg
    for k in np.flatnonzero(tangent)[::7]:
        _, ph_k = corrected_phase(loop, P[k], D[k], omega=[w[k]])
        assert abs(abs(float(ph_k.ravel()[0])) - 90.0) < 1e-6


def test_xtol_is_checked(loop):
    for bad in (0.0, -1e-6, 0.1, True, "1e-6"):
        with pytest.raises(ParameterError, match="xtol"):
            passivity_boundary(loop, **BOX, n_lines=5, xtol=bad)


def test_brackets_are_the_dense_tests_pairs():
    rng = np.random.default_rng(7)
    n_nu = 400
    D = np.cumsum(rng.normal(size=n_nu))
    D[rng.integers(0, n_nu, 12)] = np.nan                  # singular solves
    det = np.sign(rng.normal(size=n_nu) + 2.5)             # a few poles of D(nu)
    Pn = rng.uniform(-10, 10, n_nu)
    d = np.concatenate([rng.uniform(np.nanmin(D), np.nanmax(D), 50), D[[3, 50, 51]]])   # ties with samples
    for P_range in (None, (-2.0, 3.0)):
        f = D[None, :] - d[:, None]
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(f[:, :-1]) & np.isfinite(f[:, 1:]) & (np.sign(f[:, :-1]) * np.sign(f[:, 1:]) <= 0)
            ok &= (np.sign(det[:-1]) * np.sign(det[1:]) > 0)[None, :]
            if P_range is not None:
                lo, hi = np.fmin(Pn[:-1], Pn[1:]), np.fmax(Pn[:-1], Pn[1:])
                ok &= (np.isfinite(lo) & (hi >= P_range[0]) & (lo <= P_range[1]))[None, :]
        rows, i = np.nonzero(ok)
        got = _brackets(Pn, D, det, d, P_range)
        assert rows.size > 50
        np.testing.assert_array_equal(got[0], rows)
        np.testing.assert_array_equal(got[1], i)
