"""Controller structures as data (issue 24, item 1; haa_sym.model.structures, docs/model.md,
"Controller structures"): each structure's stability maps against the eigenvalues of the
reference's explicit closed loop (haa_sym.check.reference, built from the structure's equations
with its own algebra), its frequency responses and passivity decisions against the reference's,
the simulation with no limits against the linear closed loop, and the refusals: an unknown
structure, a torque loop's keys where there is none, an analysis that needs what it lacks."""
import dataclasses

import numpy as np
import pytest

from haa_sym import ClosedLoop, LoopOptions, load_params
from haa_sym.analysis.regions import region_map
from haa_sym.analysis.simulate import simulate
from haa_sym.analysis.sweep import colgate_factor
from haa_sym.analysis.torque import torque_bandwidth
from haa_sym.check import reference as ref
from haa_sym.check.crosscheck import eigenvalue_crosscheck
from haa_sym.check.reference_margins import closed_loop_spectral_radius, low_pm_reference
from haa_sym.errors import ParameterError
from haa_sym.loop.statespace import closed_loop_batch
from haa_sym.model.limits import Limits
from haa_sym.model.params import Controller
from haa_sym.model.structures import STRUCTURES

from conftest import ROOT

NEW = ("torque_pi", "torque_pi_ff", "impedance_current")
ACTUATORS = ("hyq_haa", "qdd_leg", "sea")


def _params(name, structure, Ts=None):
    """The bundled file's plant and sampling with ``structure`` (the keys it does not read left out)."""
    p = load_params(name)
    c = p.controller
    c = c if c.structure == "paper" else p.with_values(structure="paper").controller   # [controller.paper]
    keys = {k: getattr(c, k) for k in STRUCTURES[structure].keys}
    ctrl = Controller(Ts=c.Ts if Ts is None else Ts, N_av=c.N_av, structure=structure, **keys)
    return dataclasses.replace(p, controller=ctrl)


def _check_map(name, structure, Ts, shape):
    loop = ClosedLoop(_params(name, structure, Ts))
    P, D = np.geomspace(1.0, 20000.0, shape[0]), np.linspace(0.0, 50.0, shape[1])
    m = region_map(loop, P, D, progress=False)
    cc = eigenvalue_crosscheck(m, loop, band=1e-6, points="all")
    assert cc["checked"] == m.stable.size and cc["decided"] > 0.99 * cc["points"]
    assert cc["disagree"] == 0, cc
    # the exact curves (the default method) and the grid's point-by-point decisions agree
    g = region_map(loop, P, D, method="grid", passivity=False, progress=False)
    np.testing.assert_array_equal(m.stable, g.stable)
    return m


@pytest.mark.parametrize("structure", NEW)
@pytest.mark.parametrize("name", ACTUATORS)
@pytest.mark.parametrize("Ts", [5e-5, 1e-3])
def test_map_of_each_structure_agrees_with_the_reference_eigenvalues(name, structure, Ts):
    """Every point of a 40 x 20 map away from |rho - 1| <= 1e-6 (the slow test: 200 x 100)."""
    _check_map(name, structure, Ts, (40, 20))


@pytest.mark.slow
@pytest.mark.parametrize("structure", NEW)
@pytest.mark.parametrize("name", ACTUATORS)
@pytest.mark.parametrize("Ts", [5e-5, 1e-3])
def test_200_by_100_map_of_each_structure_agrees_with_the_reference_eigenvalues(name, structure, Ts):
    """The issue's acceptance: every point of a 200 x 100 map away from the boundary."""
    _check_map(name, structure, Ts, (200, 100))


def test_the_structures_change_the_maps():
    """Not one map under four names: on the QDD leg at 1 ms each structure's stable set differs
    from every other's on a 40 x 20 grid."""
    maps = {s: _check_map("qdd_leg", s, 1e-3, (40, 20)).stable for s in ("paper",) + NEW}
    names = list(maps)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert (maps[a] != maps[b]).sum() > 5, (a, b)


@pytest.mark.parametrize("structure", NEW)
@pytest.mark.parametrize("name", ["hyq_haa", "qdd_leg"])
def test_frequency_responses_equal_the_reference_closed_loops(name, structure):
    loop = ClosedLoop(_params(name, structure))
    w = np.geomspace(1.0, 0.9 * np.pi / loop.params.controller.Ts, 40)
    fr = loop.frequency_response(w, 800.0, 8.0)
    which = ("L_imp", "Z") + (("L_t", "H_T") if STRUCTURES[structure].torque_loop else ())
    want = ref.frequency_response(loop, w, 800.0, 8.0, which=which)
    for k in which:
        np.testing.assert_allclose(fr[k], want[k], rtol=1e-9, err_msg=k)


