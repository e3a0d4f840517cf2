"""Actuators as data (issue 8): every built-in actuator file and a user's own chain load,
compile, give maps and pass verify's generic rows; the plant equals an independent numpy
assembly; the closed loop agrees with the explicit reference on >= 1,000 random points per new
topology; every bad input of the format is one ParameterError; the legacy [plant] file is HyQ."""
import itertools
import re

import numpy as np
import pytest

from haa_sym import ClosedLoop, LoopOptions, ParameterError, load_params, region_map
from haa_sym.check import reference as ref
from haa_sym.model.structures import NEUTRAL, STRUCTURES
from haa_sym.model.actuator import HYQ, ROTOR
from haa_sym.model.params import builtin_actuators
from haa_sym.loop.plant import continuous_plant

from conftest import ROOT, decisions_against_reference

USER = """\
[about]
name = "three-body test chain"
description = "rotor, gearbox g, A, spring s1, B, spring s2, C (with gravity)"
[about.references]
mine = "A test chain of the haa_sym test suite"

[motor]
L   = { value = 1e-3,  unit = "H",      source = "mine", description = "coil" }
R   = 1.0
k_t = 0.1
k_w = 0.1
J_m = 2e-5
B_m = 1e-4
N   = 50

[bodies.A]
J = 1e-3
B = 0.01
[bodies.B]
J = 0.05
B = 0.1
[bodies.C]
J = { value = 0.2, unit = "kg m^2", source = "C", description = "link" }
B = 0.3
K = 5.0

[couplings.g]
between = ["rotor", "A"]
K = 5000.0
D = 5.0
[couplings.s1]
between = ["A", "B"]
K = 2000.0
D = 2.0
[couplings.s2]
between = ["C", "B"]
K = 800.0
D = 1.0

[sensors]
torque = "s1"
torque_damping = false
encoder = "A"
port = "C"

[controller]
Ts = 1e-3
N_av = 4
alpha = 0.9
beta = 1.0
P_t0 = 0.3
I_t0 = 10.0

[configurations.heavy]
J_C = 0.6
"""

BUILTIN = builtin_actuators()
NEW = [p for p in BUILTIN if p.name != "hyq_haa.toml"]


@pytest.fixture(scope="module")
def user_file(tmp_path_factory, cache):
    path = tmp_path_factory.mktemp("user") / "three.toml"
    path.write_text(USER)
    return path


def all_files(user_file):
    return BUILTIN + [user_file]


def _options(params):
    return LoopOptions(port=f"dtheta_{params.plant.topology.port}")


def test_builtin_files_present():
    names = {p.name for p in BUILTIN}
    assert "hyq_haa.toml" in names and len(BUILTIN) >= 3, names


