"""haa-sym export-mujoco (issue 25, item 2; docs/robot.md, "Export to MuJoCo"): the MJCF and its
controller module against haa-sym simulate without limits, and the command's refusals."""
import importlib.util
import sys

import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate
from haa_sym.cli import main
from haa_sym.model.limits import Limits

mujoco = pytest.importorskip("mujoco")

EXPERIMENTS = {"disturbance-step": "T_dist", "torque-step": "T_ff"}
DURATION = 0.4          # s: 401 samples
NEAR_RADIUS = 0.9995    # the point "close to the boundary": spectral radius of the sampled loop
UNSTABLE_RADIUS = 1.002
D_GAIN = {"hyq_haa": 5.0, "sea": 1.0, "qdd_leg": 1.0, "haptic_wall": 0.0}   # the wall's B = 0: Colgate's K < 4


def _export(tmp_path, name, P, D, *extra):
    out = tmp_path / f"{name}.xml"
    assert main(["export-mujoco", "--params", f"model/{name}.toml", "--P-gain", repr(P), "--D-gain", repr(D),
                 "--out", str(out), *extra]) == 0
    spec = importlib.util.spec_from_file_location(f"{name}_controller_{abs(hash((P, D)))}",
                                                  tmp_path / f"{name}_controller.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _radius(loop, P, D):
    return float(loop.stability([P], [D], radius=True).spectral_radius[0])


def _P_at(loop, D, rho, lo, hi):
    """P_gain between lo and hi where the spectral radius is rho (bisection in log P)."""
    for _ in range(50):
        mid = np.sqrt(lo * hi)
        lo, hi = (mid, hi) if _radius(loop, mid, D) < rho else (lo, mid)
    return float(np.sqrt(lo * hi))


def gain_points(loop, D):
    """From the stability map along P_gain at D: the first unstable P_b; a stable point (P_b / 4),
    a point close to the boundary (radius NEAR_RADIUS below P_b) and an unstable one."""
    P = np.logspace(0, 5, 500)
    r = np.asarray(loop.stability(P, np.full_like(P, D), radius=True).spectral_radius)
    assert r[0] < 1
    i = int(np.argmax(r >= 1))
    Pb = float(P[i])
    j = int(np.argmax(r > UNSTABLE_RADIUS))
    return {"stable": Pb / 4, "near": _P_at(loop, D, NEAR_RADIUS, Pb / 4, Pb),
            "unstable": _P_at(loop, D, UNSTABLE_RADIUS, P[j - 1], P[j])}


def _growth(torque):
    """The swing of the torque's sample-to-sample change over the run's last quarter over the
    quarter's before (the difference removes the step's slow rise, not the loop's oscillation)."""
    d = np.diff(torque)
    q = len(d) // 4
    return np.ptp(d[-q:]) / np.ptp(d[-2 * q:-q])


@pytest.mark.slow
@pytest.mark.parametrize("name", ["hyq_haa", "sea", "qdd_leg", "haptic_wall"])
def test_mujoco_equals_simulate(tmp_path, name):
    """A disturbance step and a torque-reference step in MuJoCo equal haa-sym simulate (no
    limits) within 1 % of each signal's peak, at a stable point and one close to the boundary;
    the point the map calls unstable grows in MuJoCo."""
    loop = ClosedLoop(load_params(f"model/{name}.toml"))
    D = D_GAIN[name]
    pts = gain_points(loop, D)
    assert _radius(loop, pts["stable"], D) < 1 and NEAR_RADIUS - 1e-6 < _radius(loop, pts["near"], D) < 1
    for label in ("stable", "near"):
        ctl = _export(tmp_path, name, pts[label], D)
        for exp, key in EXPERIMENTS.items():
            r = ctl.run(DURATION, **{key: 1.0})
            c = simulate(loop, pts[label], D, limits=Limits(), experiment=exp, amplitude=1.0,
                         duration=DURATION).columns()
            if label == "near" and exp == "disturbance-step":
                ctl_near_torque = r["torque"]
            for sig in ("theta", "velocity", "torque", "torque_ref", "voltage"):
                assert r[sig].shape == c[sig].shape
                err = np.abs(r[sig] - c[sig]).max() / np.abs(c[sig]).max()
                assert err < 0.01, (name, label, exp, sig, err)
    ctl = _export(tmp_path, name, pts["unstable"], D)
    r = ctl.run(DURATION, T_dist=1.0)
    assert _growth(r["torque"]) > 1.15, _growth(r["torque"])
    assert _growth(ctl_near_torque) < 1.0, _growth(ctl_near_torque)


DRIVE_TS = {"tau_drive": 3.0, "delay_drive": 1.4}       # in samples Ts: a lag and a fractional dead time


@pytest.mark.slow
@pytest.mark.parametrize("name", ["hyq_haa", "sea", "qdd_leg"])
def test_mujoco_with_a_drive_equals_simulate(tmp_path, name):
    """With a [drive] (lag 3 Ts, dead time 1.4 Ts) the callback's delay line and lag make MuJoCo
    equal haa-sym simulate (no limits, the drive exact) within 1 % of each signal's peak, at a
    stable point and one close to the boundary of the loop with the drive."""
    base = load_params(f"model/{name}.toml")
    Ts = base.controller.Ts
    sets = [f"{k}={v * Ts!r}" for k, v in DRIVE_TS.items()]
    loop = ClosedLoop(base.with_values(**{k: v * Ts for k, v in DRIVE_TS.items()}))
    D = D_GAIN[name]
    pts = gain_points(loop, D)
    assert NEAR_RADIUS - 1e-6 < _radius(loop, pts["near"], D) < 1
    for label in ("stable", "near"):
        ctl = _export(tmp_path, name, pts[label], D, *(a for s in sets for a in ("--set", s)))
        assert (ctl.TAU_DRIVE, ctl.DELAY_DRIVE) == (3.0 * Ts, 1.4 * Ts)
        for exp, key in EXPERIMENTS.items():
            r = ctl.run(DURATION, **{key: 1.0})
            c = simulate(loop, pts[label], D, limits=Limits(), experiment=exp, amplitude=1.0,
                         duration=DURATION).columns()
            for sig in ("theta", "velocity", "torque", "torque_ref", "voltage"):
                err = np.abs(r[sig] - c[sig]).max() / np.abs(c[sig]).max()
                assert err < 0.01, (name, label, exp, sig, err)


def test_drive_in_the_callback_is_the_exact_lag_after_the_dead_time(tmp_path):
    """The controller module's drive: commands held, switched at t_k + delay (a fraction of a
    sample), then the first-order lag's exact solution, at any call time."""
    ctl = _export(tmp_path, "hyq_haa", 200.0, 5.0, "--set", "tau_drive=0.003", "--set", "delay_drive=0.0014")
    c = ctl.Controller.__new__(ctl.Controller)
    c.queue, c.v_in, c.v_lag, c.s, c.h = [], 0.0, 0.0, 0.0, 1e-5
    tau, dead = 0.003, 0.0014
    V = [2.0, -1.0, 0.5]                         # the commands of samples 0, 1, 2 (Ts = 1 ms)
    c.queue = [(k * 1e-3 + dead, v) for k, v in enumerate(V)]

    def exact(t):                                # the lag's response to the delayed held commands
        y, s, v_in = 0.0, 0.0, 0.0
        for k, v in enumerate(V):
            sw = k * 1e-3 + dead
            if sw > t:
                break
            y = v_in + (y - v_in) * np.exp(-(sw - s) / tau)
            s, v_in = sw, v
        return v_in + (y - v_in) * np.exp(-(t - s) / tau)
    times = np.linspace(0.0, 0.006, 1201)
    got = np.array([c.drive(t) for t in times])
    assert np.all(got[times < dead - 1e-12] == 0.0)
    assert np.allclose(got, [exact(t) for t in times], rtol=0, atol=1e-14)


def test_model_structure(tmp_path):
    """Every hinge is named after its body; the couplings are tendons with the file's K and D; the
    dcmotor carries N, R, L, k_t, k_w, J_m and B_m; the controller's matrices are controller_batch's."""
    from haa_sym.loop.statespace import controller_batch
    ctl = _export(tmp_path, "hyq_haa", 200.0, 5.0)
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "hyq_haa.xml"))
    assert [m.joint(i).name for i in range(m.njnt)] == ["rotor", "L1", "L2"]
    p = load_params("model/hyq_haa.toml").plant
    assert m.tendon_stiffness[m.tendon("hd").id] == p.K_hd and m.tendon_damping[m.tendon("p").id] == p.D_p
    assert m.jnt_stiffness[m.joint("L2").id] == p.K_L2 and m.dof_damping[m.joint("L2").id] == p.B_L2
    assert m.actuator_gear[0, 0] == p.N
    assert m.opt.timestep == pytest.approx(1e-5) and m.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    Ac = controller_batch(ClosedLoop(load_params("model/hyq_haa.toml")), 200.0, 5.0)[0][0]
    assert np.array_equal(ctl.AC, Ac)


