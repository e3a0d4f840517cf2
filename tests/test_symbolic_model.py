"""An actuator defined in code as a sympy model (issue 8, Python API): haa_sym.symbolic.model.

A model written by hand (HyQ's Eq. 1 as xdot expressions, linearised; a two-mass joint as
matrices with its own parameter names) gives the plant matrices and the stability map of the
equivalent Topology; each bad model is one ParameterError naming the field; a model is compiled
once into the cache and reused; its ClosedLoop agrees with the reference eigenvalues."""
import re

import numpy as np
import pytest
import sympy as sp

from haa_sym import (ClosedLoop, Controller, LoopOptions, ParameterError, Params, load_params, passivity,
                     region_map)
from haa_sym.model.actuator import HYQ, Body, Coupling, Topology
from haa_sym.loop.plant import continuous_plant
from haa_sym.symbolic.chain import symbolic_model
from haa_sym.symbolic.model import LinearActuatorModel, Parameter

from conftest import ROOT, decisions_against_reference

# --- HyQ's Eq. (1)-(2) written by hand as equations of motion -------------------------------
HYQ_PARAMETERS = {
    "L": (">0", "H"), "R": (">0", "Ohm"), "k_t": (">0", "Nm/A"), "k_w": (">=0", "V s/rad"),
    "J_m": (">0", "kg m^2"), "B_m": (">=0", "Nm s/rad"), "N": (">0", "-"),
    "J_L1": (">0", "kg m^2"), "B_L1": (">=0", "Nm s/rad"),
    "J_L2": (">0", "kg m^2"), "B_L2": (">=0", "Nm s/rad"), "K_L2": (">=0", "Nm/rad"),
    "K_hd": (">0", "Nm/rad"), "D_hd": (">=0", "Nm s/rad"), "K_p": (">0", "Nm/rad"), "D_p": (">=0", "Nm s/rad"),
}


def hyq_by_hand(**changes) -> LinearActuatorModel:
    (L, R, k_t, k_w, J_m, B_m, N, J_L1, B_L1, J_L2, B_L2, K_L2, K_hd, D_hd, K_p, D_p) = sp.symbols(
        list(HYQ_PARAMETERS))
    I, th_m, w_m, th_1, w_1, th_2, w_2 = x = sp.symbols("I_m theta_m dtheta_m theta_L1 dtheta_L1 theta_L2 dtheta_L2")
    u = V_m, T_fr, T_dist = sp.symbols("V_m T_fr T_dist")
    T_hd = K_hd * (th_m / N - th_1) + D_hd * (w_m / N - w_1)          # Eq. (2)
    T_p = K_p * (th_1 - th_2) + D_p * (w_1 - w_2)
    # gravity on the leg, K_L2 sin(theta_L2): linearised at theta_L2 = 0 it is Table 1's K_L2 theta_L2
    xdot = [(V_m - R * I - k_w * w_m) / L, w_m, (k_t * I - B_m * w_m - T_hd / N + T_fr) / J_m,
            w_1, (T_hd - T_p - B_L1 * w_1) / J_L1,
            w_2, (T_p - B_L2 * w_2 - K_L2 * sp.sin(th_2) + T_dist) / J_L2]
    y = {"T_sensor": T_hd, "T_sensor_spring": K_hd * (th_m / N - th_1), "theta_encoder": th_1,
         "dtheta_L1": w_1, "dtheta_L2": w_2}
    kw = dict(name="HyQ by hand", states=x, inputs=u, xdot=xdot, outputs=y, parameters=HYQ_PARAMETERS,
              VC0=N / k_t * (R * B_m + k_t * k_w), port="L2")
    kw.update(changes)
    return LinearActuatorModel.from_equations(**kw)