# --- the plant against an independent assembly ----------------------------------------------
def numpy_plant(plant):
    """A, B, C from mass, damping and stiffness matrices of the topology (no sympy, no CasADi).

    Mechanical coordinates q = [theta_m, theta_X...]; a coupling c between a and b has
    e_c . q = theta_a - theta_b (theta_rotor = theta_m / N) and adds K_c e_c e_c^T, D_c e_c e_c^T.
    """
    top, v = plant.topology, plant.as_dict()
    names = ["m"] + list(top.body_names)
    n = len(names)
    M = np.diag([v["J_m"]] + [v[f"J_{b}"] for b in top.body_names])
    Dm = np.diag([v["B_m"]] + [v[f"B_{b}"] for b in top.body_names])
    Km = np.diag([0.0] + [v.get(f"K_{b.name}", 0.0) if b.ground else 0.0 for b in top.bodies])
    E = {}
    for c in top.couplings:
        e = np.zeros(n)
        for end, sign in ((c.a, 1.0), (c.b, -1.0)):
            if end == ROTOR:
                e[0] += sign / v["N"]
            else:
                e[names.index(end)] += sign
        E[c.name] = e
        Km += v[f"K_{c.name}"] * np.outer(e, e)
        Dm += v[f"D_{c.name}"] * np.outer(e, e)
    Minv = np.linalg.inv(M)
    nx = 1 + 2 * n
    A = np.zeros((nx, nx))
    pos = [1 + 2 * i for i in range(n)]
    vel = [2 + 2 * i for i in range(n)]
    A[0, 0], A[0, vel[0]] = -v["R"] / v["L"], -v["k_w"] / v["L"]
    for i in range(n):
        A[pos[i], vel[i]] = 1.0
    A[np.ix_(vel, pos)] = -Minv @ Km
    A[np.ix_(vel, vel)] = -Minv @ Dm
    A[vel[0], 0] = v["k_t"] / v["J_m"]
    B = np.zeros((nx, 3))
    B[0, 0] = 1 / v["L"]
    B[vel[0], 1] = 1 / v["J_m"]
    if top.port == ROTOR:                   # a rotor-only actuator: T_dist on the rotor through 1/N
        B[vel[0], 2] = 1 / (v["N"] * v["J_m"])
    else:
        B[vel[names.index(top.port)], 2] = 1 / v[f"J_{top.port}"]
    C = np.zeros((3 + len(top.bodies) + (top.port == ROTOR), nx))
    if top.sensor == "current":             # the torque estimated from the current: k_t N I_m
        C[0, 0] = C[1, 0] = v["k_t"] * v["N"]
    else:
        e = E[top.sensor]
        C[0, pos], C[0, vel] = v[f"K_{top.sensor}"] * e, v[f"D_{top.sensor}"] * e
        C[1, pos] = v[f"K_{top.sensor}"] * e
    if top.encoder == ROTOR:                # a motor-side encoder: theta_m / N
        C[2, pos[0]] = 1.0 / v["N"]
    else:
        C[2, pos[names.index(top.encoder)]] = 1.0
    for i in range(len(top.bodies)):
        C[3 + i, vel[1 + i]] = 1.0
    if top.port == ROTOR:                   # its port velocity, referred to the output
        C[-1, vel[0]] = 1.0 / v["N"]
    return A, B, C


def test_plant_equals_independent_assembly(user_file):
    rng = np.random.default_rng(8)
    worst = 0.0
    for path in all_files(user_file):
        params = load_params(path)
        for _ in range(5):
            changes = {k: v * 10 ** rng.uniform(-0.5, 0.5) for k, v in params.plant.as_dict().items()}
            plant = params.plant.replace(**changes)
            cp = continuous_plant(plant)
            assert cp.state_names == plant.topology.state_names and cp.output_names == plant.topology.output_names
            for got, want in zip((cp.A, cp.B, cp.C), numpy_plant(plant)):
                assert got.shape == want.shape
                scale = np.abs(want).max(axis=1, keepdims=True)        # per row: no cancellation issue
                err = np.abs(got - want) / np.where(scale > 0, scale, 1.0)
                worst = max(worst, float(err.max()))
            vc0 = plant.N / plant.k_t * (plant.R * plant.B_m + plant.k_t * plant.k_w)
            assert abs(cp.VC0 - vc0) <= 1e-14 * vc0
    assert worst < 1e-12, worst


# --- every actuator: compile, map, verify --------------------------------------------------
@pytest.mark.slow                     # verify's rows for four actuators (~4 s)
def test_every_actuator_gives_a_map_and_passes_verify(user_file, capsys):
    from haa_sym.check import verify
    for path in all_files(user_file):
        params = load_params(path)
        # the virtual wall renders a few Nm/rad (colgate1997: K < 2 (b - B) / Ts)
        P, D = ((np.logspace(-1, 1.3, 12), np.linspace(0.0, 0.01, 8)) if path.name == "haptic_wall.toml"
                else (np.logspace(0, 3.3, 12), np.linspace(0.5, 30, 8)))
        m = region_map(ClosedLoop(params, _options(params)), P, D)
        assert m.stable.shape == (12, 8) and m.stable.any(), path.name
        rows = verify.generic_rows(params)
        bad = [r for r in rows if r.applies and not r.ok]
        assert not bad, (path.name, [(r.claim, r.numbers) for r in bad])
        na = [r for r in rows if not r.applies]
        applies, why = __import__("haa_sym.symbolic.chain", fromlist=["x"]).exact_vc_condition(
            params.plant.topology)
        assert len(na) == (0 if applies else 1)
        assert all(r.numbers.startswith("does not apply: ") for r in na)


