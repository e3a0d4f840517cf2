"""The numeric plant against python-control, and the paper's equations (haa_sym.check.verify)."""
import numpy as np
import pytest

from haa_sym.loop.plant import continuous_plant, discretize


def test_zoh_matches_python_control(params):
    control = pytest.importorskip("control")
    cont = continuous_plant(params.plant)
    for Ts in (0.5e-3, 1e-3, 8e-3):
        d = discretize(cont, Ts)
        ref = control.c2d(control.ss(cont.A, cont.B, cont.C, 0), Ts, "zoh")
        np.testing.assert_allclose(d.Phi, ref.A, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(d.Gamma, ref.B, rtol=1e-10, atol=1e-14)


def test_vc_gain_eq6(params):
    p = params.plant
    assert np.isclose(continuous_plant(p).VC0, p.N / p.k_t * (p.R * p.B_m + p.k_t * p.k_w), rtol=1e-15)


def test_verify_all_rows_pass(params):
    from haa_sym.check import verify
    rows = verify.run(params)
    failed = [r for r in rows if not r.ok]
    assert not failed, [(r.claim, r.numbers) for r in failed]
    assert len(rows) >= 14


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
