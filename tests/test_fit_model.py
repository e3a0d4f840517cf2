"""haa_sym.fit.model and fit.closed: the sampled model, its exact derivatives and the fast
simulation, against independent computations (the hand-written equations of
tests/identify_synthetic.py, scipy's cont2discrete, dlsim and central differences; the closed
torque loop against haa_sym.check.reference)."""
import numpy as np
import pytest
import scipy.signal

from haa_sym.check.reference import closed_loop_matrices
from haa_sym.fit.closed import torque_loop_model
from haa_sym.fit.model import open_loop_model, sample, simulate
from haa_sym.loop import ClosedLoop
from haa_sym.model.params import actuator_path, load_params

from identify_synthetic import sea, two_mass

CASES = [("harmonic_drive", two_mass, ("J_link", "B_link", "K_hd", "D_hd")),
         ("sea", sea, ("J_link", "B_link", "K_bar", "D_bar"))]


def _hand(model, p, current):
    A, B, C, D = model(p, current)
    rows = [0, 1] if current else [0, 1, 3]          # torque, theta (, current)
    return A, B, C[rows], D[rows]


@pytest.mark.parametrize("name,model,keys", CASES)
@pytest.mark.parametrize("current", [False, True])
def test_zoh_and_derivatives_match_hand_model(name, model, keys, current):
    params = load_params(actuator_path(name))
    p = params.plant.as_dict()
    inputs = ("current" if current else "voltage", "T_dist")
    outputs = ("torque", "theta") if current else ("torque", "theta", "current")
    s = sample(open_loop_model(params.plant, keys, inputs, outputs), 1e-3)
    A, B, C, D = _hand(model, p, current)
    Phi, Gam, *_ = scipy.signal.cont2discrete((A, B, C, D), 1e-3, "zoh")
    np.testing.assert_allclose(s.Phi, Phi, rtol=1e-9, atol=1e-12 * np.abs(Phi).max())
    np.testing.assert_allclose(s.Gamma, Gam, rtol=1e-9, atol=1e-12 * np.abs(Gam).max())
    np.testing.assert_allclose(s.C, C, rtol=1e-12, atol=1e-12 * np.abs(C).max())
    for j, k in enumerate(keys):
        h = 1e-5 * p[k]
        up, dn = (scipy.signal.cont2discrete(_hand(model, dict(p, **{k: p[k] + d}), current), 1e-3, "zoh")
                  for d in (h, -h))
        for exact, i in ((s.dPhi[j], 0), (s.dGamma[j], 1), (s.dC[j], 2)):
            fd = (up[i] - dn[i]) / (2 * h)
            # the central difference's own error: truncation (relative 1e-5 here) and rounding,
            # eps |M| / h of the whole matrix M (its columns differ by orders of magnitude)
            rounding = 100 * np.finfo(float).eps * np.abs(up[i]).max() / h
            assert np.abs(exact - fd).max() <= max(1e-5 * np.abs(fd).max(), rounding), (k, i)


def test_simulation_and_sensitivities_match_dlsim():
    params = load_params(actuator_path("sea"))
    keys = ("J_link", "K_bar")
    rng = np.random.default_rng(3)
    u = np.column_stack([rng.standard_normal(2000), 0.1 * rng.standard_normal(2000)])
    s = sample(open_loop_model(params.plant, keys, ("voltage", "T_dist"), ("torque", "theta")), 1e-3)
    y, dy = simulate(s, u)
    _, y_ref, _ = scipy.signal.dlsim((s.Phi, s.Gamma, s.C, s.D, 1e-3), u)
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-10 * np.abs(y_ref).max())
    for j, k in enumerate(keys):
        h = 1e-6 * getattr(params.plant, k)
        ys = [scipy.signal.dlsim((m.Phi, m.Gamma, m.C, m.D, 1e-3), u)[1] for m in (
            sample(open_loop_model(params.plant.replace(**{k: getattr(params.plant, k) + d}), (), ("voltage", "T_dist"),
                                   ("torque", "theta")), 1e-3) for d in (h, -h))]
        fd = (ys[0] - ys[1]) / (2 * h)
        assert np.abs(dy[j] - fd).max() <= 1e-4 * np.abs(fd).max(), k


def test_torque_loop_matches_reference_and_its_derivative():
    params = load_params(actuator_path("harmonic_drive"))
    keys = ("K_hd", "B_m")                          # B_m also moves the velocity compensation VC0
    s = torque_loop_model(params, keys, ("torque_ref",), ("torque", "theta"))
    A, B, C, D = closed_loop_matrices(ClosedLoop(params), 0.0, 0.0, cut="T_ref")
    # the same transfer from the torque reference (state bases may differ): compare responses
    z = np.exp(1j * np.array([0.3, 3.0, 30.0, 300.0]) * 1e-3)

    def fr(Phi, G, Cm, Dm):
        return np.array([Cm @ np.linalg.solve(zz * np.eye(len(Phi)) - Phi, G) + Dm for zz in z])
    np.testing.assert_allclose(fr(s.Phi, s.Gamma[:, :1], s.C, s.D[:, :1]), fr(A, B[:, 1:], C[:2], D[:2, 1:]),
                               rtol=1e-7, atol=1e-12)
    for j, k in enumerate(keys):
        v = getattr(params.plant, k)
        # 1e-3: near z = 1 the reference's responses lose digits, so rounding, not truncation
        # (relative 1e-6 here), limits a central difference
        h = 1e-3 * v
        pair = [closed_loop_matrices(ClosedLoop(params.with_values(**{k: v + d})), 0.0, 0.0, cut="T_ref")
                for d in (h, -h)]
        dfr = (fr(pair[0][0], pair[0][1][:, 1:], pair[0][2][:2], pair[0][3][:2, 1:])
               - fr(pair[1][0], pair[1][1][:, 1:], pair[1][2][:2], pair[1][3][:2, 1:])) / (2 * h)
        # the derivative of the response from the exact matrix derivatives
        exact = []
        for zz in z:
            M = np.linalg.inv(zz * np.eye(len(s.Phi)) - s.Phi)
            exact.append(s.dC[j] @ M @ s.Gamma[:, :1] + s.C @ M @ s.dPhi[j] @ M @ s.Gamma[:, :1]
                         + s.C @ M @ s.dGamma[j][:, :1])
        exact = np.array(exact)
        for row in range(exact.shape[1]):            # torque (Nm) and theta (rad): each on its own scale
            assert np.abs(exact[:, row] - dfr[:, row]).max() <= 1e-4 * np.abs(dfr[:, row]).max(), (k, row)