def test_user_file_compiled_into_cache_and_cli(user_file, cache, capsys):
    from haa_sym.cli import main
    assert main(["compile", str(user_file)]) == 0
    out = capsys.readouterr().out
    assert "compiled: " + str(cache) in out
    assert main(["stability", "--params", str(user_file), "--P-gain", "200", "--D-gain", "5",
                 "--option", "port=dtheta_C"]) == 0
    assert "stable:" in capsys.readouterr().out
    assert main(["compile", str(ROOT / "model" / "hyq_haa.toml")]) == 0
    assert "is built in" in capsys.readouterr().out


def test_port_option_is_checked_against_the_plant(user_file):
    # by default the port is the body T_dist acts on (the file's [sensors] port)
    assert ClosedLoop(load_params(user_file), basis=False).options.structure.port == "dtheta_C"
    with pytest.raises(ParameterError, match=r"port = 'dtheta_L2' is not a velocity of the actuator "
                                             r".*three.toml; allowed: \['dtheta_A', 'dtheta_B', "
                                             r"'dtheta_C', 'encoder_average'\]"):
        ClosedLoop(load_params(user_file), LoopOptions(port="dtheta_L2"))


# --- closed loop against the explicit reference, >= 1,000 points per new topology -----------
# (Ts, N_av, delay, velocity estimate): the filter choices of haa_sym.model.elements on the new plants too
CASES = ((1e-3, 4, 0, {}), (5e-4, 10, 1, {"velocity_filter": "lowpass1", "f_c": 60.0}),
         (2e-3, 1, 0, {}), (1e-3, 20, 1, {"velocity_filter": "butterworth2", "f_c": 40.0}))


def _resolvent_condition(loop, omega, point, key) -> np.ndarray:
    """cond(e^{j omega Ts} I - A) of the reference's closed loop that ``key`` is read from."""
    cut = {"Z": None, "L_imp": "T_ref", "H_T": "T_ref", "L_t": "PI"}[key]
    A = ref.closed_loop_matrices(loop, *point, cut=cut)[0]
    z = np.exp(1j * omega * loop.params.controller.Ts)
    return np.linalg.cond(z[:, None, None] * np.eye(A.shape[0]) - A)


# The impedance gains drawn per actuator (P_gain up to, Nm/rad; D_gain up to, Nms/rad): the
# Mini Cheetah leg (qdd_leg.toml, 7e-3 kg m^2 at the joint) is unstable on 95 % of the box of
# the 0.3-1 kg m^2 joints, so its box is scaled down to keep both branches exercised.
GAIN_BOX = {"qdd_leg.toml": (300.0, 1.0), "haptic_wall.toml": (20.0, 0.05)}
# The SEA's first torque PI, with which the accuracies below were measured. With the PI of
# haa-sym tune (P_t0 0.0383, I_t0 0.101) one point (P 17632, D 42.1, beta 1.96, alpha 0.81, Ts 1 ms,
# N_av 4) has Z at 0.1 rad/s 1.30e-8 apart from the reference, 6 % above eps cond(zI - A) =
# 1.22e-8; an mpmath solve of the reference's own matrices is 1.7e-6 from both, so the bound is a
# heuristic there, not a certificate (issue 17 part 4, reported, not widened).
FIRST_PI = {"sea.toml": {"P_t0": 0.01954, "I_t0": 0.01954}}