def test_hyq_by_hand_gives_the_topology_plant_and_map(params, cache):
    model = hyq_by_hand()
    assert model.fingerprint != symbolic_model(HYQ).fingerprint           # other expressions, other code
    mine = Params.from_model(model, params.plant.as_dict(), params.controller)
    a, b = continuous_plant(mine.plant), continuous_plant(params.plant)
    assert (a.state_names, a.input_names, a.output_names) == (b.state_names, b.input_names, b.output_names)
    for x, y in ((a.A, b.A), (a.B, b.B), (a.C, b.C)):
        assert np.allclose(x, y, rtol=1e-14, atol=0), np.abs(x - y).max()
    assert a.VC0 == b.VC0
    P, D = np.logspace(0, 4, 30), np.linspace(0, 40, 20)
    m1, m2 = region_map(ClosedLoop(mine), P, D, method="grid"), region_map(ClosedLoop(params), P, D, method="grid")
    assert m1.stable.any() and not m1.stable.all()
    np.testing.assert_array_equal(m1.stable, m2.stable)
    pm1, pm2 = m1.phase_margin_deg[m2.stable], m2.phase_margin_deg[m2.stable]
    assert np.isfinite(pm2).any()
    np.testing.assert_allclose(pm1, pm2, rtol=1e-9, atol=1e-9)
    # the chain topology's own model is a LinearActuatorModel too, with the generated code's name
    assert isinstance(symbolic_model(HYQ), LinearActuatorModel) and symbolic_model(HYQ).parameter_keys == HYQ.parameter_keys


# --- a two-mass joint as matrices, with its own parameter names -----------------------------
TWO_MASS = {"La": (">0", "H"), "Ra": (">0", "Ohm"), "Kt": (">0", "Nm/A"), "Ke": (">=0", "V s/rad"),
            "Jr": (">0", "kg m^2"), "Br": (">=0", "Nm s/rad"), "n": (">0", "-"),
            "Jl": (">0", "kg m^2"), "Bl": (">=0", "Nm s/rad"), "Kg": (">0", "Nm/rad"), "Dg": (">=0", "Nm s/rad")}
# the same joint as a chain: rotor, gearbox g, link l (sensor on g, encoder and port on l)
TWO_MASS_TOPOLOGY = Topology(bodies=(Body("l"),), couplings=(Coupling("g", "rotor", "l"),), sensor="g",
                             torque_damping=True, encoder="l", port="l")
TO_TOPOLOGY = {"La": "L", "Ra": "R", "Kt": "k_t", "Ke": "k_w", "Jr": "J_m", "Br": "B_m", "n": "N",
               "Jl": "J_l", "Bl": "B_l", "Kg": "K_g", "Dg": "D_g"}
TWO_MASS_VALUES = {"La": 1e-3, "Ra": 0.8, "Kt": 0.12, "Ke": 0.12, "Jr": 3e-5, "Br": 2e-4, "n": 80.0,
                   "Jl": 0.05, "Bl": 0.05, "Kg": 6000.0, "Dg": 4.0}
CONTROLLER = {"Ts": 1e-3, "N_av": 4, "alpha": 0.9, "beta": 1.0, "P_t0": 0.3, "I_t0": 12.0}


def two_mass(**changes) -> dict:
    La, Ra, Kt, Ke, Jr, Br, n, Jl, Bl, Kg, Dg = (sp.Symbol(k) for k in TWO_MASS)
    # x = [I, theta_r, dtheta_r, theta_l, dtheta_l]; gearbox torque T = Kg (theta_r/n - theta_l) + Dg (...)
    A = sp.Matrix([[-Ra / La, 0, -Ke / La, 0, 0],
                   [0, 0, 1, 0, 0],
                   [Kt / Jr, -Kg / (n**2 * Jr), -(Br + Dg / n**2) / Jr, Kg / (n * Jr), Dg / (n * Jr)],
                   [0, 0, 0, 0, 1],
                   [0, Kg / (n * Jl), Dg / (n * Jl), -Kg / Jl, -(Bl + Dg) / Jl]])
    B = sp.Matrix([[1 / La, 0, 0], [0, 0, 0], [0, 1 / Jr, 0], [0, 0, 0], [0, 0, 1 / Jl]])
    C = sp.Matrix([[0, Kg / n, Dg / n, -Kg, -Dg],
                   [0, Kg / n, 0, -Kg, 0],
                   [0, 0, 0, 1, 0],
                   [0, 0, 0, 0, 1]])
    kw = dict(name="two-mass joint", states=("I_m", "theta_m", "dtheta_m", "theta_l", "dtheta_l"),
              inputs=("V_m", "T_fr", "T_dist"), outputs=("T_sensor", "T_sensor_spring", "theta_encoder", "dtheta_l"),
              parameters=[Parameter(k, d, u) for k, (d, u) in TWO_MASS.items()], A=A, B=B, C=C,
              VC0=n / Kt * (Ra * Br + Kt * Ke), port="l")
    kw.update(changes)
    return kw