@pytest.mark.parametrize("structure", [pytest.param("torque_pi", marks=pytest.mark.slow),
                                       pytest.param("torque_pi_ff", marks=pytest.mark.slow), "impedance_current"])
def test_pm_and_passivity_maps_agree_with_the_reference(structure):
    """PM < 30 deg against the reference's exact crossovers and the passivity excess against the
    reference closed loop's Z, on every stable point of a small QDD map at 1 ms."""
    p = _params("qdd_leg", structure, 2.5e-4)
    loop = ClosedLoop(p)
    P, D = np.geomspace(1.0, 3000.0, 3), np.linspace(0.0, 5.0, 3)
    m = region_map(loop, P, D, progress=False)
    PP, DD = np.meshgrid(P, D, indexing="ij")
    low = low_pm_reference(p, LoopOptions(), PP.ravel(), DD.ravel())
    rho = closed_loop_spectral_radius(ClosedLoop(p, basis=False), PP.ravel(), DD.ravel())
    away = ~low.near & (np.abs(rho - 1) > 1e-6)
    np.testing.assert_array_equal(m.low_pm.ravel()[away], ((rho < 1) & low.low)[away])
    Ts, w = p.controller.Ts, loop.options.omega(p.controller.Ts)
    checked = 0
    for i in np.flatnonzero(rho < 1 - 1e-6):
        Z = ref.frequency_response(loop, w, PP.ravel()[i], DD.ravel()[i], which=("Z",))["Z"]
        want = np.abs(np.degrees(np.angle(Z * colgate_factor(w, Ts, "subtract")))).max() - 90
        assert m.passive.ravel()[i] == (want <= loop.options.passivity_tol_deg)
        checked += 1
    assert checked >= 5


def test_the_paper_structure_named_is_the_default():
    a, b = ClosedLoop(load_params("sea")), ClosedLoop(load_params("sea").with_values(structure="paper"))
    np.testing.assert_array_equal(a.basis, b.basis)
    np.testing.assert_array_equal(a.const, b.const)


def test_feed_forward_and_current_command_are_what_the_docs_say():
    """The constants: torque_pi_ff's gain on T_ref is P_t0 + R/(k_t N) and its gain on T is P_t0;
    impedance_current's command is T_ref/(k_t N), a current (the plant without I_m)."""
    ff = ClosedLoop(_params("qdd_leg", "torque_pi_ff"))
    pl = ff.params.plant
    assert ff.const[0] == pytest.approx(0.1922 + pl.R / (pl.k_t * pl.N), rel=1e-15)
    assert ff.P_m0 == 0.1922 and ff.const[2] == 0.0
    cur = ClosedLoop(_params("qdd_leg", "impedance_current"))
    assert cur.const.tolist() == [1.0 / (pl.k_t * pl.N), 0.0, 0.0]
    assert "I_m" not in cur.plant.state_names and "I_m" in ff.plant.state_names


@pytest.mark.parametrize("structure", ["torque_pi", "torque_pi_ff"])
def test_simulate_with_no_limits_is_the_linear_closed_loop(structure):
    loop = ClosedLoop(_params("hyq_haa", structure), basis=False)
    P, D, A, n = 300.0, 3.0, 0.7, 400
    s = simulate(loop, P, D, limits=Limits(), experiment="disturbance-step", amplitude=A,
                 duration=(n - 1) * loop.params.controller.Ts)
    Acl, Bcl, Ccl, Dcl = (m[0] for m in closed_loop_batch(loop, P, D))
    x, u, y = np.zeros(Acl.shape[0]), np.array([A, 0.0]), np.empty((n, 3))
    for k in range(n):
        y[k] = (Ccl @ x + Dcl @ u)[:3]
        x = Acl @ x + Bcl @ u
    for name, row in (("torque", 0), ("theta", 1), ("velocity", 2)):
        err = np.abs(getattr(s, name) - y[:, row]).max() / np.abs(y[:, row]).max()
        assert err <= 1e-9, (name, err)


def test_analyses_that_need_what_a_structure_lacks_refuse_it():
    cur = ClosedLoop(_params("qdd_leg", "impedance_current"))
    with pytest.raises(ParameterError, match="needs a torque loop.*'impedance_current'"):
        torque_bandwidth(cur)
    with pytest.raises(ParameterError, match="beta = 2: structure = 'impedance_current' has no torque PI"):
        cur.stability(10.0, 0.1, beta=2.0)
    with pytest.raises(ParameterError, match="alpha = 0.5: structure = 'torque_pi' has no velocity"):
        ClosedLoop(_params("qdd_leg", "torque_pi")).stability(10.0, 0.1, alpha=0.5)