@pytest.mark.parametrize("name, sets, kind", [("qdd_leg", (), "motor"), ("qdd_leg", ("structure=paper",), "dcmotor"),
                                              ("haptic_wall", (), "motor")])
def test_current_command_is_a_motor_actuator(tmp_path, name, sets, kind):
    """A current-commanded structure (impedance_current) drives a `motor` whose control is k_t I;
    a voltage-commanded one the dcmotor. Both carry gear N, armature J_m and damping B_m (what
    import-robot reads back)."""
    ctl = _export(tmp_path, name, 2.0, 0.0, *(a for s in sets for a in ("--set", s)))
    text = (tmp_path / f"{name}.xml").read_text()
    assert f"<{kind} name=\"motor\"" in text and ("<dcmotor" in text) == (kind == "dcmotor")
    m = mujoco.MjModel.from_xml_path(str(tmp_path / f"{name}.xml"))
    p = load_params(f"model/{name}.toml").plant
    assert (m.actuator_gear[0, 0], m.actuator_armature[0], m.actuator_damping[0]) == (p.N, p.J_m, p.B_m)
    assert ctl.COMMAND == ("voltage" if kind == "dcmotor" else "current")
    assert ctl.COMMAND_SCALE == (p.k_t if kind == "motor" else pytest.approx((p.k_t / p.k_w) ** 0.5))


