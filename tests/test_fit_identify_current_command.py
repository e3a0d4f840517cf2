"""identify on current-commanded drives (issue 24; docs/identify.md, "Current-commanded drives (QDD,
haptic)"): the QDD leg and the haptic wall (structure impedance_current) are identified from logs of
the current command and the angle alone.

* The plant the fit uses for a current command (``--input current``: the electrical state removed,
  the [drive] lag and delay on the command) equals a transfer function built here by hand from the
  files' values, discretised by scipy's ZOH (cont2discrete), to 1e-10.
* Logs written by ``haa-sym simulate --log-out`` (the closed impedance loop, the current command
  logged exact, 1 % noise on the outputs) with J_m, B_m, tau_drive (and Fc_m) moved off the file's
  values: identify returns them inside their ci95.
* What the current-commanded model cannot fit is refused in one line, exit 2, nothing written.
"""
import json

import numpy as np
import pytest
import scipy.signal

from haa_sym.cli import main
from haa_sym.fit.identify import Experiment, simulate_log
from haa_sym.fit.model import open_loop_model, sample
from haa_sym.io.logs import read_log
from haa_sym.model import resources
from haa_sym.model.params import load_params

Ts = 1e-3
FREQS = np.array([0.3, 3.0, 30.0, 100.0, 300.0, 480.0])          # Hz, up to just below Nyquist


def _file(tmp_path, name, extra=""):
    f = tmp_path / f"{name}.toml"
    f.write_text((resources.data_dir("model") / f"{name}.toml").read_text() + extra)
    return f


def _drive(tau, delay):
    return f"\n[drive]\ntau_drive = {tau!r}\ndelay_drive = {delay!r}\n"


def _rotor_tf(p):
    """theta / I of the rotor-only file by hand: output-side inertia J_m N^2 and damping B_m N^2
    driven by the torque k_t N I, theta = theta_m / N at the output."""
    N = p.N
    return [p.k_t * N], [p.J_m * N ** 2, p.B_m * N ** 2, 0.0]


def _two_mass_tf(p):
    """theta_m / N over I of the QDD leg by hand (rotor-side rotor angle theta_m, the gearbox
    K_gb, D_gb between theta_m / N and the leg): [a, -c; -c, b] [theta_m; theta_leg] = [k_t I; 0]
    with a = J_m s^2 + (B_m + D_gb / N^2) s + K_gb / N^2, c = (D_gb s + K_gb) / N,
    b = J_leg s^2 + (B_leg + D_gb) s + K_leg + K_gb."""
    N, K, D = p.N, p.K_gb, p.D_gb
    a = np.array([p.J_m, p.B_m + D / N ** 2, K / N ** 2])
    c = np.array([D, K]) / N
    b = np.array([p.J_leg, p.B_leg + D, p.K_leg + K])
    return p.k_t * b / N, np.polysub(np.polymul(a, b), np.polymul(c, c))


def _with_lag(num, den, tau):
    return num, np.polymul(den, [tau, 1.0])


def _freq_fit(s, f):
    """C (z I - Phi)^-1 Gamma + D of the fit's sampled model at z = e^{j 2 pi f Ts}."""
    out = []
    for z in np.exp(2j * np.pi * f * Ts):
        out.append((s.C @ np.linalg.solve(z * np.eye(s.Phi.shape[0]) - s.Phi, s.Gamma) + s.D)[:, 0])
    return np.array(out)


def _freq_tf(num, den, f):
    numd, dend, _ = scipy.signal.cont2discrete((num, den), Ts, method="zoh")
    z = np.exp(2j * np.pi * f * Ts)
    return np.polyval(np.ravel(numd), z) / np.polyval(dend, z)


@pytest.mark.parametrize("name,sets,tf", [("haptic_wall", {}, _rotor_tf),
                                          ("haptic_wall", {"N": 3.0, "B_m": 0.004}, _rotor_tf),
                                          ("qdd_leg", {"B_m": 5e-4}, _two_mass_tf)])
