"""The friction simulation of identify (haa_sym.fit.friction): its sensitivities against finite
differences, its outputs against an independent solve_ivp with the same tanh friction, a synthetic
fit recovering Fc_m, and the RMD X8 SEA stiffness ramp (real log) fitted with friction."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate

from haa_sym.fit.friction import _phi1, _phi_s, friction_entries, simulate_friction
from haa_sym.fit.identify import Experiment, FitOptions, identify
from haa_sym.fit.model import open_loop_model
from haa_sym.io.logs import Log, read_log
from haa_sym.model.params import load_params

DATA = Path(__file__).parent / "data" / "real-logs" / "itregear-sea"
KEYS = ("k_t", "J_m", "B_m", "K_spring", "Fc_m")
FC, VS = 0.02, 0.01


def _sea(limits=None):
    """The SEA's file without its [drive] lag and delay (the simulations here are the plant's)."""
    p = load_params(DATA / "rmdx8_sea.toml").with_values(tau_drive=0.0, delay_drive=0.0)
    return dataclasses.replace(p, limits=dataclasses.replace(p.limits, **(limits or {})))


def _model(params, fc=FC, keys=KEYS):
    pk = tuple(k for k in keys if not k.startswith("Fc_"))
    m = open_loop_model(params.plant, pk, ("current",), ("torque", "theta"))
    pad = [pk.index(k) if k in pk else None for k in keys]

    def full(d):
        return np.stack([d[i] if i is not None else np.zeros(d.shape[1:]) for i in pad])
    m = type(m)(m.A, m.B, m.C, m.D, full(m.dA), full(m.dB), full(m.dC), full(m.dD))
    return m, friction_entries(params.plant, keys, ("current",), m.A.shape[0], {"m": fc}, VS)


def _excitation(n, seed=0):
    rng = np.random.default_rng(seed)
    dt = 2e-3 * (0.5 + rng.random(n - 1))           # a jittered log: every interval its own
    t = np.concatenate([[0.0], np.cumsum(dt)])
    u = (4 * np.sin(2 * np.pi * 2 * t) + 1.5 * np.sin(2 * np.pi * 13 * t) + 0.5 * rng.standard_normal(n))[:, None]
    return dt, u


def _reference(m, fr, dt, u, fc, rtol=1e-10):
    """solve_ivp (Radau, rtol ``rtol``) of dx/dt = A x + B u - W Fc tanh(v / v_s), u held per interval."""
    w, j = fr.W[:, 0], fr.sel[0]
    e_j = np.eye(m.A.shape[0])[j]
    x, X = np.zeros(m.A.shape[0]), []
    X.append(x)
    for k in range(len(dt)):
        sol = scipy.integrate.solve_ivp(lambda t, x: m.A @ x + m.B[:, 0] * u[k, 0] - w * fc * np.tanh(x[j] / VS),
                                        (0.0, dt[k]), x, method="Radau", rtol=rtol, atol=1e-4 * rtol,
                                        jac=lambda t, x: m.A - np.outer(w, e_j) * fc / VS / np.cosh(x[j] / VS) ** 2)
        x = sol.y[:, -1]
        X.append(x)
    return np.array(X) @ m.C.T + u @ m.D.T


def test_the_modes_scalar_functions_against_mpmath():
    """(e^w - 1) / w and int_0^1 tau e^{w tau} d tau (the substeps' matrices' modal factors)
    against mpmath at 80 digits, near 0 (series, cancellation) and far from it."""
    import mpmath
    mpmath.mp.dps = 80
    rng = np.random.default_rng(1)
    w = np.concatenate([(rng.normal(size=40) + 1j * rng.normal(size=40)) * s for s in (1e-6, 1e-2, 0.7, 3.0, 30.0)]
                       + [np.array([0.0, 1e-300, 1.0, -1.0, 2j, -40.0])])
    z = [mpmath.mpc(v) for v in w]
    ref1 = [complex(mpmath.expm1(v) / v) if v != 0 else 1.0 for v in z]
    refs = [complex((mpmath.exp(v) * (v - 1) + 1) / v ** 2) if abs(v) > 1e-20 else 0.5 + complex(v) / 3 for v in z]
    assert np.allclose(_phi1(w), ref1, rtol=1e-14, atol=0)
    assert np.allclose(_phi_s(w), refs, rtol=1e-13, atol=0)


def test_sensitivities_match_finite_differences():
    P = _sea()
    m, fr = _model(P)
    dt, u = _excitation(300)
    y, dy = simulate_friction(m, fr, dt, u)
    for j, k in enumerate(KEYS):
        v0 = FC if k == "Fc_m" else getattr(P.plant, k)
        e = 1e-5 * v0

        def sim(v):
            q = P if k == "Fc_m" else P.with_values(**{k: v})
            m2, fr2 = _model(q, v if k == "Fc_m" else FC)
            return simulate_friction(m2, fr2, dt, u, sensitivities=False)[0]
        fd = (sim(v0 + e) - sim(v0 - e)) / (2 * e)
        assert np.abs(fd - dy[j]).max() <= 1e-5 * np.abs(dy[j]).max(), k


def test_c_kernel_equals_the_python_recursion():
    m, fr = _model(_sea())
    dt, u = _excitation(200)
    # the last key's derivative also carries a moving-interval term (as the delay's does)
    dlen = np.random.default_rng(2).choice([-1.0, 0.0, 1.0], size=dt.size)
    y, dy = simulate_friction(m, fr, dt, u, backend="c", dlen=dlen, delay_key=4)
    yp, dyp = simulate_friction(m, fr, dt, u, backend="python", dlen=dlen, delay_key=4)
    assert np.abs(y - yp).max() <= 1e-12 * np.abs(y).max()
    assert np.abs(dy - dyp).max() <= 1e-10 * np.abs(dy).max()


@pytest.mark.slow
def test_against_solve_ivp_second_order_in_the_substep():
    """Against solve_ivp (Radau, rtol 1e-10; 120 jittered samples), the rms error over each
    output's peak at substeps of 1, 0.5, 0.25, 0.125 ms: the end-point scheme alone (order 1) falls
    about 2x per halving, Richardson's extrapolation (the default) 3.7-3.8x below 0.5 ms (its residue: a
    velocity reversal's torque switch inside a substep, not smooth in h) and is below the
    end-point scheme at every substep."""
    m, fr = _model(_sea())
    dt, u = _excitation(120, seed=1)
    ref = _reference(m, fr, dt, u, FC)
    hs = (1e-3, 5e-4, 2.5e-4, 1.25e-4)
    def rms(h, order):
        y = simulate_friction(m, fr, dt, u, sensitivities=False, max_substep=h, order=order)[0]
        return np.sqrt(np.mean(((y - ref) / np.abs(ref).max(axis=0)) ** 2))
    err = {order: np.array([rms(h, order) for h in hs]) for order in (1, 2)}
    # measured: order 1 4.4e-3 .. 4.9e-4 (3.6e-3, 1.9e-3, 9.3e-4, 4.9e-4), order 2 1.4e-3, 1.0e-3,
    # 2.8e-4, 7.3e-5
    assert 3 < err[1][1] / err[1][3] < 5.5            # measured 4.0: first order
    assert err[2][1] / err[2][3] > 8                   # measured 13.9: second order
    assert np.all(err[2] < err[1])
    assert err[2][2] < 5e-4


def test_stiff_friction_stays_bounded():
    """Fc / (v_s J) h = 50 per substep at stick: an explicit stage would diverge."""
    P = _sea()
    m, fr = _model(P, fc=0.05)
    fr = dataclasses.replace(fr, v_s=1e-4)
    dt, u = _excitation(400)
    y, _ = simulate_friction(m, fr, dt, u * 0.01, sensitivities=False)
    assert np.all(np.isfinite(y)) and np.abs(y[:, 0]).max() < 0.2


def _stamped_log(name, dt, signals):
    """A log on the stamps of the intervals ``dt`` (s), from t = 0."""
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return Log(name, float(dt.mean()), signals, {}, "0", t=t, uniform=False)


@pytest.mark.slow
def test_synthetic_fit_recovers_fc_within_3_percent():
    P = _sea()
    m, fr = _model(P, fc=0.03)
    dt, u = _excitation(300, seed=4)
    y = _reference(m, fr, dt, u, 0.03, rtol=1e-7)      # 1e-7: far inside the 1 % noise; 1e-10 took 25 s
    rng = np.random.default_rng(5)
    y = y + 0.01 * y.std(axis=0) * rng.standard_normal(y.shape)
    log = _stamped_log("syn", dt, {"current": u[:, 0], "torque": y[:, 0], "theta": y[:, 1]})
    start = P.with_values(k_t=0.18, K_spring=2500.0)
    r = identify([Experiment(log, start)], ("k_t", "K_spring", "Fc_m"), ("current",), ("torque", "theta"),
                 friction={"Fc_m": 0.02})
    got = dict(zip(r.keys, r.value))
    assert abs(got["Fc_m"] / 0.03 - 1) < 0.03
    assert abs(got["k_t"] / P.plant.k_t - 1) < 0.03 and abs(got["K_spring"] / P.plant.K_spring - 1) < 0.03


def test_offsets_are_recovered_and_reported():
    P = _sea()
    m, fr = _model(P, fc=0.03)
    dt = np.full(1999, 2e-3)
    _, u = _excitation(2000, seed=2)
    y, _ = simulate_friction(m, fr, dt, u, sensitivities=False)
    log = Log("off", 2e-3, {"current": u[:, 0], "torque": y[:, 0] + 0.05, "theta": y[:, 1] - 1e-4}, {}, "0")
    kw = dict(friction={"Fc_m": 0.03})
    # fitted at the substep the log was made with (0.5 ms), so that the fit can be exact; the
    # default would choose 0.125 ms here, and a given coarser one is said in one warning
    with pytest.warns(UserWarning, match=r"--max-substep 0.0005 s: the friction simulation's estimated error"):
        r = identify([Experiment(log, P.with_values(k_t=0.17))], ("k_t",), ("current",), ("torque", "theta"),
                     FitOptions(max_substep=5e-4), offsets=("torque", "theta"), **kw)
    assert abs(r.value[0] / P.plant.k_t - 1) < 1e-6
    assert abs(r.offsets["off"]["torque"] - 0.05) < 1e-7 and abs(r.offsets["off"]["theta"] + 1e-4) < 1e-10
    assert r.report()["offsets"] == r.offsets


def _stamped(name):
    """A real log as measured (its own stamps, split at its gaps)."""
    return read_log(DATA / name, ("current",), ("torque", "theta"))


@pytest.mark.slow
def test_stiffness_ramp_run50_with_friction():
    """The 2 Nm stiffness ramps (real logs, their own stamps and gaps, the file's drive lag and
    delay, offsets on both outputs, Fc_m on the rotor at v_s = 1e-3 rad/s): run 50's K_spring
    between 2100 and 2350 Nm/rad, and run 50's HAC interval covering run 51's value (measured:
    2289.4 [2264.7, 2314.4] against 2279.7; the white-noise interval [2286.1, 2292.6] does not)."""
    p = load_params(DATA / "rmdx8_sea.toml")
    p = dataclasses.replace(p, limits=dataclasses.replace(p.limits, friction={"m": 0.02}, friction_velocity=1e-3))
    fits = {}
    for run in ("50", "51"):
        r = identify([Experiment(_stamped(f"stiffness2Nm_run{run}_stamped.csv"), p)], ("k_t", "K_spring", "Fc_m"),
                     ("current",), ("torque", "theta"), offsets=("torque", "theta"))
        fits[run] = (dict(zip(r.keys, r.value)), dict(zip(r.keys, r.ci95)))
    got, ci = fits["50"]
    assert 2100 < got["K_spring"] < 2350
    assert got["Fc_m"] > 0.01          # friction is what the ramp's hysteresis shows, not zero
    assert ci["K_spring"][0] <= fits["51"][0]["K_spring"] <= ci["K_spring"][1]


def _drive_case(fc):
    """The SEA behind a 30 ms lag and a 3.3 ms delay, on jittered stamps with a 0.2 s gap."""
    P = load_params(DATA / "rmdx8_sea.toml").with_values(tau_drive=0.03, delay_drive=0.0033)
    keys = ("k_t", "K_spring", "tau_drive", "delay_drive", "Fc_m")
    pk = keys[:-1]
    m = open_loop_model(P.plant, pk, ("current",), ("torque", "theta"), P.drive)
    m = type(m)(m.A, m.B, m.C, m.D, *(np.concatenate([d, np.zeros((1,) + d.shape[1:])])
                                      for d in (m.dA, m.dB, m.dC, m.dD)))
    fr = friction_entries(P.plant, keys, ("current",), m.A.shape[0], {"m": fc}, VS)
    dt, u = _excitation(500, seed=3)
    dt[250] = 0.2
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return P, keys, m, fr, t, u


def test_friction_on_stamps_with_lag_delay_and_segments_reduces_to_the_linear_path():
    """Fc -> 0: the friction path on a log's own stamps (the delayed command switching inside the
    intervals, a gap with the second segment's state estimated) gives the linear path's outputs,
    sensitivities (the delay's among them) and estimated-state count (simulate_stamps, another
    code: modal recursion, exact delay derivative)."""
    from haa_sym.fit.friction import simulate_friction_stamps
    from haa_sym.fit.model import simulate_stamps
    P, keys, m, fr, t, u = _drive_case(1e-12)
    kw = dict(delay=0.0033, delay_key=3, starts=(0, 251), estimate=(False, True))
    y_lin, _, _ = simulate_stamps(m, t, u, **{**kw, "estimate": (False, False)}, sensitivities=False)
    w = np.std(y_lin, axis=0)
    y_meas = y_lin + 0.01 * w * np.random.default_rng(0).standard_normal(y_lin.shape)
    y_lin, dy_lin, r_lin = simulate_stamps(m, t, u, **kw, y=y_meas, weights=w)
    y_fr, dy_fr, r_fr = simulate_friction_stamps(m, fr, t, u, **kw, y=y_meas, weights=w, max_substep=2.5e-4)
    assert r_fr == r_lin
    assert np.abs(y_fr - y_lin).max() <= 1e-6 * np.abs(y_lin).max()
    for j, k in enumerate(keys[:-1]):
        assert np.abs(dy_fr[j] - dy_lin[j]).max() <= 1e-4 * np.abs(dy_lin[j]).max(), k


def test_delay_derivative_with_the_switches_on_the_stamps():
    """A uniform log whose delay is a whole number of periods (every switch on a stamp: no grid
    interval of its own, so a scheme that differentiates interval lengths must keep them as
    intervals of length 0): with Fc -> 0 d y / d delay equals the linear path's exact one, and with
    friction the forward difference (the switch moving into the intervals: the substeps on its
    other side differ, so the scheme's two one-sided derivatives differ by its own error, 3e-3)."""
    from haa_sym.fit.friction import simulate_friction_stamps
    from haa_sym.fit.model import simulate_stamps
    P, keys, m, fr, _, u = _drive_case(1e-12)
    t = np.arange(u.shape[0]) * 2e-3
    kw = dict(delay=0.004, delay_key=3, starts=(0,), estimate=(False,))
    y_lin, dy_lin, _ = simulate_stamps(m, t, u, **kw)
    y_fr, dy_fr, _ = simulate_friction_stamps(m, fr, t, u, **kw)
    assert np.abs(dy_lin[3]).max() > 0
    assert np.abs(dy_fr[3] - dy_lin[3]).max() <= 1e-4 * np.abs(dy_lin[3]).max()
    P, keys, m, fr, _, u = _drive_case(0.03)
    y, dy, _ = simulate_friction_stamps(m, fr, t, u, **kw)
    e = 1e-8
    yp = simulate_friction_stamps(m, fr, t, u, **{**kw, "delay": 0.004 + e}, sensitivities=False)[0]
    assert np.abs((yp - y) / e - dy[3]).max() <= 1e-4 * np.abs(dy[3]).max()


def test_friction_on_stamps_sensitivities_match_finite_differences():
    """With friction at stick-slip strength and the delay: d y / d p of the stamped friction path
    (segments from rest) against central differences of the same simulation."""
    from haa_sym.fit.friction import simulate_friction_stamps
    P, keys, m, fr, t, u = _drive_case(0.03)
    kw = dict(starts=(0, 251), estimate=(False, False), max_substep=2.5e-4)
    y, dy, _ = simulate_friction_stamps(m, fr, t, u, delay=0.0033, delay_key=3, **kw)
    vals = {"k_t": P.plant.k_t, "K_spring": P.plant.K_spring, "tau_drive": 0.03, "delay_drive": 0.0033, "Fc_m": 0.03}
    for j, k in enumerate(keys):
        e = 1e-5 * vals[k]

        def sim(v):
            q = {**vals, k: v}
            Q = P.with_values(**{x: q[x] for x in keys[:-1]})
            m2 = open_loop_model(Q.plant, (), ("current",), ("torque", "theta"), Q.drive)
            fr2 = friction_entries(Q.plant, (), ("current",), m2.A.shape[0], {"m": q["Fc_m"]}, VS)
            return simulate_friction_stamps(m2, fr2, t, u, delay=q["delay_drive"], sensitivities=False, **kw)[0]
        fd = (sim(vals[k] + e) - sim(vals[k] - e)) / (2 * e)
        assert np.abs(fd - dy[j]).max() <= 1e-3 * np.abs(dy[j]).max(), k