@pytest.mark.parametrize("name", [p.name for p in NEW] + ["user"])
def test_closed_loop_agrees_with_reference(name, user_file):
    path = user_file if name == "user" else ROOT / "model" / name
    params = load_params(path).with_values(**FIRST_PI.get(name, {}))
    rng = np.random.default_rng(len(name))
    n_points, disagree, refined, near, n_stable = 0, 0, 0, 0, 0
    fr_worst = 0.0
    for (Ts, N_av, delay, estimate), filt in zip(CASES, itertools.cycle(("both", "impedance", "compensation"))):
        p = params.with_values(Ts=Ts, N_av=N_av, **estimate)
        loop = ClosedLoop(p, LoopOptions(delay=delay, filter=filt, port=f"dtheta_{p.plant.topology.port}"))
        k = 260
        P_max, D_max = GAIN_BOX.get(name, (20000.0, 50.0))
        pts = np.stack([10 ** rng.uniform(0, np.log10(P_max), k), rng.uniform(0, D_max, k),
                        rng.uniform(0.5, 4, k), rng.uniform(0, 1.2, k)])
        st = STRUCTURES[p.controller.structure]       # a key the structure does not read: neutral
        for row, key in ((2, "beta"), (3, "alpha")):
            if key in st.unread:
                pts[row] = NEUTRAL[key]
        c = decisions_against_reference(loop, pts)
        disagree += c["disagree"]
        n_stable += c["stable"]
        near += c["near"]
        refined += c["refined"]
        n_points += k
        w = np.logspace(-1, np.log10(np.pi / Ts * 0.999), 20)
        fr = loop.frequency_response(w, *pts[:, :3])
        for i in range(3):
            which = ("L_t", "L_imp", "H_T", "Z") if st.torque_loop else ("L_imp", "Z")
            for key, val in ref.frequency_response(loop, w, *pts[:, i], which=which).items():
                if key not in which:
                    continue
                err = np.abs(fr[key][i] - val)
                # pointwise as test_evaluators; the summary is relative to the curve's scale:
                # near Nyquist L_imp of the SEA falls to ~1e-12 with errors of ~1e-18 (cancellation).
                # Where the resolvent is ill-conditioned (the SEA's Z at 0.1 rad/s: cond(zI - A)
                # ~ 3e8) both computations carry eps * cond relative error: bound by that.
                kappa = _resolvent_condition(loop, w, pts[:, i], key)
                assert ((err <= 1e-8 * np.abs(val)) | (err <= 1e-12)
                        | (err <= np.finfo(float).eps * kappa * np.abs(val))).all(), (name, key, pts[:, i])
                scale = np.abs(val).max() * max(1e-8, np.finfo(float).eps * kappa.max())
                fr_worst = max(fr_worst, float(err.max() / scale))
    assert n_points >= 1000
    assert disagree == 0, (name, disagree, n_points)
    assert near < n_points // 20, near
    assert 0.05 < n_stable / n_points < 0.95, n_stable      # both branches exercised
    # the project's accuracy of the frequency responses (test_evaluators): 1e-8; measured against
    # the independent reference (its own ZOH and interconnection): 5.7e-9 for the SEA (Z at
    # 0.1 rad/s, where z = e^{j w Ts} is within 1e-4 of 1; its first PI, FIRST_PI), 4e-11 harmonic
    # drive (4.2e-11 with its first PI, 4.1e-11 with the tuned one: the worst error relative to
    # each curve's largest |value|), 2e-12 HyQ
    assert fr_worst < 1.0, fr_worst       # relative to the curve's scale and conditioning


# --- HyQ: the new file and the legacy flat [plant] file are the same model --------------------
def test_hyq_new_and_legacy_files_are_identical(params):
    legacy = load_params(ROOT / "tests" / "data" / "hyq_haa_legacy.toml")
    assert params.plant.topology == HYQ and legacy.plant.topology == HYQ
    assert params.plant == legacy.plant and params.controller == legacy.controller
    assert params.configurations == legacy.configurations
    a, b = continuous_plant(params.plant), continuous_plant(legacy.plant)
    for x, y in ((a.A, b.A), (a.B, b.B), (a.C, b.C)):
        np.testing.assert_array_equal(x, y)
    P, D = np.logspace(0, np.log10(20000), 40), np.linspace(1, 50, 20)
    ma, mb = region_map(ClosedLoop(params), P, D), region_map(ClosedLoop(legacy), P, D)
    for k in ("stable", "low_pm", "passive"):
        np.testing.assert_array_equal(getattr(ma, k), getattr(mb, k))
    assert params.to_dict()["topology"]["fingerprint"] == HYQ.fingerprint