@pytest.fixture(scope="module")
def two_mass_params(cache):
    return Params.from_model(LinearActuatorModel(**two_mass()), TWO_MASS_VALUES, CONTROLLER)


def test_two_mass_model_equals_its_topology(two_mass_params):
    chain = Params.from_model(TWO_MASS_TOPOLOGY, {TO_TOPOLOGY[k]: v for k, v in TWO_MASS_VALUES.items()},
                              Controller(**CONTROLLER))
    a, b = continuous_plant(two_mass_params.plant), continuous_plant(chain.plant)
    for x, y in ((a.A, b.A), (a.B, b.B), (a.C, b.C)):
        scale = np.abs(y).max(axis=1, keepdims=True)
        assert (np.abs(x - y) <= 1e-14 * np.where(scale > 0, scale, 1)).all()
    assert abs(a.VC0 - b.VC0) <= 1e-15 * b.VC0
    P, D = np.logspace(0, 4, 25), np.linspace(0, 30, 15)
    m1, m2 = region_map(ClosedLoop(two_mass_params), P, D), region_map(ClosedLoop(chain), P, D)
    assert m1.stable.any() and not m1.stable.all()
    np.testing.assert_array_equal(m1.stable, m2.stable)


def test_two_mass_closed_loop_agrees_with_reference(two_mass_params):
    """A few hundred random gain points: the generated decision == reference eigenvalues (the
    reference reads the model's declared VC0; its plant is sampled by scipy, its loop assembled
    by its own algebra)."""
    rng = np.random.default_rng(82)
    n_points, disagree, n_stable = 0, 0, 0
    for Ts, N_av, delay, filt in ((1e-3, 4, 0, "both"), (5e-4, 8, 1, "impedance")):
        p = two_mass_params.with_values(Ts=Ts, N_av=N_av)
        loop = ClosedLoop(p, LoopOptions(delay=delay, filter=filt))
        k = 150
        pts = np.stack([10 ** rng.uniform(0, 4.3, k), rng.uniform(0, 50, k), rng.uniform(0.5, 4, k),
                        rng.uniform(0, 1.2, k)])
        c = decisions_against_reference(loop, pts)
        disagree += c["disagree"]
        n_stable += c["stable"]
        n_points += k
    assert n_points == 300 and disagree == 0, disagree
    assert 0.05 < n_stable / n_points < 0.95, n_stable


def test_every_analysis_runs_on_a_model(two_mass_params):
    from haa_sym.check import verify
    from haa_sym.analysis.torque import step_response, torque_loop_margins
    pa = passivity(ClosedLoop(two_mass_params), np.array([100.0, 300.0]), np.array([2.0, 5.0]))
    assert pa.stable.shape == (2,)
    assert np.isfinite(torque_loop_margins(ClosedLoop(two_mass_params)).pm_deg)
    st = step_response(ClosedLoop(two_mass_params), duration=0.05)
    assert np.isfinite(st.T).all() and st.T.shape == st.t.shape
    rows = verify.run(two_mass_params)
    assert all(r.ok for r in rows), [(r.claim, r.numbers) for r in rows]
    d = two_mass_params.to_dict()
    assert d["topology"]["parameters"]["Kg"] == {"domain": ">0", "unit": "Nm/rad"}


