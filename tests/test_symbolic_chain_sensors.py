"""Drives without a torque sensor and with a motor-side encoder (issue 16 item 7), and contact on
a port body without a stiffness to ground (item 8).

The new sensors are checked independently of the code that derives them: their rows of the
plant function against an explicit assembly from the state (k_t N I_m, theta_m / N), and the
closed loop against the reference (haa_sym.check.reference), which assembles these rows itself
-- the tests corrupt the plant function's rows the reference would otherwise read and the
decisions still agree with the generated evaluators.
"""
import json
import re

import numpy as np
import pytest

from haa_sym import ClosedLoop, LoopOptions, ParameterError, load_params
from haa_sym.analysis.contact import contact_params, contact_stability
from haa_sym.check import reference as ref
from haa_sym.check import verify
from haa_sym.cli import main
from haa_sym.loop.plant import continuous_plant
from haa_sym.symbolic import chain

from conftest import ROOT, decisions_against_reference

QDD = ROOT / "model" / "qdd_leg.toml"
HD = ROOT / "model" / "harmonic_drive.toml"


def with_sensors(text: str, **keys) -> str:
    """``text`` with its [sensors] table replaced by ``keys`` (TOML values as Python)."""
    body = "".join(f"{k} = {json.dumps(v)}\n" for k, v in keys.items())
    return re.sub(r"\[sensors\]\n(?:[^\[\n][^\n]*\n|\n)*", "[sensors]\n" + body + "\n", text, count=1)


def no_port_stiffness(text: str, body: str) -> str:
    """``text`` without the stiffness to ground K of ``body`` (its table and configurations)."""
    out = re.sub(r"(\[bodies\." + body + r"\][^\n]*\n(?:[JB] = [^\n]*\n)*)K = [^\n]*\n", r"\1", text, count=1)
    return re.sub(rf"\nK_{body} = [^\n]*", "", out)


@pytest.fixture(scope="module")
def files(tmp_path_factory, cache):
    """The bundled QDD leg and three placements on the harmonic drive (compiled on first use)."""
    d = tmp_path_factory.mktemp("sensors")
    hd = HD.read_text()
    out = {"qdd": QDD}
    for name, sensors in (("hd_rotor", dict(torque="hd", torque_damping=True, encoder="rotor", port="link")),
                          ("hd_rotor_spring", dict(torque="hd", torque_damping=False, encoder="rotor", port="link")),
                          ("hd_current_link", dict(torque="current", encoder="link", port="link"))):
        out[name] = d / f"{name}.toml"
        out[name].write_text(with_sensors(hd, **sensors))
    return out


# --- the plant function's rows against an explicit assembly from the state -------------------
def test_rows_of_the_new_sensors_equal_an_explicit_assembly(files):
    rng = np.random.default_rng(16)
    for name, path in files.items():
        params = load_params(path)
        top = params.plant.topology
        for _ in range(4):
            plant = params.plant.replace(**{k: v * 10 ** rng.uniform(-0.5, 0.5) for k, v in params.plant.as_dict().items()})
            cp = continuous_plant(plant)
            C = dict(zip(cp.output_names, cp.C))
            state = {n: i for i, n in enumerate(cp.state_names)}
            if top.sensor == "current":                     # k_t N I_m, with and without "damping"
                want = np.zeros(len(state))
                want[state["I_m"]] = plant.k_t * plant.N
                for out in ("T_sensor", "T_sensor_spring"):
                    np.testing.assert_allclose(C[out], want, rtol=1e-15, atol=0, err_msg=(name, out))
            if top.encoder == "rotor":                      # theta_m / N
                want = np.zeros(len(state))
                want[state["theta_m"]] = 1 / plant.N
                np.testing.assert_allclose(C["theta_encoder"], want, rtol=1e-15, atol=0, err_msg=name)
            else:
                assert C["theta_encoder"][state[f"theta_{top.encoder}"]] == 1.0