def test_plant_is_immutable_and_validated(params):
    with pytest.raises(AttributeError):
        params.plant.J_L2 = 1.0
    with pytest.raises(ParameterError, match=r"J_L2 = -1.0 is out of range"):
        params.plant.replace(J_L2=-1.0)
    assert params.plant.replace(J_L2=0.2).J_L2 == 0.2
    assert params.plant.as_tuple() == tuple(getattr(params.plant, k) for k in HYQ.parameter_keys)


def test_fingerprint_is_structure_only(user_file):
    a = load_params(user_file)
    b = load_params(user_file).configuration("heavy")
    assert a.plant.topology.fingerprint == b.plant.topology.fingerprint
    text = USER.replace('torque = "s1"', 'torque = "s2"')
    assert load_params_text(user_file.parent, text).plant.topology.fingerprint != a.plant.topology.fingerprint


def load_params_text(directory, text, name="act.toml"):
    p = directory / name
    p.write_text(text)
    return load_params(p)


def test_contact_adds_a_ground_stiffness_to_a_port_without_one(tmp_path, cache):
    # issue 16 item 8 (was refused): the plant variant with K_B = 0; tests/test_symbolic_chain_sensors.py checks
    # the scan against the reference's eigenvalues
    from haa_sym.analysis.contact import contact_params, contact_stability
    params = load_params_text(tmp_path, USER.replace('port = "C"', 'port = "B"'))
    variant, key, added = contact_params(params)
    assert (key, added) == ("K_B", True) and variant.plant.K_B == 0.0
    stable, rho = contact_stability(ClosedLoop(params, LoopOptions(port="dtheta_B")), [10.0, 100.0])
    assert stable.shape == rho.shape == (2,)