# --- compiled once into the cache, reused ---------------------------------------------------
def test_compiled_once_and_reused(tmp_path, capsys, monkeypatch):
    from haa_sym.compiled import plant_code
    from haa_sym.io.progress import set_progress
    import haa_sym.symbolic.symbolic_to_casadi as s2c
    cache = tmp_path / "cache"
    monkeypatch.setenv("HAA_SYM_CACHE", str(cache))
    set_progress(True)
    model = LinearActuatorModel(**two_mass(name="cached joint"))
    code = plant_code.compile_actuator(model)
    first = capsys.readouterr().err
    assert "compiling the plant of <model cached joint> (model " in first
    assert code.c_file.is_relative_to(cache) and code.c_file.name == f"{model.function_name}.c"
    assert code.backend == "vm" or code.library.is_relative_to(cache)
    stamp = code.c_file.stat().st_mtime_ns

    def refuse(*a, **k):
        raise AssertionError("regenerated")
    monkeypatch.setattr(s2c, "plant_function", refuse)
    again = plant_code.compile_actuator(LinearActuatorModel(**two_mass(name="another name")))
    assert capsys.readouterr().err == ""                    # same content: same key, no message
    assert again.c_file == code.c_file and code.c_file.stat().st_mtime_ns == stamp
    assert again.library == code.library
    f = again.function()
    v = Params.from_model(model, TWO_MASS_VALUES, CONTROLLER).plant.as_tuple()
    A = np.array(f(np.array(v))[0])
    assert A.shape == (5, 5) and np.isfinite(A).all()


def test_content_defines_the_fingerprint():
    a = LinearActuatorModel(**two_mass())
    assert a == LinearActuatorModel(**two_mass(name="renamed"))     # the name is for messages only
    assert a.fingerprint == LinearActuatorModel(**two_mass(source="x")).fingerprint
    # assumptions on a user's symbols do not matter: every parameter becomes its domain's symbol
    Kg = sp.Symbol("Kg", positive=True)
    kw = two_mass()
    b = LinearActuatorModel(**{**kw, "A": kw["A"].subs(sp.Symbol("Kg"), Kg)})
    assert b.fingerprint == a.fingerprint
    c = LinearActuatorModel(**{**kw, "VC0": 2 * kw["VC0"]})
    assert c.fingerprint != a.fingerprint and c.function_name != a.function_name
    assert a != LinearActuatorModel(**two_mass(port="l", torque_damping=False))


# --- bad models: one ParameterError each, naming the field ----------------------------------
def _kw(**changes):
    return two_mass(**changes)


