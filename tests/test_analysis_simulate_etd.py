"""The friction integrator's ETDRK4 tables (all tables in one batched expm, then squaring) against
matrices computed independently per table and level: the ZOH transition from its own expm at
the substep, the phi-functions from their integral phi_k(Z) = int_0^1 e^((1-s) Z) s^(k-1) /
(k-1)! ds (scipy quad_vec) and from Higham's block matrix with an identity at the substep
itself, combined into the Cox-Matthews coefficients."""
import math

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis import simulate as S
from haa_sym.compiled import layout as L
from haa_sym.model.limits import Limits

FRICTION = Limits(V_max=24.0, friction={"m": 0.02, "L2": 0.5})


@pytest.fixture(scope="module")
def setup():
    loop = ClosedLoop(load_params(), basis=False)
    return S._Setup(loop, FRICTION, "disturbance-step", 1.0, 0.01, 0, None)


def _phis_block(Z):
    """[phi_1(Z), phi_2(Z), phi_3(Z)] from expm of [[Z, I, 0, 0], [0, 0, I, 0], [0, 0, 0, I], 0]."""
    n = Z.shape[0]
    K = np.zeros((4 * n, 4 * n))
    K[:n, :n] = Z
    for k in range(3):
        K[k * n:(k + 1) * n, (k + 1) * n:(k + 2) * n] = np.eye(n)
    E = scipy.linalg.expm(K)
    return [E[:n, (k + 1) * n:(k + 2) * n] for k in range(3)]


def _phis_quad(Z):
    return [scipy.integrate.quad_vec(lambda s, k=k: scipy.linalg.expm((1 - s) * Z) * s ** (k - 1)
                                     / math.factorial(k - 1), 0, 1, epsabs=1e-14, epsrel=1e-12)[0]
            for k in (1, 2, 3)]


def _unpack(vec, lay, name):
    r, c = lay.shape[name]
    return vec[lay[name]].reshape(c, r).T


@pytest.mark.parametrize("level, quad", [pytest.param(0, True, marks=pytest.mark.slow), (0, False), (3, False),
                                         (12, False)])
def test_tables_are_the_etdrk4_matrices_of_each_slope_and_level(setup, level, quad):
    sel, col, fc = setup.friction
    n, m, vs = setup.nx, len(sel), FRICTION.friction_velocity
    cx = 8
    fractions = [[0.0, 0.0], [1.0, 0.0], [0.06, 0.75], [0.5, 1.0]]
    lay = L.sim_plant_layout("etd", cx)
    tab = setup.etd_tables(fractions, cx).reshape(len(fractions), S.LEVELS, lay.size)
    h = setup.Ts / 2 ** level
    for t, fr in enumerate(fractions):
        lin = np.asarray(fr) * fc / vs
        Ap = setup.A.copy()
        for b in range(m):
            Ap[:, sel[b]] -= lin[b] * col[:, b]
        got = {name: _unpack(tab[t, level], lay, name) for name in lay.names()}
        P, G = S._zoh(Ap, setup.Bu, h)
        Ph, Gh = S._zoh(Ap, setup.Bu, h / 2)
        p1, p2, p3 = _phis_quad(Ap * h) if quad else _phis_block(Ap * h)
        p1h = (_phis_quad if quad else _phis_block)(Ap * h / 2)[0]
        want = {"P": P, "G": G, "Ph": Ph, "Gh": Gh, "Qh": h / 2 * p1h @ col,
                "F1": h * (p1 - 3 * p2 + 4 * p3) @ col, "F2": h * (p2 - 2 * p3) @ col,
                "F3": h * (-p2 + 4 * p3) @ col}
        for name, w in want.items():
            g = got[name]
            assert not np.any(g[n:]) and not np.any(g[:, w.shape[1]:]), name     # padding stays zero
            err = np.abs(g[:n, :w.shape[1]] - w).max() / np.abs(w).max()
            assert err <= 1e-9, (name, fr, level, err)
        assert np.array_equal(got["lin"][:m, 0], lin) and not np.any(got["lin"][m:])
        assert np.array_equal(got["Fc"][:m, 0], fc) and got["inv_vs"][0, 0] == 1.0 / vs
        assert np.array_equal(np.nonzero(got["Fsel"])[1], sel)