# --- bad input: one ParameterError naming file, section, key, value, allowed -----------------
BAD = [
    ("no bodies", lambda t: re.sub(r"\[bodies\.\w+\]\nJ = [^\n]*\nB = [^\n]*\n(K = [^\n]*\n)?", "", t)
     .replace("[couplings.s1]", "[couplings.x1]"),
     r"\[couplings.\w+\]: a file without \[bodies\] has no couplings \(the rotor is the only body\)"),
    ("no bodies with a torque sensor", lambda t: re.sub(r"\[(bodies|couplings)\.\w+\]\n(between = [^\n]*\n)?[JK] = [^\n]*\n[BD] = [^\n]*\n(K = [^\n]*\n)?", "", t),
     r"\[sensors\]: torque = 's1' in a file without \[bodies\] \(the rotor is the only body\); allowed: torque = 'current'"),
    ("unknown body in between", lambda t: t.replace('between = ["A", "B"]', 'between = ["A", "Q"]'),
     r"\[couplings.s1\]: between = \['A', 'Q'\] names unknown body 'Q'; allowed: \['rotor', 'A', 'B', 'C'\]"),
    ("disconnected chain", lambda t: t.replace('between = ["C", "B"]', 'between = ["C", "C2"]')
     .replace("[couplings.g]", "[bodies.C2]\nJ = 1.0\nB = 0.0\n\n[couplings.g]")
     .replace('between = ["A", "B"]', 'between = ["A", "C2"]'),
     r"\[bodies.B\]: body 'B' is not connected to the rotor through couplings \(disconnected chain\)"),
    ("no coupling on rotor", lambda t: t.replace('between = ["rotor", "A"]', 'between = ["B", "A"]'),
     r"\[couplings\]: 0 couplings touch 'rotor' \(none\); allowed: exactly one \(the gearbox\)"),
    ("two couplings on rotor", lambda t: t.replace('between = ["A", "B"]', 'between = ["rotor", "B"]'),
     r"\[couplings\]: 2 couplings touch 'rotor' \(\['g', 's1'\]\); allowed: exactly one"),
    ("self coupling", lambda t: t.replace('between = ["C", "B"]', 'between = ["C", "C"]'),
     r"\[couplings.s2\]: between = \['C', 'C'\] couples a body to itself"),
    ("sensor on missing coupling", lambda t: t.replace('torque = "s1"', 'torque = "s9"'),
     r"\[sensors\]: torque = 's9' is not a coupling; allowed: \['g', 's1', 's2'\]"),
    ("encoder on missing body", lambda t: t.replace('encoder = "A"', 'encoder = "Z"'),
     r"\[sensors\]: encoder = 'Z' is not a body; allowed: \['A', 'B', 'C'\]"),
    ("port on missing body", lambda t: t.replace('port = "C"', 'port = "L2"'),
     r"\[sensors\]: port = 'L2' is not a body; allowed: \['A', 'B', 'C'\]"),
    ("unknown section", lambda t: t + "\n[gearbox]\nK = 1\n",
     r"unknown table\(s\) \['gearbox'\]; allowed: \['about', 'motor', 'bodies', 'couplings', 'sensors'"),
    ("unknown body key", lambda t: t.replace("[bodies.A]\nJ = 1e-3", "[bodies.A]\nM = 3\nJ = 1e-3"),
     r"\[bodies.A\]: unknown key\(s\) \['M'\]; allowed: \['J', 'B', 'K'\]"),
    ("unknown motor key", lambda t: t.replace("N   = 50", "N   = 50\nJ_x = 1"),
     r"\[motor\]: unknown key\(s\) \['J_x'\]; allowed: \['L', 'R', 'k_t', 'k_w', 'J_m', 'B_m', 'N'\]"),
    ("missing motor key", lambda t: t.replace("k_w = 0.1\n", ""),
     r"\[motor\]: missing key\(s\) \['k_w'\]; every key of"),
    ("missing coupling key", lambda t: t.replace("K = 2000.0\n", ""),
     r"\[couplings.s1\]: missing key\(s\) \['K'\]"),
    ("missing sensors key", lambda t: t.replace('port = "C"\n', ""),
     r"\[sensors\]: missing key\(s\) \['port'\]"),
    ("J out of domain", lambda t: t.replace("J = 0.05", "J = 0.0"),
     r"\[bodies.B\]: J = 0.0 is out of range; allowed: a finite number > 0"),
    ("coupling K out of domain", lambda t: t.replace("K = 800.0", "K = 0.0"),
     r"\[couplings.s2\]: K = 0.0 is out of range; allowed: a finite number > 0"),
    ("ground K negative", lambda t: t.replace("K = 5.0", "K = -5.0"),
     r"\[bodies.C\]: K = -5.0 is out of range; allowed: a finite number >= 0"),
    ("damping negative", lambda t: t.replace("D = 2.0", "D = -2.0"),
     r"\[couplings.s1\]: D = -2.0 is out of range; allowed: a finite number >= 0"),
    ("motor value", lambda t: t.replace("R   = 1.0", "R   = nan"),
     r"\[motor\]: R = nan is not finite; allowed: a finite number > 0"),
    ("name collision", lambda t: t.replace("[bodies.C]", "[bodies.s1]").replace('port = "C"', 'port = "s1"')
     .replace('between = ["C", "B"]', 'between = ["s1", "B"]').replace("J_C", "J_s1"),
     r"\[couplings.s1\]: parameter name K_s1 collides with \[bodies.s1\]'s K_s1"),
    ("reserved name", lambda t: t.replace("[bodies.A]", "[bodies.rotor]"),
     r"\[bodies.rotor\]: name 'rotor' is not allowed; allowed: an identifier"),
    ("bad between", lambda t: t.replace('between = ["A", "B"]', 'between = "A"'),
     r"\[couplings.s1\]: between = 'A'; allowed: two body names \[a, b\]"),
    ("unknown source", lambda t: t.replace('source = "mine"', 'source = "yours"'),
     r"\[motor\]: L: source = 'yours'; allowed: \['D', 'I', 'C', '-', 'mine'\]"),
    ("torque_damping not bool", lambda t: t.replace("torque_damping = false", 'torque_damping = "no"'),
     r"\[sensors\]: torque_damping = 'no'; allowed: true or false"),
    ("configuration key", lambda t: t.replace("J_C = 0.6", "J_L2 = 0.6"),
     r"\[configurations.heavy\]: unknown key\(s\) \['J_L2'\]; allowed: \['L', "),
    ("legacy and new mixed", lambda t: t + "\n[plant]\nJ_m = 1.0\n",
     r"unknown table\(s\) \['bodies', 'couplings', 'motor', 'sensors'\]; allowed: \['about', 'plant', "),
]