# --- the file and the command line -----------------------------------------------------------------
def _file(tmp_path, structure, drop=(), extra=""):
    text = (ROOT / "model" / "hyq_haa.toml").read_text()
    lines = [ln for ln in text.splitlines() if not any(ln.startswith(k + " ") for k in drop)]
    out = "\n".join(lines).replace("[controller]", f"[controller]\nstructure = \"{structure}\"{extra}", 1)
    path = tmp_path / "in" / f"{structure}.toml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(out)
    return path


def test_unknown_structure_is_refused_in_one_line(tmp_path, assert_refused):
    f = _file(tmp_path, "cascade")
    assert_refused(["regions", "--params", str(f), "--out", "m.npz"],
                   ("structure = 'cascade'", "allowed: paper | torque_pi | torque_pi_ff | impedance_current"))
    assert_refused(["regions", "--set", "structure=cascade", "--out", "m.npz"], "structure = 'cascade'")


def test_torque_loop_keys_in_a_file_without_a_torque_loop_are_refused(tmp_path, assert_refused):
    f = _file(tmp_path, "impedance_current", drop=("alpha", "beta", "I_t0"))
    assert_refused(["regions", "--params", str(f), "--out", "m.npz"],
                   ("P_t0 = 0.382: structure = 'impedance_current' has no torque PI", "leave P_t0 out"))
    g = _file(tmp_path, "torque_pi")
    assert_refused(["regions", "--params", str(g), "--out", "m.npz"],
                   "alpha = 0.94: structure = 'torque_pi' has no velocity compensation")


def test_switching_structure_with_set(tmp_path, capsys):
    """--set structure=impedance_current drops the torque loop's keys; back to the paper's needs them,
    from --set or from the file's [controller.paper] (the bundled QDD leg's)."""
    from haa_sym.cli import main
    assert main(["regions", "--params", "hyq_haa", "--set", "structure=impedance_current",
                 "--P-gain", "lin:1:100:3", "--D-gain", "lin:0:1:2", "--out", str(tmp_path / "m.npz")]) == 0
    f = _file(tmp_path, "impedance_current", drop=("alpha", "beta", "I_t0", "P_t0"))
    p = load_params(f)
    assert p.controller.structure == "impedance_current" and p.controller.beta == 1.0
    with pytest.raises(ParameterError, match="P_t0"):
        p.with_values(structure="paper")
    q = p.with_values(structure="paper", P_t0=0.382, I_t0=18.0, alpha=0.94, beta=1.0)
    assert ClosedLoop(q).const[0] == 0.382
    # the QDD leg: the robot's structure, the paper's from [controller.paper], and back
    qdd = load_params("qdd_leg")
    assert qdd.controller.structure == "impedance_current"
    paper = qdd.with_values(structure="paper")
    c = paper.controller
    assert (c.P_t0, c.I_t0, c.alpha, c.beta) == (0.1922, 9.05, 0.94, 1.0)
    assert paper.with_values(structure="impedance_current").controller == qdd.controller
    capsys.readouterr()
    assert main(["stability", "--params", "qdd_leg", "--set", "structure=paper", "--P-gain", "30",
                 "--D-gain", "0.2"]) == 0
    rho = float(ClosedLoop(paper).stability(30.0, 0.2, radius=True).spectral_radius)
    assert capsys.readouterr().out == f"stable: False  spectral radius: {rho:.12g}\n" and rho > 1


# --- the haptic device (a rotor-only file: no [bodies]) -------------------------------------------
def _check_haptic_map(Ts, shape):
    loop = ClosedLoop(load_params("haptic_wall").with_values(Ts=Ts))
    K, B = np.geomspace(0.01, 1000.0, shape[0]), np.linspace(0.0, 0.05, shape[1])
    m = region_map(loop, K, B, progress=False)
    np.testing.assert_array_equal(m.stable, region_map(loop, K, B, method="grid", passivity=False,
                                                       progress=False).stable)
    cc = eigenvalue_crosscheck(m, loop, band=1e-6, points="all")
    assert cc["decided"] > 0.99 * cc["points"] and cc["disagree"] == 0, cc
    assert m.stable.any() and (~m.stable).any()


@pytest.mark.parametrize("Ts", [5e-5, 1e-3])
def test_haptic_wall_map_agrees_with_the_reference_eigenvalues(Ts):
    _check_haptic_map(Ts, (40, 20))


@pytest.mark.slow
@pytest.mark.parametrize("Ts", [5e-5, 1e-3])
def test_haptic_wall_200_by_100_map_agrees_with_the_reference_eigenvalues(Ts):
    _check_haptic_map(Ts, (200, 100))