def test_the_current_commanded_plant_is_the_hand_built_transfer_function(tmp_path, name, sets, tf):
    tau = 4e-4
    params = load_params(str(_file(tmp_path, name, _drive(tau, 0.0)))).with_values(**sets)
    p = params.plant
    s = sample(open_loop_model(p, (), ("current",), ("theta", "torque"), params.drive), Ts)
    got = _freq_fit(s, FREQS)
    num, den = _with_lag(*tf(p), tau)
    theta = _freq_tf(num, den, FREQS)
    # torque = "current": the estimate k_t N I_m of the current the drive's lag delivers
    torque = _freq_tf([p.k_t * p.N], [tau, 1.0], FREQS)
    np.testing.assert_allclose(got[:, 0], theta, rtol=1e-10, atol=0)
    np.testing.assert_allclose(got[:, 1], torque, rtol=1e-10, atol=0)
    # the same plant without the lag: the fit's model is not the lag's alone
    assert np.max(np.abs(_freq_tf(*tf(p), FREQS) / theta - 1)) > 0.1


def _delayed_response(num, den, delay, u):
    """The ZOH response of num/den with its input held from t_k + delay: delay = m Ts + f Ts,
    over [k Ts, (k + 1) Ts) the input is u[k - m - 1] for f Ts, then u[k - m], so
    x[k + 1] = Phi x[k] + e^{A (1 - f) Ts} Gamma(f Ts) u[k - m - 1] + Gamma((1 - f) Ts) u[k - m],
    each Gamma from scipy's cont2discrete on its own interval."""
    A, B, C, D = scipy.signal.tf2ss(num, den)
    m, f = divmod(delay / Ts, 1.0)
    m = int(round(m)) if abs(f - 1) > 1e-12 else int(round(m)) + 1
    f = 0.0 if abs(f - 1) <= 1e-12 else f
    Phi = scipy.signal.cont2discrete((A, B, C, D), Ts, method="zoh")[0]
    Phi_b, G_b = scipy.signal.cont2discrete((A, B, C, D), (1 - f) * Ts, method="zoh")[:2]
    G_a = Phi_b @ scipy.signal.cont2discrete((A, B, C, D), f * Ts, method="zoh")[1] if f > 0 else 0 * G_b
    up = np.concatenate([np.zeros(m + 1), u])                 # up[j + m + 1] = u[j]
    x = np.zeros((A.shape[0], 1))
    y = np.zeros(u.size)
    for k in range(u.size):
        y[k] = (C @ x)[0, 0]
        x = Phi @ x + G_a * up[k] + G_b * up[k + 1]
    return y


@pytest.mark.parametrize("name,tf,delay", [("haptic_wall", _rotor_tf, 1.3e-3), ("qdd_leg", _two_mass_tf, 5e-4),
                                           ("haptic_wall", _rotor_tf, 2e-3)])
def test_the_delayed_current_commanded_plant_is_the_hand_built_one(tmp_path, name, tf, delay):
    """With the drive's delay the fit simulates on the log's stamps (the delayed command switching
    inside the intervals): its response to a pulse and to a random command equals the hand-built
    sampled model's to 1e-10 of the peak (the pulse response is the transfer function's power
    series)."""
    tau = 4e-4
    f = _file(tmp_path, name, _drive(tau, delay))
    params = load_params(str(f)).with_values(B_m=5e-4)
    n = 400
    rng = np.random.default_rng(1)
    t = np.arange(n) * Ts
    for u in (np.eye(1, n, 3).ravel(), rng.standard_normal(n)):
        # the fit holds a segment's first command into the delay before it (the command before
        # the log is its first, haa_sym.fit.model.stamp_grid); the reference starts from zero
        u[0] = 0.0
        log = tmp_path / "pulse.csv"
        log.write_text("time,current,theta\n" + "".join(f"{float(a)!r},{float(b)!r},0\n" for a, b in zip(t, u)))
        exp = Experiment(read_log(str(log), ("current",), ("theta",)), params)
        y = simulate_log(exp, ("current",), ("theta",))[0][:, 0]
        ref = _delayed_response(*_with_lag(*tf(params.plant), tau), delay, u)
        assert np.max(np.abs(y - ref)) <= 1e-10 * np.max(np.abs(ref)), (name, delay)
        # a delay off by a tenth of a sample is seen (the check can fail)
        off = _delayed_response(*_with_lag(*tf(params.plant), tau), delay + 1e-4, u)
        assert np.max(np.abs(y - off)) > 1e-4 * np.max(np.abs(ref))


