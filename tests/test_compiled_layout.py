"""haa_sym.compiled.layout: the named vectors between code generation and runtime; the gain
monomials are Eq. (6)-(8)'s products, exactly (sympy symbols as the caller's arithmetic), and work
on numpy arrays of points."""
import numpy as np
import sympy as sp

from haa_sym import ClosedLoop
from haa_sym.compiled import layout


def test_names_and_sizes():
    assert layout.CONST == ("P_t0", "I_t0", "VC0") and layout.POINT == ("P_gain", "D_gain", "beta", "alpha")
    assert layout.N_BASIS == len(layout.GAIN_MONOMIALS) == 8
    assert [name for name, _ in layout.GAIN_MONOMIALS][5] == "P_t*D_gain-VC"     # one difference, rounded together
    assert len(set(layout.FREQ_COLUMN)) == len(layout.FREQ_COLUMN) == 10
    assert len(set(layout.COEF_OUTPUTS)) == len(layout.COEF_OUTPUTS) == 4 * 3 + 1
    assert layout.COEF_OUTPUTS[:3] == ("L_t.1", "L_t.P_gain", "L_t.D_gain") and layout.COEF_OUTPUTS[-1] == "H_T"


def test_gain_monomials_are_the_products_of_eq_6_to_8():
    P, D, beta, alpha, P_t0, I_t0, VC0 = sp.symbols("P D beta alpha P_t0 I_t0 VC0")
    P_t, I_t, VC = beta * P_t0, beta * I_t0, alpha * VC0
    assert layout.torque_gains(beta, alpha, (P_t0, I_t0, VC0)) == {"P_t": P_t, "I_t": I_t, "VC": VC}
    got = layout.gain_monomials((P, D, beta, alpha), (P_t0, I_t0, VC0), one=sp.Integer(1))
    want = [1, P_t, I_t, P_t * P, I_t * P, P_t * D - VC, I_t * D, -VC]
    assert [sp.expand(g - w) for g, w in zip(got, want)] == [0] * 8
    bounds = layout.gain_monomial_bounds((P, D, beta, alpha), (P_t0, I_t0, VC0), abs, one=sp.Integer(1))
    want_bounds = [1, abs(P_t), abs(I_t), abs(P_t) * abs(P), abs(I_t) * abs(P), abs(P_t) * abs(D) + abs(VC),
                   abs(I_t) * abs(D), abs(VC)]
    assert [sp.simplify(g - w) for g, w in zip(bounds, want_bounds)] == [0] * 8


def test_gain_monomials_on_arrays_of_points_bound_the_rounding():
    rng = np.random.default_rng(4)
    k = 50
    pts = np.stack([10 ** rng.uniform(0, 4.3, k), rng.uniform(0, 50, k), rng.uniform(0.3, 8, k), rng.uniform(0, 1.2, k)])
    const = np.array([0.382, 18.0, 0.31])
    g = np.array(layout.gain_monomials(pts, const, one=np.ones(k)))
    b = np.array(layout.gain_monomial_bounds(pts, const, np.abs, one=np.ones(k)))
    assert g.shape == b.shape == (8, k)
    assert (np.abs(g) <= b).all()
    # column by column, the scalar arithmetic gives the same numbers
    for i in (0, 17, 49):
        np.testing.assert_array_equal(g[:, i], layout.gain_monomials(pts[:, i], const))


def test_the_loop_reads_its_constants_in_the_layout_order(params):
    loop = ClosedLoop(params)
    c = params.controller
    np.testing.assert_array_equal(loop.const, [c.P_t0, c.I_t0, loop.plant.VC0])
    assert loop.basis.shape == (loop.capacity + 1, layout.N_BASIS)
