"""haa_sym.loop.exact: exact Faddeev-LeVerrier (characteristic polynomial and adjugate), the
transfer polynomials, the polynomial helpers and the exact bilinear transform, against numpy on
small examples and against exact hand results."""
from fractions import Fraction

import numpy as np
import pytest

from haa_sym.loop.exact import bilinear, charpoly_adjugate, polymul, polysub, to_float, transfer_polynomials


def _dyadic(rng, n, scale=8):
    """A random n x n matrix of doubles with short dyadic expansions (k / 2**4): exact inputs."""
    return rng.integers(-4 * scale, 4 * scale, size=(n, n)) / 16.0


def _polyval(p, z):
    """Descending Fractions evaluated in complex floating point."""
    return np.polyval(to_float(p), z)


def test_charpoly_of_a_2x2_is_exact():
    Phi = np.array([[0.5, 0.25], [1.0, -0.75]])
    c, Ms = charpoly_adjugate(Phi)
    # det(zI - Phi) = z^2 - tr z + det, with tr = -1/4 and det = -3/8 - 1/4 = -5/8
    assert c == [Fraction(1), Fraction(1, 4), Fraction(-5, 8)]
    # adj(zI - Phi) = I z + [[-Phi11... ]]: [[z + 3/4, 1/4], [1, z - 1/2]]
    assert Ms[0] == [[1, 0], [0, 1]]
    assert Ms[1] == [[Fraction(3, 4), Fraction(1, 4)], [Fraction(1), Fraction(-1, 2)]]


@pytest.mark.parametrize("n", [1, 2, 3, 5, 7])
def test_charpoly_and_adjugate_against_numpy(n):
    rng = np.random.default_rng(n)
    for _ in range(3):
        Phi = _dyadic(rng, n)
        c, Ms = charpoly_adjugate(Phi)
        assert c[0] == 1 and len(c) == n + 1 and len(Ms) == n
        np.testing.assert_allclose(to_float(c), np.poly(Phi), rtol=1e-12, atol=1e-12)
        # adj(zI - Phi) = det(zI - Phi) (zI - Phi)^-1 at points off the spectrum
        for z in (1.7 + 0.3j, -2.1, 0.4j):
            M = z * np.eye(n) - Phi
            adj = sum(np.array(Mk, dtype=float) * z ** (n - 1 - k) for k, Mk in enumerate(Ms))
            np.testing.assert_allclose(adj, np.linalg.det(M) * np.linalg.inv(M), rtol=1e-10, atol=1e-10)


def test_charpoly_of_general_doubles_is_exact_before_rounding():
    """Entries with full 53-bit mantissas: the Fractions are the exact polynomial of the doubles
    (checked exactly through the trace and the determinant of a 2 x 2), rounded once by to_float."""
    rng = np.random.default_rng(3)
    Phi = rng.normal(size=(2, 2))
    c, _ = charpoly_adjugate(Phi)
    F = [[Fraction(float(x)) for x in row] for row in Phi]
    assert c[1] == -(F[0][0] + F[1][1])
    assert c[2] == F[0][0] * F[1][1] - F[0][1] * F[1][0]
    np.testing.assert_allclose(to_float(c), np.poly(Phi), rtol=1e-14)


def test_non_finite_matrix_is_refused():
    with pytest.raises(ValueError, match="non-finite"):
        charpoly_adjugate(np.array([[1.0, np.nan], [0.0, 1.0]]))


def test_transfer_polynomials_against_the_state_space():
    rng = np.random.default_rng(9)
    n = 4
    Phi, Gamma, C = _dyadic(rng, n, 2), _dyadic(rng, n)[:, :2], _dyadic(rng, n)[:3]
    d, N = transfer_polynomials(Phi, Gamma, C)
    assert len(d) == n + 1 and len(N) == 3 and len(N[0]) == 2 and all(len(p) == n for row in N for p in row)
    for z in (1.3 + 0.2j, -0.9 + 1.1j):
        G = C @ np.linalg.solve(z * np.eye(n) - Phi, Gamma)
        got = np.array([[_polyval(N[o][i], z) / _polyval(d, z) for i in range(2)] for o in range(3)])
        np.testing.assert_allclose(got, G, rtol=1e-10)


def test_polymul_and_polysub_are_numpys_exactly():
    a = [Fraction(1, 3), Fraction(-2), Fraction(5, 7)]
    b = [Fraction(3, 2), Fraction(1, 9)]
    assert polymul(a, b) == [Fraction(1, 2), Fraction(1, 27) - 3, Fraction(-2, 9) + Fraction(15, 14), Fraction(5, 63)]
    np.testing.assert_allclose(to_float(polymul(a, b)), np.polymul(to_float(a), to_float(b)), rtol=1e-15)
    assert polymul() == [1] and polymul(a) == a
    assert polysub(a, b) == [Fraction(1, 3), Fraction(-7, 2), Fraction(5, 7) - Fraction(1, 9)]
    np.testing.assert_allclose(to_float(polysub(b, a)), np.polysub(to_float(b), to_float(a)), rtol=1e-15)


def test_to_float_rounds_correctly():
    assert to_float([Fraction(1, 3), Fraction(2, 3), Fraction(10 ** 30 + 1, 10 ** 30)]).tolist() == [1 / 3, 2 / 3, 1.0]


def test_bilinear_is_the_cayley_transform():
    """q(s) = (1 - s)^n p((1 + s)/(1 - s)), ascending, for p descending; z inside the circle maps
    to s in the left half plane: roots z_k of p become the roots (z_k - 1)/(z_k + 1) of q."""
    roots = np.array([0.5, -0.3, 0.2 + 0.6j, 0.2 - 0.6j, 1.5])
    p = [Fraction(float(x)) for x in np.real(np.poly(roots))]
    q = bilinear(p)
    assert len(q) == len(p)
    s = np.array([0.3, -0.7 + 0.2j, 2.0j])
    n = len(p) - 1
    np.testing.assert_allclose(np.polyval(to_float(q)[::-1], s),
                               (1 - s) ** n * np.polyval(to_float(p), (1 + s) / (1 - s)), rtol=1e-12)
    got = np.roots(to_float(q)[::-1])
    want = (roots - 1) / (roots + 1)
    assert got.size == want.size and np.abs(got[:, None] - want[None, :]).min(axis=0).max() < 1e-9
    assert ((np.abs(roots) < 1) == (want.real < 0)).all()          # Schur stable <=> Hurwitz stable


def test_bilinear_is_exact_and_a_root_at_minus_one_lowers_the_degree():
    # p(z) = z^2 - 1/4: q(s) = (1 + s)^2 - (1 - s)^2 / 4 = 3/4 + 5/2 s + 3/4 s^2
    assert bilinear([Fraction(1), Fraction(0), Fraction(-1, 4)]) == [Fraction(3, 4), Fraction(5, 2), Fraction(3, 4)]
    # p(z) = (z + 1)(z - 1/2): the root at z = -1 goes to s = infinity, the s^2 coefficient is 0
    q = bilinear(polymul([1, 1], [1, Fraction(-1, 2)]))
    assert q[-1] == 0 and q[:2] != [0, 0]