Kg, n = sp.Symbol("Kg"), sp.Symbol("n")
BAD = {
    "missing role output": (lambda: _kw(outputs=("T_sensor", "theta_encoder", "dtheta_l", "x"),
                                        C=sp.zeros(4, 5)),
                            r"outputs: missing role output\(s\) \['T_sensor_spring'\]"),
    "undeclared symbol": (lambda: _kw(VC0=n / sp.Symbol("Kt") * sp.Symbol("Rx")),
                          r"VC0: .* contains undeclared symbol\(s\) \['Rx'\]; allowed: the declared parameters"),
    "float constant": (lambda: _kw(A=two_mass()["A"].subs(Kg, 0.5 * Kg)),
                       r"A\[2, 1\]: .* contains the float -?0\.5\d*; allowed: exact rationals"),
    "float in VC0": (lambda: _kw(VC0=1.5), r"VC0: .* contains the float 1\.5\d*"),
    "wrong shape B": (lambda: _kw(B=sp.zeros(5, 2)), r"B: shape \(5, 2\); allowed: \(5, 3\)"),
    "wrong shape C": (lambda: _kw(C=sp.zeros(3, 5)), r"C: shape \(3, 5\); allowed: \(4, 5\)"),
    "bad domain": (lambda: _kw(parameters=[Parameter(k, "<0" if k == "Bl" else d, u) for k, (d, u) in TWO_MASS.items()]),
                   r"parameters\['Bl'\]\.domain: '<0'; allowed: \['>0', '>=0'\]"),
    "missing unit": (lambda: _kw(parameters={**TWO_MASS, "Bl": (">=0", "")}),
                     r"parameters\['Bl'\]\.unit: ''; allowed: the SI unit"),
    "wrong inputs": (lambda: _kw(inputs=("V_m", "T_dist", "T_fr")),
                     r"inputs: \('V_m', 'T_dist', 'T_fr'\); allowed: exactly \('V_m', 'T_fr', 'T_dist'\)"),
    "state in a matrix": (lambda: _kw(A=two_mass()["A"].subs(Kg, Kg * sp.Symbol("theta_l"))),
                          r"A\[2, 1\]: .* contains the signal\(s\) \['theta_l'\]; allowed: expressions of "
                          r"the parameters alone"),
    "not rational": (lambda: _kw(A=two_mass()["A"].subs(Kg, sp.sqrt(Kg))),
                     r"A\[2, 1\]: .* contains sqrt\(Kg\) \(Pow\); allowed: exact rationals"),
    "port without velocity": (lambda: _kw(port="r"),
                              r"port: 'r' has no velocity output 'dtheta_r'; allowed: one of \['l'\]"),
    "reserved name": (lambda: _kw(parameters={**TWO_MASS, "Ts": (">0", "s")}),
                      r"parameters\['Ts'\]: the name 'Ts' is reserved"),
    "duplicate state": (lambda: _kw(states=("I_m", "theta_m", "theta_m", "theta_l", "dtheta_l")),
                        r"states: 'theta_m' appears twice"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_model_is_one_clear_error(case):
    make, msg = BAD[case]
    with pytest.raises(ParameterError) as exc:
        LinearActuatorModel(**make())
    text = str(exc.value)
    assert text.startswith("LinearActuatorModel 'two-mass joint': ") and "\n" not in text, text
    assert re.search(msg, text), text


def test_bad_linearisation_and_values(params):
    th = sp.Symbol("theta_L1")
    with pytest.raises(ParameterError, match=r"outputs: output\(s\) \['theta_encoder'\] depend on the "
                                             r"inputs directly \(D != 0\)"):
        hyq_by_hand(outputs={"T_sensor": th, "T_sensor_spring": th, "theta_encoder": th + sp.Symbol("V_m"),
                             "dtheta_L1": th, "dtheta_L2": th})
    with pytest.raises(ParameterError, match=r"xdot: 6 expressions for 7 states"):
        hyq_by_hand(xdot=[0] * 6)
    # linearised at another point: K_L2 sin(theta_L2) at theta_L2 = pi/4 has cos(pi/4), irrational
    with pytest.raises(ParameterError, match=r"A\[6, 5\]: .* contains sqrt\(2\) \(Pow\); allowed: exact rationals"):
        hyq_by_hand(operating_point={"theta_L2": sp.pi / 4})
    with pytest.raises(ParameterError, match=r"operating_point: 'q' is not a state or input"):
        hyq_by_hand(operating_point={"q": 0})
    model = LinearActuatorModel(**two_mass())
    with pytest.raises(ParameterError, match=r"<model two-mass joint> values: Jl = -1\.0 is out of range; "
                                             r"allowed: a finite number > 0"):
        Params.from_model(model, {**TWO_MASS_VALUES, "Jl": -1.0}, CONTROLLER)
    with pytest.raises(ParameterError, match=r"<model two-mass joint> values: missing key\(s\) \['Dg'\]"):
        Params.from_model(model, {k: v for k, v in TWO_MASS_VALUES.items() if k != "Dg"}, CONTROLLER)
    with pytest.raises(ParameterError, match=r"<model two-mass joint> controller: missing key\(s\) \['Ts'\]"):
        Params.from_model(model, TWO_MASS_VALUES, {k: v for k, v in CONTROLLER.items() if k != "Ts"})
    with pytest.raises(ParameterError, match=r"model = 3; allowed: a haa_sym.symbolic.model.LinearActuatorModel"):
        Params.from_model(3, TWO_MASS_VALUES, CONTROLLER)


def test_load_params_unchanged(params):
    assert params.plant.topology == HYQ and load_params().plant == params.plant


def test_docs_example_runs(tmp_path, monkeypatch):
    """docs/model.md, "An actuator in code": the example runs and prints what it shows."""
    import doctest
    monkeypatch.setenv("HAA_SYM_CACHE", str(tmp_path / "cache"))
    text = (ROOT / "docs" / "model.md").read_text()
    start = text.index("## An actuator in code")
    section = text[start:text.index("\n## ", start + 1)]
    test = doctest.DocTestParser().get_doctest(section, {}, "docs/model.md: An actuator in code",
                                               str(ROOT / "docs" / "model.md"), 0)
    assert len(test.examples) >= 10
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    runner.run(test)
    assert runner.summarize(verbose=False).failed == 0


def test_contact_needs_the_port_stiffness(two_mass_params):
    from haa_sym.analysis.contact import contact_stability
    with pytest.raises(ParameterError, match=r"<model two-mass joint>: the model has no parameter K_l \(the "
                                             r"port's stiffness to ground"):
        contact_stability(ClosedLoop(two_mass_params), [100.0])