def test_bundled_qdd_file_reads_as_documented():
    params = load_params(QDD)
    top = params.plant.topology
    assert (top.sensor, top.encoder, top.port, top.torque_damping) == ("current", "rotor", "leg", False)
    assert top.output_names == ("T_sensor", "T_sensor_spring", "theta_encoder", "dtheta_leg")
    # every value cites a source; the estimates say so
    text = QDD.read_text()
    assert text.count('source = "estimate"') == 3        # L, K_gb, D_gb
    assert params.plant.N == 6 and params.plant.R == 0.173 and params.plant.k_t == 0.075
    assert params.plant.J_m == 6.3e-5 and params.plant.k_w == 0.05


# --- the closed loop against the reference, which assembles the new rows itself --------------
CASES = ((1e-3, 4, 0, "both", {}), (5e-4, 10, 1, "impedance", {"velocity_filter": "lowpass1", "f_c": 60.0}),
         (2e-3, 1, 0, "compensation", {}))


def _corrupted(cont_plant):
    """``continuous_plant`` with the rows the reference must assemble itself set to garbage."""
    def corrupt(plant, backend="auto"):
        cp = cont_plant(plant, backend)
        top = plant.topology
        own = (["T_sensor", "T_sensor_spring"] if top.sensor == "current" else []) \
            + (["theta_encoder"] if top.encoder == "rotor" else [])
        C = cp.C.copy()
        for o in own:
            C[cp.output_names.index(o)] = np.pi * np.arange(1, C.shape[1] + 1)
        return type(cp)(cp.A, cp.B, C, cp.VC0, cp.plant, cp.state_names, cp.input_names, cp.output_names)
    return corrupt


@pytest.mark.parametrize("name", ["qdd", "hd_rotor", "hd_current_link"])
def test_closed_loop_agrees_with_the_reference(name, files, monkeypatch):
    monkeypatch.setattr(ref, "continuous_plant", _corrupted(ref.continuous_plant))
    params = load_params(files[name])
    if params.controller.structure != "paper":      # the QDD leg's own is impedance_current, which
        params = params.with_values(structure="paper")   # reads no torque: the rows need the PI's
    P_max, D_max = {"qdd": (300.0, 1.0), "hd_rotor": (3e5, 300.0)}.get(name, (20000.0, 50.0))
    rng = np.random.default_rng(7)
    n, disagree, stable, fr_worst = 0, 0, 0, 0.0
    for Ts, N_av, delay, filt, estimate in CASES:
        p = params.with_values(Ts=Ts, N_av=N_av, **estimate)
        loop = ClosedLoop(p, LoopOptions(delay=delay, filter=filt))
        k = 200
        pts = np.stack([10 ** rng.uniform(0, np.log10(P_max), k), rng.uniform(0, D_max, k),
                        rng.uniform(0.5, 3, k), rng.uniform(0, 1.1, k)])
        c = decisions_against_reference(loop, pts)
        disagree, stable, n = disagree + c["disagree"], stable + c["stable"], n + k
        w = np.logspace(-1, np.log10(np.pi / Ts * 0.99), 15)
        fr = loop.frequency_response(w, *pts[:, :2])
        for i in range(2):
            for key, val in ref.frequency_response(loop, w, *pts[:, i]).items():
                fr_worst = max(fr_worst, float((np.abs(fr[key][i] - val) / np.abs(val).max()).max()))
    assert disagree == 0, (name, disagree)
    assert 0.05 < stable / n < 0.95, (name, stable, n)        # both branches exercised
    assert fr_worst < 1e-7, (name, fr_worst)


def test_the_corruption_is_seen_by_a_reference_reading_the_plant(files, monkeypatch):
    """Control: the same corruption on a row the reference does read (the harmonic drive's gearbox
    sensor) changes its eigenvalues, so the agreement above is not vacuous."""
    params = load_params(files["hd_rotor"])
    loop = ClosedLoop(params)
    pts = np.array([[100.0], [5.0], [1.0], [0.94]])
    before = ref.closed_loop_eigenvalues(loop, pts)
    cont = ref.continuous_plant

    def corrupt(plant, backend="auto"):
        cp = cont(plant, backend)
        C = cp.C.copy()
        C[cp.output_names.index("T_sensor")] *= 2.0
        return type(cp)(cp.A, cp.B, C, cp.VC0, cp.plant, cp.state_names, cp.input_names, cp.output_names)
    monkeypatch.setattr(ref, "continuous_plant", corrupt)
    after = ref.closed_loop_eigenvalues(loop, pts)
    assert np.abs(np.sort_complex(before[0]) - np.sort_complex(after[0])).max() > 1e-3