def test_bad_input_one_line_nothing_written(tmp_path, capsys):
    cases = [(["--out", str(tmp_path / "m.txt")], "unsupported file type"),
             (["--set", "k_w=0", "--out", str(tmp_path / "m.xml")], "k_w"),
             (["--P-gain", "1,2", "--out", str(tmp_path / "m.xml")], "one point")]
    for extra, word in cases:
        argv = ["export-mujoco", "--params", "model/hyq_haa.toml", "--P-gain", "200", "--D-gain", "5"] + extra
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("haa-sym: error:") and word in err[0], err
        assert list(tmp_path.iterdir()) == []


def test_mujoco_absent(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)          # import mujoco raises ImportError
    assert main(["export-mujoco", "--params", "sea", "--P-gain", "200", "--D-gain", "1", "--out",
                 str(tmp_path / "m.xml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "haa_sym[mujoco]" in err[0]
    assert list(tmp_path.iterdir()) == []


def test_the_summary_counts_one_hinge_in_the_singular(tmp_path, capsys):
    """The haptic wall's rotor-only chain: `1 hinge (rotor)`; the QDD leg's two: `2 hinges`."""
    pytest.importorskip("mujoco")
    for name, words in (("haptic_wall", "export-mujoco: 1 hinge (rotor), "), ("qdd_leg", "export-mujoco: 2 hinges (")):
        assert main(["export-mujoco", "--params", name, "--P-gain", "1", "--D-gain", "0",
                     "--out", str(tmp_path / f"{name}.xml")]) == 0
        assert capsys.readouterr().out.startswith(words), name