@pytest.mark.parametrize("case,edit,msg", BAD, ids=[b[0] for b in BAD])
def test_bad_input(tmp_path, case, edit, msg):
    text = edit(USER)
    assert text != USER, case
    with pytest.raises(ParameterError) as exc:
        load_params_text(tmp_path, text)
    assert re.search(r"act.toml.*" + msg, str(exc.value)), (case, str(exc.value))
    assert "\n" not in str(exc.value)


def test_bad_input_in_the_cli_exits_2(tmp_path, assert_refused):
    p = tmp_path / "act.toml"
    p.write_text(USER.replace('torque = "s1"', 'torque = "s9"'))
    assert_refused(["compile", str(p)], "is not a coupling")


# --- the compile step of a user's topology --------------------------------------------------
def test_user_topology_without_compiler_runs_in_the_vm(user_file, tmp_path, monkeypatch):
    from haa_sym.compiled.plant_code import compile_topology
    top = load_params(user_file).plant.topology
    compiled = compile_topology(top, "compiled", cache_dir=tmp_path, quiet=True)
    monkeypatch.setenv("CC", "/nonexistent/cc")
    monkeypatch.setenv("PATH", "/nonexistent")
    with pytest.warns(RuntimeWarning, match="no C compiler found.*virtual machine"):
        vm = compile_topology(top, "auto", cache_dir=tmp_path, quiet=True)
    assert vm.backend == "vm" and compiled.backend == "compiled"
    x = np.linspace(0.5, 2.0, len(top.parameter_keys))
    for a, b in zip(compiled.function()(x), vm.function()(x)):
        np.testing.assert_array_equal(np.array(a), np.array(b))


def test_damaged_cached_code_is_regenerated(user_file, tmp_path, capsys):
    from haa_sym.compiled.plant_code import compile_topology
    from haa_sym.io.progress import set_progress
    set_progress(None)
    top = load_params(user_file).plant.topology
    first = compile_topology(top, "compiled", cache_dir=tmp_path)
    assert "haa_sym: compiling the plant of" in capsys.readouterr().err
    again = compile_topology(top, "compiled", cache_dir=tmp_path)
    assert again.library == first.library and capsys.readouterr().err == ""   # cached: silent
    first.c_file.write_text(first.c_file.read_text().replace("casadi_real", "casadi_real ", 1))
    fixed = compile_topology(top, "compiled", cache_dir=tmp_path)
    assert "haa_sym: compiling the plant of" in capsys.readouterr().err
    assert fixed.library == first.library                  # same C again: the same library


