"""haa_sym.loop.closed_loop: ClosedLoop's decisions and frequency responses (the generated
evaluators) against an independent state-space construction (haa_sym.check.reference).

Issue 2's acceptance: >= 1,000 random points across beta in [0.5, 6], alpha in [0, 1.2],
N_av in {1, 4, 10, 20, 50}, Ts in {0.5, 1, 2, 4, 6, 8} ms and both leg configurations; the
stability decision must agree with numpy.linalg.eigvals wherever the spectral radius is not
within 1e-6 of 1; frequency responses to 1e-8 relative (1e-12 absolute near zero).
"""
import itertools

import numpy as np
import pytest

from haa_sym import ClosedLoop, LoopOptions, ParameterError, passivity, region_map
from haa_sym.analysis.contact import contact_stability
from haa_sym.analysis.torque import step_response, torque_bandwidth
from haa_sym.check import reference as ref
from haa_sym.loop import FILTERS, PORTS

from conftest import decisions_against_reference

N_AVS = (1, 4, 10, 20, 50)
TSS = (0.5e-3, 1e-3, 2e-3, 4e-3, 6e-3, 8e-3)
CONFIGS = ("extended", "retracted")
POINTS_PER_CASE = 17  # 60 cases x 17 = 1020 points


def cases():
    rng = np.random.default_rng(2016)
    for N_av, Ts, cfg in itertools.product(N_AVS, TSS, CONFIGS):
        opts = LoopOptions(delay=int(rng.integers(2)), torque_damping=bool(rng.integers(2)),
                           port=PORTS[int(rng.integers(3))], filter=FILTERS[int(rng.integers(3))])
        pts = np.stack([10 ** rng.uniform(0, np.log10(20000), POINTS_PER_CASE),
                        rng.uniform(0, 50, POINTS_PER_CASE),
                        rng.uniform(0.5, 6, POINTS_PER_CASE),
                        rng.uniform(0, 1.2, POINTS_PER_CASE)])
        yield N_av, Ts, cfg, opts, pts


@pytest.fixture(scope="module")
def results(params):
    """Per case: the loop, its points, the raw and the refined decision, and the reference's
    eigenvalue moduli (k, order) and spectral radius. The eigenvalues of all the case's points at
    once (ref.closed_loop_eigenvalues): the same matrices and LAPACK call as ref.spectral_radius
    point by point (bit for bit on these points), ten times faster."""
    out = []
    for N_av, Ts, cfg, opts, pts in cases():
        loop = ClosedLoop(params.configuration(cfg).with_values(N_av=N_av, Ts=Ts), opts)
        raw = loop.stability(*pts, certify=False)
        refined = loop.stability(*pts, radius=True)
        eig = np.abs(ref.closed_loop_eigenvalues(loop, pts))
        out.append((loop, pts, raw, refined, eig.max(axis=1), eig))
    return out


def test_thousand_points(results):
    assert sum(r[1].shape[1] for r in results) >= 1000


def test_decision_agrees_with_eigvals(results):
    bad = []
    for loop, pts, raw, refined, rho, eig in results:
        c = decisions_against_reference(loop, pts, 1e-6, eig=eig, certified=False)
        bad += [(loop.params.controller, loop.options, pts[:, i], rho[i], raw.spectral_radius[i]) for i in c["bad"]]
        assert np.array_equal(refined.stable[np.abs(rho - 1) > 1e-12], (rho < 1)[np.abs(rho - 1) > 1e-12])
    assert not bad, bad[:3]


def test_radius_and_unstable_count_match_eigvals(results):
    # radius=True reports the eigenvalue radius; the generated Routh count of poles outside the
    # circle must equal the eigenvalue count wherever no pole is within 1e-6 of |z| = 1
    for loop, pts, raw, refined, rho, eig in results:
        np.testing.assert_allclose(refined.spectral_radius, rho, rtol=0, atol=1e-12)
        clear = np.all(np.abs(eig - 1) > 1e-6, axis=1)
        np.testing.assert_array_equal(raw.n_unstable[clear], (eig[clear] > 1).sum(axis=1))


