"""The current-commanded simulation (impedance_current) against an independent one written here:
the haptic wall's rotor and the QDD leg's rotor-gearbox-leg chain by hand (checked against the
plant the simulation uses), integrated by scipy's solve_ivp (DOP853) from switch to switch with
the current held; the virtual wall's controller by hand (the average of N_av differences, the
impedance law, T_ref / (k_t N)); the current limit, then the supply's window
(+-V_max - k_w dtheta_m) / R (docs/simulate.md, "A current command"), then the drive's dead time
(a list of past commands) and lag (one more ODE state); Coulomb friction as the smooth tanh."""
import math

import numpy as np
import pytest
import scipy.integrate

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import simulate
from haa_sym.loop.plant import continuous_plant, current_commanded
from haa_sym.model.limits import Limits

RTOL_IVP = 1e-11


def hand_plant(p):
    """(A, b_I, b_dist, rotor velocity index, body velocity indices, inertias) of dx/dt = A x +
    b_I I + b_dist T_dist, the motor current I imposed. Haptic wall: [theta_m, dtheta_m];
    QDD leg: [theta_m, dtheta_m, theta_leg, dtheta_leg], gearbox torque
    T_gb = K (theta_m / N - theta_leg) + D (dtheta_m / N - dtheta_leg) on the leg, T_gb / N back on
    the rotor."""
    pl = p.plant
    if not pl.topology.bodies:
        A = np.array([[0.0, 1.0], [0.0, -pl.B_m / pl.J_m]])
        return A, np.array([0.0, pl.k_t / pl.J_m]), np.array([0.0, 1.0 / pl.J_m]), {"m": (1, pl.J_m)}
    N, K, D = pl.N, pl.K_gb, pl.D_gb
    gb = np.array([K / N, D / N, -K, -D])
    A = np.zeros((4, 4))
    A[0, 1] = A[2, 3] = 1.0
    A[1] = (-np.eye(4)[1] * pl.B_m - gb / N) / pl.J_m
    A[3] = (gb - np.eye(4)[3] * pl.B_leg - np.eye(4)[2] * pl.K_leg) / pl.J_leg
    return (A, np.eye(4)[1] * pl.k_t / pl.J_m, np.eye(4)[3] / pl.J_leg,
            {"m": (1, pl.J_m), "leg": (3, pl.J_leg)})


def hand_simulation(p, P, D, lim: Limits, n, T_dist, tau=0.0, delay=0.0):
    pl, Ts, Nav = p.plant, p.controller.Ts, p.controller.N_av
    A, bI, bd, vel = hand_plant(p)
    nx = A.shape[0]
    vs = lim.friction_velocity
    fr = {vel[b]: (Fc, vel[b][1]) for b, Fc in lim.friction.items() if Fc > 0}
    whole = int(math.floor(delay / Ts + 1e-9))
    frac = delay - whole * Ts
    frac = 0.0 if frac < 1e-9 * Ts else frac

    def f(t, x, I):
        xm = x[:nx]
        cur = x[nx] if tau else I
        dx = A @ xm + bI * cur + bd * T_dist
        for (i, J), (Fc, _) in ((k, v) for k, v in zip(fr, fr.values())):
            dx[i] -= Fc * math.tanh(xm[i] / vs) / J
        return np.append(dx, (I - x[nx]) / tau) if tau else dx

    x = np.zeros(nx + (1 if tau else 0))
    enc = 1.0 / pl.N                      # the encoder on the rotor: theta_m / N
    theta_hist = [0.0] * Nav
    cmds = [0.0] * (whole + 2)            # past clipped commands, newest last
    held = 0.0                            # the current held up to t_k (no lag)
    I_max = math.inf if lim.I_max is None else lim.I_max
    V_max = math.inf if lim.V_max is None else lim.V_max
    out = {k: np.empty(n) for k in ("theta", "velocity", "torque", "voltage", "current")}
    for k in range(n):
        th = enc * x[0]
        w = x[1]
        cur = x[nx] if tau else held
        v_d = (th - theta_hist[-Nav]) / (Nav * Ts)
        theta_hist.append(th)
        T_ref = -(P * th + D * v_d)
        I = min(max(T_ref / (pl.k_t * pl.N), -I_max), I_max)
        lo, hi = (-V_max - pl.k_w * w) / pl.R, (V_max - pl.k_w * w) / pl.R
        I = min(max(I, lo), hi)
        port = vel.get(pl.topology.port, vel["m"])[0] if pl.topology.port != "rotor" else 1
        out["theta"][k], out["velocity"][k] = th, x[port]
        out["current"][k], out["torque"][k], out["voltage"][k] = cur, pl.k_t * pl.N * cur, I
        cmds.append(I)
        pieces = [(frac, cmds[-2 - whole]), (Ts - frac, cmds[-1 - whole])] if frac else [(Ts, cmds[-1 - whole])]
        for h, u in pieces:
            x = scipy.integrate.solve_ivp(f, (0, h), x, args=(u,), method="DOP853", rtol=RTOL_IVP,
                                          atol=1e-14).y[:, -1]
            held = u
    return out


@pytest.mark.parametrize("name", ["haptic_wall", "qdd_leg"])
def test_hand_plant_is_the_current_commanded_plant(name):
    p = load_params(name)
    cont = current_commanded(continuous_plant(p.plant))
    A, bI, bd, _ = hand_plant(p)
    np.testing.assert_allclose(cont.A, A, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(cont.B[:, 0], bI, rtol=1e-12)
    np.testing.assert_allclose(cont.B[:, cont.input_names.index("T_dist")], bd, rtol=1e-12)


CASES = {
    # the virtual wall above its passive stiffness with rotor friction and a 4 A limit
    "wall": ("haptic_wall", 6.0, 0.001, Limits(I_max=4.0, friction={"m": 0.01}, friction_velocity=0.05), 0.0, 0.0),
    # and with a 6 V supply, a 2 ms lag and 1.4 samples of dead time
    "wall+drive": ("haptic_wall", 6.0, 0.001, Limits(I_max=4.0, V_max=6.0, friction={"m": 0.01},
                                                     friction_velocity=0.05), 0.002, 0.0014),
    # the QDD leg with the leg's friction, a 3 A limit, a 3 V supply
    "qdd": ("qdd_leg", 150.0, 0.5, Limits(I_max=3.0, V_max=3.0, friction={"leg": 0.2}, friction_velocity=0.05),
            0.0, 0.0),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_current_command_with_friction_and_clip_agrees_with_solve_ivp(case):
    name, P, D, lim, tau, delay = CASES[case]
    p = load_params(name).with_values(tau_drive=tau, delay_drive=delay)
    n, T_dist = 150, 1.5
    s = simulate(ClosedLoop(p, basis=False), P, D, limits=lim, experiment="disturbance-step", amplitude=T_dist,
                 duration=(n - 1) * p.controller.Ts, rtol=1e-9)
    ref = hand_simulation(p, P, D, lim, n, T_dist, tau, delay)
    assert s.saturated.sum() >= 5                            # the clip acts
    for c in ("theta", "velocity", "torque", "voltage", "current"):
        err = np.abs(getattr(s, c) - ref[c]).max() / np.abs(ref[c]).max()
        assert err <= 1e-6, (c, err)