def test_compiler_failure_exits_2_with_one_message(user_file, tmp_path):
    import os
    import subprocess
    import sys
    env = dict(os.environ, CC="/bin/false", HAA_SYM_CACHE=str(tmp_path / "cache"))
    proc = subprocess.run([sys.executable, "-m", "haa_sym.cli", "--quiet", "compile", str(user_file)],
                          env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("haa-sym: error: compiling ") and "Traceback" not in proc.stderr
    assert "set CC to a working C compiler" in proc.stderr


def test_builtin_runtime_does_not_import_sympy():
    import subprocess
    import sys
    code = ("import sys\n"
            "from haa_sym import load_params, ClosedLoop, LoopOptions\n"
            "from haa_sym.model.params import builtin_actuators\n"
            "for f in builtin_actuators():\n"
            "    p = load_params(f)\n"
            "    ClosedLoop(p, LoopOptions(port='dtheta_' + p.plant.topology.port)).stability(200.0, 10.0)\n"
            "assert 'sympy' not in sys.modules, 'sympy imported by the runtime'\n")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_actuator_defined_in_code(params, cache):
    """The Python API: a Topology and its values give the same plant as the same file."""
    from haa_sym import Params, Plant
    from haa_sym.model.actuator import Body, Coupling, Topology
    top = Topology(bodies=(Body("L1"), Body("L2", ground=True)),
                   couplings=(Coupling("hd", "rotor", "L1"), Coupling("p", "L1", "L2")),
                   sensor="hd", torque_damping=True, encoder="L1", port="L2")
    assert top == HYQ and top.fingerprint == HYQ.fingerprint
    mine = Params(Plant(top, **params.plant.as_dict()), params.controller)
    a, b = continuous_plant(mine.plant), continuous_plant(params.plant)
    for x, y in ((a.A, b.A), (a.B, b.B), (a.C, b.C)):
        np.testing.assert_array_equal(x, y)
    with pytest.raises(ParameterError, match=r"<memory> \[sensors\]: port = 'L3' is not a body"):
        Topology(top.bodies, top.couplings, "hd", True, "L1", "L3")
    with pytest.raises(ParameterError, match=r"missing key\(s\) \['K_L2'\]"):
        Plant(top, **{k: v for k, v in params.plant.as_dict().items() if k != "K_L2"})


# --- generated code per topology ------------------------------------------------------------
def test_manifest_lists_every_builtin_topology():
    from haa_sym.compiled.generated import GeneratedCode
    code = GeneratedCode()
    topologies = code.manifest["topologies"]
    for path in BUILTIN:
        top = load_params(path).plant.topology
        entry = topologies[top.fingerprint]
        assert entry["function"] == top.function_name and path.name in entry["actuators"]
        assert entry["function"] in code.function_names
    assert "paper.toml" not in {a for t in topologies.values() for a in t["actuators"]}


def test_changed_builtin_topology_is_refused(tmp_path):
    import shutil
    from haa_sym.errors import StaleGeneratedCode
    from haa_sym.compiled.generated import GeneratedCode
    import json
    root = tmp_path / "tree"
    for rel in ("generated", "model"):
        shutil.copytree(ROOT / rel, root / rel)
    for rel in json.loads((ROOT / "generated" / "MANIFEST.json").read_text())["sources"]:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, root / rel)
    hyq = root / "model" / "hyq_haa.toml"
    hyq.write_text(hyq.read_text().replace("J = { value = 0.439", "J = { value = 0.5"))
    GeneratedCode(root / "generated", root=root)            # a value is an input: still valid
    hyq.write_text(hyq.read_text().replace('encoder = "L1"', 'encoder = "L2"'))
    with pytest.raises(StaleGeneratedCode, match=r"topology of the built-in actuator file\(s\) "
                                                 r"\['hyq_haa.toml'\] changed.*run `make derive`"):
        GeneratedCode(root / "generated", root=root)


def test_malformed_topologies_in_manifest_are_refused(tmp_path):
    import json
    import shutil
    from haa_sym.errors import StaleGeneratedCode
    from haa_sym.compiled.generated import GeneratedCode
    gen = shutil.copytree(ROOT / "generated", tmp_path / "generated")
    m = json.loads((gen / "MANIFEST.json").read_text())
    m["topologies"][HYQ.fingerprint]["function"] = "haa_plant_nonexistent"
    (gen / "MANIFEST.json").write_text(json.dumps(m))
    with pytest.raises(StaleGeneratedCode, match=r"missing or malformed: topologies\['" + HYQ.fingerprint):
        GeneratedCode(gen)


def test_coupling_order_in_the_file_does_not_flip_the_torque_sign(tmp_path, params):
    text = (ROOT / "model" / "hyq_haa.toml").read_text()
    rev = text.replace('between = ["rotor", "L1"]', 'between = ["L1", "rotor"]') \
              .replace('between = ["L1", "L2"]', 'between = ["L2", "L1"]')
    assert rev != text
    f = tmp_path / "rev.toml"
    f.write_text(rev)
    p = load_params(f)
    assert p.plant.topology == params.plant.topology
    P, D = np.meshgrid(np.logspace(0, 4.3, 12), np.linspace(0, 50, 6), indexing="ij")
    np.testing.assert_array_equal(ClosedLoop(p).stability(P, D).stable, ClosedLoop(params).stability(P, D).stable)