def _simulate(tmp_path, params, P, D, amplitude, truth):
    log = tmp_path / "run.csv"
    assert main(["simulate", "--params", str(params), "--P-gain", str(P), "--D-gain", str(D), "--experiment",
                 "chirp", "--excitation", "multisine:0.5:100:40", "--amplitude", str(amplitude), "--duration", "6",
                 "--log-out", str(log), "--log-noise", "0.01", "--seed", "3", "-q",
                 *[a for k, v in truth.items() for a in ("--set", f"{k}={v!r}")]]) == 0
    return log


def _identify(tmp_path, params, log, keys, start, *extra):
    rep = tmp_path / "fit.json"
    assert main(["identify", "--params", str(params), "--log", str(log), "--input", "current", "--output", "theta",
                 "--fit", ",".join(keys), *[a for k, v in start.items() for a in ("--set", f"{k}={v!r}")],
                 "--out", str(tmp_path / "fitted.toml"), "--report", str(rep), "-q", *extra]) == 0
    return json.loads(rep.read_text())


def _check(report, truth, widths):
    """Every key's ci95 holds the truth and is no wider than ``widths`` (relative half-width: the
    1 % output noise over 6000 samples determines these keys to this)."""
    for k, v in truth.items():
        par = report["parameters"][k]
        lo, hi = par["ci95"]
        assert lo <= v <= hi, (k, v, par)
        assert (hi - lo) / 2 / par["value"] < widths[k], (k, par)


def test_identify_recovers_the_haptic_wall_from_its_current_log(tmp_path):
    """The virtual wall (K 1 Nm/rad, B 0.001 Nms/rad) closed around a device whose rotor is 12 %
    lighter, whose damping is 25 % higher and whose amplifier lags 0.4 ms behind a 0.5 ms delay;
    fitted from the file's values (tau_drive from 0.6 ms), the delay known."""
    f = _file(tmp_path, "haptic_wall", _drive(4e-4, 5e-4))
    truth = {"J_m": 1.0e-4, "B_m": 0.0025, "tau_drive": 4e-4}
    log = _simulate(tmp_path, f, 1, 0.001, 0.05, truth)
    rep = _identify(tmp_path, f, log, tuple(truth), {"tau_drive": 6e-4})
    # measured: half-widths 0.02 %, 0.05 %, 0.9 %
    _check(rep, truth, {"J_m": 0.002, "B_m": 0.002, "tau_drive": 0.02})
    assert rep["residuals"]["run.csv"]["theta"]["white"]


@pytest.mark.parametrize("delay", [0.0, pytest.param(1.5e-3, marks=pytest.mark.slow)])
def test_identify_recovers_the_qdd_leg_from_its_current_log(tmp_path, delay):
    """The QDD leg under its impedance PD (P 5 Nm/rad, D 0.05 Nms/rad), rotor inertia 11 % above
    the file's, a rotor damping of 5e-4 Nms/rad (the file's 0), a drive lag of 0.5 ms (behind a
    1.5 ms delay in the slow case: the log's own stamps path, 1 s longer); fitted from the file's
    J_m, B_m 1e-3 and tau_drive 1 ms, the delay known."""
    f = _file(tmp_path, "qdd_leg", _drive(5e-4, delay))
    truth = {"J_m": 7e-5, "B_m": 5e-4, "tau_drive": 5e-4}
    log = _simulate(tmp_path, f, 5, 0.05, 0.5, truth)
    rep = _identify(tmp_path, f, log, tuple(truth), {"B_m": 1e-3, "tau_drive": 1e-3})
    # measured: half-widths 0.1 %, 0.2 %, 3 %
    _check(rep, truth, {"J_m": 0.005, "B_m": 0.005, "tau_drive": 0.06})