def test_torque_damping_option_changes_nothing_with_the_current_estimate():
    params = load_params(QDD).with_values(structure="paper")      # a torque loop on the estimate
    pts = (np.array([5.0, 30.0, 100.0]), np.array([0.05, 0.2, 0.5]))
    a = ClosedLoop(params, LoopOptions(torque_damping=True)).stability(*pts, radius=True)
    b = ClosedLoop(params, LoopOptions(torque_damping=False)).stability(*pts, radius=True)
    np.testing.assert_array_equal(a.stable, b.stable)
    np.testing.assert_allclose(a.spectral_radius, b.spectral_radius, rtol=0, atol=0)


# --- verify: the chain's identities for the new outputs ------------------------------------
def test_verify_rows(files):
    expect = {"qdd": True, "hd_rotor": True, "hd_rotor_spring": True, "hd_current_link": False}
    for name, applies in expect.items():
        rows = verify.generic_rows(load_params(files[name]))
        bad = [(r.claim, r.numbers) for r in rows if r.applies and not r.ok]
        assert not bad, (name, bad)
        assert rows[1].applies is applies, (name, rows[1].numbers)
        assert chain.exact_vc_condition(load_params(files[name]).plant.topology)[0] is applies
    assert verify.main(["--params", str(QDD)]) == 0


def test_exact_compensation_of_the_current_estimate_is_the_back_emf_alone(files):
    """The derived G_tVC (Cramer's rule on the chain) with VC_gain = N k_w is N k_t/(L s + R), and
    with Eq. (5) instead it is not (the rotor's dynamics are then fed back twice)."""
    from haa_sym.symbolic import torque_tf as tt
    top = load_params(files["qdd"]).plant.topology
    p = chain.symbols(top)
    expected = p["N"] * p["k_t"] / (p["L"] * chain.s + p["R"])
    num, den, ring = chain.torque_tf_fraction(top, p, vc=p["N"] * p["k_w"])
    assert tt.same_rational(num, den, expected, ring)
    num, den, ring = chain.torque_tf_fraction(top, p, vc=chain.vc_gain_exact(p))
    assert not tt.same_rational(num, den, expected, ring)


# --- the file format ------------------------------------------------------------------------
def _load_text(tmp_path, text):
    path = tmp_path / "act.toml"
    path.write_text(text)
    return load_params(path)


def test_torque_damping_is_optional_with_the_current_estimate(tmp_path):
    hd = HD.read_text()
    a = _load_text(tmp_path, with_sensors(hd, torque="current", encoder="rotor", port="link"))
    b = _load_text(tmp_path, with_sensors(hd, torque="current", torque_damping=True, encoder="rotor", port="link"))
    assert a.plant.topology == b.plant.topology and a.plant.topology.torque_damping is False
    assert a.plant.topology.fingerprint == b.plant.topology.fingerprint