def test_haptic_wall_is_the_rotor_alone_under_a_current_command():
    p = load_params("haptic_wall")
    top = p.plant.topology
    assert top.bodies == () and (top.sensor, top.encoder, top.port) == ("current", "rotor", "rotor")
    loop = ClosedLoop(p)
    # two states (theta_m, dtheta_m), the backward difference's one: a loop of order 3
    assert loop.plant.state_names == ("theta_m", "dtheta_m") and loop.degree == 3
    # the port: T_dist on the handle moves it as 1/(J s^2 + b s) (N = 1), in the sampled plant
    Phi, G = loop.plant.Phi, loop.plant.Gamma[:, 2]
    J, b, Ts = p.plant.J_m, p.plant.B_m, p.controller.Ts
    a = np.exp(-b / J * Ts)
    np.testing.assert_allclose(Phi, [[1.0, J / b * (1 - a)], [0.0, a]], rtol=1e-12)
    np.testing.assert_allclose(G, [(Ts - J / b * (1 - a)) / b, (1 - a) / b], rtol=1e-9)


@pytest.mark.parametrize("argv, match", [
    (["contact", "--P-gain", "2", "--D-gain", "0.001"], "the port is the rotor of an actuator without [bodies]"),
    (["step", "--out", "s.csv"], "step_response needs a torque loop"),
    (["tune", "--out", "t.toml"], "tune (the torque PI tuner) needs a torque loop"),
    (["regions", "--set", "beta=2", "--out", "m.npz"], "beta = 2: structure = 'impedance_current' has no torque PI"),
])
def test_haptic_wall_refusals(argv, match, assert_refused):
    assert_refused(argv + ["--params", "haptic_wall"], match)


def test_margins_of_a_structure_without_torque_loop_say_so(capsys):
    from haa_sym.cli import main
    assert main(["margins", "--params", "haptic_wall", "--P-gain", "2", "--D-gain", "0.001"]) == 0
    out = capsys.readouterr().out
    assert "torque loop (opened at the PI output): none (structure = 'impedance_current'" in out
    assert "impedance loop (opened at T_lref):\n  PM +" in out


@pytest.mark.parametrize("name", ["qdd_leg", "haptic_wall"])
def test_verify_derives_every_structure_in_sympy(name):
    """python -m haa_sym.verify: one row per structure (chi and Z against their sympy derivation)."""
    from haa_sym.check import verify
    rows = verify.row_structures(load_params(name))
    assert [r.claim.split("'")[1] for r in rows] == list(STRUCTURES)
    assert all(r.ok for r in rows), [(r.claim, r.numbers) for r in rows if not r.ok]
    assert all("one constant at 3 gain points x 2 rational z: True" in r.numbers for r in rows)


def test_a_controller_sub_table_must_hold_exactly_its_structures_keys(tmp_path, assert_refused):
    text = (ROOT / "model" / "qdd_leg.toml").read_text()
    bad = tmp_path / "in" / "bad.toml"
    bad.parent.mkdir()
    bad.write_text(text.replace("[controller.paper]", "[controller.torque_pi]"))
    assert_refused(["regions", "--params", str(bad), "--out", "m.npz"],
                   ("[controller.torque_pi]", "alpha"))
    bad.write_text(text.replace("[controller.paper]", "[controller.impedance_current]"))
    assert_refused(["regions", "--params", str(bad), "--out", "m.npz"],
                   "[controller.impedance_current]: the file's own structure")


@pytest.mark.parametrize("structure", ["paper", "torque_pi", "torque_pi_ff"])
def test_describing_functions_controller_is_the_flows(structure):
    """The describing function's linear part reads the controller as V = -(K_T T + K_theta theta);
    with each structure that is the controller of the one flow (statespace.controller_batch)."""
    from haa_sym.analysis.describing import _controller
    from haa_sym.loop.statespace import CONTROLLER_INPUTS, controller_batch
    loop = ClosedLoop(_params("hyq_haa", structure), basis=False)
    w = np.geomspace(1.0, 3000.0, 25)
    K_T, K_th = _controller(loop, 300.0, 4.0, w)
    A, B, C, D = (m[0] for m in controller_batch(loop, 300.0, 4.0))
    z = np.exp(1j * w * loop.params.controller.Ts)
    X = np.linalg.solve(z[:, None, None] * np.eye(A.shape[0]) - A, np.broadcast_to(B, (w.size,) + B.shape))
    H = np.einsum("j,wjk->wk", C[0], X) + D[0]                    # V from each controller input
    np.testing.assert_allclose(-H[:, CONTROLLER_INPUTS.index("T_meas")], K_T, rtol=1e-10)
    np.testing.assert_allclose(-H[:, CONTROLLER_INPUTS.index("theta_encoder")], K_th, rtol=1e-10)