@pytest.mark.slow
def test_identify_recovers_the_haptic_walls_friction(tmp_path, capsys):
    """With brush friction Fc_m 3 mNm (v_s 0.01 rad/s) in the device: J_m, B_m, tau_drive, Fc_m
    fitted together at the default substep, which identify chooses for this log (the fixed 0.5 ms
    of before stopped at its iteration limit with tau_drive 2.3 ms: the stick slope
    Fc / (v_s J_m) = 3000 1/s of this light rotor, whose angle integrates the scheme's error)."""
    f = _file(tmp_path, "haptic_wall", _drive(4e-4, 5e-4) + "\n[limits]\nFc_m = 0.003\n")
    truth = {"J_m": 1.0e-4, "B_m": 0.0025, "tau_drive": 4e-4}
    log = _simulate(tmp_path, f, 1, 0.001, 0.05, truth)
    rep = _identify(tmp_path, f, log, tuple(truth) + ("Fc_m",), {"tau_drive": 6e-4, "Fc_m": 0.002})
    _check(rep, {**truth, "Fc_m": 0.003}, {"J_m": 0.002, "B_m": 0.002, "tau_drive": 0.02, "Fc_m": 0.002})
    fr = rep["meta"]["friction"]
    # the substep used, and why: its estimated error within the bound, the coarser ones' not
    assert fr["max_substep"] < 5e-4 and fr["substep_error"] <= 5e-4, fr
    assert all(e > 5e-4 for h, e in fr["substep_search"] if h > fr["max_substep"]), fr
    assert rep["residuals"]["run.csv"]["theta"]["white"]
    # a given --max-substep coarser than that: 0.125 ms is used with a one-line warning naming
    # the bound; 0.5 ms (estimated error 0.07 of the angle's spread) is refused
    capsys.readouterr()
    for h, code in (("1.25e-4", 0), ("5e-4", 2)):
        assert main(["identify", "--params", str(f), "--log", str(log), "--input", "current", "--output", "theta",
                     "--fit", "J_m,B_m,tau_drive,Fc_m", "--set", "tau_drive=0.0006", "--set", "Fc_m=0.002", "--out",
                     str(tmp_path / f"f{h}.toml"), "-q", "--max-substep", h]) == code
        err = capsys.readouterr().err
        lines = [x for x in err.splitlines() if x.startswith("haa-sym:")]
        assert len(lines) == 1, err
        assert lines[0].startswith(("haa-sym: warning: " if code == 0 else "haa-sym: error: ")
                                   + f"--max-substep {float(h):g} s: the friction simulation's estimated error"), lines
        assert f"a substep of {fr['max_substep']:.3g} s or less keeps it" in lines[0], lines
        assert (tmp_path / f"f{h}.toml").exists() == (code == 0)


@pytest.fixture(scope="module")
def wall_log(tmp_path_factory):
    d = tmp_path_factory.mktemp("wall")
    f = _file(d, "haptic_wall")
    return f, _simulate(d, f, 1, 0.001, 0.05, {"J_m": 1.0e-4})