@pytest.mark.parametrize("sensors, message", [
    (dict(torque="hd", encoder="rotor", port="link"),
     r"act.toml \[sensors\]: missing key\(s\) \['torque_damping'\]"),
    (dict(torque="amps", torque_damping=True, encoder="link", port="link"),
     r"act.toml \[sensors\]: torque = 'amps' is not a coupling; allowed: \['hd'\] or 'current'"),
    (dict(torque="current", encoder="stator", port="link"),
     r"act.toml \[sensors\]: encoder = 'stator' is not a body; allowed: \['link'\] or 'rotor'"),
    (dict(torque="current", encoder="rotor", port="rotor"),
     r"act.toml \[sensors\]: port = 'rotor' is not a body; allowed: \['link'\]"),
    (dict(torque="current", torque_damping="yes", encoder="rotor", port="link"),
     r"act.toml \[sensors\]: torque_damping = 'yes'; allowed: true or false"),
])
def test_bad_sensors_exit_2_with_one_line(tmp_path, capsys, sensors, message):
    path = tmp_path / "act.toml"
    path.write_text(with_sensors(HD.read_text(), **sensors))
    with pytest.raises(ParameterError, match=message):
        load_params(path)
    assert main(["stability", "--params", str(path), "--P-gain", "100", "--D-gain", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and re.search(message, err), err


def test_a_coupling_may_not_be_called_current(tmp_path):
    text = HD.read_text().replace("[couplings.hd]", "[couplings.current]").replace('torque = "hd"', 'torque = "current"')
    with pytest.raises(ParameterError, match=r"\[couplings.current\]: name 'current' is not allowed for a coupling"):
        _load_text(tmp_path, text)


# --- contact on a port body without a stiffness to ground (item 8) -------------------------
def _rho(params, K, P, D):
    """Spectral radius of the reference closed loop of the bundled QDD file (its port body has
    K_leg) at K_leg = K: the file with the stiffness written out, not the contact scan's variant."""
    return ref.spectral_radius(ClosedLoop(params.with_values(K_leg=K), basis=False), P, D)


@pytest.fixture(scope="module")
def free_leg(tmp_path_factory, cache):
    path = tmp_path_factory.mktemp("contact") / "qdd_free.toml"
    path.write_text(no_port_stiffness(QDD.read_text(), "leg"))
    return path


def test_free_leg_file_has_no_port_stiffness(free_leg):
    top = load_params(free_leg).plant.topology
    assert "K_leg" not in top.parameter_keys and not top.bodies[0].ground
    variant, key, added = contact_params(load_params(free_leg))
    assert (key, added) == ("K_leg", True) and variant.plant.K_leg == 0.0
    assert variant.plant.topology == load_params(QDD).plant.topology      # the bundled topology


@pytest.mark.parametrize("P, D", [(0.0, 0.0), (30.0, 0.2)])
def test_contact_stability_on_a_free_port_against_the_reference(free_leg, P, D):
    bundled = load_params(QDD)
    K = np.array([0.3, 3.0, 30.0, 300.0, 3000.0, 3e4])
    for mode in ("replace", "add"):
        stable, rho = contact_stability(ClosedLoop(load_params(free_leg)), K, P_gain=P, D_gain=D, mode=mode)
        want = np.array([_rho(bundled, k, P, D) for k in K])
        np.testing.assert_allclose(rho, want, rtol=1e-9)
        np.testing.assert_array_equal(stable, want < 1)


def test_contact_command_on_a_free_port(free_leg, tmp_path, capsys):
    out = tmp_path / "contact.json"
    # the paper's structure of the file ([controller.paper]), whose torque loop the ends below are of
    assert main(["contact", "--params", str(free_leg), "--K-range", "0.1:100000", "--n-scan", "40",
                 "--P-gain", "30", "--D-gain", "0.2", "--set", "structure=paper", "--out", str(out)]) == 0
    assert "new stiffness to ground K_leg" in capsys.readouterr().out
    data = json.loads(out.read_text())
    assert data["ground_added"] is True and data["stiffness_key"] == "K_leg"
    bundled = load_params(QDD).with_values(structure="paper")
    (lo, hi), = data["unstable_intervals"]
    assert lo == 0.1 and 1.0 < hi < 1e3, data["unstable_intervals"]
    # the end is exact: unstable just inside, stable just outside, in the reference's eigenvalues
    assert _rho(bundled, hi * (1 - 1e-9), 30.0, 0.2) > 1 > _rho(bundled, hi * (1 + 1e-9), 30.0, 0.2)
    # the same ends as the scan of the bundled file (which has K_leg) in "replace" mode
    assert main(["contact", "--params", str(QDD), "--K-range", "0.1:100000", "--n-scan", "40",
                 "--P-gain", "30", "--D-gain", "0.2", "--set", "structure=paper", "--out", str(tmp_path / "b.json")]) == 0
    b = json.loads((tmp_path / "b.json").read_text())
    assert b["ground_added"] is False
    np.testing.assert_allclose(b["unstable_intervals"], data["unstable_intervals"], rtol=1e-9)
    np.testing.assert_allclose(b["not_passive_intervals"], data["not_passive_intervals"], rtol=1e-9)