def test_both_branches_exercised(results):
    stable = np.concatenate([rho < 1 for *_, rho, _eig in results])
    assert 0.05 < stable.mean() < 0.95, stable.mean()


def test_frequency_responses_match_state_space(results):
    worst = 0.0
    for loop, pts, *_ in results[::3]:
        Ts = loop.params.controller.Ts
        w = np.logspace(-1, np.log10(np.pi / Ts * 0.999), 25)
        fr = loop.frequency_response(w, *pts[:, :4])
        for i in range(4):
            fref = ref.frequency_response(loop, w, *pts[:, i])
            for key, val in fref.items():
                got = fr[key][i]
                err = np.abs(got - val)
                ok = (err <= 1e-8 * np.abs(val)) | (err <= 1e-12)
                assert ok.all(), (key, loop.options, pts[:, i], (err / np.abs(val)).max())
                worst = max(worst, float((err / np.maximum(np.abs(val), 1e-300)).max()))
    assert worst < 1e-8


def test_characteristic_polynomial_is_det(params):
    loop = ClosedLoop(params.with_values(N_av=3), LoopOptions(delay=1))
    chi = loop.characteristic_polynomial(300.0, 7.0, 2.0, 0.5)
    A = ref.closed_loop_matrices(loop, 300.0, 7.0, 2.0, 0.5)[0]
    assert len(chi) == A.shape[0] + 1
    np.testing.assert_allclose(chi / chi[0], np.poly(A), rtol=1e-7, atol=1e-9)


def test_broadcasting_and_shapes(params):
    loop = ClosedLoop(params)
    P, D = np.meshgrid([1.0, 200.0, 20000.0], [1.0, 10.0])
    res = loop.stability(P, D)
    assert res.stable.shape == (2, 3) and res.spectral_radius.shape == (2, 3)
    fr = loop.frequency_response([1.0, 10.0], P, D)
    assert fr["Z"].shape == (2, 3, 2)


def test_bad_gain_input(params):
    loop = ClosedLoop(params)
    with pytest.raises(ParameterError, match="P_gain contains nan"):
        loop.stability([1.0, float("nan")], 1.0)
    with pytest.raises(ParameterError, match="port = 'foot'"):
        LoopOptions(port="foot")
    with pytest.raises(ParameterError, match="delay = 2"):
        LoopOptions(delay=2)
    with pytest.raises(ParameterError, match="N_av = 200 gives a closed loop of order 208.*allowed: N_av <= 56"):
        ClosedLoop(params.with_values(N_av=200))


@pytest.mark.parametrize("changes", [{}, {"Ts": 2e-4}, {"Ts": 1e-4}])
@pytest.mark.parametrize("cfg", ["extended", "retracted"])
def test_free_link_position_mode_is_marginal_not_stable(params, cfg, changes):
    # K_L2 = 0 and P_gain = 0: nothing holds the leg's position, a pole sits exactly at z = 1;
    # the rounding of the sampled plant put it either side of the circle before
    p = params.configuration(cfg).with_values(K_L2=0.0, **changes)
    res = ClosedLoop(p).stability([0.0, 10.0], [0.0, 0.0])
    assert list(res.stable) == [False, True] and list(res.marginal) == [True, False]


@pytest.fixture(scope="module")
def loop(params):
    return ClosedLoop(params)