@pytest.mark.parametrize("fit,words", [
    ("J_m,R", "--fit R: the current-commanded model (--input current: the drive imposes the current, the electrical "
              "state removed) does not contain L, R, k_w; allowed: its keys ['k_t', 'J_m', 'B_m', 'N', 'tau_drive', "
              "'delay_drive', 'Fc_m']"),
    ("L", "--fit L: the current-commanded model"),
    ("k_w,J_m", "--fit k_w: the current-commanded model"),
    ("k_t,J_m,B_m", "--fit k_t,J_m,B_m: these logs cannot tell k_t, J_m, B_m apart"),
])
def test_what_the_current_commanded_model_cannot_fit_is_refused(tmp_path, wall_log, capsys, fit, words):
    f, log = wall_log
    out = tmp_path / "fitted.toml"
    assert main(["identify", "--params", str(f), "--log", str(log), "--input", "current", "--output", "theta",
                 "--fit", fit, "--out", str(out), "--report", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("haa-sym: error: " + words), err
    assert not out.exists() and not (tmp_path / "r.json").exists()


def test_a_torque_reference_fit_of_a_current_commanded_file_names_the_current_input(tmp_path, wall_log, capsys):
    f, log = wall_log
    out = tmp_path / "fitted.toml"
    assert main(["identify", "--params", str(f), "--log", str(log), "--input", "torque_ref", "--output", "theta",
                 "--fit", "J_m", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "structure = 'impedance_current'" in err and \
        err.endswith("allowed: --input current (the log's current command, A)"), err
    assert not out.exists()


@pytest.mark.parametrize("value", ["0", "-1e-4", "nan", "inf"])
def test_max_substep_is_checked(tmp_path, wall_log, capsys, value):
    f, log = wall_log
    out = tmp_path / "fitted.toml"
    assert main(["identify", "--params", str(f), "--log", str(log), "--input", "current", "--output", "theta",
                 "--fit", "J_m", f"--max-substep={value}", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"haa-sym: error: --max-substep {float(value)!r}; allowed: a "
                                                         "positive finite number of seconds"), err
    assert not out.exists()


def _refused(keys, value, initial, near):
    from haa_sym.errors import ParameterError
    from haa_sym.fit.identify import FitResult, refuse_unreliable
    n = len(keys)
    r = FitResult(keys=keys, value=np.array(value), initial=np.array(initial), ci95=np.zeros((n, 2)),
                  covariance=np.eye(n), rms_initial={}, rms_fitted={}, iterations=1, samples=10, sampling={},
                  outputs=("theta",), inputs=("current",),
                  meta={"condition_number": 3.2e13, "near_null_keys": near, "converged": True})
    with pytest.raises(ParameterError) as e:
        refuse_unreliable(r)
    return str(e.value)


def test_a_near_null_direction_along_one_key_says_the_logs_do_not_determine_it():
    """One key alone in the near-null direction (the QDD leg's tau_drive run to 0 by delay_drive,
    docs/identify.md, "Current-commanded drives") is not a group to 'tell apart': the line says the
    logs do not determine it, with its start and where the fit took it; a group keeps its words."""
    one = _refused(("J_m", "tau_drive"), [7e-5, 1.52e-11], [6.3e-5, 1e-3], ["tau_drive"])
    assert "these logs do not determine tau_drive (run from 0.001 to 1.52e-11) (condition number 3.2e+13" in one, one
    assert "apart" not in one
    two = _refused(("k_t", "J_m"), [0.07, 1e-4], [0.075, 1e-4], ["k_t", "J_m"])
    assert "these logs cannot tell k_t, J_m apart (condition number" in two, two


@pytest.mark.slow
def test_the_qdd_legs_lag_and_delay_together_are_refused_naming_the_lag(tmp_path, capsys):
    """The QDD leg's lag 0.5 ms behind a 1.5 ms delay, J_m, B_m, tau_drive, delay_drive fitted
    together: the lag runs to 0 and the delay takes the whole 2 ms; one line, exit 2, nothing written."""
    f = _file(tmp_path, "qdd_leg", _drive(5e-4, 1.5e-3))
    log = _simulate(tmp_path, f, 5, 0.05, 0.5, {"J_m": 7e-5, "B_m": 5e-4, "tau_drive": 5e-4})
    capsys.readouterr()
    out = tmp_path / "fitted.toml"
    assert main(["identify", "--params", str(f), "--log", str(log), "--input", "current", "--output", "theta",
                 "--fit", "J_m,B_m,tau_drive,delay_drive", "--set", "B_m=0.001", "--set", "tau_drive=0.001",
                 "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(
        "haa-sym: error: --fit J_m,B_m,tau_drive,delay_drive: these logs do not determine tau_drive (run from 0.001 to "), err
    assert not out.exists()