@pytest.mark.parametrize("call,msg", [
    (lambda p, lp: lp.stability(-1.0, 0.0), r"P_gain = -1.0 is out of range"),
    (lambda p, lp: lp.stability([1.0, 2.0], [0.0, -3.0]), r"D_gain contains -3.0, which is out of range"),
    (lambda p, lp: lp.stability(1.0, 1.0, beta=0.0), r"beta = 0.0 is out of range; allowed: a finite number > 0"),
    (lambda p, lp: lp.loop_coefficients(beta=0.0), r"beta = 0.0 is out of range"),
    (lambda p, lp: lp.loop_coefficients(alpha=-0.5), r"alpha = -0.5 is out of range"),
    (lambda p, lp: lp.frequency_response([1.0], -1.0), r"P_gain = -1.0 is out of range"),
    (lambda p, lp: region_map(lp, [1.0], [1.0], beta=0.0), r"beta = 0.0 is out of range"),
    (lambda p, lp: passivity(lp, -1.0, 0.0), r"P_gain = -1.0 is out of range"),
    (lambda p, lp: step_response(lp, alpha=-1.0), r"alpha = -1.0 is out of range"),
    (lambda p, lp: torque_bandwidth(lp, beta=0.0), r"beta = 0.0 is out of range"),
    (lambda p, lp: contact_stability(ClosedLoop(p), [1.0], D_gain=-1.0), r"D_gain = -1.0 is out of range"),
])
def test_api_applies_the_same_gain_rule(params, loop, call, msg):
    with pytest.raises(ParameterError, match=msg):
        call(params, loop)


# --- the API the analyses share ---------------------------------------------------------------------
def test_gain_points_broadcast_and_refuse_what_cannot(params, loop):
    P, D, b, a = loop.gain_points([[1.0], [2.0]], [3.0, 4.0, 5.0])
    assert P.tolist() == [1.0, 1.0, 1.0, 2.0, 2.0, 2.0] and D.tolist() == [3.0, 4.0, 5.0] * 2    # C order
    assert (b, a) == (params.controller.beta, params.controller.alpha)
    assert loop.gain_points(1.0, 2.0, 3.0, 0.5)[2:] == (3.0, 0.5)
    with pytest.raises(ParameterError, match=r"P_gain has shape \(2,\) and D_gain \(3,\); allowed: shapes that broadcast"):
        loop.gain_points([1.0, 2.0], [1.0, 2.0, 3.0])
    with pytest.raises(ParameterError, match=r"beta has 2 and alpha 1 values; allowed: one value each"):
        loop.gain_points(1.0, 1.0, [1.0, 2.0])


def test_analyses_take_the_loop_first(params):
    from haa_sym.loop import loop_first

    @loop_first
    def analysis(loop, x):
        return x
    assert analysis(ClosedLoop(params, basis=False), 3) == 3
    with pytest.raises(ParameterError, match=r"analysis: the first argument is a Params; allowed: a haa_sym.ClosedLoop "
                                             r"\(the analyses take the loop first: analysis\(ClosedLoop\(params, options\), \.\.\.\)\)"):
        analysis(params, 3)


def test_loop_coefficients_give_the_frequency_response(loop):
    w = np.logspace(0, 3, 9)
    P, D = np.array([0.0, 200.0, 3000.0]), np.array([0.0, 10.0, 40.0])
    fr = loop.frequency_response(w, P, D)
    co = loop.loop_coefficients(w)
    assert co.L_t.shape == co.L_imp.shape == co.Z_num.shape == (9, 3) and co.H_T.shape == (9,)
    for k in ("L_t", "L_imp", "Z", "H_T"):
        np.testing.assert_allclose(co.evaluate(k, P, D), fr[k], rtol=1e-13, err_msg=k)
        assert fr[k] is getattr(fr, k)
    with pytest.raises(KeyError):
        fr["L_x"]
    np.testing.assert_array_equal(fr.omega, w)


def test_stability_result_shapes_and_the_radius_only_when_asked(loop):
    res = loop.stability([[1.0, 200.0], [2000.0, 20000.0]], 10.0)
    for a in (res.stable, res.spectral_radius, res.refined, res.n_unstable):
        assert a.shape == (2, 2)
    assert np.isnan(res.spectral_radius[~res.refined]).all()
    assert np.isfinite(loop.stability(200.0, 10.0, radius=True).spectral_radius).all()


def test_provenance_names_what_produced_a_result(params, loop):
    prov = loop.provenance(method="test")
    assert prov["params"] == params.to_dict() and prov["options"] == loop.options.to_dict()
    assert prov["method"] == "test" and prov["backend"] in ("compiled", "vm")
    assert len(prov["generated_source_sha256"]) == 64 and prov["haa_sym"]
